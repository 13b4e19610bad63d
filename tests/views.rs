//! Many views in one pass: each plain view gives the bits a single frustum pass gives, and each light view keeps
//! every shadow caster the exact reference (`cullet_truth::shadows`) needs, for cascades, cube faces with near
//! planes down to 1e-4, orthographic views with huge extents, and cameras far from the origin.

use cullet::frustum::{
    FrustumOptions, Light, SimdBackend, View, cascade_clip_from_relative, cascade_frustum, cube_face_cameras,
    cull_frustum, cull_views, cull_views_with,
};
use cullet::{BoundsStore, Camera, DepthConvention, Frustum, VisibleSet};
use cullet_test_support::store_of;
use cullet_truth::half_spaces::{exact_half_spaces, half_spaces, moved};
use cullet_truth::shadows::{ExactLight, caster_needed};
use glam::{DVec4, Vec3};
use proptest::prelude::*;

/// Cascade splits, in view distance.
const SPLITS: [f32; 5] = [0.0, 5.0, 20.0, 60.0, 150.0];

/// A light view under test: what it culls with, and its exact half-spaces and light relative to the camera.
struct LightView {
    view: View,
    half_spaces: Vec<DVec4>,
    light: ExactLight,
}

/// The camera's four cascades for a sun shining along `direction`, and one orthographic view 100 km across.
fn cascades(camera: &Camera, direction: Vec3) -> Vec<LightView> {
    let receivers = camera.frustum().unwrap();
    SPLITS
        .windows(2)
        .chain([[0.0, 1.0e5].as_slice()])
        .map(|split| {
            let frustum = cascade_frustum(camera, direction, split[0], split[1]).unwrap();
            let matrix = cascade_clip_from_relative(camera, direction, split[0], split[1]).unwrap();
            LightView {
                view: View::shadow_casters(frustum, Light::Directional { direction }, &receivers).unwrap(),
                half_spaces: half_spaces(matrix, DepthConvention::Standard),
                light: ExactLight::Directional(direction.as_dvec3()),
            }
        })
        .collect()
}

/// The six cube faces of a point light at `lamp`.
fn cube_faces(camera: &Camera, lamp: Vec3, near: f32, far: Option<f32>) -> Vec<LightView> {
    let receivers = camera.frustum().unwrap();
    let from_camera = lamp.as_dvec3() - camera.position.as_dvec3();
    cube_face_cameras(lamp, near, far)
        .iter()
        .map(|face| LightView {
            view: View::shadow_casters(face.frustum().unwrap(), Light::Point { position: lamp }, &receivers).unwrap(),
            half_spaces: moved(&exact_half_spaces(face), lamp.as_dvec3(), camera.position.as_dvec3()),
            light: ExactLight::Point(from_camera),
        })
        .collect()
}

/// Culls `plain` and `lights` in one pass; checks that every backend gives the same bits, each plain view
/// against its own single-view pass and each light view against the exact reference. Returns the light views' kept counts.
fn cull_and_check(store: &BoundsStore, camera: &Camera, plain: &[Frustum], lights: &[LightView]) -> Vec<usize> {
    let views: Vec<View> =
        plain.iter().map(|&frustum| View::new(frustum)).chain(lights.iter().map(|light| light.view.clone())).collect();
    let mut visible = Vec::new();
    let counts = cull_views(store, &views, &mut visible);
    let mut scalar = Vec::new();
    assert_eq!(cull_views_with(store, &views, SimdBackend::Scalar, &mut scalar), counts);
    assert_eq!(scalar, visible, "the scalar and SIMD backends disagree");
    for ((frustum, set), &count) in plain.iter().zip(&visible).zip(&counts) {
        let mut single = VisibleSet::default();
        assert_eq!(cull_frustum(store, frustum, FrustumOptions::default(), &mut single), count);
        assert_eq!(&single, set, "one pass over many views differs from a pass of its own");
    }
    let receivers = exact_half_spaces(camera);
    let origin = camera.position.as_dvec3();
    for ((light, set), &count) in lights.iter().zip(&visible[plain.len()..]).zip(&counts[plain.len()..]) {
        assert_eq!(set.count(), count);
        for slot in 0..store.len() {
            let bounds = store.get(slot).unwrap();
            let center = bounds.center.as_dvec3() - origin;
            let (min, max) = (center - bounds.half_extent.as_dvec3(), center + bounds.half_extent.as_dvec3());
            if !set.contains(slot) && caster_needed(&light.half_spaces, &receivers, light.light, min, max) {
                panic!("a light view culled a caster it needs: {bounds:?}, {:?}, camera {camera:?}", light.light);
            }
        }
    }
    counts[plain.len()..].to_vec()
}

fn camera_strategy() -> impl Strategy<Value = Camera> {
    (
        prop::sample::select(vec![0.0f32, 1.0e5, 1.0e7]),
        prop::array::uniform3(-10.0f32..10.0),
        prop::array::uniform3(-1.0f32..1.0),
        prop::sample::select(vec![1e-4f32, 0.1, 1.0]),
        prop::option::of(100.0f32..400.0),
    )
        .prop_filter("forward must not be parallel to up", |(_, _, f, ..)| {
            Vec3::from(*f).normalize_or_zero().cross(Vec3::Y).length() > 1e-2
        })
        .prop_map(|(offset, position, forward, near, far)| Camera {
            position: Vec3::splat(offset) + Vec3::from(position),
            forward: Vec3::from(forward),
            near,
            far,
            ..Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z)
        })
}

/// Boxes within 80 units of the camera, from 1 cm to 10 m across.
fn boxes_strategy() -> impl Strategy<Value = Vec<(Vec3, Vec3)>> {
    prop::collection::vec((prop::array::uniform3(-80.0f32..80.0), prop::array::uniform3(0.005f32..5.0)), 1..80)
        .prop_map(|boxes| boxes.into_iter().map(|(c, e)| (Vec3::from(c), Vec3::from(e))).collect())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn light_views_keep_every_caster_they_need(
        camera in camera_strategy(),
        boxes in boxes_strategy(),
        sun in prop::array::uniform3(-1.0f32..1.0),
        lamp in prop::array::uniform3(-30.0f32..30.0),
        lamp_near in prop::sample::select(vec![1e-4f32, 0.05, 1.0]),
        lamp_far in prop::option::of(20.0f32..90.0),
    ) {
        let sun = Vec3::from(sun);
        prop_assume!(sun.length() > 0.1);
        let boxes: Vec<(Vec3, Vec3)> = boxes.into_iter().map(|(c, e)| (camera.position + c, e)).collect();
        let store = store_of(&boxes);
        let lamp = camera.position + Vec3::from(lamp);
        let mut lights = cascades(&camera, sun);
        lights.extend(cube_faces(&camera, lamp, lamp_near, lamp_far));
        // Plain views: the camera, an orthographic view 100 km across, and the lamp's faces unrestricted.
        let mut plain = vec![camera.frustum().unwrap(), cascade_frustum(&camera, sun, 0.0, 1.0e5).unwrap()];
        plain.extend(cube_face_cameras(lamp, lamp_near, lamp_far).map(|face| face.frustum().unwrap()));
        cull_and_check(&store, &camera, &plain, &lights);
    }
}

/// A sun straight overhead, a camera looking along -z from the origin: a caster far above the cascade's box is
/// kept (its shadow falls into view), a caster behind the camera is dropped (its shadow falls behind it) though
/// it lies inside the cascade's box, and a plain view of the same box keeps both.
#[test]
fn a_cascade_keeps_casters_above_it_and_drops_those_whose_shadows_fall_out_of_view() {
    let camera = Camera { far: Some(100.0), ..Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z) };
    let sun = Vec3::NEG_Y;
    let above = (Vec3::new(0.0, 500.0, -10.0), Vec3::ONE);
    let behind = (Vec3::new(0.0, 0.0, 6.0), Vec3::splat(0.5));
    let store = store_of(&[above, behind]);
    let lights = cascades(&camera, sun);
    let plain = [cascade_frustum(&camera, sun, 0.0, 20.0).unwrap()];
    let kept = cull_and_check(&store, &camera, &plain, &lights);
    let mut visible = Vec::new();
    cull_views(&store, &[View::new(plain[0]), lights[1].view.clone()], &mut visible);
    assert!(!visible[0].contains(0) && visible[0].contains(1), "the plain cascade box: {:?}", visible[0]);
    assert!(visible[1].contains(0) && !visible[1].contains(1), "the caster view: {:?}", visible[1]);
    assert_eq!(kept[1], 1);
}

/// Every light view of a camera on real scenes' paths: the built-in city and truck_town (where the shared
/// scenes are present), a sun's cascades and a lamp's faces near the camera, judged by the exact reference.
#[test]
fn scenes_lose_no_caster_along_their_paths() {
    use cullet::scene::city::{CityParams, CityScene};
    let city = CityScene::generate(CityParams::with_objects(20_000));
    let mut scenes = vec![("city", city.scene.clone(), city.flythrough())];
    if let Some(town) = cullet_test_support::shared_scene("truck_town/town_model.gltf") {
        scenes.push(("truck_town", town.scene.clone(), town.scene.orbit_path()));
    }
    for (name, scene, path) in scenes {
        let store = store_of_scene(&scene);
        let mut casters = [0, 0];
        for frame in 0..4 {
            let camera = path.camera_at(path.duration() * (frame as f32 + 0.5) / 4.0, 16.0 / 9.0);
            let mut lights = cascades(&camera, Vec3::new(0.35, -1.0, 0.25));
            lights.extend(cube_faces(&camera, camera.position + Vec3::new(4.0, 6.0, -8.0), 1e-4, Some(60.0)));
            let kept = cull_and_check(&store, &camera, &[camera.frustum().unwrap()], &lights);
            casters[0] += kept.iter().sum::<usize>();
            casters[1] += store.len() * lights.len();
        }
        println!("{name}: light views keep {} of {} object-views", casters[0], casters[1]);
    }
}

/// A lamp's faces keep the caster between the lamp and the camera's view, and drop one whose shadow is thrown
/// away from it; bad lights are errors, not silent culls.
#[test]
fn cube_faces_keep_casters_between_the_lamp_and_the_view() {
    let camera = Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z);
    let lamp = Vec3::new(0.0, 10.0, -20.0);
    let between = (Vec3::new(0.0, 5.0, -20.0), Vec3::ONE);
    let away = (Vec3::new(0.0, 10.0, -10.0), Vec3::splat(0.5));
    let store = store_of(&[between, away]);
    let kept = cull_and_check(&store, &camera, &[], &cube_faces(&camera, lamp, 1e-4, None));
    assert_eq!(kept.iter().sum::<usize>(), 1, "kept per face: {kept:?}");
    let receivers = camera.frustum().unwrap();
    let face = cube_face_cameras(lamp, 0.1, None)[0].frustum().unwrap();
    for light in [Light::Point { position: Vec3::NAN }, Light::Directional { direction: Vec3::ZERO }] {
        assert!(View::shadow_casters(face, light, &receivers).is_err());
    }
}

/// The stress suite's scenes and cameras (world offsets up to 1e8, near planes down to 1e-5, fields of view
/// from 0.5 to 179.5 degrees, every depth convention), each with a sun's cascades and a lamp's faces scaled to
/// the scene.
#[test]
fn the_stress_cases_lose_no_caster() {
    for case in cullet_truth::stress::cases() {
        let store = store_of_scene(&case.scene);
        let camera = case.camera;
        let mut lights = cascades(&camera, Vec3::new(0.35, -1.0, 0.25));
        let lamp = camera.position + camera.forward.normalize() * 5.0 + Vec3::Y * 3.0;
        lights.extend(cube_faces(&camera, lamp, 1e-4, None));
        cull_and_check(&store, &camera, &[camera.frustum().unwrap()], &lights);
    }
}

/// A store of `scene`'s objects, entity `i + 1` for object `i`.
fn store_of_scene(scene: &cullet::scene::Scene) -> BoundsStore {
    let mut store = BoundsStore::default();
    for (i, object) in scene.objects.iter().enumerate() {
        let entity = bevy_ecs::entity::Entity::from_raw_u32(i as u32 + 1).unwrap();
        let local = scene.mesh_bounds[object.mesh as usize];
        store.update(entity, &local, &cullet::ObjectTransform(object.transform)).unwrap();
    }
    store
}

/// The pipeline culls the `LightViews` with the camera: the same sets as `cull_views` gives, every object kept
/// where the frustum stage is off, and a bad light reported while the others still cull.
#[test]
fn the_pipeline_culls_light_views_with_the_camera() {
    use bevy_ecs::prelude::*;
    use cullet::frustum::LightSource;
    use cullet::prelude::*;
    let boxes: Vec<(Vec3, Vec3)> = (0..300)
        .map(|i| (Vec3::new((i % 20) as f32 * 6.0 - 60.0, (i / 100) as f32 * 4.0, -((i / 20) as f32) * 5.0), Vec3::ONE))
        .collect();
    let (mut world, mut schedule) = (World::new(), Schedule::default());
    cullet::install(&mut world, &mut schedule, PipelineSettings::default());
    let camera =
        Camera { far: Some(200.0), ..Camera::looking_at(Vec3::new(0.0, 3.0, 10.0), Vec3::new(0.0, 0.0, -30.0)) };
    world.insert_resource(camera);
    for (center, half_extent) in &boxes {
        let local = LocalBounds { center: Vec3::ZERO, half_extent: *half_extent };
        world.spawn((local, ObjectTransform(glam::Affine3A::from_translation(*center))));
    }
    let sun = LightSource::Sun { direction: Vec3::new(0.3, -1.0, 0.2), splits: vec![0.1, 10.0, 40.0] };
    let lamp = LightSource::Lamp { position: Vec3::new(5.0, 8.0, -20.0), near: 0.05, range: Some(40.0) };
    world.insert_resource(LightViews(vec![sun.clone(), lamp.clone()]));
    schedule.run(&mut world);
    world.clear_trackers();

    let store = world.resource::<BoundsStore>();
    let mut expected = Vec::new();
    let built: Vec<_> = [&sun, &lamp].iter().flat_map(|light| light.light_views(&camera).unwrap()).collect();
    let views: Vec<View> = std::iter::once(View::new(camera.frustum().unwrap()))
        .chain(built.iter().map(|light| light.view.clone()))
        .collect();
    let counts = cull_views(store, &views, &mut expected);
    let results = &world.resource::<LightViewsVisible>().0;
    assert_eq!(results.len(), 2 + 6);
    assert_eq!(world.resource::<CameraCuller>().frustum_visible(), &expected[0]);
    for (result, (set, &count)) in results.iter().zip(expected[1..].iter().zip(&counts[1..])) {
        assert_eq!((&result.visible, result.kept), (set, count));
    }
    assert_eq!(results.iter().map(|r| r.light).collect::<Vec<_>>(), [0, 0, 1, 1, 1, 1, 1, 1]);
    let named = world.resource::<LightViewsVisible>().kept_by_view(world.resource::<LightViews>());
    let names: Vec<&str> = named.iter().map(|(name, _)| name.as_str()).collect();
    assert_eq!(
        names,
        ["sun cascade 1", "sun cascade 2", "lamp +x", "lamp -x", "lamp +y", "lamp -y", "lamp +z", "lamp -z"]
    );
    assert!(named.iter().zip(results).all(|((_, kept), result)| *kept == result.kept));
    let stats = *world.resource::<CullStats>();
    assert_eq!((stats.light_views, stats.light_view_casters), (8, counts[1..].iter().sum()));
    assert!(stats.light_view_casters > 0 && stats.light_view_casters < 8 * boxes.len());

    // A lamp with a bad near distance is reported; the sun still culls.
    let bad_lamp = LightSource::Lamp { position: Vec3::new(5.0, 8.0, -20.0), near: 0.0, range: Some(40.0) };
    world.insert_resource(LightViews(vec![sun, bad_lamp]));
    schedule.run(&mut world);
    world.clear_trackers();
    let stats = *world.resource::<CullStats>();
    assert!(stats.light_view_error.is_some());
    assert_eq!(world.resource::<LightViewsVisible>().0.len(), 2);

    // With the frustum stage off, every light view keeps everything.
    world.insert_resource(FrustumSettings { enabled: false });
    schedule.run(&mut world);
    world.clear_trackers();
    assert!(world.resource::<LightViewsVisible>().0.iter().all(|view| view.kept == boxes.len()));
}

/// Culls `scene` from each of `cameras` in turn with a sun's cascades (`splits`) and a lamp 6 m above the first
/// camera (near plane 1e-4), every light view occlusion culled (`min_casters` 1), and judges every light view
/// of every frame exactly at `judge_size` texels; returns the casters hidden over the frames.
fn cull_with_light_occlusion(
    name: &str,
    scene: &cullet::scene::Scene,
    cameras: &[Camera],
    splits: Vec<f32>,
    judge_size: u32,
) -> usize {
    use cullet::culler::LightOcclusionSettings;
    use cullet::frustum::LightSource;
    use cullet::pipeline::{CullStats, LightViews};

    use cullet::culler::OcclusionSettings;
    use cullet::scene::flight::Flight;
    use cullet_truth::shadows::light_view_false_negatives;
    let path = cullet::CameraPath { fov_y_deg: 60.0, near: 0.1, far: None, keys: Vec::new() };
    let mut flight = Flight::new(path, cameras[0].aspect, 1, OcclusionSettings::default(), |world| {
        scene.spawn(world);
    });
    let lamp = cameras[0].position + Vec3::new(0.0, 6.0, 0.0);
    flight.world.insert_resource(LightViews(vec![
        LightSource::Sun { direction: Vec3::new(0.35, -1.0, 0.25), splits },
        LightSource::Lamp { position: lamp, near: 1e-4, range: Some(60.0) },
    ]));
    flight.world.insert_resource(LightOcclusionSettings { min_casters: 1, ..LightOcclusionSettings::default() });
    let mut occluded = 0;
    for (frame, camera) in cameras.iter().enumerate() {
        let stats: CullStats = flight.run_with_camera(*camera, 0.0);
        occluded += stats.light_view_occluded;
        let missed = light_view_false_negatives(&flight.world, &scene.meshes, judge_size);
        assert!(missed.iter().all(|&n| n == 0), "{name}, frame {frame}: needed casters culled {missed:?}");
    }
    println!("{name}: light views' occlusion hid {occluded} casters");
    occluded
}

/// `frames` cameras evenly along `path`.
fn cameras_along(path: &cullet::CameraPath, frames: u32) -> Vec<Camera> {
    (0..frames).map(|frame| path.camera_at(path.duration() * frame as f32 / frames as f32, 16.0 / 9.0)).collect()
}

/// Each light view's own occlusion over the city's fly-through, also 1e5 m from the origin, and truck_town's
/// orbit (where the shared scenes are present, with automatic occluders as the game gives it): casters hidden
/// from their lights are dropped (some, not none), and none that the exact rendering from the light shows at
/// its texel centres is. The sun's last cascade is 10 km deep (orthographic, with huge extents); the lamp's
/// faces have a near plane of 1e-4.
#[test]
fn light_views_drop_only_casters_hidden_from_their_lights() {
    use cullet::scene::city::{CityParams, CityScene};
    let splits = vec![0.1, 12.0, 40.0, 120.0, 1.0e4];
    for offset in [Vec3::ZERO, Vec3::new(1.0e5, 0.0, -1.0e5)] {
        let mut city = CityScene::generate(CityParams::with_objects(4_000));
        city.scene.translate(offset);
        let cameras = cameras_along(&city.flythrough().translated(offset), 5);
        let occluded =
            cull_with_light_occlusion(&format!("city at {offset}"), &city.scene, &cameras, splits.clone(), 512);
        assert!(occluded > 0, "the light views' occlusion hid nothing");
    }
    if let Some(mut town) = cullet_test_support::shared_scene("truck_town/town_model.gltf") {
        use cullet::scene::auto_occluders::{AutoOccluderSettings, add_auto_occluders};
        add_auto_occluders(&mut town.scene, &AutoOccluderSettings::default());
        let cameras = cameras_along(&town.scene.orbit_path(), 3);
        cull_with_light_occlusion("truck_town", &town.scene, &cameras, splits, 512);
    }
}

/// The stress suite's scenes and cameras (world offsets up to 1e8, near planes down to 1e-5, every depth
/// convention, fields of view from 0.5 to 179.5 degrees), each with a sun's cascades and a lamp's faces whose
/// occlusion runs: no light view culls a caster its exact rendering shows.
#[test]
fn the_stress_cases_lose_no_caster_to_light_views_occlusion() {
    for case in cullet_truth::stress::cases() {
        let name = format!("{} = {}", case.sweep, case.value);
        cull_with_light_occlusion(&name, &case.scene, &[case.camera], SPLITS.to_vec(), 256);
    }
}

/// The pipeline's light views' occlusion: a roof facing the sun hides the boxes under it from a cascade (the
/// camera, below the roof, still sees them); turning it off takes effect on the next frame though nothing
/// else changed (an unchanged frame keeps them, unbuilt); and a view whose occlusion hides too little is
/// skipped after a few frames, then re-probed.
#[test]
fn the_pipeline_occludes_light_views_and_gates_them() {
    use bevy_ecs::prelude::*;
    use cullet::frustum::LightSource;
    use cullet::prelude::*;
    let (mut world, mut schedule) = (World::new(), Schedule::default());
    cullet::install(&mut world, &mut schedule, PipelineSettings::default());
    world.insert_resource(Camera::looking_at(Vec3::new(0.0, 2.0, 20.0), Vec3::new(0.0, 0.0, -15.0)));
    // A 20 m roof facing up at 10 m, and 25 boxes under it.
    let corners = [Vec3::new(-10.0, 0.0, 10.0), Vec3::new(10.0, 0.0, 10.0), Vec3::new(10.0, 0.0, -10.0)];
    let far_corner = Vec3::new(-10.0, 0.0, -10.0);
    let roof = Occluder::new(vec![corners[0], corners[1], corners[2], corners[0], corners[2], far_corner]);
    let roof_bounds = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::new(10.0, 0.1, 10.0) };
    let at = |p: Vec3| ObjectTransform(glam::Affine3A::from_translation(p));
    world.spawn((roof_bounds, at(Vec3::new(0.0, 10.0, -15.0)), roof));
    let boxes: Vec<Entity> = (0..25)
        .map(|i| {
            let center = Vec3::new((i % 5) as f32 * 2.0 - 4.0, 0.0, -(i / 5) as f32 * 2.0 - 11.0);
            world.spawn((LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) }, at(center))).id()
        })
        .collect();
    let sun = LightSource::Sun { direction: Vec3::new(0.1, -1.0, 0.05), splits: vec![0.1, 60.0] };
    world.insert_resource(LightViews(vec![sun]));
    world.insert_resource(LightOcclusionSettings { min_casters: 1, ..LightOcclusionSettings::default() });
    let mut frame = |world: &mut World| {
        schedule.run(world);
        world.clear_trackers();
        *world.resource::<CullStats>()
    };
    let stats = frame(&mut world);
    assert_eq!((stats.light_view_occluded, stats.after_occlusion), (25, 26));
    let store = world.resource::<BoundsStore>();
    let cascade = &world.resource::<LightViewsVisible>().0[0];
    assert!(boxes.iter().all(|&entity| !cascade.visible.contains(store.slot_of(entity).unwrap())));
    assert_eq!((cascade.kept, cascade.occluded), (1, 25));

    // Nothing changed: the camera's result is reused, and last frame's light views, occlusion included, stand
    // (they are not built again).
    let kept_before = world.resource::<LightViewsVisible>().0[0].visible.clone();
    let stats = frame(&mut world);
    assert!(stats.reused);
    assert_eq!((stats.light_view_occluded, stats.after_occlusion), (25, 26));
    let cascade = &world.resource::<LightViewsVisible>().0[0];
    assert_eq!((cascade.kept, cascade.occluded, &cascade.visible), (1, 25, &kept_before));

    world.insert_resource(LightOcclusionSettings { enabled: false, min_casters: 1, ..Default::default() });
    let stats = frame(&mut world);
    assert!(!stats.reused);
    assert_eq!((stats.light_view_occluded, stats.light_view_casters), (0, 26));

    // A bar no view can clear: after 2 frames under it, skipped for 3, then probed again.
    let adaptive = AdaptiveSettings {
        reuse_unchanged: false,
        min_light_occlusion_benefit: 1.0,
        low_benefit_frames: 2,
        reprobe_every: 3,
        ..AdaptiveSettings::default()
    };
    world.insert_resource(adaptive);
    world.insert_resource(LightOcclusionSettings { min_casters: 1, ..LightOcclusionSettings::default() });
    let gated: Vec<usize> = (0..7).map(|_| frame(&mut world).light_occlusion_gated).collect();
    assert_eq!(gated, [0, 0, 1, 1, 1, 0, 0]);

    // A buffer without texels hides nothing, and breaks nothing.
    world.insert_resource(AdaptiveSettings::default());
    world.insert_resource(LightOcclusionSettings { size: 0, min_casters: 1, ..LightOcclusionSettings::default() });
    let stats = frame(&mut world);
    assert_eq!((stats.light_view_occluded, stats.light_view_casters), (0, 26));
}
