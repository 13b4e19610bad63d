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
    world.resource::<OcclusionState>().visible.contains(slot)
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
        world.resource::<FrustumVisible>().0.contains(world.resource::<BoundsStore>().slot_of(behind_wall).unwrap())
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
