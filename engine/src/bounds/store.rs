//! The [`BoundsStore`]: world bounds of every culled object as seven linear `f32` arrays, padded for SIMD.
//!
//! # Invariant: the SoA layout
//! The arrays are private, and every method that changes their length changes all seven together, so that at
//! all times:
//! - every array has the same length, [`BoundsStore::padded_len`], a multiple of [`SOA_PADDING`];
//! - `padded_len` is [`BoundsStore::len`] rounded up to a multiple of [`SOA_PADDING`];
//! - the group flags and the occluder bitset cover `padded_len` slots.
//!
//! The SIMD kernels of the frustum stage read 8 lanes at a time without bounds checks: they rely on this
//! invariant, which `insert` and `remove` establish and check (`BoundsStore::check_layout`) whenever they
//! resize the arrays. Every bound written passed [`WorldBounds::validate`] or came from
//! [`WorldBounds::from_local`], whose results satisfy it by construction.

use super::components::{BoundsError, LocalBounds, ObjectTransform, WorldBounds};
use super::groups::{GROUPS_PER_SUPERGROUP, GroupBounds, outward_range};
use crate::parallel;
use crate::visible::VisibleSet;
use bevy_ecs::entity::EntityHashMap;
use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use std::time::Duration;

/// Every SoA array's length is a multiple of this: one 64-bit word of a visibility bitset, and one group of
/// the culling hierarchy ([`GroupBounds`]).
pub const SOA_PADDING: usize = 64;

/// [`BoundsStore::update_many`] writes in parallel from this many objects on.
const PARALLEL_WRITES_FROM: usize = 1024;

/// Objects whose world bounds one task of [`BoundsStore::update_many`] computes, at least.
const UPDATES_PER_TASK: usize = 128;

/// Loose groups one task of [`BoundsStore::tighten_some_groups`] tightens.
const TIGHTEN_GROUPS_PER_TASK: usize = 4;

/// Pieces [`BoundsStore::update_many`] cuts its objects into, at most: each supergroup's writer looks at each.
const MAX_UPDATE_PIECES: usize = 64;

/// Objects one [`UpdatePiece`] of `objects` updated together should hold: few enough pieces that each
/// supergroup's writer looks through all of them cheaply ([`BoundsStore::apply_pieces`]), each large enough to
/// be worth a task.
pub(crate) fn piece_len(objects: usize) -> usize {
    objects.div_ceil(MAX_UPDATE_PIECES).max(UPDATES_PER_TASK)
}

/// Updates computed apart from the store ([`BoundsStore::compute_piece`]) by one task, to be applied with the
/// other tasks' in order ([`BoundsStore::apply_pieces`]).
#[derive(Debug, Default)]
pub struct UpdatePiece {
    /// Each `(entity, its slot as looked up, its world bounds or why they were refused)`, in order.
    pub(crate) updates: Vec<(Entity, Option<usize>, Result<WorldBounds, BoundsError>)>,
    /// Every update has a slot and valid bounds.
    in_place: bool,
    /// Where `in_place`: the updates' indices grouped by supergroup, in order within each.
    by_supergroup: Vec<u32>,
    /// Where `in_place`: each supergroup's first index in `by_supergroup`, and one past the last.
    starts: Vec<u32>,
    /// The store's layout generation the slots were looked up at: a piece of another is stored one by one,
    /// each slot checked.
    layout: u64,
}

/// Each stored entity's slot. Looked up once per moved object a frame, so by the entity's index in a dense
/// table where indices are small (a world numbers its entities from 0, reusing freed numbers), instead of
/// hashing; an entity whose index is large, or whose index another stored entity (of another generation)
/// holds in the table, goes in a hash map instead.
#[derive(Clone, Debug, Default)]
struct EntitySlots {
    /// At each index, the stored entity of that index and its slot; [`Entity::PLACEHOLDER`] for none.
    dense: Vec<(Entity, u32)>,
    sparse: EntityHashMap<u32>,
}

/// Indices below this always go in the dense table; above it, those below four times the number stored.
const DENSE_INDICES: usize = 1 << 16;

impl EntitySlots {
    fn get(&self, entity: Entity) -> Option<usize> {
        match self.dense.get(entity.index_u32() as usize) {
            Some(&(stored, slot)) if stored == entity => Some(slot as usize),
            _ if self.sparse.is_empty() => None,
            _ => self.sparse.get(&entity).map(|&slot| slot as usize),
        }
    }

    /// Records `entity` (of `count` stored) in `slot`, replacing its slot if it has one.
    fn insert(&mut self, entity: Entity, slot: usize, count: usize) {
        let index = entity.index_u32() as usize;
        if index < DENSE_INDICES.max(4 * count) {
            if index >= self.dense.len() {
                self.dense.resize(index + 1, (Entity::PLACEHOLDER, 0));
            }
            let held = &mut self.dense[index];
            if held.0 == Entity::PLACEHOLDER || held.0 == entity {
                *held = (entity, slot as u32);
                return;
            }
        }
        self.sparse.insert(entity, slot as u32);
    }

    fn remove(&mut self, entity: Entity) -> Option<usize> {
        match self.dense.get_mut(entity.index_u32() as usize) {
            Some(held) if held.0 == entity => {
                let slot = held.1 as usize;
                *held = (Entity::PLACEHOLDER, 0);
                Some(slot)
            }
            _ => self.sparse.remove(&entity).map(|slot| slot as usize),
        }
    }
}

/// Slots of one supergroup.
const SUPERGROUP_SLOTS: usize = SOA_PADDING * GROUPS_PER_SUPERGROUP;

// A group's written marks are one word ([`SlotsMut::write`]).
const _: () = assert!(SOA_PADDING == u64::BITS as usize);

/// The whole store borrowed apart into what the writers of its slots change ([`BoundsStore::parts_mut`]).
struct StoreParts<'a> {
    /// In the order of [`BoundsStore::soa`]'s arrays.
    arrays: [&'a mut [f32]; 7],
    groups: &'a mut [GroupBounds],
    supergroups: &'a mut [GroupBounds],
    occluder_radii: &'a mut [f32],
    /// The written marks' words.
    written: &'a mut [u64],
    occluders: &'a VisibleSet,
    /// Per group, whether it is queued to be tightened.
    loose_flags: &'a mut [bool],
}

/// The store's slots from the first of a supergroup on (or all of them), to write them: their seven arrays,
/// and their groups' boxes, occluder radii and written words (one word a group); and the box of the supergroup
/// whose slots are written through it. Supergroups share none of it, so each can be written at once through
/// its own.
struct SlotsMut<'a> {
    /// In the order of [`BoundsStore::soa`]'s arrays.
    arrays: [&'a mut [f32]; 7],
    groups: &'a mut [GroupBounds],
    occluder_radii: &'a mut [f32],
    written: &'a mut [u64],
    supergroup: &'a mut GroupBounds,
}

impl SlotsMut<'_> {
    /// Stores `bounds` in slot `at` (counted from the first of these slots, and in the supergroup whose box this
    /// holds), that of an occluder or not: the arrays and the written mark; the group's occluder radius and box,
    /// and so the supergroup's, grow to hold it at once.
    #[inline(always)] // in the parallel pass's loop: a call per write cost 5% more instructions there
    fn write(&mut self, at: usize, bounds: &WorldBounds, occluder: bool) {
        let [cx, cy, cz, ex, ey, ez, r] = &mut self.arrays;
        (cx[at], cy[at], cz[at]) = bounds.center.into();
        (ex[at], ey[at], ez[at]) = bounds.half_extent.into();
        r[at] = bounds.radius;
        let group = at / SOA_PADDING;
        self.written[group] |= 1 << (at % SOA_PADDING);
        if occluder {
            self.occluder_radii[group] = self.occluder_radii[group].max(bounds.radius);
        }
        if !self.groups[group].contains(bounds) {
            self.groups[group].grow(bounds);
            *self.supergroup = self.supergroup.union(&self.groups[group]);
        }
    }
}

/// Read-only views of the store's seven SoA arrays, each [`BoundsStore::padded_len`] long; slot `i` of each is
/// the object in store slot `i` (padding slots hold zeros).
#[derive(Clone, Copy, Debug)]
pub struct SoaSlices<'a> {
    /// Centre x of each object's world AABB.
    pub center_x: &'a [f32],
    /// Centre y.
    pub center_y: &'a [f32],
    /// Centre z.
    pub center_z: &'a [f32],
    /// Half-extent x.
    pub extent_x: &'a [f32],
    /// Half-extent y.
    pub extent_y: &'a [f32],
    /// Half-extent z.
    pub extent_z: &'a [f32],
    /// Radius of the bounding sphere around the centre.
    pub radius: &'a [f32],
}

impl<'a> SoaSlices<'a> {
    /// The seven arrays in field order.
    pub fn all(&self) -> [&'a [f32]; 7] {
        [self.center_x, self.center_y, self.center_z, self.extent_x, self.extent_y, self.extent_z, self.radius]
    }
}

/// World-space bounds of every object as parallel `f32` arrays, one per coordinate, padded with empty slots to a
/// multiple of [`SOA_PADDING`] so SIMD blocks and bitset words never run past the end.
///
/// Slot `i` of every array and of `entities` describes the same object. Padding slots hold zeros and are masked
/// out of every result by [`BoundsStore::len`]. The arrays are read through [`BoundsStore::soa`] and written
/// only by the store's own methods, which validate every bound (see the module's invariant):
///
/// ```compile_fail,E0616
/// let mut store = cullet::BoundsStore::default();
/// store.extent_x = Vec::new(); // private: the SIMD kernels rely on every array having the padded length
/// ```
///
/// # Example
/// ```
/// use bevy_ecs::entity::Entity;
/// use cullet::bounds::{BoundsStore, WorldBounds};
/// use glam::Vec3;
///
/// let mut store = BoundsStore::default();
/// let entity = Entity::PLACEHOLDER;
/// let slot = store.insert(entity, &WorldBounds::new(entity, Vec3::ZERO, Vec3::ONE)?)?;
/// assert_eq!(store.get(slot).unwrap().center, Vec3::ZERO);
/// assert_eq!(store.soa().center_x.len(), 64, "padded to a whole SIMD word");
/// assert!(store.get(1).is_none());
/// # Ok::<(), cullet::BoundsError>(())
/// ```
#[derive(Resource, Default, Debug, Clone)]
pub struct BoundsStore {
    center_x: Vec<f32>,
    center_y: Vec<f32>,
    center_z: Vec<f32>,
    extent_x: Vec<f32>,
    extent_y: Vec<f32>,
    extent_z: Vec<f32>,
    radius: Vec<f32>,
    /// Per group of [`SOA_PADDING`] slots, a box containing every object of the group (see [`GroupBounds`]).
    groups: Vec<GroupBounds>,
    /// Per run of [`GROUPS_PER_SUPERGROUP`] groups, a box containing them all: the level above the groups.
    supergroups: Vec<GroupBounds>,
    /// Per group, at least the largest radius among its occluders (0 without one): grown at once, tightened
    /// with the group's box. With the group's box it bounds how well any of its occluders can rank.
    occluder_radii: Vec<f32>,
    /// Groups whose box may be looser than needed since an object moved or left; tightened by
    /// [`BoundsStore::tighten_groups`].
    loose_groups: std::collections::VecDeque<u32>,
    /// Per group: queued in `loose_groups`.
    loose_flags: Vec<bool>,
    /// Set where the object carries an [`Occluder`](crate::occluders::Occluder). Lets occluder selection find candidates with a bitwise
    /// AND against the frustum stage's output instead of a scan of every occluder. Sized to the padded length.
    occluders: VisibleSet,
    entities: Vec<Entity>,
    slots: EntitySlots,
    /// Slots written (inserted, updated, or filled by a swap-remove) since the last
    /// [`BoundsStore::take_written_slots`]: what a consumer mirroring the store (the GPU instances) must copy.
    written: VisibleSet,
    /// Objects whose bounds were recomputed (inserted or updated) by the last bounds stage ([`crate::pipeline::CullStage::Bounds`]) run.
    pub(crate) recomputed_last_sync: usize,
    /// Wall time of the last bounds stage ([`crate::pipeline::CullStage::Bounds`]) run.
    pub(crate) last_sync_time: Duration,
    /// Every rejection since the last [`BoundsStore::take_errors`].
    pub(crate) errors: Vec<BoundsError>,
    /// Counts every change of the stored bounds or occluder marks: equal generations mean equal contents.
    generation: u64,
    /// Counts changes of which objects are stored where, and of occluders: inserts of new objects, removals,
    /// occluder marks set or cleared, occluders replaced. Equal layouts differ at most in the bounds of `moved`
    /// slots.
    layout_generation: u64,
    /// Slots whose bounds were overwritten in place since the last [`BoundsStore::take_moved_slots`]
    /// (duplicates possible); `None` once there were too many to be worth listing.
    moved: Option<Vec<u32>>,
    /// The generation at the last [`BoundsStore::take_moves`].
    moves_taken_at: u64,
    /// What the last [`BoundsStore::take_moves`] handed over, for the stages after the one that took them.
    last_moves: Option<StoreMoves>,
}

/// The slots whose bounds changed in place between two generations of a store, increasing
/// ([`BoundsStore::take_moves`]). A view culled at generation `from` that sees the store at `to`, with the
/// same layout, needs to re-test only these slots: every other slot holds the bounds it culled.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct StoreMoves {
    /// The generation the moves start from.
    pub from: u64,
    /// The generation they lead to.
    pub to: u64,
    /// The slots that moved.
    pub slots: Vec<u32>,
}

impl BoundsStore {
    /// Number of stored objects (not counting padding).
    pub fn len(&self) -> usize {
        self.entities.len()
    }

    /// Whether no object is stored.
    pub fn is_empty(&self) -> bool {
        self.entities.is_empty()
    }

    /// Length of every SoA array: [`Self::len`] rounded up to a multiple of [`SOA_PADDING`].
    pub fn padded_len(&self) -> usize {
        self.center_x.len()
    }

    /// The entity stored in each slot.
    pub fn entities(&self) -> &[Entity] {
        &self.entities
    }

    /// The slot of `entity`, if it is stored.
    pub fn slot_of(&self, entity: Entity) -> Option<usize> {
        self.slots.get(entity)
    }

    /// The seven SoA arrays, each [`BoundsStore::padded_len`] long.
    pub fn soa(&self) -> SoaSlices<'_> {
        SoaSlices {
            center_x: &self.center_x,
            center_y: &self.center_y,
            center_z: &self.center_z,
            extent_x: &self.extent_x,
            extent_y: &self.extent_y,
            extent_z: &self.extent_z,
            radius: &self.radius,
        }
    }

    /// The bounds stored in `slot`, or `None` past [`BoundsStore::len`].
    pub fn get(&self, slot: usize) -> Option<WorldBounds> {
        (slot < self.len()).then(|| self.get_unchecked_slot(slot))
    }

    /// The bounds in `slot`, which must be below `padded_len` (panics otherwise; a plain indexing check).
    fn get_unchecked_slot(&self, slot: usize) -> WorldBounds {
        WorldBounds {
            center: Vec3::new(self.center_x[slot], self.center_y[slot], self.center_z[slot]),
            half_extent: Vec3::new(self.extent_x[slot], self.extent_y[slot], self.extent_z[slot]),
            radius: self.radius[slot],
        }
    }

    /// Objects whose bounds the last bounds stage ([`crate::pipeline::CullStage::Bounds`]) run recomputed.
    pub fn recomputed_last_sync(&self) -> usize {
        self.recomputed_last_sync
    }

    /// Wall time of the last bounds stage ([`crate::pipeline::CullStage::Bounds`]) run.
    pub fn last_sync_time(&self) -> Duration {
        self.last_sync_time
    }

    /// The error for `slot` past [`BoundsStore::len`].
    fn check_slot(&self, slot: usize) -> Result<(), BoundsError> {
        if slot < self.len() { Ok(()) } else { Err(BoundsError::SlotOutOfRange { slot, len: self.len() }) }
    }

    /// Marks whether the object in `slot` carries an occluder.
    ///
    /// # Errors
    /// [`BoundsError::SlotOutOfRange`] past [`BoundsStore::len`]; nothing changes.
    pub fn set_occluder(&mut self, slot: usize, has_occluder: bool) -> Result<(), BoundsError> {
        self.check_slot(slot)?;
        self.mark_occluder(slot, has_occluder);
        Ok(())
    }

    /// Marks the object in `slot` as carrying an occluder that was just inserted or replaced: unlike
    /// [`BoundsStore::set_occluder`], the store's layout changes even where the slot had an occluder already,
    /// since what was culled against the old one is stale. The engine's observer of inserted occluders calls it.
    ///
    /// # Errors
    /// [`BoundsError::SlotOutOfRange`] past [`BoundsStore::len`]; nothing changes.
    pub fn replace_occluder(&mut self, slot: usize) -> Result<(), BoundsError> {
        self.check_slot(slot)?;
        self.mark_occluder(slot, true);
        self.layout_generation += 1;
        Ok(())
    }

    /// [`BoundsStore::set_occluder`] of a stored slot.
    pub(crate) fn mark_occluder(&mut self, slot: usize, has_occluder: bool) {
        self.generation += 1;
        if self.occluders.contains(slot) != has_occluder {
            self.layout_generation += 1;
            // One fewer occluder may leave the group's radius larger than needed.
            self.mark_loose(slot / SOA_PADDING);
        }
        self.occluders.set(slot, has_occluder);
        if has_occluder {
            self.grow_occluder_radius(slot, self.radius[slot]);
        }
    }

    /// The slots whose object carries an occluder.
    pub fn occluders(&self) -> &VisibleSet {
        &self.occluders
    }

    /// The box around each group of [`SOA_PADDING`] consecutive slots.
    pub fn groups(&self) -> &[GroupBounds] {
        &self.groups
    }

    /// Per group, a radius no smaller than any of its occluders' ([`BoundsStore::occluders`]); 0 where it has
    /// none. It may exceed the largest until the group is tightened ([`BoundsStore::tighten_groups`]).
    pub fn occluder_radii(&self) -> &[f32] {
        &self.occluder_radii
    }

    /// The box around each run of [`GROUPS_PER_SUPERGROUP`] consecutive groups.
    pub fn supergroups(&self) -> &[GroupBounds] {
        &self.supergroups
    }

    /// Recomputes the boxes of all groups that were loosened by moves and removals. Group boxes are always
    /// conservative; this only makes them tight again. bounds stage ([`crate::pipeline::CullStage::Bounds`]) tightens a few groups a frame.
    pub fn tighten_groups(&mut self) {
        self.tighten_some_groups(usize::MAX);
    }

    /// [`BoundsStore::tighten_groups`] for at most `budget` groups, the longest-loose first: the work of many
    /// moving objects is spread over frames, while every group box stays conservative in between.
    pub fn tighten_some_groups(&mut self, budget: usize) {
        let mut tightened = Vec::new();
        while tightened.len() < budget {
            let Some(group) = self.loose_groups.pop_front() else { break };
            let group = group as usize;
            if group >= self.groups.len() {
                continue; // Truncated away since it was queued.
            }
            self.loose_flags[group] = false;
            tightened.push(group);
        }
        // Each group's box and occluder radius from its members, read in parallel, then stored.
        let tight = |group: usize| {
            let slots = group * SOA_PADDING..((group + 1) * SOA_PADDING).min(self.len());
            let axes =
                [(&self.center_x, &self.extent_x), (&self.center_y, &self.extent_y), (&self.center_z, &self.extent_z)]
                    .map(|(centers, extents)| outward_range(&centers[slots.clone()], &extents[slots.clone()]));
            let bounds = GroupBounds {
                min: Vec3::new(axes[0].0, axes[1].0, axes[2].0),
                max: Vec3::new(axes[0].1, axes[1].1, axes[2].1),
            };
            let occluders = self.occluders.words()[group];
            let radius = crate::visible::set_slots(group, &[occluders])
                .fold(0.0, |largest: f32, slot| largest.max(self.radius[slot]));
            (bounds, radius)
        };
        let boxes: Vec<Vec<(GroupBounds, f32)>> = parallel::region(|region| {
            let chunk = |groups: &[usize]| region.task(|| groups.iter().map(|&group| tight(group)).collect());
            tightened.par_chunks(TIGHTEN_GROUPS_PER_TASK).map(chunk).collect()
        });
        for (&group, (bounds, radius)) in tightened.iter().zip(boxes.into_iter().flatten()) {
            (self.groups[group], self.occluder_radii[group]) = (bounds, radius);
        }
        let mut supergroups: Vec<usize> = tightened.iter().map(|group| group / GROUPS_PER_SUPERGROUP).collect();
        supergroups.sort_unstable();
        supergroups.dedup();
        for supergroup in supergroups {
            let first = supergroup * GROUPS_PER_SUPERGROUP;
            let last = (first + GROUPS_PER_SUPERGROUP).min(self.groups.len());
            self.supergroups[supergroup] =
                self.groups[first..last].iter().fold(GroupBounds::EMPTY, |acc, g| acc.union(g));
        }
    }

    /// Grows the occluder radius of `slot`'s group to at least `radius`.
    fn grow_occluder_radius(&mut self, slot: usize, radius: f32) {
        let group = &mut self.occluder_radii[slot / SOA_PADDING];
        *group = group.max(radius);
    }

    /// Queues `group` for tightening, once.
    fn mark_loose(&mut self, group: usize) {
        if !self.loose_flags[group] {
            self.loose_flags[group] = true;
            self.loose_groups.push_back(group as u32);
        }
    }

    /// Overwrites the bounds in `slot`. Its group box grows at once, so it stays conservative; it is marked
    /// loose, since the object may have left part of it.
    ///
    /// # Errors
    /// [`BoundsError::SlotOutOfRange`] past [`BoundsStore::len`], and [`BoundsError::InvalidWorld`] for bounds
    /// that fail [`WorldBounds::validate`]; the store is unchanged.
    pub fn set(&mut self, slot: usize, bounds: &WorldBounds) -> Result<(), BoundsError> {
        self.check_slot(slot)?;
        bounds.validate(self.entities[slot])?;
        self.overwrite(slot, bounds);
        Ok(())
    }

    /// [`BoundsStore::set`] of a valid slot and valid bounds.
    fn overwrite(&mut self, slot: usize, bounds: &WorldBounds) {
        self.note_moved(slot);
        self.write(slot, bounds);
    }

    /// What an overwrite of `slot` records in the order of the writes: its group to tighten, and the slot
    /// among those moved.
    fn note_moved(&mut self, slot: usize) {
        self.mark_loose(slot / SOA_PADDING);
        let listed = self.lists_moves(1);
        match self.moved.as_mut().filter(|_| listed) {
            Some(moved) => moved.push(slot as u32),
            None => self.moved = None,
        }
    }

    /// Whether the moved slots are still listed and `more` of them fit the list: past an eighth of the store,
    /// re-culling everything is as cheap as re-culling the list.
    fn lists_moves(&self, more: usize) -> bool {
        self.moved.as_ref().is_some_and(|moved| moved.len() + more <= self.len() / 8)
    }

    fn write(&mut self, slot: usize, bounds: &WorldBounds) {
        self.generation += 1;
        let occluder = self.occluders.contains(slot);
        let parts = self.parts_mut();
        let mut slots = SlotsMut {
            arrays: parts.arrays,
            groups: parts.groups,
            occluder_radii: parts.occluder_radii,
            written: parts.written,
            supergroup: &mut parts.supergroups[slot / SUPERGROUP_SLOTS],
        };
        slots.write(slot, bounds, occluder);
    }

    /// The arrays and bookkeeping a slot's writer changes, borrowed apart, with the written marks grown to the
    /// store's padded length first so that every slot has its bit.
    fn parts_mut(&mut self) -> StoreParts<'_> {
        if self.written.len() < self.padded_len() {
            self.written.resize(self.padded_len());
        }
        let Self {
            center_x,
            center_y,
            center_z,
            extent_x,
            extent_y,
            extent_z,
            radius,
            groups,
            supergroups,
            occluder_radii,
            written,
            occluders,
            loose_flags,
            ..
        } = self;
        StoreParts {
            arrays: [center_x, center_y, center_z, extent_x, extent_y, extent_z, radius].map(Vec::as_mut_slice),
            groups,
            supergroups,
            occluder_radii,
            written: written.words_mut(),
            occluders,
            loose_flags,
        }
    }

    /// Stores `entity`'s bounds: overwrites its slot if it has one, else appends it. Returns the slot.
    /// Amortized O(1).
    ///
    /// # Errors
    /// [`BoundsError::InvalidWorld`] for bounds that fail [`WorldBounds::validate`]; the store is unchanged.
    pub fn insert(&mut self, entity: Entity, bounds: &WorldBounds) -> Result<usize, BoundsError> {
        bounds.validate(entity)?;
        if let Some(slot) = self.slot_of(entity) {
            self.overwrite(slot, bounds);
            return Ok(slot);
        }
        let slot = self.entities.len();
        self.layout_generation += 1;
        self.entities.push(entity);
        self.slots.insert(entity, slot, slot + 1);
        if slot == self.padded_len() {
            let padded = slot + SOA_PADDING;
            for array in self.arrays_mut() {
                array.resize(padded, 0.0);
            }
            self.groups.push(GroupBounds::EMPTY);
            self.occluder_radii.push(0.0);
            self.loose_flags.push(false);
            self.occluders.resize(padded);
            if self.groups.len() > self.supergroups.len() * GROUPS_PER_SUPERGROUP {
                self.supergroups.push(GroupBounds::EMPTY);
            }
            self.check_layout();
        }
        self.write(slot, bounds);
        Ok(slot)
    }

    /// Removes `entity` by moving the last object into its slot. Returns whether it was stored. O(1).
    pub fn remove(&mut self, entity: Entity) -> bool {
        let Some(slot) = self.slots.remove(entity) else { return false };
        self.generation += 1;
        self.layout_generation += 1;
        let last = self.entities.len() - 1;
        self.entities.swap_remove(slot);
        if slot != last {
            self.slots.insert(self.entities[slot], slot, last);
        }
        for array in self.arrays_mut() {
            array[slot] = array[last];
            array[last] = 0.0;
        }
        let last_has_occluder = self.occluders.contains(last);
        self.occluders.set(last, false);
        self.occluders.set(slot, slot != last && last_has_occluder);
        if slot != last {
            let moved = self.get_unchecked_slot(slot);
            self.write(slot, &moved);
        }
        self.mark_loose(slot / SOA_PADDING);
        self.mark_loose(last / SOA_PADDING);
        // Shrink only when a whole padding word is free, so the arrays stay a multiple of SOA_PADDING.
        let padded = last.div_ceil(SOA_PADDING) * SOA_PADDING;
        if padded + SOA_PADDING <= self.padded_len() {
            for array in self.arrays_mut() {
                array.truncate(padded);
            }
            self.groups.truncate(padded / SOA_PADDING);
            self.occluder_radii.truncate(padded / SOA_PADDING);
            self.loose_flags.truncate(padded / SOA_PADDING);
            self.occluders.resize(padded);
            self.supergroups.truncate(self.groups.len().div_ceil(GROUPS_PER_SUPERGROUP));
            self.check_layout();
        }
        true
    }

    /// Checks the SoA layout invariant (see the module documentation) after the arrays were resized. O(1):
    /// the SIMD kernels' unchecked loads depend on it, so it is checked in release builds too.
    fn check_layout(&self) {
        let padded = self.center_x.len();
        assert!(
            self.arrays().iter().all(|array| array.len() == padded)
                && padded == self.len().div_ceil(SOA_PADDING) * SOA_PADDING
                && self.groups.len() * SOA_PADDING == padded
                && self.loose_flags.len() == self.groups.len()
                && self.occluder_radii.len() == self.groups.len()
                && self.occluders.len() == padded,
            "BoundsStore SoA layout broken: {} objects, arrays {:?} long",
            self.len(),
            self.arrays().map(|a| a.len())
        );
    }

    /// Validates and stores one object, or drops any bounds it had. Returns its slot, or the error.
    pub fn update(
        &mut self,
        entity: Entity,
        local: &LocalBounds,
        transform: &ObjectTransform,
    ) -> Result<usize, BoundsError> {
        let bounds = WorldBounds::from_local(entity, local, &transform.0);
        self.apply_update(entity, self.slot_of(entity), bounds)
    }

    /// [`BoundsStore::update`] of many objects, each `(entity, local bounds, transform)`: their world bounds are
    /// computed and their slots looked up in parallel (rayon), then stored as `update` would one by one in the
    /// order given. Returns each object's outcome in that order. The same entity must not appear twice.
    ///
    /// Where there are many and each already has a slot and valid bounds (objects that moved), they are
    /// written in parallel, each thread a range of slots (the arrays' writes miss the caches of a large
    /// store); only what depends on their order is recorded in order.
    pub fn update_many(&mut self, objects: &[(Entity, LocalBounds, Affine3A)]) -> Vec<Result<usize, BoundsError>> {
        let per_piece = piece_len(objects.len());
        let pieces: Vec<UpdatePiece> = parallel::region(|region| {
            let piece =
                |chunk: &[(Entity, LocalBounds, Affine3A)]| region.task(|| self.compute_piece(chunk.iter().copied()));
            objects.par_chunks(per_piece).map(piece).collect()
        });
        let slots: Vec<Option<usize>> =
            pieces.iter().flat_map(|piece| piece.updates.iter().map(|update| update.1)).collect();
        match self.apply_pieces(pieces) {
            Some(outcomes) => outcomes.into_iter().map(|(_, outcome)| outcome).collect(),
            // Written in place: each in the slot it was found in (every one found).
            None => slots.into_iter().flatten().map(Ok).collect(),
        }
    }

    /// The updates of `objects` (each `(entity, local bounds, transform)`), computed without changing the store:
    /// their world bounds, and their slots looked up. Many tasks may compute pieces at once (it reads the store
    /// only), as [`BoundsStore::update_many`] and the bounds stage do, each over some of the objects; then
    /// [`BoundsStore::apply_pieces`] stores them all. The same entity must not appear twice among the pieces
    /// applied together.
    pub fn compute_piece(&self, objects: impl IntoIterator<Item = (Entity, LocalBounds, Affine3A)>) -> UpdatePiece {
        let updates: Vec<_> = objects
            .into_iter()
            .map(|(entity, local, transform)| {
                (entity, self.slot_of(entity), WorldBounds::from_local(entity, &local, &transform))
            })
            .collect();
        let in_place = updates.iter().all(|(_, slot, bounds)| slot.is_some() && bounds.is_ok());
        if !in_place || updates.is_empty() {
            return UpdatePiece { updates, in_place, layout: self.layout_generation, ..UpdatePiece::default() };
        }
        // The updates by supergroup, in order within each (a counting sort: no comparisons).
        let supergroup_of = |update: &(Entity, Option<usize>, _)| update.1.unwrap_or(0) / SUPERGROUP_SLOTS;
        let mut starts = vec![0u32; self.padded_len().div_ceil(SUPERGROUP_SLOTS) + 1];
        for update in &updates {
            starts[supergroup_of(update) + 1] += 1;
        }
        for supergroup in 1..starts.len() {
            starts[supergroup] += starts[supergroup - 1];
        }
        let mut by_supergroup = vec![0; updates.len()];
        let mut next = starts.clone();
        for (index, update) in updates.iter().enumerate() {
            let next = &mut next[supergroup_of(update)];
            by_supergroup[*next as usize] = index as u32;
            *next += 1;
        }
        UpdatePiece { updates, in_place, by_supergroup, starts, layout: self.layout_generation }
    }

    /// Applies `pieces` of updates from [`BoundsStore::compute_piece`], in order, as [`BoundsStore::update`]
    /// would one by one. Where there are many and every one has a slot and valid bounds, they are written in
    /// parallel, each task a supergroup's slots, and `None` is returned (each object is in the slot looked up);
    /// otherwise they are applied one by one and each object's outcome returned, in order.
    ///
    /// Pieces computed before an insertion or a removal (which may move slots) are applied one by one, each
    /// slot looked up checked against its entity: the outcome is the same either way.
    pub fn apply_pieces(&mut self, pieces: Vec<UpdatePiece>) -> Option<Vec<(Entity, Result<usize, BoundsError>)>> {
        let total: usize = pieces.iter().map(|piece| piece.updates.len()).sum();
        let supergroups = self.padded_len().div_ceil(SUPERGROUP_SLOTS);
        // Every object stored already, none refused, and the store's layout as when they were looked up: each
        // write is an overwrite of the slot looked up.
        let in_place = total >= PARALLEL_WRITES_FROM
            && pieces.iter().all(|p| p.in_place && p.layout == self.layout_generation)
            && pieces.iter().all(|p| p.updates.is_empty() || p.starts.len() == supergroups + 1);
        if !in_place {
            let updates = pieces.into_iter().flat_map(|piece| piece.updates);
            return Some(
                updates.map(|(entity, slot, bounds)| (entity, self.apply_update(entity, slot, bounds))).collect(),
            );
        }
        self.generation += total as u64;
        let list_moves = self.lists_moves(total);
        let written = self.write_pieces(&pieces, list_moves);
        if let Some(listed) = self.moved.as_mut().filter(|_| list_moves) {
            listed.reserve(written.iter().map(|(moved, _)| moved.len()).sum());
        }
        for (moved, loose) in written {
            if let Some(listed) = self.moved.as_mut().filter(|_| list_moves) {
                listed.extend(moved);
            }
            self.loose_groups.extend(loose);
        }
        if !list_moves {
            self.moved = None;
        }
        None
    }

    /// Writes every update of `pieces` (each in place: a slot and valid bounds, grouped by supergroup) as
    /// [`BoundsStore::write`] does but the generation and the moves, in parallel over supergroups ([`SlotsMut`]:
    /// no two share a slot, a group or a word). Where a slot appears twice, the later write stands, as written
    /// one by one. Returns, per supergroup, the slots written (increasing, where `list_moves`) and the groups
    /// that became loose.
    fn write_pieces(&mut self, pieces: &[UpdatePiece], list_moves: bool) -> Vec<(Vec<u32>, Vec<u32>)> {
        let StoreParts { arrays, groups, supergroups, occluder_radii, written, occluders, loose_flags } =
            self.parts_mut();
        let [center_x, center_y, center_z, extent_x, extent_y, extent_z, radius] = arrays;
        // One item per supergroup. The written marks may have more words than the store has groups: the zip
        // stops at the shortest.
        let parts = (
            center_x.par_chunks_mut(SUPERGROUP_SLOTS),
            center_y.par_chunks_mut(SUPERGROUP_SLOTS),
            center_z.par_chunks_mut(SUPERGROUP_SLOTS),
            extent_x.par_chunks_mut(SUPERGROUP_SLOTS),
            extent_y.par_chunks_mut(SUPERGROUP_SLOTS),
            extent_z.par_chunks_mut(SUPERGROUP_SLOTS),
            radius.par_chunks_mut(SUPERGROUP_SLOTS),
            groups.par_chunks_mut(GROUPS_PER_SUPERGROUP),
            occluder_radii.par_chunks_mut(GROUPS_PER_SUPERGROUP),
            supergroups.par_iter_mut(),
            written.par_chunks_mut(GROUPS_PER_SUPERGROUP),
            loose_flags.par_chunks_mut(GROUPS_PER_SUPERGROUP),
        );
        parallel::region(|region| {
            parts
                .into_par_iter()
                .enumerate()
                .map(
                    |(index, (cx, cy, cz, ex, ey, ez, r, groups, occluder_radii, supergroup, written, loose_flags))| {
                        region.task(|| {
                            let arrays = [cx, cy, cz, ex, ey, ez, r];
                            let mut part = SlotsMut { arrays, groups, occluder_radii, written, supergroup };
                            let (mut moved, mut loose) = (Vec::new(), Vec::new());
                            for piece in pieces.iter().filter(|piece| !piece.updates.is_empty()) {
                                let range = piece.starts[index] as usize..piece.starts[index + 1] as usize;
                                for &update in &piece.by_supergroup[range] {
                                    let (_, Some(slot), Ok(bounds)) = &piece.updates[update as usize] else { continue };
                                    part.write(slot % SUPERGROUP_SLOTS, bounds, occluders.contains(*slot));
                                    let group = slot / SOA_PADDING;
                                    let flag = &mut loose_flags[group % GROUPS_PER_SUPERGROUP];
                                    if !*flag {
                                        *flag = true;
                                        loose.push(group as u32);
                                    }
                                    if list_moves {
                                        moved.push(*slot as u32);
                                    }
                                }
                            }
                            moved.sort_unstable();
                            (moved, loose)
                        })
                    },
                )
                .collect()
        })
    }

    /// Stores `bounds` computed by [`WorldBounds::from_local`] for `entity`, whose slot was looked up as `slot`
    /// (a lookup a removal since may have made stale: it is checked), or drops the entity on an error.
    fn apply_update(
        &mut self,
        entity: Entity,
        slot: Option<usize>,
        bounds: Result<WorldBounds, BoundsError>,
    ) -> Result<usize, BoundsError> {
        match bounds {
            // `from_local`'s results satisfy `WorldBounds::validate` by construction.
            Ok(bounds) => match slot.filter(|&slot| self.entities.get(slot) == Some(&entity)) {
                Some(slot) => {
                    self.overwrite(slot, &bounds);
                    Ok(slot)
                }
                None => self.insert(entity, &bounds),
            },
            Err(error) => {
                self.remove(entity);
                Err(error)
            }
        }
    }

    /// Changes so far: two equal generations mean no bounds or occluder mark changed in between (the stages
    /// may then reuse their last result).
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Changes of the layout so far (see [`BoundsStore::take_moved_slots`]).
    pub fn layout_generation(&self) -> u64 {
        self.layout_generation
    }

    /// The slots whose bounds changed in place since the last call, in increasing order, and forgets them;
    /// `None` when too many changed to list (an eighth of the store). Together with an unchanged
    /// [`BoundsStore::layout_generation`], these are the only slots whose bounds differ from the last call's.
    pub fn take_moved_slots(&mut self) -> Option<Vec<u32>> {
        let mut moved = self.moved.replace(Vec::new())?;
        moved.sort_unstable();
        moved.dedup();
        Some(moved)
    }

    /// The slots written since the last call, in order, and forgets them. Slots at or past [`BoundsStore::len`]
    /// were emptied by removals.
    pub fn take_written_slots(&mut self) -> Vec<u32> {
        let slots = self.written.iter().map(|slot| slot as u32).collect();
        self.written.reset(self.padded_len());
        slots
    }

    /// The slots whose bounds changed in place since the last call (or since the store was made), with the
    /// generations before and after, and forgets them; `None` when too many changed to list (an eighth of the
    /// store). Take them once a frame, after the bounds are brought up to date, and hand them to every view's
    /// culler ([`crate::culler::ViewFrame::moves`]).
    pub fn take_moves(&mut self) -> Option<StoreMoves> {
        let from = std::mem::replace(&mut self.moves_taken_at, self.generation);
        let moves = self.take_moved_slots().map(|slots| StoreMoves { from, to: self.generation, slots });
        self.last_moves.clone_from(&moves);
        moves
    }

    /// What the last [`BoundsStore::take_moves`] returned: the stages after the one that took them (in the
    /// pipeline, the frustum stage) read the frame's moves here. `None` before any, or when too many moved to
    /// list.
    pub fn last_moves(&self) -> Option<&StoreMoves> {
        self.last_moves.as_ref()
    }

    /// Drains the rejections recorded since the last call.
    pub fn take_errors(&mut self) -> Vec<BoundsError> {
        std::mem::take(&mut self.errors)
    }

    fn arrays(&self) -> [&Vec<f32>; 7] {
        [&self.center_x, &self.center_y, &self.center_z, &self.extent_x, &self.extent_y, &self.extent_z, &self.radius]
    }

    fn arrays_mut(&mut self) -> [&mut Vec<f32>; 7] {
        [
            &mut self.center_x,
            &mut self.center_y,
            &mut self.center_z,
            &mut self.extent_x,
            &mut self.extent_y,
            &mut self.extent_z,
            &mut self.radius,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy_ecs::entity::{EntityGeneration, EntityIndex};

    fn entity(index: u32, generation: u32) -> Entity {
        let index = EntityIndex::from_raw_u32(index).unwrap();
        Entity::from_index_and_generation(index, EntityGeneration::FIRST.after_versions(generation))
    }

    /// Two entities of one index (different generations) both stored, a large index, removals and the swap
    /// that a removal makes: each entity finds its own slot.
    #[test]
    fn entities_sharing_an_index_or_with_large_ones_keep_their_slots() {
        let mut store = BoundsStore::default();
        let (old, new, far) = (entity(5, 0), entity(5, 1), entity(3_000_000, 0));
        let at = |e: Entity, x: f32| WorldBounds::new(e, Vec3::new(x, 0.0, 0.0), Vec3::ONE).unwrap();
        for (i, e) in [old, new, far, entity(6, 0)].into_iter().enumerate() {
            assert_eq!(store.insert(e, &at(e, i as f32)), Ok(i));
        }
        assert_eq!([old, new, far].map(|e| store.slot_of(e)), [Some(0), Some(1), Some(2)]);
        assert_eq!(store.slot_of(entity(5, 2)), None);
        assert!(store.remove(old));
        // The last object moved into slot 0.
        assert_eq!([old, new, far, entity(6, 0)].map(|e| store.slot_of(e)), [None, Some(1), Some(2), Some(0)]);
        assert!(store.remove(new) && store.remove(far) && !store.remove(far));
        assert_eq!(store.len(), 1);
        assert_eq!(store.insert(old, &at(old, 0.0)), Ok(1));
        assert_eq!(store.slot_of(old), Some(1));
    }

    /// Pieces computed before a removal moved a slot still store each object's bounds in its own slot.
    #[test]
    fn pieces_computed_before_a_removal_land_in_the_right_slots() {
        let mut store = BoundsStore::default();
        let count = 2 * PARALLEL_WRITES_FROM;
        let local = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::ONE };
        let objects: Vec<(Entity, LocalBounds, Affine3A)> =
            (0..count as u32).map(|i| (entity(i, 0), local, Affine3A::from_translation(Vec3::X * i as f32))).collect();
        assert!(store.update_many(&objects).iter().all(Result::is_ok));
        let moved: Vec<_> =
            objects[1..].iter().map(|&(e, l, t)| (e, l, t * Affine3A::from_translation(Vec3::Y))).collect();
        let piece = store.compute_piece(moved.iter().copied());
        // The last object moves into slot 0.
        assert!(store.remove(objects[0].0));
        let outcomes = store.apply_pieces(vec![piece]).expect("applied one by one");
        assert!(outcomes.iter().all(|(_, outcome)| outcome.is_ok()));
        for (entity, _, transform) in &moved {
            let bounds = store.get(store.slot_of(*entity).unwrap()).unwrap();
            assert_eq!(bounds.center, transform.translation.into());
        }
    }
}
