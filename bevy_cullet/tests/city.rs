//! The built-in city in two headless Bevy apps, one with Bevy's own visibility check and one with the plugin,
//! along the city's fly-through, judged against Bevy's result and against the exact rendering.

mod support;

use bevy_camera::primitives::{Aabb, Frustum};
use bevy_camera::visibility::{NoFrustumCulling, ViewVisibility, VisibleEntities};
use bevy_cullet::{CulletSettings, CulletStore, CulletView, spawn_scene};
use bevy_ecs::prelude::*;
use cullet::culler::OcclusionSettings;
use cullet::scene::city::{CityParams, CityScene};
use cullet_truth::{ReferenceObject, ReferenceSettings, render_ids};
use std::any::TypeId;
use support::*;

/// Bevy's far plane in these tests: beyond the whole city, so both sides cull with the same planes that
/// matter.
const FAR: f32 = 1e5;
/// Sample times along the 20-second fly-through.
const TIMES: [f32; 8] = [0.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 19.0];

struct Fixture {
    city: CityScene,
    app: bevy_app::App,
    entities: Vec<Entity>,
    camera: Entity,
}

fn fixture(objects: usize, settings: Option<CulletSettings>) -> Fixture {
    let city = CityScene::generate(CityParams::with_objects(objects));
    let mut app = app(settings);
    let world = app.world_mut();
    let entities = spawn_scene(world, &city.scene, |_, entity| {
        entity.insert(drawn());
    });
    let camera = spawn_camera(world, &city.flythrough().camera_at(0.0, 16.0 / 9.0), FAR);
    Fixture { city, app, entities, camera }
}

impl Fixture {
    /// Moves the camera to time `t` of the fly-through and runs one frame.
    fn frame(&mut self, t: f32) {
        let camera = self.city.flythrough().camera_at(t, 16.0 / 9.0);
        set_camera(self.app.world_mut(), self.camera, &camera, FAR);
        self.app.update();
    }

    fn visible(&self) -> Vec<bool> {
        view_visible(self.app.world(), &self.entities)
    }

    /// The objects as the exact rendering sees them this frame, at `width` x `height`.
    fn exact(&self, width: u32, height: u32) -> Vec<bool> {
        let world = self.app.world();
        let objects: Vec<ReferenceObject> = self
            .city
            .scene
            .objects
            .iter()
            .zip(&self.entities)
            .map(|(object, &entity)| {
                ReferenceObject::new(&self.city.scene.meshes[object.mesh as usize], world_transform(world, entity))
            })
            .collect();
        let camera = cullet_camera(world, self.camera, Some(FAR));
        let settings = ReferenceSettings { width, height, cull_back_faces: true };
        let exact = render_ids(&camera, &objects, &settings).visibility().visible;
        (0..objects.len()).map(|i| exact.contains(i)).collect()
    }
}

/// Entities visible in some view, the camera's own included (Bevy's check makes it visible too).
fn visible_in_world(app: &mut bevy_app::App) -> usize {
    let world = app.world_mut();
    world.query::<&ViewVisibility>().iter(world).filter(|v| v.get()).count()
}

fn settings(occlusion: bool) -> CulletSettings {
    CulletSettings { occlusion: OcclusionSettings { enabled: occlusion, ..Default::default() }, ..Default::default() }
}

#[test]
fn with_occlusion_off_the_plugin_keeps_what_bevy_keeps_and_everything_visible() {
    let mut bevy = fixture(3000, None);
    let mut plugin = fixture(3000, Some(settings(false)));
    let (mut bevy_total, mut plugin_total, mut extra_total) = (0, 0, 0);
    for t in TIMES {
        bevy.frame(t);
        plugin.frame(t);
        let (theirs, ours) = (bevy.visible(), plugin.visible());
        let missing: Vec<usize> = (0..ours.len()).filter(|&i| theirs[i] && !ours[i]).collect();
        assert!(missing.is_empty(), "t = {t}: Bevy keeps {missing:?}, the plugin culls them");
        // Cullet tests each object's world box; Bevy tests the oriented box, tighter for rotated objects
        // (the city's crates and cars). Every extra object's world box is one Bevy's own test keeps.
        let extra: Vec<usize> = (0..ours.len()).filter(|&i| !theirs[i] && ours[i]).collect();
        let kept_by_bevy_as_world_box = |i: usize| {
            let world = plugin.app.world();
            let store = world.resource::<CulletStore>().store();
            let bounds = store.get(store.slot_of(plugin.entities[i]).unwrap()).unwrap();
            let v = |v: glam::Vec3| bevy_math::Vec3A::from_array(v.to_array());
            let aabb = Aabb { center: v(bounds.center), half_extents: v(bounds.half_extent) };
            let frustum = world.get::<Frustum>(plugin.camera).unwrap();
            frustum.intersects_obb(&aabb, &bevy_math::Affine3A::IDENTITY, true, false)
        };
        let unexplained: Vec<usize> = extra.iter().copied().filter(|&i| !kept_by_bevy_as_world_box(i)).collect();
        assert!(unexplained.is_empty(), "t = {t}: the plugin keeps {unexplained:?}, whose world boxes Bevy culls");
        extra_total += extra.len();
        let exact = plugin.exact(480, 270);
        let lost: Vec<usize> = (0..ours.len()).filter(|&i| exact[i] && !ours[i]).collect();
        assert!(lost.is_empty(), "t = {t}: visible objects {lost:?} culled");
        bevy_total += theirs.iter().filter(|&&v| v).count();
        plugin_total += ours.iter().filter(|&&v| v).count();

        // The camera's list holds exactly the visible entities, sorted, in the entities' visibility class.
        let world = plugin.app.world();
        let listed = world.get::<VisibleEntities>(plugin.camera).unwrap().get(TypeId::of::<Drawn>()).to_vec();
        let mut expected: Vec<Entity> = (0..ours.len()).filter(|&i| ours[i]).map(|i| plugin.entities[i]).collect();
        expected.sort_unstable();
        assert_eq!(listed, expected, "t = {t}");
        let stats = *world.get::<CulletView>(plugin.camera).unwrap().stats();
        assert_eq!((stats.objects, stats.after_frustum), (3000, expected.len()));
        assert_eq!(stats.visible, visible_in_world(&mut plugin.app), "t = {t}: the count includes the camera");
    }
    assert_eq!(bevy_total + extra_total, plugin_total);
    // Rotated objects at the frustum's sides are few.
    assert!(extra_total * 50 <= plugin_total, "{extra_total} extra of {plugin_total}");
    assert!(plugin_total < TIMES.len() * 3000 / 2, "the frustum culls most of the city: {plugin_total}");
}

#[test]
fn with_occlusion_on_nothing_visible_is_culled_and_occlusion_pays() {
    let mut plugin = fixture(3000, Some(settings(true)));
    let (mut after_frustum, mut after_occlusion) = (0, 0);
    for t in TIMES {
        plugin.frame(t);
        let ours = plugin.visible();
        let exact = plugin.exact(640, 360);
        let lost: Vec<usize> = (0..ours.len()).filter(|&i| exact[i] && !ours[i]).collect();
        assert!(lost.is_empty(), "t = {t}: visible objects {lost:?} culled");
        let stats = *plugin.app.world().get::<CulletView>(plugin.camera).unwrap().stats();
        assert!(stats.occluders > 0, "t = {t}: {stats:?}");
        assert_eq!(stats.visible, visible_in_world(&mut plugin.app));
        (after_frustum, after_occlusion) =
            (after_frustum + stats.after_frustum, after_occlusion + stats.after_occlusion);
    }
    assert!(
        after_occlusion * 10 < after_frustum * 9,
        "occlusion culls over a tenth: {after_occlusion} of {after_frustum}"
    );
}

/// The plugin's default, a masked buffer standing for the camera's viewport (here at its size), hides nothing
/// the exact rendering at the viewport's resolution shows, and culls more than the 256x144 buffer.
#[test]
fn the_default_buffer_for_the_viewport_culls_nothing_visible_at_the_viewports_resolution() {
    let mut plugin = fixture(3000, Some(CulletSettings::default()));
    let mut fixed = fixture(3000, Some(settings(true)));
    let physical_size = bevy_math::UVec2::new(640, 360);
    let viewport = bevy_camera::Viewport { physical_size, ..Default::default() };
    plugin.app.world_mut().get_mut::<bevy_camera::Camera>(plugin.camera).unwrap().viewport = Some(viewport);
    let (mut after_frustum, mut kept, mut kept_by_fixed) = (0, 0, 0);
    for t in TIMES {
        plugin.frame(t);
        fixed.frame(t);
        let view = plugin.app.world().get::<CulletView>(plugin.camera).unwrap();
        let depth = view.depth();
        assert_eq!((depth.width(), depth.height(), depth.texel_size()), (160, 90, 4), "640x360 in 4x4 blocks");
        let ours = plugin.visible();
        let exact = plugin.exact(640, 360);
        let lost: Vec<usize> = (0..ours.len()).filter(|&i| exact[i] && !ours[i]).collect();
        assert!(lost.is_empty(), "t = {t}: visible objects {lost:?} culled");
        let stats = *view.stats();
        (after_frustum, kept) = (after_frustum + stats.after_frustum, kept + stats.after_occlusion);
        kept_by_fixed += fixed.app.world().get::<CulletView>(fixed.camera).unwrap().stats().after_occlusion;
    }
    assert!(kept * 10 < after_frustum * 9, "occlusion culls over a tenth: {kept} of {after_frustum}");
    assert!(kept < kept_by_fixed, "{kept} kept against the 256x144 buffer's {kept_by_fixed}");
}

#[test]
fn with_every_object_kept_each_is_shown_and_listed_once() {
    // Frustum culling off: all 3000 objects kept, which the write splits over several rayon tasks.
    let mut plugin = fixture(3000, Some(CulletSettings { frustum: false, ..settings(false) }));
    for t in [0.0, 10.0] {
        plugin.frame(t);
        assert!(plugin.visible().iter().all(|&v| v), "t = {t}: an object not shown");
        let world = plugin.app.world();
        let listed = world.get::<VisibleEntities>(plugin.camera).unwrap().get(TypeId::of::<Drawn>()).to_vec();
        let mut expected = plugin.entities.clone();
        expected.sort_unstable();
        assert_eq!(listed, expected, "t = {t}: the camera's list");
        let stats = *world.get::<CulletView>(plugin.camera).unwrap().stats();
        assert_eq!((stats.after_frustum, stats.after_occlusion), (3000, 3000));
        assert_eq!(stats.visible, visible_in_world(&mut plugin.app), "t = {t}");
    }
    // Despawning moves the store's last entities into the holes, out of the entities' order, and an entity
    // Cullet does not cull (`NoFrustumCulling`) is listed after the kept ones: the list is sorted all the same.
    let first_stored = plugin.app.world().resource::<CulletStore>().store().entities()[..3].to_vec();
    for entity in first_stored {
        plugin.entities.retain(|&e| e != entity);
        plugin.app.world_mut().despawn(entity);
    }
    let aabb = Aabb::from_min_max(bevy_math::Vec3::splat(-0.5), bevy_math::Vec3::splat(0.5));
    let other = (aabb, bevy_transform::components::Transform::default(), drawn(), NoFrustumCulling);
    let other = plugin.app.world_mut().spawn((other, bevy_camera::visibility::Visibility::default())).id();
    plugin.frame(20.0);
    assert!(!plugin.app.world().resource::<CulletStore>().store().entities().is_sorted());
    let world = plugin.app.world();
    let listed = world.get::<VisibleEntities>(plugin.camera).unwrap().get(TypeId::of::<Drawn>()).to_vec();
    let mut expected: Vec<Entity> = plugin.entities.iter().copied().chain([other]).collect();
    expected.sort_unstable();
    assert_eq!(listed, expected, "after despawns, with an entity Cullet does not cull");
}
