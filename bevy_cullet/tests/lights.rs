//! The plugin's light views against Bevy's own light visibility, in two headless apps flying the same camera
//! over the same scene (a sun with four cascades, a point light and a spot light with shadows, over a town of
//! unrotated boxes): every shadow map's list of casters is a subset of Bevy's, and it holds every caster that
//! the exact judge (`cullet_truth::shadows`) says the map needs, judged from Bevy's own matrices. With the light
//! views' occlusion on, a caster is needed only where it also owns a texel of the map's exact rendering.

mod support;

use bevy_app::App;
use bevy_camera::primitives::{Aabb, CUBE_MAP_FACES};
use bevy_camera::visibility::{
    CascadesVisibleEntities, CubemapVisibleEntities, NoFrustumCulling, RenderLayers, ViewVisibility, VisibleEntities,
    VisibleMeshEntities,
};
use bevy_cullet::{CulletSettings, CulletView};
use bevy_ecs::prelude::*;
use bevy_light::cluster::ClusterVisibilityClass;
use bevy_light::{Cascades, DirectionalLight, NotShadowCaster, PointLight, SpotLight, spot_light_world_from_view};
use bevy_mesh::Mesh3d;
use bevy_transform::prelude::*;
use cullet::camera::DepthConvention;
use cullet::culler::LightOcclusionSettings;
use cullet::frustum::{Light, LightView, View};
use cullet::mesh::Mesh;
use cullet::{Camera, LocalBounds, Occluder};
use cullet_truth::half_spaces::{exact_half_spaces, half_spaces, moved};
use cullet_truth::render::{ReferenceObject, render_light_view};
use cullet_truth::shadows::{ExactLight, caster_needed};
use glam::{Affine3A, DMat4, DVec3, Vec3};
use std::any::TypeId;
use std::collections::BTreeSet;
use support::{app_with_lights, cullet_camera, set_camera, spawn_camera};

const FAR: f32 = 1000.0;
/// The town's box that casts no shadow, and the one in another layer than the lights.
const NOT_CASTING: usize = 300;
const OTHER_LAYER: usize = 301;

/// What the scene's special entities are, for the checks.
struct Town {
    /// Every box spawned, with its local bounds.
    boxes: Vec<(Entity, LocalBounds)>,
    unbounded: Entity,
    sun: Entity,
    lamp: Entity,
    spot: Entity,
    camera: Entity,
}

fn bevy_vec(v: Vec3) -> bevy_math::Vec3 {
    bevy_math::Vec3::from_array(v.to_array())
}

/// A 24 x 24 town of unrotated boxes of varied heights on a 6 m grid, the taller ones occluders; a sun, a
/// lamp and a spot light with shadows; one box that casts no shadow, one in another layer, and one entity
/// without bounds that Bevy puts in every map.
fn spawn_town(app: &mut App, camera: &Camera) -> Town {
    let world = app.world_mut();
    let cube = Mesh::unit_cube(1);
    let mut boxes = Vec::new();
    for i in 0..24 {
        for j in 0..24 {
            let hash = (i * 7919 + j * 104_729) % 97;
            let height = 1.0 + (hash % 13) as f32;
            let size = Vec3::new(2.0 + (hash % 3) as f32, height, 2.0 + (hash % 4) as f32 * 0.5);
            let bounds = LocalBounds { center: Vec3::new(0.0, height / 2.0, 0.0), half_extent: size / 2.0 };
            let position = Vec3::new(i as f32 * 6.0 - 72.0, 0.0, j as f32 * 6.0 - 72.0);
            let aabb = Aabb::from_min_max(
                bevy_vec(bounds.center - bounds.half_extent),
                bevy_vec(bounds.center + bounds.half_extent),
            );
            let mut entity = world.spawn((Mesh3d::default(), aabb, Transform::from_translation(bevy_vec(position))));
            if height >= 8.0 {
                entity.insert(Occluder::new(cube.scaled(size, bounds.center).triangle_soup()));
            }
            boxes.push((entity.id(), bounds));
        }
    }
    world.entity_mut(boxes[NOT_CASTING].0).insert(NotShadowCaster);
    world.entity_mut(boxes[OTHER_LAYER].0).insert(RenderLayers::layer(1));
    let unbounded = world.spawn((Mesh3d::default(), NoFrustumCulling, Transform::from_xyz(0.0, 1.0, 0.0))).id();
    let sun = world
        .spawn((
            DirectionalLight { shadow_maps_enabled: true, ..Default::default() },
            Transform::default().looking_to(bevy_math::Vec3::new(-1.0, -0.6, -0.4), bevy_math::Vec3::Y),
        ))
        .id();
    let lamp = world
        .spawn((
            PointLight { shadow_maps_enabled: true, range: 25.0, ..Default::default() },
            Transform::from_xyz(3.0, 6.0, 3.0),
        ))
        .id();
    let spot = world
        .spawn((
            SpotLight { shadow_maps_enabled: true, range: 40.0, outer_angle: 0.6, ..Default::default() },
            Transform::from_xyz(-20.0, 15.0, 10.0)
                .looking_at(bevy_math::Vec3::new(-30.0, 0.0, 0.0), bevy_math::Vec3::Y),
        ))
        .id();
    let camera = spawn_camera(world, camera, FAR);
    Town { boxes, unbounded, sun, lamp, spot, camera }
}

/// The camera's frames: a walk through the town, a turn, a cut to the far side, a look down from above, a
/// look at the sky.
fn frames() -> Vec<Camera> {
    let at = |position: Vec3, target: Vec3| Camera::looking_at(position, target);
    let mut frames: Vec<Camera> =
        (0..6).map(|k| at(Vec3::new(-40.0 + 8.0 * k as f32, 2.0, -30.0), Vec3::new(10.0, 1.0, 20.0))).collect();
    frames.push(at(Vec3::new(0.0, 2.0, -30.0), Vec3::new(-60.0, 2.0, -30.0)));
    frames.push(at(Vec3::new(60.0, 3.0, 60.0), Vec3::new(0.0, 0.0, 0.0)));
    frames.push(at(Vec3::new(0.0, 80.0, 1.0), Vec3::ZERO));
    frames.push(at(Vec3::new(0.0, 2.0, 0.0), Vec3::new(0.0, 100.0, 5.0)));
    frames
}

/// Every shadow map's list of casters: `(light, map)` with the map a cascade (per camera), face or 0; the
/// casters as their index in the town's boxes (the entity without bounds as one past the last), the same in
/// both apps.
fn lists(world: &mut World, town: &Town) -> Vec<((usize, usize), BTreeSet<usize>)> {
    let mut out = Vec::new();
    let index = |entity: &Entity| {
        let position = town.boxes.iter().position(|(listed, _)| listed == entity);
        position.unwrap_or_else(|| if *entity == town.unbounded { town.boxes.len() } else { panic!("{entity} listed") })
    };
    let light_index = |light: Entity| [town.sun, town.lamp, town.spot].iter().position(|&l| l == light).unwrap();
    let set = |list: &VisibleMeshEntities| {
        assert!(list.entities.is_sorted(), "every list sorted, as Bevy's renderer reads them");
        list.entities.iter().map(index).collect::<BTreeSet<_>>()
    };
    for (light, cascades) in world.query::<(Entity, &CascadesVisibleEntities)>().iter(world) {
        for lists in cascades.entities.values() {
            out.extend(lists.iter().enumerate().map(|(i, list)| ((light_index(light), i), set(list))));
        }
    }
    for (light, faces) in world.query::<(Entity, &CubemapVisibleEntities)>().iter(world) {
        out.extend(faces.iter().enumerate().map(|(i, list)| ((light_index(light), i), set(list))));
    }
    for (light, list) in world.query_filtered::<(Entity, &VisibleMeshEntities), With<SpotLight>>().iter(world) {
        out.push(((light_index(light), 0), set(list)));
    }
    out.sort_by_key(|(map, _)| *map);
    out
}

/// One of Bevy's shadow maps as the judge sees it.
struct Map {
    /// `(light, map)` as [`lists`] has it.
    key: (usize, usize),
    /// Its view, from Bevy's own matrices.
    view: LightView,
    light: ExactLight,
    /// A lamp's range.
    range: Option<f32>,
}

/// The light view (Cullet's) of each of Bevy's shadow maps for the camera, from Bevy's own matrices: a
/// cascade's `clip_from_world`, a lamp's face or spot cone cut at its range.
fn bevy_maps(world: &World, town: &Town, camera: &Camera) -> Vec<Map> {
    let receivers = camera.frustum().unwrap();
    let origin = camera.position;
    let mut maps = Vec::new();
    let sun = world.get::<GlobalTransform>(town.sun).unwrap();
    let direction = Vec3::from_array(sun.forward().to_array());
    for (i, cascade) in world.get::<Cascades>(town.sun).unwrap().cascades[&town.camera].iter().enumerate() {
        let clip_from_world = DMat4::from_cols_array(&cascade.clip_from_world.to_cols_array().map(f64::from));
        let clip_from_relative = clip_from_world * DMat4::from_translation(origin.as_dvec3());
        let depth = DepthConvention::Reversed;
        let frustum = cullet::Frustum::from_clip_from_relative_f64(origin, clip_from_relative, depth).unwrap();
        let view = View::shadow_casters(frustum, Light::Directional { direction }, &receivers).unwrap();
        let light_view = LightView { view, clip_from_relative, origin, depth, near: None };
        let light = ExactLight::Directional(direction.as_dvec3());
        maps.push(Map { key: (0, i), view: light_view, light, range: None });
    }
    let lamp_view = |position: Vec3, rotation: bevy_math::Quat, fov: f32, near: f32, range: f32| {
        let g = |v: bevy_math::Vec3| Vec3::from_array(v.to_array());
        let face = Camera {
            position,
            forward: g(rotation * bevy_math::Vec3::NEG_Z),
            up: g(rotation * bevy_math::Vec3::Y),
            fov_y: fov,
            aspect: 1.0,
            near,
            far: Some(range),
            depth: DepthConvention::Reversed,
        };
        let light = Light::Point { position };
        let view = View::shadow_casters(face.frustum().unwrap(), light, &receivers).unwrap();
        let clip_from_relative = face.clip_from_relative_f64();
        let light_view = LightView { view, clip_from_relative, origin: position, depth: face.depth, near: Some(near) };
        (light_view, ExactLight::Point((position - origin).as_dvec3()))
    };
    let (lamp, lamp_at) =
        (world.get::<PointLight>(town.lamp).unwrap(), world.get::<GlobalTransform>(town.lamp).unwrap());
    let position = Vec3::from_array(lamp_at.translation().to_array());
    for (i, face) in CUBE_MAP_FACES.iter().enumerate() {
        let rotation = Transform::IDENTITY.looking_at(face.target, face.up).rotation;
        let (view, light) =
            lamp_view(position, rotation, std::f32::consts::FRAC_PI_2, lamp.shadow_map_near_z, lamp.range);
        maps.push(Map { key: (1, i), view, light, range: Some(lamp.range) });
    }
    let (spot, spot_at) =
        (world.get::<SpotLight>(town.spot).unwrap(), world.get::<GlobalTransform>(town.spot).unwrap());
    let rotation = bevy_math::Quat::from_mat3a(&spot_light_world_from_view(spot_at).matrix3);
    let position = Vec3::from_array(spot_at.translation().to_array());
    let (view, light) = lamp_view(position, rotation, 2.0 * spot.outer_angle, spot.shadow_map_near_z, spot.range);
    maps.push(Map { key: (2, 0), view, light, range: Some(spot.range) });
    maps
}

/// The casters of Bevy's `map` that the exact judge says the map needs: their box's shadow reaches the map's
/// view inside the camera's frustum, and (with `occlusion`) they own a texel of the map's exact rendering of
/// Bevy's casters.
fn needed(
    world: &World,
    town: &Town,
    camera: &Camera,
    map: &Map,
    bevy: &BTreeSet<usize>,
    occlusion: bool,
) -> BTreeSet<usize> {
    let (light_view, light) = (&map.view, map.light);
    let origin = camera.position.as_dvec3();
    let receivers = exact_half_spaces(camera);
    let view =
        moved(&half_spaces(light_view.clip_from_relative, light_view.depth), light_view.origin.as_dvec3(), origin);
    let boxes: Vec<(usize, LocalBounds, Affine3A)> = (town.boxes.iter().enumerate())
        .filter(|(index, _)| bevy.contains(index))
        .map(|(index, &(entity, bounds))| (index, bounds, support::world_transform(world, entity)))
        .collect();
    let seen = occlusion.then(|| {
        let objects: Vec<ReferenceObject> =
            boxes.iter().map(|(_, bounds, transform)| ReferenceObject::from_bounds(bounds, *transform)).collect();
        render_light_view(light_view, &objects, 256).visibility().visible
    });
    let reaches = |bounds: &LocalBounds, transform: &Affine3A| {
        let center = transform.transform_point3(bounds.center).as_dvec3() - origin;
        let extent = bounds.half_extent.as_dvec3();
        // A lamp lights nothing beyond its range: a box wholly beyond it shadows nothing lit.
        let in_range = match (light, map.range) {
            (ExactLight::Point(position), Some(range)) => {
                ((center - position).abs() - extent).max(DVec3::ZERO).length() <= f64::from(range)
            }
            _ => true,
        };
        in_range && caster_needed(&view, &receivers, light, center - extent, center + extent)
    };
    boxes
        .iter()
        .enumerate()
        .filter(|(i, (_, bounds, transform))| {
            seen.as_ref().is_none_or(|seen| seen.contains(*i)) && reaches(bounds, transform)
        })
        .map(|(_, (index, ..))| *index)
        .collect()
}

/// Whether box `index` of the town touches `light_view`'s frustum, within a millimetre.
fn touches(world: &World, town: &Town, light_view: &LightView, index: usize) -> bool {
    let (entity, bounds) = town.boxes[index];
    let transform = support::world_transform(world, entity);
    let center = (transform.transform_point3(bounds.center) - light_view.origin).as_dvec3();
    let extent = bounds.half_extent.as_dvec3();
    half_spaces(light_view.clip_from_relative, light_view.depth).iter().all(|plane| {
        let normal = plane.truncate();
        (normal.dot(center) + normal.abs().dot(extent) + plane.w) / normal.length() >= -1e-3
    })
}

/// Flies both apps over the town; for each frame and shadow map checks the plugin's list against Bevy's and
/// the judge. Returns the casters listed by the plugin and by Bevy, summed over the frames and maps.
/// Each mesh entity's `ViewVisibility` at the end of a frame: (entity, visible, changed this frame).
#[derive(Resource, Default)]
struct VisibilityLog(Vec<(Entity, bool, bool)>);

fn log_visibility(mut log: ResMut<VisibilityLog>, meshes: Query<(Entity, Ref<ViewVisibility>), With<Mesh3d>>) {
    log.0 = meshes.iter().map(|(entity, visibility)| (entity, visibility.get(), visibility.is_changed())).collect();
}

fn fly(occlusion: bool) -> (usize, usize) {
    let settings = CulletSettings {
        light_occlusion: LightOcclusionSettings { enabled: occlusion, min_casters: 1, ..Default::default() },
        ..Default::default()
    };
    let frames = frames();
    let (mut cullet_app, mut bevy_app) = (app_with_lights(Some(settings)), app_with_lights(None));
    cullet_app.init_resource::<VisibilityLog>().add_systems(bevy_app::Last, log_visibility);
    let town = spawn_town(&mut cullet_app, &frames[0]);
    let bevy_town = spawn_town(&mut bevy_app, &frames[0]);
    let (mut plugin_total, mut bevy_total, mut occluded) = (0, 0, 0);
    let (mut was_visible, mut shown_by_lights_alone) = (std::collections::HashMap::new(), 0);
    for (frame, camera) in frames.iter().enumerate() {
        for (app, town) in [(&mut cullet_app, &town), (&mut bevy_app, &bevy_town)] {
            if frame == 3 {
                // Despawns in the middle of the store move its last objects into the holes: its slots no longer
                // follow the entities' order.
                for index in (100..160).step_by(3) {
                    app.world_mut().despawn(town.boxes[index].0);
                }
            }
            set_camera(app.world_mut(), town.camera, camera, FAR);
            app.update();
        }
        let camera = cullet_camera(cullet_app.world(), town.camera, Some(FAR));
        let plugin = lists(cullet_app.world_mut(), &town);
        let bevy = lists(bevy_app.world_mut(), &bevy_town);
        assert_eq!(plugin.len(), bevy.len(), "frame {frame}: the same shadow maps");
        let maps = bevy_maps(bevy_app.world(), &bevy_town, &camera);
        // Bevy leaves a lamp no camera sees with last frame's lists; the plugin empties them.
        let seen_lights = bevy_app.world().get::<VisibleEntities>(bevy_town.camera).unwrap();
        let seen_lights = seen_lights.get(TypeId::of::<ClusterVisibilityClass>());
        let lamp_seen =
            |light: usize| light == 0 || seen_lights.contains(&[bevy_town.sun, bevy_town.lamp, bevy_town.spot][light]);
        for ((map, plugin), (bevy_map, bevy)) in plugin.iter().zip(&bevy) {
            assert_eq!(map, bevy_map);
            if !lamp_seen(map.0) {
                assert!(plugin.is_empty(), "frame {frame}, map {map:?}: a lamp out of view lists casters");
                continue;
            }
            let judged = maps.iter().find(|judged| judged.key == *map).expect("a map of every list");
            // Beyond Bevy's list, only boxes touching the map's frustum, which the plugin's rounding slack keeps.
            let extra: Vec<_> =
                plugin.difference(bevy).filter(|&&i| !touches(cullet_app.world(), &town, &judged.view, i)).collect();
            assert!(extra.is_empty(), "frame {frame}, map {map:?}: the plugin lists {extra:?}, which Bevy does not");
            let needed = needed(bevy_app.world(), &bevy_town, &camera, judged, bevy, occlusion);
            let missing: Vec<_> = needed.difference(plugin).collect();
            assert!(missing.is_empty(), "frame {frame}, map {map:?}: needed casters {missing:?} dropped");
            for excluded in [NOT_CASTING, OTHER_LAYER] {
                assert!(!plugin.contains(&excluded), "frame {frame}, map {map:?}: box {excluded} listed");
            }
            if !bevy.is_empty() {
                let unbounded = town.boxes.len();
                assert!(plugin.contains(&unbounded), "frame {frame}, map {map:?}: the unbounded entity missing");
            }
            plugin_total += plugin.len();
            bevy_total += bevy.len();
        }
        // Every listed caster is made visible, so that Bevy extracts it for the shadow pass.
        let world = cullet_app.world();
        let entity = |index: usize| town.boxes.get(index).map_or(town.unbounded, |(entity, _)| *entity);
        for (_, list) in &plugin {
            assert!(list.iter().all(|&i| world.get::<ViewVisibility>(entity(i)).unwrap().get()), "frame {frame}");
        }
        let view = world.get::<CulletView>(town.camera).unwrap();
        occluded += view.stats().light_occluded;
        // `ViewVisibility` changes, as Bevy's own systems change it, exactly where an entity's visibility does;
        // entities only a light shows (not in the camera's list) become visible too.
        let camera_list = world.get::<VisibleEntities>(town.camera).unwrap().get(TypeId::of::<Mesh3d>());
        for &(entity, visible, changed) in &world.resource::<VisibilityLog>().0 {
            if let Some(before) = was_visible.insert(entity, visible) {
                assert_eq!(
                    changed,
                    visible != before,
                    "frame {frame}: {entity} changed {changed}, {before} -> {visible}"
                );
                shown_by_lights_alone += usize::from(visible && !before && !camera_list.contains(&entity));
            }
        }
    }
    assert!(shown_by_lights_alone > 0, "some casters come into view through a light alone");
    assert_eq!(occluded > 0, occlusion, "the light views' occlusion hides casters exactly where it is on");
    (plugin_total, bevy_total)
}

#[test]
fn light_views_keep_a_subset_of_bevys_casters_and_every_needed_one() {
    let (plugin, bevy) = fly(false);
    assert!(plugin < bevy, "the plugin drops casters whose shadows cannot reach the view ({plugin} of {bevy})");
}

#[test]
fn light_views_occlusion_drops_only_casters_hidden_from_the_light() {
    let (plugin, bevy) = fly(true);
    assert!(plugin < bevy, "{plugin} of {bevy}");
}

/// A light with shadows off, one hidden, and the plugin's light culling switched off (Bevy's checks then run).
#[test]
fn lights_without_shadows_list_nothing_and_switching_off_gives_bevys_lists() {
    let frames = frames();
    let mut app = app_with_lights(Some(CulletSettings::default()));
    let town = spawn_town(&mut app, &frames[0]);
    app.world_mut().get_mut::<PointLight>(town.lamp).unwrap().shadow_maps_enabled = false;
    *app.world_mut().get_mut::<bevy_camera::visibility::Visibility>(town.spot).unwrap() =
        bevy_camera::visibility::Visibility::Hidden;
    app.update();
    let lists_now = lists(app.world_mut(), &town);
    for ((light, _), list) in &lists_now {
        if *light != 0 {
            assert!(list.is_empty(), "{light} lists {} casters", list.len());
        } else {
            assert!(!list.is_empty());
        }
    }
    // Off: Bevy's own checks give the same lists as an app without the plugin.
    app.world_mut().resource_mut::<CulletSettings>().lights = false;
    app.update();
    let mut bevy_app = app_with_lights(None);
    let bevy_town = spawn_town(&mut bevy_app, &frames[0]);
    bevy_app.world_mut().get_mut::<PointLight>(bevy_town.lamp).unwrap().shadow_maps_enabled = false;
    *bevy_app.world_mut().get_mut::<bevy_camera::visibility::Visibility>(bevy_town.spot).unwrap() =
        bevy_camera::visibility::Visibility::Hidden;
    bevy_app.update();
    assert_eq!(lists(app.world_mut(), &town), lists(bevy_app.world_mut(), &bevy_town));
}

/// A light with `NoCulletLightCulling` keeps every caster of its own maps, as Bevy's checks do: the same lists
/// as Bevy's, up to boxes touching a map's edge, and none occluded.
#[test]
fn a_light_opted_out_keeps_what_bevy_keeps() {
    let frames = frames();
    let (mut cullet_app, mut bevy_app) = (app_with_lights(Some(CulletSettings::default())), app_with_lights(None));
    let town = spawn_town(&mut cullet_app, &frames[0]);
    let bevy_town = spawn_town(&mut bevy_app, &frames[0]);
    cullet_app.world_mut().entity_mut(town.sun).insert(bevy_cullet::NoCulletLightCulling);
    let mut listed = 0;
    for camera in &frames[..6] {
        for (app, town) in [(&mut cullet_app, &town), (&mut bevy_app, &bevy_town)] {
            set_camera(app.world_mut(), town.camera, camera, FAR);
            app.update();
        }
        let camera = cullet_camera(cullet_app.world(), town.camera, Some(FAR));
        let maps = bevy_maps(bevy_app.world(), &bevy_town, &camera);
        let (plugin, bevy) = (lists(cullet_app.world_mut(), &town), lists(bevy_app.world_mut(), &bevy_town));
        for ((map, plugin), (_, bevy)) in plugin.iter().zip(&bevy).filter(|((map, _), _)| map.0 == 0) {
            let judged = maps.iter().find(|judged| judged.key == *map).unwrap();
            let differ = plugin.symmetric_difference(bevy).filter(|&&i| i < town.boxes.len());
            let apart: Vec<_> = differ.filter(|&&i| !touches(bevy_app.world(), &bevy_town, &judged.view, i)).collect();
            assert!(apart.is_empty(), "map {map:?}: {apart:?} listed by one and not the other");
            listed += plugin.len();
        }
        let view = cullet_app.world().get::<CulletView>(town.camera).unwrap();
        assert_eq!(view.stats().light_occluded, 0, "an opted-out light's maps are not occluded");
    }
    assert!(listed > 0);
}

/// Casters that change between frames (a shadow switched off on one box and on for another in the same
/// frame, a box moved to another layer, a box hidden) leave or join the lights' lists on that frame, as in
/// Bevy's, with the camera still.
#[test]
fn caster_changes_reach_the_lists_on_their_frame() {
    let frames = frames();
    let (mut cullet_app, mut bevy_app) = (app_with_lights(Some(CulletSettings::default())), app_with_lights(None));
    let town = spawn_town(&mut cullet_app, &frames[0]);
    let bevy_town = spawn_town(&mut bevy_app, &frames[0]);
    let sun_casters = |app: &mut App, town: &Town| -> BTreeSet<usize> {
        let maps = lists(app.world_mut(), town).into_iter().filter(|((light, _), _)| *light == 0);
        maps.flat_map(|(_, casters)| casters).collect()
    };
    let mut update = |change: &dyn Fn(&mut World, &Town)| {
        for (app, town) in [(&mut cullet_app, &town), (&mut bevy_app, &bevy_town)] {
            change(app.world_mut(), town);
            app.update();
        }
        let (plugin, bevy) = (sun_casters(&mut cullet_app, &town), sun_casters(&mut bevy_app, &bevy_town));
        assert!(plugin.is_subset(&bevy), "listed beyond Bevy's: {:?}", plugin.difference(&bevy));
        plugin
    };
    let first = update(&|_, _| {});
    let listed: Vec<usize> =
        first.iter().copied().filter(|&i| i < town.boxes.len() && i != NOT_CASTING && i != OTHER_LAYER).collect();
    assert!(listed.len() >= 3, "{listed:?}");
    let (unlit, relayered, hidden) = (listed[0], listed[1], listed[2]);
    let now = update(&|world, town| {
        world.entity_mut(town.boxes[unlit].0).insert(NotShadowCaster);
        world.entity_mut(town.boxes[NOT_CASTING].0).remove::<NotShadowCaster>();
    });
    assert!(!now.contains(&unlit), "a box that casts no shadow any more is listed");
    let now = update(&|world, town| {
        world.entity_mut(town.boxes[relayered].0).insert(RenderLayers::layer(1));
    });
    assert!(!now.contains(&relayered), "a box moved out of the sun's layer is listed");
    let now = update(&|world, town| {
        *world.get_mut::<bevy_camera::visibility::Visibility>(town.boxes[hidden].0).unwrap() =
            bevy_camera::visibility::Visibility::Hidden;
    });
    assert!(!now.contains(&hidden), "a hidden box is listed");
    let now = update(&|world, town| {
        world.entity_mut(town.boxes[unlit].0).remove::<NotShadowCaster>();
        world.entity_mut(town.boxes[relayered].0).remove::<RenderLayers>();
        *world.get_mut::<bevy_camera::visibility::Visibility>(town.boxes[hidden].0).unwrap() =
            bevy_camera::visibility::Visibility::Inherited;
    });
    assert!([unlit, relayered, hidden].iter().all(|i| now.contains(i)), "restored boxes listed again");
}
