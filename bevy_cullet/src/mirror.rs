//! Stage 1 in a Bevy app: entities' `Aabb` and `GlobalTransform` mirrored into Cullet's SoA store.

use crate::convert;
use bevy_app::App;
use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::{NoCpuCulling, NoFrustumCulling};
use bevy_ecs::entity::EntityHashSet;
use bevy_ecs::prelude::*;
use bevy_transform::components::GlobalTransform;
use cullet::Occluder;
use cullet::bounds::{BoundsStore, StoreMoves, UpdatePiece};
use rayon::prelude::*;

/// The objects the plugin culls: the bounds of every mirrored entity, and the entities Cullet refused.
#[derive(Resource, Default, Debug)]
pub struct CulletStore {
    pub(crate) store: BoundsStore,
    /// Entities with an `Aabb` and a `GlobalTransform` whose bounds Cullet rejected: always visible. Never
    /// in `store` (checked in [`CulletStore::update`]), which the write in `cull` relies on to show each entity
    /// once.
    pub(crate) rejected: EntityHashSet,
    /// Entities to mirror again whatever changed (they lost `NoFrustumCulling` or `NoCpuCulling`).
    pending: Vec<Entity>,
    /// What the last mirroring changed in place; `None` when too many slots changed to list.
    pub(crate) moves: Option<StoreMoves>,
}

impl CulletStore {
    /// The mirrored bounds (world-space boxes, one slot per entity).
    pub fn store(&self) -> &BoundsStore {
        &self.store
    }

    /// Entities whose bounds Cullet rejected (not finite, too large): each is logged once, kept out of the
    /// store and visible in every view until its bounds are valid again.
    pub fn rejected(&self) -> &EntityHashSet {
        &self.rejected
    }

    /// Stores `objects` (entity, local bounds, transform, has an occluder), or records their rejection.
    fn update(&mut self, objects: &[(Entity, cullet::LocalBounds, glam::Affine3A)], occluders: &[bool]) {
        let outcomes = self.store.update_many(objects);
        let outcomes = objects.iter().map(|&(entity, ..)| entity).zip(outcomes).collect();
        self.record(outcomes, occluders);
    }

    /// Records what storing each entity gave, in order, with whether it carries an occluder: its occluder mark,
    /// or its rejection.
    fn record(&mut self, outcomes: Vec<(Entity, Result<usize, cullet::bounds::BoundsError>)>, occluders: &[bool]) {
        for ((entity, outcome), &has_occluder) in outcomes.into_iter().zip(occluders) {
            match outcome {
                Ok(slot) => {
                    self.rejected.remove(&entity);
                    // The slot was just returned by the store.
                    let _ = self.store.set_occluder(slot, has_occluder);
                }
                Err(error) => {
                    // A rejected entity is never stored (`update_many` dropped it): the write relies on the two
                    // being disjoint to list each entity once.
                    assert!(self.store.slot_of(entity).is_none(), "{entity} both stored and rejected");
                    if self.rejected.insert(entity) {
                        tracing::warn!("bevy_cullet keeps {entity} visible: {error}");
                    }
                }
            }
        }
    }

    fn forget(&mut self, entity: Entity) {
        self.store.remove(entity);
        self.rejected.remove(&entity);
    }
}

/// What the plugin mirrors: bounded entities that Bevy would frustum-cull on the CPU.
type Mirrored = (Without<NoFrustumCulling>, Without<NoCpuCulling>);

/// Mirrors the bounds of entities whose `Aabb` or `GlobalTransform` changed (or that were just spawned), and of
/// those waiting after an opt-out was removed. A frame where nothing moved writes nothing.
///
/// The tables' change ticks are walked in parallel, row ranges at a time, each task computing the new bounds of
/// its changed rows straight into a piece of updates ([`BoundsStore::compute_piece`]); where every one moves
/// an entity already stored, the pieces are written in place, in parallel. Otherwise (new entities, refused
/// bounds) they are stored one by one, in the tables' order, which is the order entities were spawned in
/// within each table: a scene spawned in spatial order stays grouped for the frustum's hierarchy.
#[allow(clippy::type_complexity)]
pub(crate) fn mirror_bounds(
    mut cullet: ResMut<CulletStore>,
    changed: MirroredRows,
    all: Query<(Entity, &Aabb, &GlobalTransform, Has<Occluder>), Mirrored>,
) {
    let mirror = |(entity, aabb, transform, has_occluder): (Entity, &Aabb, &GlobalTransform, bool)| {
        ((entity, convert::local_bounds(aabb), convert::affine(transform)), has_occluder)
    };
    let pieces = changed_pieces(&cullet.store, &changed);
    let occluders: Vec<bool> = pieces.iter().flat_map(|(_, occluders)| occluders.iter().copied()).collect();
    let pieces: Vec<UpdatePiece> = pieces.into_iter().map(|(piece, _)| piece).collect();
    if let Some(outcomes) = cullet.store.apply_pieces(pieces) {
        cullet.record(outcomes, &occluders);
    }
    let pending = std::mem::take(&mut cullet.pending);
    let mut waiting: Vec<Mirror> = pending.into_iter().filter_map(|entity| all.get(entity).ok()).map(mirror).collect();
    if !waiting.is_empty() {
        // An entity pending and changed is stored again: the same bounds.
        waiting.sort_unstable_by_key(|((entity, ..), _)| *entity);
        waiting.dedup_by_key(|((entity, ..), _)| *entity);
        let (objects, occluders): (Vec<_>, Vec<_>) = waiting.into_iter().unzip();
        cullet.update(&objects, &occluders);
    }
    // Taken every frame, so that the list covers exactly the changes since the last mirroring (removals in
    // between change the layout, which the cameras compare too).
    cullet.moves = cullet.store.take_moves();
}

/// The mirrored entities as the change walk reads them.
type MirroredRows<'w, 's> =
    Query<'w, 's, (Entity, Ref<'static, Aabb>, Ref<'static, GlobalTransform>, Has<Occluder>), Mirrored>;

/// Rows of a table one task of the mirroring walks: few and large tasks, as a rayon task costs microseconds to
/// hand out.
const WALK_ROWS: usize = 8192;

/// The updates of every mirrored entity whose `Aabb` or `GlobalTransform` changed since the mirroring last
/// ran, computed in parallel over ranges of table rows, in the query's order, each with whether each of its
/// entities carries an occluder.
fn changed_pieces(store: &BoundsStore, changed: &MirroredRows) -> Vec<(UpdatePiece, Vec<bool>)> {
    let object = |entity, aabb: &Aabb, transform: &GlobalTransform| {
        (entity, convert::local_bounds(aabb), convert::affine(transform))
    };
    let Ok(tables) = changed.contiguous_iter() else {
        // Not stored in tables (not the case of Bevy's components): one walk on this thread.
        let moved = changed.iter().filter(|(_, aabb, transform, _)| aabb.is_changed() || transform.is_changed());
        let (objects, occluders): (Vec<_>, Vec<_>) =
            moved.map(|(entity, aabb, transform, occluder)| (object(entity, &aabb, &transform), occluder)).unzip();
        return vec![(store.compute_piece(objects), occluders)];
    };
    let mut ranges = Vec::new();
    for (entities, aabbs, transforms, occluders) in tables {
        let (last_run, this_run) = (aabbs.last_run_tick(), aabbs.this_run_tick());
        let ticks = [aabbs.changed_ticks_slice(), transforms.changed_ticks_slice()];
        let (aabbs, transforms) = (aabbs.into_inner(), transforms.into_inner());
        for first in (0..entities.len()).step_by(WALK_ROWS) {
            let rows = first..(first + WALK_ROWS).min(entities.len());
            ranges.push((entities, aabbs, transforms, occluders, ticks, rows, last_run, this_run));
        }
    }
    ranges
        .into_par_iter()
        .map(|(entities, aabbs, transforms, occluders, ticks, rows, last_run, this_run)| {
            let newer = |row: &usize| ticks.iter().any(|ticks| ticks[*row].is_newer_than(last_run, this_run));
            let rows: Vec<usize> = rows.filter(newer).collect();
            let objects = rows.iter().map(|&row| object(entities[row], &aabbs[row], &transforms[row]));
            // `Has` is the table's: every row of it carries an occluder, or none does.
            (store.compute_piece(objects), vec![occluders; rows.len()])
        })
        .collect()
}

/// One entity to mirror: entity, local bounds, transform; and whether it carries an occluder.
type Mirror = ((Entity, cullet::LocalBounds, glam::Affine3A), bool);

/// Keeps the store in step with removals at once: despawns, a lost `Aabb` or `GlobalTransform`, an opt-out
/// added or removed, an occluder added or removed.
pub(crate) fn add_observers(app: &mut App) {
    let forget = |event: On<Remove<(Aabb, GlobalTransform)>>, mut cullet: ResMut<CulletStore>| {
        cullet.forget(event.entity);
    };
    let opted_out = |event: On<Insert<(NoFrustumCulling, NoCpuCulling)>>, mut cullet: ResMut<CulletStore>| {
        cullet.forget(event.entity);
    };
    let opted_in = |event: On<Remove<(NoFrustumCulling, NoCpuCulling)>>, mut cullet: ResMut<CulletStore>| {
        cullet.pending.push(event.entity);
    };
    let occluder_added = |event: On<Insert<Occluder>>, mut cullet: ResMut<CulletStore>| {
        if let Some(slot) = cullet.store.slot_of(event.entity) {
            let _ = cullet.store.replace_occluder(slot);
        }
    };
    let occluder_removed = |event: On<Remove<Occluder>>, mut cullet: ResMut<CulletStore>| {
        if let Some(slot) = cullet.store.slot_of(event.entity) {
            let _ = cullet.store.set_occluder(slot, false);
        }
    };
    app.add_observer(forget)
        .add_observer(opted_out)
        .add_observer(opted_in)
        .add_observer(occluder_added)
        .add_observer(occluder_removed);
}
