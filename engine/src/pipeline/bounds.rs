//! The `bevy_ecs` systems and observers that keep the [`BoundsStore`] in step with the entities' components.

use crate::bounds::{
    self, BoundsError, BoundsRejected, BoundsStore, LocalBounds, ObjectTransform, Static, UpdatePiece,
};
use crate::occluders::Occluder;
use crate::parallel::{self, Stage};
use bevy_ecs::change_detection::Tick;
use bevy_ecs::entity::EntityHashMap;
use bevy_ecs::prelude::*;
use glam::Affine3A;
use rayon::prelude::*;
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
pub fn sync_bounds(mut commands: Commands, mut store: ResMut<BoundsStore>, objects: MovableObjects) {
    let start = Instant::now();
    let _stage = Stage::Bounds.enter();
    // Many objects may move in a frame (200 000 cars in a 1e7-object city): the walk over every movable
    // object's change ticks and the bounds of those that changed are cut into tasks, then stored in order.
    let (pieces, previous) = changed_pieces(&store, &objects);
    let updated = pieces.iter().map(|piece| piece.updates.len()).sum();
    match store.apply_pieces(pieces) {
        // Each object stored in place: only an earlier rejection has something to report (that it is over).
        None => {
            for (&entity, rejected) in &previous {
                report(&mut store, &mut commands, entity, Ok(0), Some(rejected));
            }
        }
        Some(outcomes) => {
            for (entity, outcome) in outcomes {
                report(&mut store, &mut commands, entity, outcome, previous.get(&entity));
            }
        }
    }
    store.tighten_some_groups(TIGHTEN_BUDGET);
    store.recomputed_last_sync = updated;
    store.last_sync_time = start.elapsed();
}

/// The objects the bounds stage keeps up to date: every one not [`Static`], with an earlier rejection where
/// there was one.
type MovableObjects<'w, 's> = Query<
    'w,
    's,
    (Entity, Ref<'static, LocalBounds>, Ref<'static, ObjectTransform>, Option<&'static BoundsRejected>),
    Without<Static>,
>;

/// Rows of one table of movable objects, walked by one task of the bounds stage.
struct TableRows<'w> {
    entities: &'w [Entity],
    locals: &'w [LocalBounds],
    transforms: &'w [ObjectTransform],
    /// The change ticks of the local bounds and of the transforms.
    changed: [&'w [Tick]; 2],
    rejected: Option<&'w [BoundsRejected]>,
    rows: std::ops::Range<usize>,
    /// The stage's last run and this one: rows changed in between are updated.
    last_run: Tick,
    this_run: Tick,
}

/// Rows of a table one task of the bounds stage walks, looking at their change ticks.
const WALK_ROWS: usize = 1024;

/// The updates of every object of `objects` whose [`LocalBounds`] or [`ObjectTransform`] changed since the
/// stage last ran, in the order of the query: found in parallel over ranges of table rows, then computed in
/// parallel over pieces of each range's changed objects, none larger than [`bounds::store::piece_len`]; and
/// the earlier rejection of each that had one.
fn changed_pieces(store: &BoundsStore, objects: &MovableObjects) -> (Vec<UpdatePiece>, EntityHashMap<BoundsRejected>) {
    let Ok(tables) = objects.contiguous_iter() else {
        // Not stored in tables (not the case of the engine's components): one walk on this thread.
        let changed = objects.iter().filter(|(_, local, transform, _)| local.is_changed() || transform.is_changed());
        let (mut moved, mut previous) = (Vec::new(), EntityHashMap::default());
        for (entity, local, transform, rejected) in changed {
            moved.push((entity, *local, transform.0));
            if let Some(rejected) = rejected {
                previous.insert(entity, rejected.clone());
            }
        }
        let piece = store.compute_piece(moved);
        return (vec![piece], previous);
    };
    let mut ranges = Vec::new();
    for (entities, locals, transforms, rejected) in tables {
        let (last_run, this_run) = (locals.last_run_tick(), locals.this_run_tick());
        let changed = [locals.changed_ticks_slice(), transforms.changed_ticks_slice()];
        let (locals, transforms) = (locals.into_inner(), transforms.into_inner());
        for first in (0..entities.len()).step_by(WALK_ROWS) {
            let rows = first..(first + WALK_ROWS).min(entities.len());
            ranges.push(TableRows { entities, locals, transforms, changed, rejected, rows, last_run, this_run });
        }
    }
    // The walk looks at every movable row's ticks; the bounds are computed afterwards, in pieces sized by how
    // many changed, so that no task computes many more than the others (moving objects are rarely spread
    // evenly over the rows).
    let walked: Vec<(&TableRows, Vec<usize>)> = parallel::region(|region| {
        ranges.par_iter().map(|table| region.task(|| (table, table.changed_rows()))).collect()
    });
    let per_piece = bounds::store::piece_len(walked.iter().map(|(_, rows)| rows.len()).sum());
    let chunks: Vec<(&TableRows, &[usize])> =
        walked.iter().flat_map(|(table, rows)| rows.chunks(per_piece).map(move |chunk| (*table, chunk))).collect();
    let pieces = parallel::region(|region| {
        let piece = |(table, rows): (&TableRows, &[usize])| region.task(|| store.compute_piece(table.objects(rows)));
        chunks.into_par_iter().map(piece).collect()
    });
    let previous = walked.iter().flat_map(|(table, rows)| table.rejections(rows)).collect();
    (pieces, previous)
}

impl TableRows<'_> {
    /// This range's rows whose local bounds or transform changed between the stage's last run and this one.
    fn changed_rows(&self) -> Vec<usize> {
        let newer =
            |row: &usize| self.changed.iter().any(|ticks| ticks[*row].is_newer_than(self.last_run, self.this_run));
        self.rows.clone().filter(newer).collect()
    }

    /// The entity, local bounds and transform of each of `rows`, in order.
    fn objects(&self, rows: &[usize]) -> impl Iterator<Item = (Entity, LocalBounds, Affine3A)> {
        rows.iter().map(|&row| (self.entities[row], self.locals[row], self.transforms[row].0))
    }

    /// The earlier rejection of each of `rows` that had one.
    fn rejections(&self, rows: &[usize]) -> Vec<(Entity, BoundsRejected)> {
        match self.rejected {
            Some(rejected) => rows.iter().map(|&row| (self.entities[row], rejected[row].clone())).collect(),
            None => Vec::new(),
        }
    }
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
        // The slot was just looked up.
        let _ = store.replace_occluder(slot);
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
