//! Entities and cameras coming, moving, hiding and going in a headless Bevy app with the plugin.

mod support;

use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::{NoFrustumCulling, RenderLayers, Visibility, VisibleEntities};
use bevy_cullet::{CulletSettings, CulletStore, CulletView, NoCulletOcclusion};
use bevy_ecs::prelude::*;
use bevy_math::Vec3;
use bevy_transform::prelude::*;
use cullet::Occluder;
use cullet::culler::OcclusionSettings;
use cullet::mesh::Mesh;
use cullet::raster::RasterMode;
use std::any::TypeId;
use support::*;

/// A camera at the origin looking down -Z (90 degrees, square), far plane at 1000.
fn camera_looking(forward: glam::Vec3) -> cullet::Camera {
    cullet::Camera { fov_y: 90f32.to_radians(), aspect: 1.0, ..cullet::Camera::looking_at(glam::Vec3::ZERO, forward) }
}

fn unit_box() -> Aabb {
    Aabb::from_min_max(Vec3::splat(-0.5), Vec3::splat(0.5))
}

fn spawn_box(app: &mut bevy_app::App, at: Vec3) -> Entity {
    app.world_mut().spawn((unit_box(), Transform::from_translation(at), Visibility::default(), drawn())).id()
}

fn visible(app: &bevy_app::App, entity: Entity) -> bool {
    view_visible(app.world(), &[entity])[0]
}

fn listed(app: &bevy_app::App, camera: Entity) -> Vec<Entity> {
    app.world().get::<VisibleEntities>(camera).unwrap().get(TypeId::of::<Drawn>()).to_vec()
}

#[test]
fn spawning_moving_hiding_and_despawning_follow_within_the_frame() {
    let mut app = app(Some(CulletSettings::default()));
    let camera = spawn_camera(app.world_mut(), &camera_looking(glam::Vec3::NEG_Z), 1000.0);
    let ahead = spawn_box(&mut app, Vec3::new(0.0, 0.0, -5.0));
    let behind = spawn_box(&mut app, Vec3::new(0.0, 0.0, 5.0));
    app.update();
    assert!(visible(&app, ahead) && !visible(&app, behind));
    assert_eq!(listed(&app, camera), vec![ahead]);

    // Moved in front: visible the same frame.
    app.world_mut().get_mut::<Transform>(behind).unwrap().translation = Vec3::new(2.0, 0.0, -5.0);
    app.update();
    assert!(visible(&app, behind));

    // Hidden: not visible, and not listed.
    *app.world_mut().get_mut::<Visibility>(ahead).unwrap() = Visibility::Hidden;
    app.update();
    assert!(!visible(&app, ahead) && visible(&app, behind));
    assert_eq!(listed(&app, camera), vec![behind]);

    // Despawned: gone from the store at once; the rest still culls.
    app.world_mut().despawn(behind);
    assert_eq!(app.world().resource::<CulletStore>().store().len(), 1);
    *app.world_mut().get_mut::<Visibility>(ahead).unwrap() = Visibility::Inherited;
    app.update();
    assert!(visible(&app, ahead));
    assert_eq!(listed(&app, camera), vec![ahead]);

    // Nothing changed: the next frame reuses the result and writes the same.
    app.update();
    let view = app.world().get::<CulletView>(camera).unwrap();
    assert!(view.stats().reused);
    assert!(visible(&app, ahead));
}

#[test]
fn render_layers_and_two_cameras_each_get_their_own_view() {
    let mut app = app(Some(CulletSettings::default()));
    let front = spawn_camera(app.world_mut(), &camera_looking(glam::Vec3::NEG_Z), 1000.0);
    let back = spawn_camera(app.world_mut(), &camera_looking(glam::Vec3::Z), 1000.0);
    let ahead = spawn_box(&mut app, Vec3::new(0.0, 0.0, -5.0));
    let behind = spawn_box(&mut app, Vec3::new(0.0, 0.0, 5.0));
    app.update();
    assert_eq!(listed(&app, front), vec![ahead]);
    assert_eq!(listed(&app, back), vec![behind]);
    assert!(visible(&app, ahead) && visible(&app, behind));

    // On layer 1 only: the layer-0 cameras no longer see it; a layer-1 camera does.
    app.world_mut().entity_mut(ahead).insert(RenderLayers::layer(1));
    app.update();
    assert!(!visible(&app, ahead));
    assert!(listed(&app, front).is_empty());
    app.world_mut().entity_mut(front).insert(RenderLayers::layer(1));
    app.update();
    assert_eq!(listed(&app, front), vec![ahead]);
    assert_eq!(listed(&app, back), vec![behind]);

    // An inactive camera is skipped, as Bevy skips it: the other still culls.
    app.world_mut().get_mut::<bevy_camera::Camera>(front).unwrap().is_active = false;
    app.update();
    assert!(!visible(&app, ahead) && visible(&app, behind));
}

/// A wall (with an occluder) between the camera and a box, after one frame.
fn walled() -> (bevy_app::App, Entity, Entity, Entity) {
    let (mut app, camera, wall, hidden_box) = wall_and_box(-4.0);
    app.update();
    (app, camera, wall, hidden_box)
}

/// A camera at the origin looking down -Z, a wide wall (with an occluder) at `wall_z` and a box at z = -20, not
/// yet updated: the app, the camera, the wall, the box.
fn wall_and_box(wall_z: f32) -> (bevy_app::App, Entity, Entity, Entity) {
    let mut app = app(Some(CulletSettings::default()));
    let camera = spawn_camera(app.world_mut(), &camera_looking(glam::Vec3::NEG_Z), 1000.0);
    let occluder = Occluder::new(Mesh::unit_cube(1).triangle_soup());
    let wall = Transform::from_xyz(0.0, 0.0, wall_z).with_scale(Vec3::new(40.0, 40.0, 1.0));
    let wall = app.world_mut().spawn((unit_box(), wall, Visibility::default(), drawn(), occluder)).id();
    let boxed = spawn_box(&mut app, Vec3::new(0.0, 0.0, -20.0));
    (app, camera, wall, boxed)
}

/// Moves `camera` (of [`wall_and_box`]) `frame` thousandths along x and runs a frame: a camera that drifts a
/// little, so that no frame reuses the last one's result. Returns its stats.
fn drifted_frame(app: &mut bevy_app::App, camera: Entity, frame: u32) -> bevy_cullet::ViewStats {
    let at = glam::Vec3::new(frame as f32 * 1e-3, 0.0, 0.0);
    set_camera(app.world_mut(), camera, &cullet::Camera { position: at, ..camera_looking(glam::Vec3::NEG_Z) }, 1000.0);
    app.update();
    *app.world().get::<CulletView>(camera).unwrap().stats()
}

#[test]
fn occluders_hide_what_is_behind_them_while_they_are_shown() {
    let (mut app, camera, wall, hidden_box) = walled();
    assert!(visible(&app, wall) && !visible(&app, hidden_box));
    let stats = *app.world().get::<CulletView>(camera).unwrap().stats();
    assert_eq!((stats.after_frustum, stats.after_occlusion, stats.occluders), (2, 1, 1));

    // A hidden wall hides nothing.
    *app.world_mut().get_mut::<Visibility>(wall).unwrap() = Visibility::Hidden;
    app.update();
    assert!(!visible(&app, wall) && visible(&app, hidden_box));
    *app.world_mut().get_mut::<Visibility>(wall).unwrap() = Visibility::Inherited;
    app.update();
    assert!(!visible(&app, hidden_box));

    // Hidden on a frame the camera moved (culled in full, so the change is not looked for), then with the
    // camera still (the last result reused): the box stays visible; shown again, the still camera sees that.
    *app.world_mut().get_mut::<Visibility>(wall).unwrap() = Visibility::Hidden;
    app.world_mut().get_mut::<Transform>(camera).unwrap().translation.x += 0.01;
    app.update();
    assert!(visible(&app, hidden_box));
    app.update();
    assert!(visible(&app, hidden_box) && app.world().get::<CulletView>(camera).unwrap().stats().reused);
    *app.world_mut().get_mut::<Visibility>(wall).unwrap() = Visibility::Inherited;
    app.update();
    assert!(!visible(&app, hidden_box));

    // Without its occluder, neither.
    app.world_mut().entity_mut(wall).remove::<Occluder>();
    app.update();
    assert!(visible(&app, hidden_box));
}

/// Occlusion that hides nothing (a wall behind everything) is skipped after 8 such frames, for 30, then tried
/// again. While it is skipped, everything the frustum keeps is visible: a box behind the wall moved in front of
/// it too, until the next try hides it.
#[test]
fn occlusion_that_hides_too_little_is_skipped_for_a_while_then_tried_again() {
    let (mut app, camera, wall, boxed) = wall_and_box(-40.0);
    let mut gated = Vec::new();
    for frame in 0..40 {
        if frame == 20 {
            app.world_mut().get_mut::<Transform>(wall).unwrap().translation.z = -4.0;
        }
        let stats = drifted_frame(&mut app, camera, frame);
        gated.push(stats.occlusion_gated);
        if stats.occlusion_gated {
            assert_eq!((stats.occluders, stats.after_occlusion), (0, stats.after_frustum), "frame {frame}");
            assert!(visible(&app, boxed), "frame {frame}");
        }
    }
    // The first 8 frames rasterized the wall and removed nothing; the next 30 skipped it; the 39th tried again
    // and, the wall now in front, hid the box, so the 40th ran too.
    let expected: Vec<bool> = (0..40).map(|frame| (8..38).contains(&frame)).collect();
    assert_eq!(gated, expected);
    assert!(!visible(&app, boxed));

    // With `min_occlusion_benefit` 0 it is never skipped.
    app.world_mut().resource_mut::<CulletSettings>().adaptive.min_occlusion_benefit = 0.0;
    app.world_mut().get_mut::<Transform>(wall).unwrap().translation.z = -40.0;
    for frame in 0..12 {
        assert!(!drifted_frame(&mut app, camera, frame).occlusion_gated, "frame {frame}");
    }
}

/// The occlusion gate counts only the frames where occlusion would run: a camera that opts out while the
/// stage is skipped finds it still skipped when it opts back in, for what was left of the 30 frames.
#[test]
fn frames_without_occlusion_leave_the_skipped_stage_as_it_was() {
    let (mut app, camera, ..) = wall_and_box(-40.0);
    let mut frame = 0;
    let mut step = |app: &mut bevy_app::App| {
        frame += 1;
        drifted_frame(app, camera, frame).occlusion_gated
    };
    // 8 frames removing nothing close the gate; 10 of its 30 frames pass.
    assert!((0..8).all(|_| !step(&mut app)) && (0..10).all(|_| step(&mut app)));
    app.world_mut().entity_mut(camera).insert(NoCulletOcclusion);
    assert!((0..40).all(|_| !step(&mut app)), "no occlusion, so nothing skipped");
    app.world_mut().entity_mut(camera).remove::<NoCulletOcclusion>();
    // The 20 frames left, then the stage runs again.
    assert!((0..20).all(|_| step(&mut app)) && !step(&mut app));
}

/// A still camera over moving boxes: each frame only the boxes that moved are re-tested, and every entity ends
/// up exactly as in an app that culls everything each frame. A moved occluder, or a moved camera, runs the
/// frame in full.
#[test]
fn with_the_camera_still_only_the_entities_that_moved_are_re_tested() {
    let full = CulletSettings {
        adaptive: cullet::culler::AdaptiveSettings { reuse_unchanged: false, ..Default::default() },
        ..Default::default()
    };
    let mut apps = [app(Some(CulletSettings::default())), app(Some(full))];
    let mut spawned = Vec::new();
    for app in &mut apps {
        let camera = spawn_camera(app.world_mut(), &camera_looking(glam::Vec3::NEG_Z), 1000.0);
        let wall = Transform::from_xyz(-3.0, 0.0, -6.0).with_scale(Vec3::new(6.0, 6.0, 1.0));
        let occluder = Occluder::new(Mesh::unit_cube(1).triangle_soup());
        let wall = app.world_mut().spawn((unit_box(), wall, Visibility::default(), drawn(), occluder)).id();
        let boxes: Vec<Entity> = (0..12).map(|i| spawn_box(app, Vec3::new(i as f32 - 6.0, 0.0, -12.0))).collect();
        // Still boxes around them, so that the few moving ones are under an eighth of the store (past that the
        // store stops listing them: re-culling everything costs as much).
        for i in 0..100 {
            spawn_box(app, Vec3::new((i % 20) as f32 * 3.0 - 30.0, (i / 20) as f32 * 3.0 - 6.0, -30.0));
        }
        app.update();
        spawned.push((camera, wall, boxes));
    }
    assert_eq!(spawned[0], spawned[1], "both apps spawn the same entities");
    let (camera, wall, boxes) = spawned.pop().unwrap();
    let (mut hidden_in_view, mut out_of_view) = (false, false);
    for frame in 1..40 {
        for app in &mut apps {
            // Every third box sweeps across the view, behind the wall and out of the frustum at times.
            for (i, &entity) in boxes.iter().enumerate().filter(|(i, _)| i % 3 == 0) {
                let x = ((frame as f32 * 0.7 + i as f32) % 30.0) - 15.0;
                app.world_mut().get_mut::<Transform>(entity).unwrap().translation = Vec3::new(x, 0.0, -12.0);
            }
            if frame == 20 {
                app.world_mut().get_mut::<Transform>(wall).unwrap().translation.x = 3.0;
            }
            if frame == 30 {
                let eye =
                    cullet::Camera { position: glam::Vec3::new(0.5, 0.0, 0.0), ..camera_looking(glam::Vec3::NEG_Z) };
                set_camera(app.world_mut(), camera, &eye, 1000.0);
            }
            app.update();
        }
        let [retesting, full] = &apps;
        let all: Vec<Entity> = boxes.iter().copied().chain([wall]).collect();
        assert_eq!(view_visible(retesting.world(), &all), view_visible(full.world(), &all), "frame {frame}");
        assert_eq!(listed(retesting, camera), listed(full, camera), "frame {frame}");
        let stats = *retesting.world().get::<CulletView>(camera).unwrap().stats();
        let expected = if frame == 20 || frame == 30 { 0 } else { 4 };
        assert_eq!(stats.retested, expected, "frame {frame}");
        assert_eq!(full.world().get::<CulletView>(camera).unwrap().stats().retested, 0);
        for &entity in boxes.iter().step_by(3) {
            let x = retesting.world().get::<Transform>(entity).unwrap().translation.x;
            if !visible(retesting, entity) {
                // The view's edges at the boxes' depth are at x = -12 and 12.
                hidden_in_view |= x.abs() < 11.0;
                out_of_view |= x.abs() > 13.0;
            }
        }
    }
    // Along the way moving boxes were hidden behind the wall and left the view: the re-tests met both.
    assert!(hidden_in_view && out_of_view);
}

#[test]
fn pixel_centre_and_masked_buffers_follow_the_cameras_viewport() {
    let (mut app, camera, _, hidden_box) = walled();
    let buffer = |app: &bevy_app::App| {
        let depth = app.world().get::<CulletView>(camera).unwrap().depth();
        (depth.width(), depth.height(), depth.texel_size())
    };
    let set_viewport = |app: &mut bevy_app::App, width, height| {
        let physical_size = bevy_math::UVec2::new(width, height);
        let viewport = bevy_camera::Viewport { physical_size, ..Default::default() };
        app.world_mut().get_mut::<bevy_camera::Camera>(camera).unwrap().viewport = Some(viewport);
    };
    // The default: a masked buffer (a texel per 4x4 samples) standing for the viewport's pixels, at its size
    // up to 960x540 samples, then at a whole divisor of it.
    set_viewport(&mut app, 320, 180);
    app.update();
    assert_eq!(buffer(&app), (80, 45, 4));
    assert!(!visible(&app, hidden_box));
    set_viewport(&mut app, 1920, 1080);
    app.update();
    assert_eq!(buffer(&app), (240, 135, 4));
    assert!(!visible(&app, hidden_box));
    // A camera with no size known (no viewport, no render target in this headless app) gets the buffer that is
    // conservative at any size.
    app.world_mut().get_mut::<bevy_camera::Camera>(camera).unwrap().viewport = None;
    app.update();
    assert_eq!(buffer(&app), (256, 144, 1));
    assert!(!visible(&app, hidden_box));
    // A pixel-centre or masked buffer with no frame takes the viewport's size.
    let pixel_centres = OcclusionSettings { mode: RasterMode::PixelCentres, ..OcclusionSettings::default() };
    app.world_mut().resource_mut::<CulletSettings>().occlusion = pixel_centres;
    set_viewport(&mut app, 320, 180);
    app.update();
    assert_eq!(buffer(&app), (320, 180, 1));
    assert!(!visible(&app, hidden_box));
    app.world_mut().resource_mut::<CulletSettings>().occlusion.mode = RasterMode::Masked;
    app.update();
    assert_eq!(buffer(&app), (80, 45, 4));
    assert!(!visible(&app, hidden_box));
    // A conservative buffer keeps its size.
    app.world_mut().resource_mut::<CulletSettings>().occlusion = OcclusionSettings::default();
    app.update();
    assert_eq!(buffer(&app), (256, 144, 1));
    assert!(!visible(&app, hidden_box));
}

#[test]
fn settings_and_the_per_camera_opt_out_turn_occlusion_off() {
    let (mut app, camera, _, hidden_box) = walled();
    app.world_mut().resource_mut::<CulletSettings>().occlusion.enabled = false;
    app.update();
    assert!(visible(&app, hidden_box));
    app.world_mut().resource_mut::<CulletSettings>().occlusion.enabled = true;
    app.update();
    assert!(!visible(&app, hidden_box));
    app.world_mut().entity_mut(camera).insert(NoCulletOcclusion);
    app.update();
    assert!(visible(&app, hidden_box));
}

#[test]
fn bad_bounds_and_opted_out_entities_stay_visible() {
    let mut app = app(Some(CulletSettings::default()));
    spawn_camera(app.world_mut(), &camera_looking(glam::Vec3::NEG_Z), 1000.0);
    // Behind the camera, but Cullet cannot trust its bounds: kept, and reported.
    let broken = app
        .world_mut()
        .spawn((
            Aabb { center: bevy_math::Vec3A::splat(f32::NAN), half_extents: bevy_math::Vec3A::ONE },
            Transform::from_xyz(0.0, 0.0, 5.0),
            Visibility::default(),
            drawn(),
        ))
        .id();
    // Behind the camera with NoFrustumCulling: kept, as Bevy keeps it.
    let unculled = spawn_box(&mut app, Vec3::new(0.0, 0.0, 5.0));
    app.world_mut().entity_mut(unculled).insert(NoFrustumCulling);
    // No bounds at all: kept, as Bevy keeps it.
    let unbounded = app.world_mut().spawn((Transform::from_xyz(0.0, 0.0, 5.0), Visibility::default(), drawn())).id();
    app.update();
    assert!(app.world().resource::<CulletStore>().rejected().contains(&broken));
    assert!(visible(&app, broken) && visible(&app, unculled) && visible(&app, unbounded));
    assert_eq!(app.world().resource::<CulletStore>().store().len(), 0);

    // Opting back in culls it.
    app.world_mut().entity_mut(unculled).remove::<NoFrustumCulling>();
    app.update();
    assert!(!visible(&app, unculled));
    assert_eq!(app.world().resource::<CulletStore>().store().len(), 1);

    // Fixed bounds are culled like any others.
    *app.world_mut().get_mut::<Aabb>(broken).unwrap() = unit_box();
    app.update();
    assert!(!visible(&app, broken));
    assert!(app.world().resource::<CulletStore>().rejected().is_empty());
}

#[test]
fn meshes_named_or_marked_as_occluders_occlude_and_are_no_longer_drawn() {
    use bevy_asset::{Assets, Handle};
    use bevy_cullet::OccluderMesh;
    use bevy_ecs::hierarchy::ChildOf;
    use bevy_ecs::name::Name;
    use bevy_mesh::{Mesh, Mesh3d};

    let mut app = app(Some(CulletSettings::default()));
    let camera = spawn_camera(app.world_mut(), &camera_looking(glam::Vec3::NEG_Z), 1000.0);
    let wall = app.world_mut().resource_mut::<Assets<Mesh>>().add(Mesh::from(bevy_shape::Cuboid::new(40.0, 40.0, 1.0)));
    // As Bevy's glTF loader spawns a node: the named node, its primitive a child with the mesh.
    let node = app
        .world_mut()
        .spawn((Name::new("wall_occluder"), Transform::from_xyz(0.0, 0.0, -4.0), Visibility::default()))
        .id();
    let primitive = app.world_mut().spawn((Mesh3d(wall.clone()), ChildOf(node))).id();
    let hidden_box = spawn_box(&mut app, Vec3::new(0.0, 0.0, -20.0));
    // Marked by hand, its mesh not loaded yet: it waits, and is drawn meanwhile.
    let waiting =
        app.world_mut().spawn((Mesh3d(Handle::default()), OccluderMesh, Transform::from_xyz(0.0, 0.0, -2.0))).id();
    app.update();

    let world = app.world();
    assert!(world.get::<Occluder>(primitive).is_some() && world.get::<Mesh3d>(primitive).is_none());
    assert!(world.get::<OccluderMesh>(waiting).is_some() && world.get::<Mesh3d>(waiting).is_some());
    assert!(!visible(&app, hidden_box));
    let stats = *app.world().get::<CulletView>(camera).unwrap().stats();
    assert_eq!(stats.occluders, 1, "{stats:?}");
    // The occluder entity is listed in no class: the renderer has nothing to draw for it.
    assert!(!listed(&app, camera).contains(&primitive));

    // Its mesh arrives: it becomes an occluder too.
    let mesh = app.world_mut().resource_mut::<Assets<Mesh>>().add(Mesh::from(bevy_shape::Cuboid::new(1.0, 1.0, 1.0)));
    app.world_mut().get_mut::<Mesh3d>(waiting).unwrap().0 = mesh;
    app.update();
    assert!(app.world().get::<Occluder>(waiting).is_some() && app.world().get::<OccluderMesh>(waiting).is_none());
}

/// Stands in for `bevy_gltf::GltfExtras`, which Bevy's glTF loader puts on the nodes and primitives that have
/// extras: the plugin finds it by its short type path in the app's type registry.
#[derive(Component, bevy_reflect::Reflect, Default)]
#[reflect(Component)]
struct GltfExtras {
    value: String,
}

#[test]
fn meshes_whose_gltf_extras_say_occluder_occlude_and_are_no_longer_drawn() {
    use bevy_asset::Assets;
    use bevy_ecs::hierarchy::ChildOf;
    use bevy_mesh::{Mesh, Mesh3d};

    let mut app = app(Some(CulletSettings::default()));
    app.register_type::<GltfExtras>();
    let camera = spawn_camera(app.world_mut(), &camera_looking(glam::Vec3::NEG_Z), 1000.0);
    let wall = app.world_mut().resource_mut::<Assets<Mesh>>().add(Mesh::from(bevy_shape::Cuboid::new(40.0, 40.0, 1.0)));
    let extras = |json: &str| GltfExtras { value: json.to_string() };
    // A node whose extras mark it, its primitive a child with the mesh; a primitive marked by its own extras;
    // and one whose extras say otherwise.
    let world = app.world_mut();
    let node = world.spawn((extras(r#"{"occluder": true}"#), Transform::from_xyz(0.0, 0.0, -4.0))).id();
    let primitive = world.spawn((Mesh3d(wall.clone()), ChildOf(node))).id();
    let marked = world
        .spawn((Mesh3d(wall.clone()), extras(r#"{"occluder": true, "lod": 2}"#), Transform::from_xyz(0.0, 0.0, 50.0)))
        .id();
    let unmarked =
        world.spawn((Mesh3d(wall.clone()), extras(r#"{"occluder": false}"#), Transform::from_xyz(0.0, 0.0, 60.0))).id();
    let hidden_box = spawn_box(&mut app, Vec3::new(0.0, 0.0, -20.0));
    app.update();

    let world = app.world();
    for occluder in [primitive, marked] {
        assert!(world.get::<Occluder>(occluder).is_some() && world.get::<Mesh3d>(occluder).is_none());
    }
    assert!(world.get::<Occluder>(unmarked).is_none() && world.get::<Mesh3d>(unmarked).is_some());
    assert!(!visible(&app, hidden_box));
    assert!(app.world().get::<CulletView>(camera).unwrap().stats().occluders >= 1);
}

#[test]
fn switched_off_bevy_checks_visibility_again_and_back_on_the_plugin_does() {
    let (mut app, camera, _, hidden_box) = walled();
    assert!(!visible(&app, hidden_box));
    app.world_mut().resource_mut::<CulletSettings>().enabled = false;
    app.update();
    // Bevy's own check: frustum only, so the box behind the wall is visible; the plugin's stats stand still.
    assert!(visible(&app, hidden_box));
    assert_eq!(listed(&app, camera).len(), 2);
    app.world_mut().resource_mut::<CulletSettings>().enabled = true;
    app.update();
    assert!(!visible(&app, hidden_box));
}

#[test]
fn automatic_occluders_come_from_large_meshes_when_switched_on() {
    use bevy_asset::Assets;
    use bevy_mesh::{Mesh, Mesh3d};
    use cullet::scene::auto_occluders::AutoOccluderSettings;

    let settings = CulletSettings { auto_occluders: Some(AutoOccluderSettings::default()), ..Default::default() };
    let mut app = app(Some(settings));
    spawn_camera(app.world_mut(), &camera_looking(glam::Vec3::NEG_Z), 1000.0);
    let cuboid = |app: &mut bevy_app::App, size: f32| {
        let mesh = Mesh::from(bevy_shape::Cuboid::new(size, size, 1.0));
        app.world_mut().resource_mut::<Assets<Mesh>>().add(mesh)
    };
    // A drawn wall with no occluder of its own, its Aabb from Bevy's own bounds system; and a small box.
    let (wall_mesh, small_mesh) = (cuboid(&mut app, 40.0), cuboid(&mut app, 0.1));
    let wall = app.world_mut().spawn((Mesh3d(wall_mesh), Transform::from_xyz(0.0, 0.0, -4.0))).id();
    let small = app.world_mut().spawn((Mesh3d(small_mesh), Transform::from_xyz(5.0, 0.0, -10.0))).id();
    let hidden_box = spawn_box(&mut app, Vec3::new(0.0, 0.0, -20.0));
    app.update();
    app.update();
    let world = app.world();
    assert!(world.get::<Occluder>(wall).is_some(), "the wall is large: it occludes");
    assert!(world.get::<Occluder>(small).is_none(), "the small box is not");
    assert!(world.get::<Mesh3d>(wall).is_some(), "and is still drawn");
    assert!(visible(&app, wall) && !visible(&app, hidden_box));
}
