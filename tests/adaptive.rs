//! Adaptive stages: unchanged frames reuse their result, an occlusion stage that removes too little is skipped
//! and re-probed, the fixed pipeline never gates, and gating adds no false negatives on the built-in scenes
//! (city, field, cad) against the exact rendering.

use cullet::camera::CameraPath;
use cullet::detail::DetailSettings;
use cullet::mesh::Mesh;
use cullet::pipeline::CullStats;

use cullet::culler::{AdaptiveSettings, OcclusionSettings};
use cullet::scene::flight::Flight;
use cullet::scene::{Scene, SceneObject};
use cullet::{Camera, ObjectTransform, Occluder};
use glam::{Affine3A, Vec3};

/// A wall with an occluder 20 units in front of the camera and `behind` boxes behind it, `beside` boxes
/// beside it.
fn wall_scene(behind: usize, beside: usize) -> Scene {
    let cube = Mesh::unit_cube(1);
    let occluder = Occluder::new(Mesh::unit_cube(1).scaled(Vec3::splat(0.98), Vec3::ZERO).triangle_soup());
    let mut objects = vec![SceneObject {
        mesh: 0,
        transform: Affine3A::from_scale_rotation_translation(
            Vec3::new(20.0, 10.0, 1.0),
            glam::Quat::IDENTITY,
            Vec3::new(0.0, 0.0, -20.0),
        ),
        occluder: Some(occluder),
        velocity: None,
        color: [200; 4],
    }];
    let place = |x: f32, z: f32| SceneObject {
        mesh: 0,
        transform: Affine3A::from_translation(Vec3::new(x, 0.0, z)),
        occluder: None,
        velocity: None,
        color: [200; 4],
    };
    objects.extend((0..behind).map(|i| place(i as f32 - behind as f32 * 0.5, -40.0)));
    objects.extend((0..beside).map(|i| place(30.0 + i as f32 * 2.0, -60.0)));
    Scene::new(vec![cube], objects)
}

fn flight(scene: &Scene, adaptive: AdaptiveSettings) -> Flight {
    let path = CameraPath { fov_y_deg: 90.0, near: 0.1, far: None, keys: Vec::new() };
    let mut flight = Flight::new(path, 1.0, 1, OcclusionSettings::default(), |world| {
        scene.spawn(world);
    });
    flight.world.insert_resource(adaptive);
    flight
}

fn camera() -> Camera {
    Camera { aspect: 1.0, fov_y: 90f32.to_radians(), ..Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z) }
}

#[test]
fn unchanged_frames_reuse_the_last_result_and_any_change_reruns() {
    let scene = wall_scene(8, 4);
    let mut flight = flight(&scene, AdaptiveSettings::default());
    let first = flight.run_with_camera(camera(), 0.0);
    assert!(!first.reused && first.after_occlusion < first.after_frustum, "{first:?}");
    let second = flight.run_with_camera(camera(), 0.0);
    assert!(second.reused);
    assert_eq!((second.after_frustum, second.after_occlusion), (first.after_frustum, first.after_occlusion));
    // The camera turns: run again.
    let turned = Camera { forward: Vec3::new(0.1, 0.0, -1.0), ..camera() };
    assert!(!flight.run_with_camera(turned, 0.0).reused);
    assert!(flight.run_with_camera(turned, 0.0).reused);
    // An object moves (a static one, so by inserting its new transform): run again.
    let entity = flight.world.resource::<cullet::BoundsStore>().entities()[3];
    flight.world.entity_mut(entity).insert(ObjectTransform(Affine3A::from_translation(Vec3::new(0.0, 0.0, 10.0))));
    let moved = flight.run_with_camera(turned, 0.0);
    assert!(!moved.reused);
    // A setting changes: run again.
    flight.world.resource_mut::<OcclusionSettings>().width = 128;
    assert!(!flight.run_with_camera(turned, 0.0).reused);
    // The wall's occluder is replaced by a smaller one: run in full (neither reused nor re-tested), and the
    // boxes it no longer hides come back.
    let before = flight.run_with_camera(turned, 0.0);
    assert!(before.reused);
    let wall = flight.world.resource::<cullet::BoundsStore>().entities()[0];
    let sliver = Occluder::new(Mesh::unit_cube(1).scaled(Vec3::new(0.05, 0.98, 0.98), Vec3::ZERO).triangle_soup());
    flight.world.entity_mut(wall).insert(sliver);
    let replaced = flight.run_with_camera(turned, 0.0);
    assert!(!replaced.reused && replaced.retested == 0, "{replaced:?}");
    assert!(replaced.after_occlusion > before.after_occlusion, "{before:?} -> {replaced:?}");
    // The fixed pipeline never reuses.
    let mut fixed = self::flight(&scene, AdaptiveSettings::fixed());
    fixed.run_with_camera(camera(), 0.0);
    assert!(!fixed.run_with_camera(camera(), 0.0).reused);
}

#[test]
fn occlusion_that_removes_nothing_is_skipped_then_reprobed() {
    // Nothing behind the wall: occlusion runs, removes nothing.
    let scene = wall_scene(0, 6);
    let adaptive =
        AdaptiveSettings { reuse_unchanged: false, low_benefit_frames: 3, reprobe_every: 5, ..Default::default() };
    let mut flight = flight(&scene, adaptive);
    let gated: Vec<bool> =
        (0..12).map(|_| flight.run_with_camera(camera(), 0.0)).map(|s: CullStats| s.occlusion_gated).collect();
    // 3 frames that remove nothing, 5 skipped, a probe that removes nothing, ...
    assert_eq!(gated, [false, false, false, true, true, true, true, true, false, false, false, true]);
    // Where occlusion pays, it is never skipped.
    let mut paying = self::flight(&wall_scene(8, 0), adaptive);
    assert!((0..12).all(|_| !paying.run_with_camera(camera(), 0.0).occlusion_gated));
}

/// The hierarchy and the portals (a world without cells: the frustum, then occlusion) skip occlusion that
/// removes nothing as the stages do, and never skip it where it pays.
#[test]
fn the_structures_skip_occlusion_that_removes_nothing() {
    use cullet::culler::{CullScene, Culler, HierarchyCuller, HierarchySettings, PortalCuller, PortalSettings};
    let adaptive =
        AdaptiveSettings { reuse_unchanged: false, low_benefit_frames: 3, reprobe_every: 5, ..Default::default() };
    let cullers = || -> [Box<dyn Culler>; 2] {
        [
            Box::new(HierarchyCuller::new(HierarchySettings { adaptive, ..Default::default() })),
            Box::new(PortalCuller::new(PortalSettings { adaptive, ..Default::default() })),
        ]
    };
    for (scene, pays) in [(wall_scene(0, 6), false), (wall_scene(8, 0), true)] {
        let path = CameraPath { fov_y_deg: 90.0, near: 0.1, far: None, keys: Vec::new() };
        let mut flight = Flight::for_cullers(path, 1.0, 1, |world| {
            scene.spawn(world);
        });
        flight.schedule.run(&mut flight.world);
        for mut culler in cullers() {
            let gated: Vec<bool> =
                (0..12).map(|_| culler.cull(&CullScene::new(&flight.world), &camera()).stats.occlusion_gated).collect();
            let expected = if pays {
                [false; 12]
            } else {
                [false, false, false, true, true, true, true, true, false, false, false, true]
            };
            assert_eq!(gated, expected, "{}", culler.name());
            let culled = culler.cull(&CullScene::new(&flight.world), &camera());
            assert_eq!(culled.stats.after_occlusion, culled.kept().count(), "{}", culler.name());
        }
    }
}

/// The built-in scenes along their paths, with the default gating and with gating that skips the occlusion
/// stage at once: zero false negatives, the repeated frame reused, and the stage skipped where it had
/// occluders to skip.
#[test]
fn gating_adds_no_false_negatives_on_the_built_in_scenes() {
    let city = cullet::scene::city::CityScene::generate(cullet::scene::city::CityParams::with_objects(3000));
    let scenes = [
        ("city", city.scene.clone(), city.flythrough()),
        ("field", cullet::scene::field::field(3000).0, cullet::scene::field::field(3000).1),
        ("cad", cullet::scene::cad::cad(2000).0, cullet::scene::cad::cad(2000).1),
    ];
    // Gating that engages at once: every frame counts as one of too little benefit, so after two the occlusion
    // stage is skipped for five frames, then re-probed.
    let eager =
        AdaptiveSettings { min_occlusion_benefit: 1.0, low_benefit_frames: 2, reprobe_every: 5, ..Default::default() };
    let mut gated_scenes = 0;
    for (name, scene, path) in scenes {
        for adaptive in [AdaptiveSettings::default(), eager] {
            // The path, then its last frame twice more: reused (or only what moved re-tested), and judged again.
            let frames = 24;
            let run = (0..frames).chain([frames - 1; 2]);
            let (metrics, stats) = cullet_test_support::fly_and_judge_with(&scene, path.clone(), frames, run, adaptive);
            println!("{name}: {metrics:?}");
            let last = &stats[stats.len() - 2..];
            let reused = |stats: &&CullStats| stats.reused || stats.retested > 0;
            if adaptive == AdaptiveSettings::default() {
                assert!(last.iter().all(|stats| reused(&stats)), "{name}: the repeated frame is reused");
            }
            if adaptive == eager && stats.iter().any(|stats| stats.occluders > 0) {
                let gated = stats.iter().filter(|stats| stats.occlusion_gated).count();
                assert!(gated >= 5, "{name}: the occlusion stage was skipped in {gated} frames");
                assert!(stats.iter().any(|stats| stats.occluders > 0 && !stats.occlusion_gated));
                gated_scenes += 1;
            }
        }
    }
    assert!(gated_scenes >= 2, "gating engaged in {gated_scenes} scenes");
}

/// Plane coherence in the pipeline: along the city's path, the frustum stage keeps exactly the objects the
/// all-planes test keeps, frame after frame.
#[test]
fn plane_coherence_keeps_exactly_what_all_planes_keep() {
    let city = cullet::scene::city::CityScene::generate(cullet::scene::city::CityParams::with_objects(5000));
    let run = |adaptive: AdaptiveSettings| {
        let mut flight = Flight::new(city.flythrough(), 16.0 / 9.0, 60, OcclusionSettings::default(), |world| {
            city.spawn(world);
        });
        flight.world.insert_resource(adaptive);
        (0..60)
            .map(|frame| {
                flight.run_frame(frame);
                flight.world.resource::<cullet::pipeline::CameraCuller>().frustum_visible().clone()
            })
            .collect::<Vec<_>>()
    };
    let coherent = run(AdaptiveSettings { plane_coherence: true, ..AdaptiveSettings::fixed() });
    let all_planes = run(AdaptiveSettings::fixed());
    for (frame, (a, b)) in coherent.iter().zip(&all_planes).enumerate() {
        assert_eq!(a, b, "frame {frame}");
    }
}

/// A static camera over the city while its cars move: after the first frame only the cars are re-tested, and
/// both stages keep exactly what the full (fixed) pipeline keeps, frame after frame, with detail culling too.
/// An occluder that moves makes the next frame run in full.
#[test]
fn only_moved_objects_are_retested_and_keep_what_a_full_run_keeps() {
    let city = cullet::scene::city::CityScene::generate(cullet::scene::city::CityParams::with_objects(5000));
    let mut path = city.flythrough();
    path.keys.truncate(1);
    for detail in [DetailSettings::default(), DetailSettings { min_pixels: 8.0, viewport_height: 360 }] {
        retests_keep_what_a_full_run_keeps(&city, &path, detail);
    }

    // An occluder moves: the next frame runs in full.
    let scene = wall_scene(8, 4);
    let mut flight = flight(&scene, AdaptiveSettings::default());
    flight.run_with_camera(camera(), 0.0);
    let boxes: Vec<_> = flight
        .world
        .query::<(bevy_ecs::entity::Entity, &ObjectTransform)>()
        .iter(&flight.world)
        .map(|(e, _)| e)
        .collect();
    let wall = boxes.into_iter().find(|&e| flight.world.get::<Occluder>(e).is_some()).unwrap();
    let mut moved_wall = *flight.world.get::<ObjectTransform>(wall).unwrap();
    moved_wall.0.translation.x += 5.0;
    flight.world.entity_mut(wall).insert(moved_wall);
    let after = flight.run_with_camera(camera(), 0.0);
    assert_eq!((after.reused, after.retested), (false, 0), "{after:?}");
}

/// [`only_moved_objects_are_retested_and_keep_what_a_full_run_keeps`] with `detail`.
fn retests_keep_what_a_full_run_keeps(
    city: &cullet::scene::city::CityScene,
    path: &CameraPath,
    detail: DetailSettings,
) {
    let run = |adaptive: AdaptiveSettings, frames: u32| {
        let mut flight = Flight::new(path.clone(), 16.0 / 9.0, frames, OcclusionSettings::default(), |world| {
            city.spawn(world);
        });
        flight.world.insert_resource(adaptive);
        flight.world.insert_resource(detail);
        (0..frames)
            .map(|frame| {
                let stats = flight.run_frame(frame);
                let world = &flight.world;
                let occlusion = world.resource::<cullet::pipeline::CameraCuller>();
                let frustum = world.resource::<cullet::pipeline::CameraCuller>().frustum_visible().clone();
                (stats, frustum, occlusion.visible().clone(), occlusion.occluded().clone())
            })
            .collect::<Vec<_>>()
    };
    let frames = 30;
    let adaptive = run(AdaptiveSettings::default(), frames);
    let fixed = run(AdaptiveSettings::fixed(), frames);
    let moving = city.scene.objects.iter().filter(|o| o.velocity.is_some()).count();
    assert!(moving > 0);
    for (frame, (a, f)) in adaptive.iter().zip(&fixed).enumerate() {
        assert_eq!(a.1, f.1, "frame {frame}: frustum");
        assert_eq!(a.2, f.2, "frame {frame}: occlusion visible");
        assert_eq!(a.3, f.3, "frame {frame}: occluded");
        assert_eq!((a.0.after_frustum, a.0.after_occlusion), (f.0.after_frustum, f.0.after_occlusion));
        if frame > 0 {
            assert_eq!(a.0.retested, moving, "frame {frame}: only the cars are re-tested");
        }
    }
    assert!(adaptive[5].0.after_occlusion < adaptive[5].0.after_frustum, "occlusion does cull here");
    if detail.enabled() {
        assert!(adaptive[5].0.detail_culled > 0, "detail culling drops something here");
    }
}

/// The pipeline's stages through the culler interface keep, frame after frame, exactly what the ECS pipeline
/// keeps with the same settings (one core, two wrappers), and the judge finds no false negative in either
/// culler, frustum-only included.
#[test]
fn cullers_through_the_interface_keep_what_the_pipeline_keeps() {
    use cullet::culler::{Culler, StageCuller, ViewSettings};
    use cullet_truth::{JudgeSettings, ReferenceSettings, judge_culler};
    let city = cullet::scene::city::CityScene::generate(cullet::scene::city::CityParams::with_objects(3000));
    let frames = 20;
    let mut flight = Flight::new(city.flythrough(), 16.0 / 9.0, frames, OcclusionSettings::default(), |world| {
        city.spawn(world);
    });
    let mut stages = StageCuller::new("pipeline", ViewSettings::default());
    let mut frustum_only = StageCuller::frustum_only();
    let judge = JudgeSettings {
        reference: ReferenceSettings { width: 640, height: 360, ..ReferenceSettings::default() },
        occlusion_ideal: false,
    };
    let mut culled_by_occlusion = 0;
    for frame in 0..frames {
        let stats = flight.run_frame(frame);
        let (world, camera) = (&flight.world, *flight.world.resource::<Camera>());
        let pipeline = world.resource::<cullet::pipeline::CameraCuller>();
        let judged = judge_culler(&mut stages, world, &camera, &city.scene.meshes, &judge);
        assert_eq!(stages.view().frustum_visible(), pipeline.frustum_visible(), "frame {frame}: frustum");
        assert_eq!(stages.view().visible(), pipeline.visible(), "frame {frame}: occlusion");
        assert_eq!(stages.view().stats().after_occlusion, stats.after_occlusion);
        assert!(judged.metrics.false_negatives.is_empty(), "frame {frame}: {:?}", judged.metrics.false_negatives);
        culled_by_occlusion += stats.after_frustum - stats.after_occlusion;
        let judged = judge_culler(&mut frustum_only, world, &camera, &city.scene.meshes, &judge);
        assert!(judged.metrics.false_negatives.is_empty());
        assert_eq!(frustum_only.view().visible(), pipeline.frustum_visible(), "frame {frame}: frustum only");
        assert!(stages.is_conservative((640, 360)) && frustum_only.is_conservative((640, 360)));
    }
    assert!(culled_by_occlusion > 0, "the occlusion stage culls on this path");
}

/// A culler driven by a flight of its own ([`Flight::for_cullers`]: the bounds stage alone, the moves handed to
/// the culler) keeps what the pipeline keeps, frame by frame, on a city whose objects move (a tenth of them).
#[test]
fn a_culler_on_its_own_flight_keeps_what_the_pipeline_keeps() {
    use cullet::culler::{StageCuller, ViewSettings};
    let params =
        cullet::scene::city::CityParams { moving_fraction: 0.1, ..cullet::scene::city::CityParams::with_objects(3000) };
    let city = cullet::scene::city::CityScene::generate(params);
    let frames = 20;
    let mut pipeline = Flight::new(city.flythrough(), 16.0 / 9.0, frames, OcclusionSettings::default(), |world| {
        city.spawn(world);
    });
    let mut own = Flight::for_cullers(city.flythrough(), 16.0 / 9.0, frames, |world| {
        city.spawn(world);
    });
    let mut culler = StageCuller::new("stages", ViewSettings::default());
    for frame in 0..frames {
        let stats = pipeline.run_frame(frame);
        let (_, culled) = own.cull_frame(frame, &mut culler);
        assert_eq!(culled.stats.after_frustum, stats.after_frustum, "frame {frame}: frustum");
        assert_eq!(culled.stats.after_occlusion, stats.after_occlusion, "frame {frame}: occlusion");
        assert_eq!(culled.stats.retested, stats.retested, "frame {frame}: re-tested");
        let expected = pipeline.world.resource::<cullet::pipeline::CameraCuller>();
        assert_eq!(culler.view().visible(), expected.visible(), "frame {frame}: kept");
    }
}
