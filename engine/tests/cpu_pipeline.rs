//! The CPU pipeline through its one way in, with no feature on (CI runs it with `--no-default-features`): the
//! frustum and occlusion stages on a hand-made scene whose answer is known, and the store following spawns,
//! moves and despawns.

use bevy_ecs::prelude::*;
use cullet::prelude::*;
use glam::{Affine3A, Vec3};

const UNIT: LocalBounds = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) };

fn at(position: Vec3) -> ObjectTransform {
    ObjectTransform(Affine3A::from_translation(position))
}

/// A world with the pipeline installed, a camera at eye height looking down -z, and a wall 20 wide and 10
/// high, 20 ahead, carrying its own box as occluder.
fn world() -> (World, Schedule) {
    let (mut world, mut schedule) = (World::new(), Schedule::default());
    cullet::install(&mut world, &mut schedule, PipelineSettings::default());
    world.insert_resource(Camera::looking_at(Vec3::new(0.0, 2.0, 0.0), Vec3::new(0.0, 2.0, -100.0)));
    let wall = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::new(10.0, 5.0, 0.5) };
    let occluder = Occluder::new(Mesh::unit_cube(1).scaled(wall.half_extent * 2.0, Vec3::ZERO).triangle_soup());
    world.spawn((wall, at(Vec3::new(0.0, 5.0, -20.0)), occluder, Static));
    (world, schedule)
}

fn run(world: &mut World, schedule: &mut Schedule) -> CullStats {
    schedule.run(world);
    world.clear_trackers();
    *world.resource::<CullStats>()
}

fn visible(world: &World, entity: Entity) -> bool {
    let slot = world.resource::<BoundsStore>().slot_of(entity).expect("stored");
    world.resource::<CameraCuller>().visible().contains(slot)
}

#[test]
fn frustum_and_occlusion_decide_a_known_scene() {
    let (mut world, mut schedule) = world();
    let in_front = world.spawn((UNIT, at(Vec3::new(0.0, 2.0, -10.0)))).id();
    let behind_wall = world.spawn((UNIT, at(Vec3::new(0.0, 2.0, -40.0)))).id();
    let above_wall = world.spawn((UNIT, at(Vec3::new(0.0, 25.0, -40.0)))).id();
    let beside_wall = world.spawn((UNIT, at(Vec3::new(30.0, 2.0, -40.0)))).id();
    let behind_camera = world.spawn((UNIT, at(Vec3::new(0.0, 2.0, 10.0)))).id();
    let stats = run(&mut world, &mut schedule);

    assert_eq!(stats.objects, 6);
    assert_eq!(stats.after_frustum, 5, "only the object behind the camera is outside the frustum");
    assert_eq!(stats.occluders, 1);
    for (name, entity, expected) in [
        ("in front of the wall", in_front, true),
        ("behind the wall", behind_wall, false),
        ("above the wall", above_wall, true),
        ("beside the wall", beside_wall, true),
        ("behind the camera", behind_camera, false),
    ] {
        assert_eq!(visible(&world, entity), expected, "{name}");
    }
    assert!(
        world
            .resource::<CameraCuller>()
            .frustum_visible()
            .contains(world.resource::<BoundsStore>().slot_of(behind_wall).unwrap())
    );
}

#[test]
fn moves_and_despawns_are_followed() {
    let (mut world, mut schedule) = world();
    let mover = world.spawn((UNIT, at(Vec3::new(0.0, 2.0, -40.0)))).id();
    let other = world.spawn((UNIT, at(Vec3::new(5.0, 2.0, -10.0)))).id();
    run(&mut world, &mut schedule);
    assert!(!visible(&world, mover), "hidden behind the wall");

    // Out from behind the wall: seen, and only it was recomputed.
    world.get_mut::<ObjectTransform>(mover).unwrap().0.translation.x = 40.0;
    let stats = run(&mut world, &mut schedule);
    assert_eq!(stats.bounds_recomputed, 1);
    assert!(visible(&world, mover));

    // Despawned: gone from the store, the rest still culled.
    world.despawn(other);
    let stats = run(&mut world, &mut schedule);
    assert_eq!(stats.objects, 2);
    assert_eq!(world.resource::<BoundsStore>().slot_of(other), None);
    assert!(visible(&world, mover));

    // Invalid bounds are refused with an error naming the entity, never stored.
    let bad = world.spawn((LocalBounds { center: Vec3::NAN, half_extent: Vec3::ONE }, at(Vec3::ZERO))).id();
    run(&mut world, &mut schedule);
    assert_eq!(world.resource::<BoundsStore>().slot_of(bad), None);
    assert!(world.get::<BoundsRejected>(bad).is_some());
}

/// The scene of the bad-input tests: the wall, and 2,001 boxes in a grid behind and beside it.
fn crowded_world() -> (World, Schedule) {
    let (mut world, schedule) = world();
    for i in 0..2001 {
        let (x, z) = ((i % 69) as f32 - 34.0, -(30.0 + (i / 69) as f32 * 2.0));
        world.spawn((UNIT, at(Vec3::new(x * 2.0, 2.0, z))));
    }
    (world, schedule)
}

/// A camera the docs call invalid is refused by every stage: the frame keeps every object, and the error says
/// why. A valid camera over the same scene culls.
#[test]
fn an_invalid_camera_culls_nothing_anywhere() {
    let (mut world, mut schedule) = crowded_world();
    let valid = run(&mut world, &mut schedule);
    assert_eq!(valid.objects, 2002);
    assert!(valid.after_occlusion < valid.after_frustum, "the wall hides some: {valid:?}");
    let good = *world.resource::<Camera>();
    for (name, camera) in [
        ("fov_y 4", Camera { fov_y: 4.0, ..good }),
        ("fov_y 0", Camera { fov_y: 0.0, ..good }),
        ("near 0", Camera { near: 0.0, ..good }),
        ("near -1", Camera { near: -1.0, ..good }),
        ("aspect NaN", Camera { aspect: f32::NAN, ..good }),
        ("far before near", Camera { far: Some(0.05), ..good }),
        ("no forward", Camera { forward: Vec3::ZERO, ..good }),
    ] {
        world.insert_resource(camera);
        let stats = run(&mut world, &mut schedule);
        assert!(
            matches!(stats.frustum_error, Some(cullet::frustum::FrustumError::InvalidCamera(_))),
            "{name}: {:?}",
            stats.frustum_error
        );
        assert_eq!((stats.after_frustum, stats.after_occlusion), (2002, 2002), "{name}");
        assert_eq!(world.resource::<CameraCuller>().visible().count(), 2002, "{name}");
    }
    world.insert_resource(good);
    assert_eq!(run(&mut world, &mut schedule).after_occlusion, valid.after_occlusion);
}

/// An occlusion buffer past the documented bounds is refused with an error instead of allocated; the frame
/// keeps what the frustum kept. The light views' buffer likewise.
#[test]
fn oversized_occlusion_buffers_are_refused() {
    let (mut world, mut schedule) = crowded_world();
    world.insert_resource(OcclusionSettings { width: 100_000, height: 100_000, ..OcclusionSettings::default() });
    let stats = run(&mut world, &mut schedule);
    assert!(matches!(stats.occlusion_error, Some(cullet::culler::SettingsError::BufferTooLarge { .. })));
    assert_eq!(stats.after_occlusion, stats.after_frustum);
    assert_eq!(stats.occluders, 0);
    for (width, height) in [(0, 144), (20_000, 1), (4097, 4097)] {
        let settings = OcclusionSettings { width, height, ..OcclusionSettings::default() };
        assert!(settings.validate().is_err(), "{width}x{height}");
    }
    assert!(OcclusionSettings { frame: Some((0, 1080)), ..OcclusionSettings::default() }.validate().is_err());

    world.insert_resource(OcclusionSettings::default());
    world.insert_resource(LightOcclusionSettings {
        size: 100_000,
        min_casters: 0,
        ..LightOcclusionSettings::default()
    });
    world.insert_resource(LightViews(vec![LightSource::Sun {
        direction: Vec3::new(0.3, -1.0, 0.2),
        splits: vec![0.1, 20.0, 80.0],
    }]));
    let stats = run(&mut world, &mut schedule);
    assert!(stats.occlusion_error.is_none() && stats.after_occlusion < stats.after_frustum);
    assert!(stats.light_occlusion_error.is_some());
    assert_eq!(stats.light_view_occluded, 0);
}
