//! The ECS bounds store: incremental updates through change detection, O(1) swap-remove, validation, and world
//! boxes that always contain the exactly transformed box.

use bevy_ecs::prelude::*;
use cullet::bounds::{BoundsRejected, GroupBounds, LocalBounds, ObjectTransform, Static, WorldBounds};
use cullet::pipeline::{self, CameraCuller, CullStats};
use cullet::{BoundsError, BoundsStore, Camera};
use glam::{Affine3A, DVec3, Quat, Vec3};
use proptest::prelude::*;

fn world_with_schedule() -> (World, Schedule) {
    let (mut world, mut schedule) = (World::new(), Schedule::default());
    pipeline::install(&mut world, &mut schedule, pipeline::PipelineSettings::default());
    world.insert_resource(Camera::looking_at(Vec3::new(0.0, 0.0, 50.0), Vec3::ZERO));
    (world, schedule)
}

fn frame(world: &mut World, schedule: &mut Schedule) -> CullStats {
    schedule.run(world);
    world.clear_trackers();
    *world.resource::<CullStats>()
}

fn spawn_box(world: &mut World, position: Vec3) -> Entity {
    world
        .spawn((
            LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) },
            ObjectTransform(Affine3A::from_translation(position)),
        ))
        .id()
}

/// Every stored slot points at an entity whose slot points back, with bounds matching its components, and every
/// group box contains its members.
fn assert_store_consistent(world: &mut World) {
    let store = world.resource::<BoundsStore>().clone();
    let mut query = world.query::<(Entity, &LocalBounds, &ObjectTransform, Has<cullet::Occluder>)>();
    let mut seen = 0;
    for (entity, local, transform, has_occluder) in query.iter(world) {
        let Some(slot) = store.slot_of(entity) else { continue };
        assert_eq!(store.occluders().contains(slot), has_occluder, "occluder bit of {entity}");
        assert_eq!(store.entities()[slot], entity);
        assert_eq!(store.get(slot).unwrap(), WorldBounds::from_local(entity, local, &transform.0).unwrap());
        assert!(store.groups()[slot / 64].contains(&store.get(slot).unwrap()));
        seen += 1;
    }
    assert_eq!(seen, store.len());
    // Padding past the last object stays zero so SIMD blocks read nothing stale.
    assert!(store.soa().all().iter().all(|array| array[store.len()..].iter().all(|&x| x == 0.0)));
    assert_eq!(store.padded_len() % 64, 0);
}

#[test]
fn only_changed_entities_are_recomputed() {
    let (mut world, mut schedule) = world_with_schedule();
    let entities: Vec<Entity> = (0..100).map(|i| spawn_box(&mut world, Vec3::new(i as f32, 0.0, 0.0))).collect();
    assert_eq!(world.resource::<BoundsStore>().len(), 100, "spawning stores objects at once");
    assert_eq!(frame(&mut world, &mut schedule).bounds_recomputed, 100);
    assert_eq!(frame(&mut world, &mut schedule).bounds_recomputed, 0, "a quiet frame recomputes nothing");
    assert_eq!(frame(&mut world, &mut schedule).bounds_recomputed, 0);

    world.get_mut::<ObjectTransform>(entities[7]).unwrap().0.translation.y = 3.0;
    world.get_mut::<ObjectTransform>(entities[42]).unwrap().0.translation.y = -3.0;
    let stats = frame(&mut world, &mut schedule);
    assert_eq!(stats.bounds_recomputed, 2);
    let slot = world.resource::<BoundsStore>().slot_of(entities[7]).unwrap();
    assert_eq!(world.resource::<BoundsStore>().get(slot).unwrap().center, Vec3::new(7.0, 3.0, 0.0));
    assert_eq!(frame(&mut world, &mut schedule).bounds_recomputed, 0);
    assert_store_consistent(&mut world);
}

/// The store reports which slots it wrote (for consumers that mirror it, like the GPU instances): updates,
/// and the slot a removal fills with the last object.
#[test]
fn written_slots_are_reported_once() {
    let (mut world, mut schedule) = world_with_schedule();
    let entities: Vec<Entity> = (0..10).map(|i| spawn_box(&mut world, Vec3::new(i as f32, 0.0, 0.0))).collect();
    frame(&mut world, &mut schedule);
    let written = world.resource_mut::<BoundsStore>().take_written_slots();
    assert_eq!(written, (0..10).collect::<Vec<u32>>());
    frame(&mut world, &mut schedule);
    assert!(world.resource_mut::<BoundsStore>().take_written_slots().is_empty(), "a quiet frame writes nothing");

    world.get_mut::<ObjectTransform>(entities[3]).unwrap().0.translation.y = 1.0;
    frame(&mut world, &mut schedule);
    world.despawn(entities[5]);
    let store = world.resource::<BoundsStore>();
    let (slot_of_3, moved_into) =
        (store.slot_of(entities[3]).unwrap() as u32, store.slot_of(entities[9]).unwrap() as u32);
    let written = world.resource_mut::<BoundsStore>().take_written_slots();
    assert_eq!(written, vec![slot_of_3, moved_into]);
}

#[test]
fn removal_swaps_the_last_object_into_the_hole() {
    let (mut world, mut schedule) = world_with_schedule();
    let entities: Vec<Entity> = (0..130).map(|i| spawn_box(&mut world, Vec3::new(i as f32, 0.0, 0.0))).collect();
    frame(&mut world, &mut schedule);
    assert_eq!(world.resource::<BoundsStore>().padded_len(), 192);

    let removed_slot = world.resource::<BoundsStore>().slot_of(entities[3]).unwrap();
    let last = *world.resource::<BoundsStore>().entities().last().unwrap();
    world.despawn(entities[3]);
    // Immediately, without running the schedule: the last object now sits in the freed slot.
    assert_eq!(world.resource::<BoundsStore>().len(), 129);
    assert_eq!(world.resource::<BoundsStore>().slot_of(last), Some(removed_slot));
    assert_eq!(world.resource::<BoundsStore>().slot_of(entities[3]), None);
    assert_store_consistent(&mut world);

    // Removing a component (not despawning) removes the object too, and a quiet frame after stays quiet.
    world.entity_mut(entities[10]).remove::<LocalBounds>();
    for &entity in &entities[60..130] {
        world.despawn(entity);
    }
    assert_eq!(frame(&mut world, &mut schedule).bounds_recomputed, 0);
    assert_eq!(world.resource::<BoundsStore>().len(), 58);
    assert_eq!(world.resource::<BoundsStore>().padded_len(), 64, "the arrays shrink by whole words");
    assert_eq!(world.resource::<BoundsStore>().slot_of(entities[10]), None);
    assert_store_consistent(&mut world);

    // Removing an occluder clears its bit.
    world.entity_mut(entities[0]).remove::<cullet::Occluder>();
    assert_store_consistent(&mut world);

    // Re-adding the component brings the object back.
    world.entity_mut(entities[10]).insert(LocalBounds { center: Vec3::ZERO, half_extent: Vec3::ONE });
    assert_eq!(world.resource::<BoundsStore>().len(), 59);
    frame(&mut world, &mut schedule);
    assert_store_consistent(&mut world);
}

#[test]
fn static_objects_are_never_scanned_but_reinsertion_moves_them() {
    let (mut world, mut schedule) = world_with_schedule();
    let statics: Vec<Entity> = (0..50)
        .map(|i| {
            let entity = spawn_box(&mut world, Vec3::new(i as f32, 0.0, 0.0));
            world.entity_mut(entity).insert(Static);
            entity
        })
        .collect();
    let dynamic = spawn_box(&mut world, Vec3::ZERO);
    assert_eq!(world.resource::<BoundsStore>().len(), 51);
    assert_eq!(frame(&mut world, &mut schedule).bounds_recomputed, 1, "only the dynamic object is scanned");
    world.get_mut::<ObjectTransform>(dynamic).unwrap().0.translation.z = -5.0;
    assert_eq!(frame(&mut world, &mut schedule).bounds_recomputed, 1);
    // Static objects move only by inserting a new transform, and are stored again immediately.
    world.entity_mut(statics[4]).insert(ObjectTransform(Affine3A::from_translation(Vec3::new(0.0, 9.0, 0.0))));
    let slot = world.resource::<BoundsStore>().slot_of(statics[4]).unwrap();
    assert_eq!(world.resource::<BoundsStore>().get(slot).unwrap().center, Vec3::new(0.0, 9.0, 0.0));
    assert_eq!(frame(&mut world, &mut schedule).bounds_recomputed, 0);
    assert_store_consistent(&mut world);
}

#[test]
fn invalid_bounds_are_rejected_with_the_entity_named() {
    let (mut world, mut schedule) = world_with_schedule();
    let good = spawn_box(&mut world, Vec3::ZERO);
    let nan = world
        .spawn((
            LocalBounds { center: Vec3::new(f32::NAN, 0.0, 0.0), half_extent: Vec3::ONE },
            ObjectTransform(Affine3A::IDENTITY),
        ))
        .id();
    let negative = world
        .spawn((
            LocalBounds { center: Vec3::ZERO, half_extent: Vec3::new(1.0, -1.0, 1.0) },
            ObjectTransform(Affine3A::IDENTITY),
        ))
        .id();
    let infinite = world
        .spawn((
            LocalBounds { center: Vec3::ZERO, half_extent: Vec3::ONE },
            ObjectTransform(Affine3A::from_translation(Vec3::new(0.0, f32::INFINITY, 0.0))),
        ))
        .id();
    let overflow = world
        .spawn((
            LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(1e30) },
            ObjectTransform(Affine3A::from_scale(Vec3::splat(1e30))),
        ))
        .id();
    frame(&mut world, &mut schedule);

    let store = world.resource::<BoundsStore>();
    assert_eq!(store.entities(), &[good]);
    let errors = world.resource_mut::<BoundsStore>().take_errors();
    assert_eq!(errors.len(), 4);
    assert!(matches!(errors[0], BoundsError::NonFiniteLocal { entity, .. } if entity == nan));
    assert!(matches!(errors[1], BoundsError::NegativeExtent { entity, .. } if entity == negative));
    assert!(matches!(errors[2], BoundsError::NonFiniteTransform { entity } if entity == infinite));
    assert!(matches!(errors[3], BoundsError::WorldOverflow { entity } if entity == overflow));
    assert!(errors[0].to_string().contains(&nan.to_string()), "the message names the entity");
    assert!(world.get::<BoundsRejected>(nan).is_some());

    // A stored object that turns invalid leaves the store (reported), and the rest is untouched.
    world.get_mut::<ObjectTransform>(good).unwrap().0.translation.x = f32::NAN;
    frame(&mut world, &mut schedule);
    assert!(world.resource::<BoundsStore>().is_empty());
    assert!(world.get::<BoundsRejected>(good).is_some());
    // Fixing it brings it back.
    world.get_mut::<ObjectTransform>(good).unwrap().0.translation.x = 0.0;
    frame(&mut world, &mut schedule);
    assert_eq!(world.resource::<BoundsStore>().entities(), &[good]);
    assert!(world.get::<BoundsRejected>(good).is_none());
    assert!(world.resource::<CameraCuller>().frustum_visible().contains(0));
}

proptest! {
    /// The stored f32 box contains the box transformed exactly (in f64), corner for corner, at any scale.
    #[test]
    fn world_bounds_contain_the_exact_box(
        center in prop::array::uniform3(-1e3f32..1e3),
        extent in prop::array::uniform3(0f32..1e3),
        translation in prop::array::uniform3(-1e8f32..1e8),
        scale in prop::array::uniform3(1e-3f32..1e3),
        axis in prop::array::uniform3(-1f32..1.0),
        angle in 0f32..7.0,
    ) {
        let local = LocalBounds { center: Vec3::from(center), half_extent: Vec3::from(extent) };
        let rotation = Quat::from_axis_angle(Vec3::from(axis).normalize_or(Vec3::Y), angle);
        let transform = Affine3A::from_scale_rotation_translation(Vec3::from(scale), rotation, Vec3::from(translation));
        let bounds = WorldBounds::from_local(Entity::PLACEHOLDER, &local, &transform).unwrap();
        let matrix = transform.matrix3.as_dmat3();
        let t = DVec3::from(Vec3::from(transform.translation));
        // In f64: the stored (centre, extent) pair is what culling reads, not a rounded f32 min and max.
        let (min, max) = (
            bounds.center.as_dvec3() - bounds.half_extent.as_dvec3(),
            bounds.center.as_dvec3() + bounds.half_extent.as_dvec3(),
        );
        for corner in 0..8 {
            let sign = Vec3::new((corner & 1) as f32 * 2.0 - 1.0, (corner & 2) as f32 - 1.0, (corner & 4) as f32 / 2.0 - 1.0);
            let exact = matrix * (local.center.as_dvec3() + local.half_extent.as_dvec3() * sign.as_dvec3()) + t;
            prop_assert!(exact.cmpge(min).all() && exact.cmple(max).all(),
                "corner {exact} outside [{min}, {max}]");
        }
        prop_assert!(bounds.radius as f64 >= bounds.half_extent.as_dvec3().length());
        // What the store writes without validating again (`update`, `update_many`) passes the validation.
        prop_assert!(bounds.validate(Entity::PLACEHOLDER).is_ok());
    }
}

/// After objects move away, tightening makes every group box exactly the box grown from its members again (not
/// merely one that contains them), and the supergroup boxes the union of their groups.
#[test]
fn tightened_group_boxes_equal_their_members_box() {
    let (mut world, mut schedule) = world_with_schedule();
    let entities: Vec<Entity> =
        (0..300).map(|i| spawn_box(&mut world, Vec3::new(i as f32 * 1.5, (i % 7) as f32, -(i as f32)))).collect();
    frame(&mut world, &mut schedule);
    for (i, &entity) in entities.iter().enumerate().step_by(3) {
        let far = Vec3::new(-1.0e5 + i as f32 * 0.37, 3.0e4, 7.0 - i as f32);
        world.get_mut::<ObjectTransform>(entity).unwrap().0 = Affine3A::from_translation(far);
    }
    frame(&mut world, &mut schedule);
    for (i, &entity) in entities.iter().enumerate().step_by(3) {
        world.get_mut::<ObjectTransform>(entity).unwrap().0 = Affine3A::from_translation(Vec3::splat(i as f32 * 0.01));
    }
    frame(&mut world, &mut schedule);
    let mut store = world.resource::<BoundsStore>().clone();
    store.tighten_groups();
    for (group, bounds) in store.groups().iter().enumerate() {
        let mut expected = GroupBounds::EMPTY;
        for slot in group * 64..((group + 1) * 64).min(store.len()) {
            expected.grow(&store.get(slot).unwrap());
        }
        assert_eq!(*bounds, expected, "group {group}");
    }
    let union = store.groups().iter().fold(GroupBounds::EMPTY, |acc, g| acc.union(g));
    assert_eq!(store.supergroups()[0], union);
}

/// Each group's occluder radius stays at least the radius of every occluder in it through inserts, moves,
/// removals (which move the last object into the hole) and occluder marks set and cleared; tightening makes it
/// exactly the largest, or 0 for a group without an occluder.
#[test]
fn group_occluder_radii_bound_their_occluders_and_tighten_to_the_largest() {
    let entity = |i: u32| Entity::from_raw_u32(i + 1).unwrap();
    let bounds = |i: u32, size: f32| WorldBounds::new(entity(i), Vec3::new(i as f32, 0.0, 0.0), Vec3::splat(size));
    let check = |store: &BoundsStore, tight: bool| {
        for (group, &radius) in store.occluder_radii().iter().enumerate() {
            let slots = group * 64..((group + 1) * 64).min(store.len());
            let occluders = slots.filter(|&slot| store.occluders().contains(slot));
            let largest = occluders.map(|slot| store.get(slot).unwrap().radius).fold(0.0, f32::max);
            if tight {
                assert_eq!(radius, largest, "group {group}, tightened");
            } else {
                assert!(radius >= largest, "group {group}: {radius} under its occluders' {largest}");
            }
        }
    };
    let mut store = BoundsStore::default();
    for i in 0..300 {
        let slot = store.insert(entity(i), &bounds(i, 1.0 + (i % 5) as f32).unwrap()).unwrap();
        store.set_occluder(slot, i % 3 == 0).unwrap();
    }
    check(&store, false);
    // Clearing marks alone (the largest occluders' here) leaves the groups to tighten.
    store.tighten_groups();
    for i in (0..300).filter(|i| i % 3 == 0 && i % 5 == 4) {
        store.set_occluder(store.slot_of(entity(i)).unwrap(), false).unwrap();
    }
    store.tighten_groups();
    check(&store, true);
    for i in (0..300).step_by(7) {
        let slot = store.slot_of(entity(i)).unwrap();
        store.set(slot, &bounds(i, 9.0 - (i % 4) as f32).unwrap()).unwrap();
        check(&store, false);
    }
    for i in (0..300).step_by(11) {
        let slot = store.slot_of(entity(i)).unwrap();
        store.set_occluder(slot, i % 2 == 0).unwrap();
        check(&store, false);
    }
    for i in (0..300).step_by(5) {
        store.remove(entity(i));
        check(&store, false);
    }
    store.tighten_groups();
    check(&store, true);
}

/// Every write path of the store validates what it writes: `insert`, `set`, `set_occluder` and the component
/// path (`update`) refuse NaN, infinite and negative extents, radii too small for their box and slots out of
/// range with a `BoundsError`, and leave the store exactly as it was.
#[test]
fn every_write_path_refuses_invalid_bounds_and_changes_nothing() {
    let entity = |i: u32| Entity::from_raw_u32(i).unwrap();
    let mut store = BoundsStore::default();
    let good = WorldBounds::new(entity(1), Vec3::new(1.0, 2.0, 3.0), Vec3::ONE).unwrap();
    let slot = store.insert(entity(1), &good).unwrap();
    let before = store.clone();
    let unchanged = |store: &BoundsStore| {
        assert_eq!(store.len(), before.len());
        assert_eq!(store.get(slot), before.get(slot));
        assert_eq!(store.soa().all(), before.soa().all());
        assert_eq!(store.generation(), before.generation());
    };
    let bad = [
        ("NaN centre", WorldBounds { center: Vec3::new(f32::NAN, 0.0, 0.0), ..good }),
        ("infinite centre", WorldBounds { center: Vec3::new(0.0, f32::INFINITY, 0.0), ..good }),
        ("NaN extent", WorldBounds { half_extent: Vec3::new(1.0, f32::NAN, 1.0), ..good }),
        (
            "infinite extent",
            WorldBounds { half_extent: Vec3::new(1.0, 1.0, f32::INFINITY), radius: f32::INFINITY, ..good },
        ),
        ("negative extent", WorldBounds { half_extent: Vec3::new(1.0, -1.0, 1.0), ..good }),
        ("NaN radius", WorldBounds { radius: f32::NAN, ..good }),
        ("radius smaller than the box", WorldBounds { radius: 1.0, ..good }),
    ];
    for (what, bounds) in bad {
        let inserted = store.insert(entity(2), &bounds);
        assert!(matches!(inserted, Err(BoundsError::InvalidWorld { .. })), "insert, {what}: {inserted:?}");
        unchanged(&store);
        let overwritten = store.insert(entity(1), &bounds);
        assert!(matches!(overwritten, Err(BoundsError::InvalidWorld { .. })), "re-insert, {what}: {overwritten:?}");
        unchanged(&store);
        let set = store.set(slot, &bounds);
        assert!(matches!(set, Err(BoundsError::InvalidWorld { entity: e, .. }) if e == entity(1)), "set, {what}");
        unchanged(&store);
        assert!(WorldBounds::new(entity(3), bounds.center, bounds.half_extent).is_err() || what.contains("radius"));
    }
    // Slots past the stored objects (padding included) are errors, not panics.
    for past in [1, 63, 64, usize::MAX] {
        assert_eq!(store.set(past, &good), Err(BoundsError::SlotOutOfRange { slot: past, len: 1 }));
        assert_eq!(store.set_occluder(past, true), Err(BoundsError::SlotOutOfRange { slot: past, len: 1 }));
        assert_eq!(store.get(past), None);
        unchanged(&store);
    }
    // The component path: `update` validates through `from_local`, and drops what it refuses.
    let nan_local = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::new(f32::NAN, 1.0, 1.0) };
    let refused = store.update(entity(1), &nan_local, &ObjectTransform(Affine3A::IDENTITY));
    assert!(matches!(refused, Err(BoundsError::NonFiniteLocal { .. })));
    assert!(store.is_empty(), "an object whose new bounds are refused leaves the store");
    // Valid writes go through.
    assert_eq!(store.insert(entity(1), &good), Ok(0));
    let moved = WorldBounds::new(entity(1), Vec3::splat(9.0), Vec3::splat(0.5)).unwrap();
    assert_eq!(store.set(0, &moved), Ok(()));
    assert_eq!(store.get(0), Some(moved));
    assert_eq!(store.set_occluder(0, true), Ok(()));
    assert!(store.occluders().contains(0));
}

/// `update_many` (the parallel path `sync_bounds` takes) stores exactly what `update` one by one stores, and
/// returns the same outcomes, also when a refused object's removal moves another object mid-batch.
#[test]
fn update_many_equals_update_one_by_one() {
    // Three supergroups of slots, written by tasks of their own.
    const OBJECTS: u32 = 10_000;
    let entity = |i: u32| Entity::from_raw_u32(i + 1).unwrap();
    let unit = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) };
    let mut one_by_one = BoundsStore::default();
    for i in 0..OBJECTS {
        one_by_one
            .update(entity(i), &unit, &ObjectTransform(Affine3A::from_translation(Vec3::splat(i as f32))))
            .unwrap();
    }
    let mut many = one_by_one.clone();
    let nan = LocalBounds { center: Vec3::NAN, ..unit };
    // Moves of early and late objects, a refused one in the middle (its removal moves the last object into its
    // slot), then a move of that last object and a new object.
    let batch: Vec<(Entity, LocalBounds, Affine3A)> = (0..2000)
        .map(|i| (entity(i), unit, Affine3A::from_translation(Vec3::new(i as f32, -1.0, 0.0))))
        .chain([(entity(2500), nan, Affine3A::IDENTITY)])
        .chain([
            (entity(OBJECTS - 1), unit, Affine3A::from_translation(Vec3::X)),
            (entity(2 * OBJECTS), unit, Affine3A::IDENTITY),
        ])
        .collect();
    let expected: Vec<_> =
        batch.iter().map(|(e, local, t)| one_by_one.update(*e, local, &ObjectTransform(*t))).collect();
    let outcomes = many.update_many(&batch);
    // Compared as slots and refusals: the refusal carries a NaN, which equals nothing.
    let slots = |outcomes: &[Result<usize, BoundsError>]| outcomes.iter().map(|o| o.ok()).collect::<Vec<_>>();
    assert_eq!(slots(&outcomes), slots(&expected));
    assert!(matches!(outcomes[2000], Err(BoundsError::NonFiniteLocal { .. })));
    assert_eq!(many.entities(), one_by_one.entities());
    assert_eq!(many.soa().all(), one_by_one.soa().all());
    assert_eq!(many.groups(), one_by_one.groups());
    // Moves only, enough of them and out of slot order: written in parallel, to the same store.
    let moves: Vec<(Entity, LocalBounds, Affine3A)> = (0..OBJECTS - 1)
        .map(|i| (i * 7) % (OBJECTS - 1))
        .filter(|&i| i != 2500) // refused above: no longer stored
        .map(|i| (entity(i), unit, Affine3A::from_translation(Vec3::new(-(i as f32), 2.0 * i as f32, 1.0))))
        .collect();
    many.take_moved_slots();
    one_by_one.take_moved_slots();
    // Some of them occluders, so that their groups' occluder radii grow too.
    for slot in (0..OBJECTS as usize - 1).step_by(5) {
        many.set_occluder(slot, true).unwrap();
        one_by_one.set_occluder(slot, true).unwrap();
    }
    let expected: Vec<_> =
        moves.iter().map(|(e, local, t)| one_by_one.update(*e, local, &ObjectTransform(*t))).collect();
    let outcomes = many.update_many(&moves);
    assert_eq!(slots(&outcomes), slots(&expected));
    assert_eq!(many.soa().all(), one_by_one.soa().all());
    assert_eq!(many.groups(), one_by_one.groups());
    assert_eq!(many.supergroups(), one_by_one.supergroups());
    assert_eq!(many.occluder_radii(), one_by_one.occluder_radii());
    assert_eq!(many.generation(), one_by_one.generation());
    assert_eq!(many.take_moved_slots(), one_by_one.take_moved_slots());
    assert_eq!(many.take_written_slots(), one_by_one.take_written_slots());
    many.tighten_some_groups(usize::MAX);
    one_by_one.tighten_some_groups(usize::MAX);
    assert_eq!(many.groups(), one_by_one.groups());
}
