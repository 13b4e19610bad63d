//! The `bevy_ecs` systems and observers that keep the [`BoundsStore`] in step with the entities' components.

use crate::bounds::{BoundsError, BoundsRejected, BoundsStore, LocalBounds, ObjectTransform, Static};
use crate::occluders::Occluder;
use crate::parallel::Stage;
use bevy_ecs::prelude::*;
use glam::Affine3A;
use std::time::Instant;

/// Group boxes [`sync_bounds`] tightens per frame at most (seed 001 section 4.3.4: spread work over frames).
pub const TIGHTEN_BUDGET: usize = 256;

/// Reports the outcome of [`BoundsStore::update`]: a new error is logged, kept for [`BoundsStore::take_errors`] and
/// marked with [`BoundsRejected`]; success clears an old mark. The same error twice is reported once.
fn report(
    store: &mut BoundsStore,
    commands: &mut Commands,
    entity: Entity,
    outcome: Result<usize, BoundsError>,
    previous: Option<&BoundsRejected>,
) {
    match (outcome, previous) {
        (Ok(_), Some(_)) => {
            commands.entity(entity).try_remove::<BoundsRejected>();
        }
        (Ok(_), None) => {}
        // Compared by kind: a NaN payload never equals itself.
        (Err(error), Some(BoundsRejected(old))) if std::mem::discriminant(old) == std::mem::discriminant(&error) => {}
        (Err(error), _) => {
            tracing::warn!("{error}");
            store.errors.push(error);
            commands.entity(entity).try_insert(BoundsRejected(error));
        }
    }
}

/// Recomputes the bounds of non-[`Static`] objects whose [`LocalBounds`] or [`ObjectTransform`] were mutated
/// since the last run. A frame in which nothing moved touches no bounds, and static objects are not even
/// scanned. (New objects were stored already by [`on_bounds_inserted`]; their first run counts them again.)
///
/// Invalid input is never stored: the entity gets [`BoundsRejected`], the error is logged and kept in
/// [`BoundsStore::take_errors`], and an entity that was stored before is removed from the store.
#[allow(clippy::type_complexity)]
pub fn sync_bounds(
    mut commands: Commands,
    mut store: ResMut<BoundsStore>,
    changed: Query<
        (Entity, &LocalBounds, &ObjectTransform, Option<&BoundsRejected>),
        (Without<Static>, Or<(Changed<LocalBounds>, Changed<ObjectTransform>)>),
    >,
) {
    let start = Instant::now();
    let _stage = Stage::Bounds.enter();
    // Many objects may move in a frame (200 000 cars in a 1e7-object city): their bounds are computed in
    // parallel, then stored in order (`BoundsStore::update_many`).
    let (objects, previous): (Vec<(Entity, LocalBounds, Affine3A)>, Vec<Option<BoundsRejected>>) = changed
        .iter()
        .map(|(entity, local, transform, previous)| ((entity, *local, transform.0), previous.cloned()))
        .unzip();
    let outcomes = store.update_many(&objects);
    for ((&(entity, ..), outcome), previous) in objects.iter().zip(outcomes).zip(&previous) {
        report(&mut store, &mut commands, entity, outcome, previous.as_ref());
    }
    store.tighten_some_groups(TIGHTEN_BUDGET);
    store.recomputed_last_sync = objects.len();
    store.last_sync_time = start.elapsed();
}

/// Observer: stores an object as soon as it has both [`LocalBounds`] and [`ObjectTransform`], and re-stores it
/// whenever either is inserted again.
pub fn on_bounds_inserted(
    event: On<Insert<(LocalBounds, ObjectTransform)>>,
    mut commands: Commands,
    mut store: ResMut<BoundsStore>,
    objects: Query<(&LocalBounds, &ObjectTransform, Option<&BoundsRejected>, Has<Occluder>)>,
) {
    let entity = event.entity;
    if let Ok((local, transform, previous, has_occluder)) = objects.get(entity) {
        let outcome = store.update(entity, local, transform);
        if let Ok(slot) = outcome {
            store.mark_occluder(slot, has_occluder);
        }
        report(&mut store, &mut commands, entity, outcome, previous);
    }
}

/// Observer: marks the object's slot as carrying an occluder (if it is stored already; otherwise
/// [`on_bounds_inserted`] marks it when it is).
pub fn on_occluder_inserted(event: On<Insert<Occluder>>, mut store: ResMut<BoundsStore>) {
    if let Some(slot) = store.slot_of(event.entity) {
        store.mark_occluder(slot, true);
    }
}

/// Observer: clears the occluder mark of the object's slot.
pub fn on_occluder_removed(event: On<Remove<Occluder>>, mut store: ResMut<BoundsStore>) {
    if let Some(slot) = store.slot_of(event.entity) {
        store.mark_occluder(slot, false);
    }
}

/// Observer: when an entity loses its [`LocalBounds`] or [`ObjectTransform`] (or is despawned), it is
/// swap-removed from the store at once. O(1).
pub fn on_bounds_removed(event: On<Remove<(LocalBounds, ObjectTransform)>>, mut store: ResMut<BoundsStore>) {
    store.remove(event.entity);
}
