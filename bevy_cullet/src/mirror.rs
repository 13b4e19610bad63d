//! Stage 1 in a Bevy app: entities' `Aabb` and `GlobalTransform` mirrored into Cullet's SoA store.

use crate::convert;
use bevy_app::App;
use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::{NoCpuCulling, NoFrustumCulling};
use bevy_ecs::entity::EntityHashSet;
use bevy_ecs::prelude::*;
use bevy_transform::components::GlobalTransform;
use bevy_utils::Parallel;
use cullet::Occluder;
use cullet::bounds::{BoundsStore, StoreMoves};

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
        for ((&(entity, ..), outcome), &has_occluder) in objects.iter().zip(outcomes).zip(occluders) {
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
#[allow(clippy::type_complexity)]
pub(crate) fn mirror_bounds(
    mut cullet: ResMut<CulletStore>,
    changed: Query<
        (Entity, &Aabb, &GlobalTransform, Has<Occluder>),
        (Or<(Changed<Aabb>, Changed<GlobalTransform>)>, Mirrored),
    >,
    all: Query<(Entity, &Aabb, &GlobalTransform, Has<Occluder>), Mirrored>,
    mut queues: Local<Parallel<Vec<Mirror>>>,
) {
    let mirror = |(entity, aabb, transform, has_occluder): (Entity, &Aabb, &GlobalTransform, bool)| {
        ((entity, convert::local_bounds(aabb), convert::affine(transform)), has_occluder)
    };
    // The change scan reads a tick per entity: in parallel, as Bevy's own visibility passes are.
    changed.par_iter().for_each_init(|| queues.borrow_local_mut(), |queue, item| queue.push(mirror(item)));
    let mut changed: Vec<Mirror> = queues.iter_mut().flat_map(|queue| queue.drain(..)).collect();
    let pending = std::mem::take(&mut cullet.pending);
    changed.extend(pending.into_iter().filter_map(|entity| all.get(entity).ok()).map(mirror));
    if !changed.is_empty() {
        // In entity order, whatever the threads did: new objects take slots in the order they were spawned,
        // which keeps a scene spawned in spatial order grouped for the frustum's hierarchy. An entity pending
        // and changed is stored once.
        changed.sort_unstable_by_key(|((entity, ..), _)| *entity);
        changed.dedup_by_key(|((entity, ..), _)| *entity);
        let (objects, occluders): (Vec<_>, Vec<_>) = changed.into_iter().unzip();
        cullet.update(&objects, &occluders);
    }
    // Taken every frame, so that the list covers exactly the changes since the last mirroring (removals in
    // between change the layout, which the cameras compare too).
    cullet.moves = cullet.store.take_moves();
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
