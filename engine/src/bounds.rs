//! Stage 1, bounds: the components a user attaches to an entity, and the world-space bounds of every culled
//! object kept as linear structure-of-arrays (SoA) in the [`BoundsStore`] resource.
//!
//! The store is updated incrementally:
//! - inserting [`LocalBounds`] or [`ObjectTransform`] (spawning, or replacing either) stores the object at once,
//!   through the [`on_bounds_inserted`] observer;
//! - [`sync_bounds`] recomputes, through `bevy_ecs` change detection, only non-[`Static`] entities whose
//!   components were mutated since its last run; static objects are never scanned nor recomputed;
//! - removing either component or despawning is an O(1) swap-remove, the moved object's slot fixed up
//!   ([`on_bounds_removed`]).
//!
//! # Large worlds
//! Bounds are stored in absolute world coordinates as `f32`. Two rules keep culling correct and precise far
//! from the origin:
//! - every stored box is inflated by the rounding error of its own computation ([`WorldBounds::from_local`]), so
//!   it always contains the exact box, at any distance from the origin;
//! - culling is camera-relative: the frustum stage subtracts the camera position from each centre before any
//!   plane test, so plane distances are small numbers near the camera instead of differences of two values of
//!   1e7 (see [`crate::frustum`]).
//!
//! At 1e7 units from the origin an `f32` position is quantized to 1 unit, and boxes there grow by up to about
//! 5 units (`4 * f32::EPSILON` of the distance): culling stays conservative and loses only that much
//! efficiency. Beyond that, keep transforms small by rebasing the world origin near the camera.

use crate::visible::VisibleSet;
use bevy_ecs::entity::EntityHashMap;
use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3, Vec3A};
use std::sync::Arc;
use std::time::{Duration, Instant};
use thiserror::Error;

/// Objects per SIMD block; every SoA array is padded to a multiple of [`SOA_PADDING`] (a visibility word).
pub const SIMD_LANES: usize = 8;
/// Every SoA array's length is a multiple of this: one 64-bit word of a visibility bitset, and one group of
/// the culling hierarchy ([`GroupBounds`]).
pub const SOA_PADDING: usize = 64;
/// Group boxes [`sync_bounds`] tightens per frame at most (seed 001 section 4.3.4: spread work over frames).
pub const TIGHTEN_BUDGET: usize = 256;
/// Groups per supergroup, the top level of the culling hierarchy (4096 objects, one rayon task).
pub const GROUPS_PER_SUPERGROUP: usize = 64;

/// Relative rounding slack added to world bounds: 8 half-ulps (`8 * 2^-24`), twice the error bound of the
/// four rounded operations per axis that transform a box.
const BOUNDS_SLACK: f32 = 4.0 * f32::EPSILON;

/// An object's axis-aligned bounding box in its local space, as centre and half-extent.
///
/// Attach it with an [`ObjectTransform`] to make an entity cullable.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct LocalBounds {
    /// Centre of the box in local space.
    pub center: Vec3,
    /// Half the size of the box along each local axis; each component must be finite and non-negative.
    pub half_extent: Vec3,
}

impl LocalBounds {
    /// The box spanning `min..=max`.
    pub fn from_min_max(min: Vec3, max: Vec3) -> Self {
        Self { center: (min + max) * 0.5, half_extent: (max - min) * 0.5 }
    }

    /// The smallest box around `points`, or `None` for no points.
    pub fn from_points(points: &[Vec3]) -> Option<Self> {
        let first = *points.first()?;
        let (min, max) = points.iter().fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p)));
        Some(Self::from_min_max(min, max))
    }
}

/// The object's placement in the world.
///
/// A glam [`Affine3A`] (rotation, scale and shear plus translation) rather than Bevy's `Transform`: culling needs
/// only the matrix, and `Affine3A` is the SIMD-aligned form glam transforms points and boxes with fastest. The
/// engine has no hierarchy: give it the final world transform.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ObjectTransform(pub Affine3A);

/// Which mesh of the scene's mesh library the object draws.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct MeshRef(pub u32);

/// Marks an object that never moves: [`sync_bounds`] never scans it, and later stages skip per-frame work for
/// it. To move a static object anyway, insert a new [`ObjectTransform`] (an insert, not a mutation).
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct Static;

/// Marks an edge of an [`Occluder`] triangle without a neighbouring triangle.
pub const NO_NEIGHBOUR: u32 = u32::MAX;

/// An artist occluder: triangles in the entity's local space, meant to lie inside the rendered geometry, that
/// the software occlusion stage rasterizes to hide what is behind them. Triangles are counter-clockwise seen
/// from outside; closed meshes occlude best, since the raster covers the union of their front faces.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct Occluder {
    /// Triangle list: every three vertices form one triangle, in the entity's local space. Shared, since many
    /// objects of one shape carry the same occluder.
    pub triangles: Arc<[Vec3]>,
    /// For edge `e` of triangle `t` (from vertex `e` to vertex `e + 1`), at `3 * t + e`: the triangle sharing
    /// that edge in the opposite direction, or [`NO_NEIGHBOUR`]. Built once by [`Occluder::new`].
    pub neighbours: Arc<[u32]>,
}

impl Occluder {
    /// An occluder from a triangle list (a trailing partial triangle is ignored). Edges are matched by exact
    /// vertex positions; an edge shared by more than two triangles counts as having no neighbour.
    pub fn new(triangles: impl Into<Arc<[Vec3]>>) -> Self {
        let triangles: Arc<[Vec3]> = triangles.into();
        let key = |p: Vec3| p.to_array().map(f32::to_bits);
        let mut edges: std::collections::HashMap<([u32; 3], [u32; 3]), Vec<u32>> = std::collections::HashMap::new();
        let count = triangles.len() / 3;
        for t in 0..count {
            for e in 0..3 {
                let (a, b) = (triangles[3 * t + e], triangles[3 * t + (e + 1) % 3]);
                edges.entry((key(a), key(b))).or_default().push(t as u32);
            }
        }
        let mut neighbours = vec![NO_NEIGHBOUR; 3 * count];
        for t in 0..count {
            for e in 0..3 {
                let (a, b) = (triangles[3 * t + e], triangles[3 * t + (e + 1) % 3]);
                let forward = edges.get(&(key(a), key(b))).map_or(0, Vec::len);
                if let Some([other]) = edges.get(&(key(b), key(a))).map(Vec::as_slice)
                    && forward == 1
                {
                    neighbours[3 * t + e] = *other;
                }
            }
        }
        Self { triangles: Arc::from(&triangles[..3 * count]), neighbours: neighbours.into() }
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len() / 3
    }
}

/// Inserted on an entity whose bounds were rejected, with the reason. The entity is not in the store, so no
/// stage culls or draws it; the error was also logged and kept in [`BoundsStore::errors`].
#[derive(Component, Clone, Debug, PartialEq)]
pub struct BoundsRejected(pub BoundsError);

/// Why an object's bounds were refused.
#[derive(Error, Clone, Copy, Debug, PartialEq)]
pub enum BoundsError {
    /// The local box has a NaN or infinite coordinate.
    #[error("entity {entity}: local bounds are not finite (center {center}, half extent {half_extent})")]
    NonFiniteLocal {
        /// The offending entity.
        entity: Entity,
        /// Its local centre.
        center: Vec3,
        /// Its local half-extent.
        half_extent: Vec3,
    },
    /// A half-extent is negative.
    #[error("entity {entity}: local bounds have a negative half extent {half_extent}")]
    NegativeExtent {
        /// The offending entity.
        entity: Entity,
        /// Its local half-extent.
        half_extent: Vec3,
    },
    /// The transform has a NaN or infinite entry.
    #[error("entity {entity}: transform is not finite")]
    NonFiniteTransform {
        /// The offending entity.
        entity: Entity,
    },
    /// The transformed box overflowed `f32`.
    #[error("entity {entity}: world bounds overflow f32 (transform or box too large)")]
    WorldOverflow {
        /// The offending entity.
        entity: Entity,
    },
}

/// A world-space box (centre, half-extent) and the radius of its circumscribed sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldBounds {
    /// Centre in world space.
    pub center: Vec3,
    /// Half-extent along the world axes.
    pub half_extent: Vec3,
    /// Radius of the sphere around `center` that contains the box.
    pub radius: f32,
}

impl WorldBounds {
    /// Transforms a local box to a world AABB that is guaranteed to contain the exactly transformed box: the
    /// `f32` result is inflated by a bound on its own rounding error. Validates everything on the way in.
    pub fn from_local(entity: Entity, local: &LocalBounds, transform: &Affine3A) -> Result<Self, BoundsError> {
        if !local.center.is_finite() || !local.half_extent.is_finite() {
            return Err(BoundsError::NonFiniteLocal { entity, center: local.center, half_extent: local.half_extent });
        }
        if local.half_extent.cmplt(Vec3::ZERO).any() {
            return Err(BoundsError::NegativeExtent { entity, half_extent: local.half_extent });
        }
        if !transform.is_finite() {
            return Err(BoundsError::NonFiniteTransform { entity });
        }
        let m = transform.matrix3;
        let abs_m = glam::Mat3A::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
        let local_center = Vec3A::from(local.center);
        let center = m * local_center + transform.translation;
        let extent = abs_m * Vec3A::from(local.half_extent);
        // Magnitude of every term that was rounded, per axis: the slack covers each one's error.
        let magnitude = abs_m * local_center.abs() + transform.translation.abs() + extent;
        let half_extent = extent + magnitude * BOUNDS_SLACK;
        // Scaled so that squaring cannot overflow for boxes near the top of the f32 range.
        let largest = half_extent.max_element();
        let radius =
            if largest > 0.0 { largest * (half_extent / largest).length() * (1.0 + BOUNDS_SLACK) } else { 0.0 };
        if !center.is_finite() || !half_extent.is_finite() || !radius.is_finite() {
            return Err(BoundsError::WorldOverflow { entity });
        }
        Ok(Self { center: center.into(), half_extent: half_extent.into(), radius })
    }

    /// The smallest and largest corner of the box.
    pub fn min_max(&self) -> (Vec3, Vec3) {
        (self.center - self.half_extent, self.center + self.half_extent)
    }
}

/// A box around a group of [`SOA_PADDING`] consecutive store slots, rounded outward so that it contains every
/// member's box exactly. The frustum stage tests it first: a group entirely outside or inside the frustum needs
/// no per-object test.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupBounds {
    /// Smallest corner.
    pub min: Vec3,
    /// Largest corner.
    pub max: Vec3,
}

/// The range `[min, max]` along one axis of the boxes `centers[i] ± extents[i]`, each rounded outward as
/// [`GroupBounds::grow`] rounds it (so a group box is the same whichever computes it). Eight running minima and
/// maxima, one per SIMD lane, so the loop vectorizes; min and max are exact, so the lane order changes nothing.
fn outward_range(centers: &[f32], extents: &[f32]) -> (f32, f32) {
    let (mut lo, mut hi) = ([f32::INFINITY; SIMD_LANES], [f32::NEG_INFINITY; SIMD_LANES]);
    // Selects rather than `f32::min`: bounds are never NaN, and plain compares vectorize without NaN fix-ups.
    let lane = |c: f32, e: f32, lo: &mut f32, hi: &mut f32| {
        let slack = (c.abs() + e) * f32::EPSILON;
        let (low, high) = (c - e - slack, c + e + slack);
        *lo = if low < *lo { low } else { *lo };
        *hi = if high > *hi { high } else { *hi };
    };
    let (center_chunks, extent_chunks) = (centers.chunks_exact(SIMD_LANES), extents.chunks_exact(SIMD_LANES));
    let (center_tail, extent_tail) = (center_chunks.remainder(), extent_chunks.remainder());
    for (c, e) in center_chunks.zip(extent_chunks) {
        let (c, e): ([f32; SIMD_LANES], [f32; SIMD_LANES]) = (c.try_into().unwrap(), e.try_into().unwrap());
        for i in 0..SIMD_LANES {
            lane(c[i], e[i], &mut lo[i], &mut hi[i]);
        }
    }
    for (i, (&c, &e)) in center_tail.iter().zip(extent_tail).enumerate() {
        lane(c, e, &mut lo[i], &mut hi[i]);
    }
    (lo.into_iter().fold(f32::INFINITY, f32::min), hi.into_iter().fold(f32::NEG_INFINITY, f32::max))
}

impl GroupBounds {
    /// The empty box: growing it by a box gives that box.
    pub const EMPTY: Self = Self { min: Vec3::INFINITY, max: Vec3::NEG_INFINITY };

    /// The corners of `bounds`, rounded outward by a bound on the error of `center ± extent`.
    fn outward_corners(bounds: &WorldBounds) -> (Vec3, Vec3) {
        let slack = (bounds.center.abs() + bounds.half_extent) * f32::EPSILON;
        (bounds.center - bounds.half_extent - slack, bounds.center + bounds.half_extent + slack)
    }

    /// Extends the box to contain `bounds`, rounding outward by a bound on the error of `center ± extent`.
    pub fn grow(&mut self, bounds: &WorldBounds) {
        let (min, max) = Self::outward_corners(bounds);
        self.min = self.min.min(min);
        self.max = self.max.max(max);
    }

    /// The box around both boxes.
    pub fn union(&self, other: &GroupBounds) -> Self {
        Self { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    /// Whether the box already contains `bounds` (compared as [`GroupBounds::grow`] would extend it).
    pub fn contains(&self, bounds: &WorldBounds) -> bool {
        let (min, max) = Self::outward_corners(bounds);
        min.cmpge(self.min).all() && max.cmple(self.max).all()
    }
}

/// World-space bounds of every object as parallel `f32` arrays, one per coordinate, padded with empty slots to a
/// multiple of [`SOA_PADDING`] so SIMD blocks and bitset words never run past the end.
///
/// Slot `i` of every array and of `entities` describes the same object. Padding slots hold zeros and are masked
/// out of every result by [`BoundsStore::len`].
#[derive(Resource, Default, Debug, Clone)]
pub struct BoundsStore {
    /// Centre x of each object's world AABB.
    pub center_x: Vec<f32>,
    /// Centre y.
    pub center_y: Vec<f32>,
    /// Centre z.
    pub center_z: Vec<f32>,
    /// Half-extent x.
    pub extent_x: Vec<f32>,
    /// Half-extent y.
    pub extent_y: Vec<f32>,
    /// Half-extent z.
    pub extent_z: Vec<f32>,
    /// Radius of the bounding sphere around the centre.
    pub radius: Vec<f32>,
    /// Per group of [`SOA_PADDING`] slots, a box containing every object of the group (see [`GroupBounds`]).
    groups: Vec<GroupBounds>,
    /// Per run of [`GROUPS_PER_SUPERGROUP`] groups, a box containing them all: the level above the groups.
    supergroups: Vec<GroupBounds>,
    /// Groups whose box may be looser than needed since an object moved or left; tightened by
    /// [`BoundsStore::tighten_groups`].
    loose_groups: std::collections::VecDeque<u32>,
    /// Per group: queued in `loose_groups`.
    loose_flags: Vec<bool>,
    /// Set where the object carries an [`Occluder`]. Lets occluder selection find candidates with a bitwise
    /// AND against the frustum stage's output instead of a scan of every occluder. Sized to the padded length.
    occluders: VisibleSet,
    entities: Vec<Entity>,
    slots: EntityHashMap<u32>,
    /// Slots written (inserted, updated, or filled by a swap-remove) since the last
    /// [`BoundsStore::take_written_slots`]: what a consumer mirroring the store (the GPU instances) must copy.
    written: VisibleSet,
    /// Objects whose bounds were recomputed (inserted or updated) by the last [`sync_bounds`] run.
    pub recomputed_last_sync: usize,
    /// Wall time of the last [`sync_bounds`] run.
    pub last_sync_time: Duration,
    /// Every rejection since the last [`BoundsStore::take_errors`].
    pub errors: Vec<BoundsError>,
    /// Counts every change of the stored bounds or occluder marks: equal generations mean equal contents.
    generation: u64,
    /// Counts changes of which objects are stored where, and of occluder marks: inserts of new objects,
    /// removals, occluder marks set or cleared. Equal layouts differ at most in the bounds of `moved` slots.
    layout_generation: u64,
    /// Slots whose bounds were overwritten in place since the last [`BoundsStore::take_moved_slots`]
    /// (duplicates possible); `None` once there were too many to be worth listing.
    moved: Option<Vec<u32>>,
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
        self.slots.get(&entity).map(|&slot| slot as usize)
    }

    /// The bounds stored in `slot`.
    pub fn get(&self, slot: usize) -> WorldBounds {
        WorldBounds {
            center: Vec3::new(self.center_x[slot], self.center_y[slot], self.center_z[slot]),
            half_extent: Vec3::new(self.extent_x[slot], self.extent_y[slot], self.extent_z[slot]),
            radius: self.radius[slot],
        }
    }

    /// Marks whether the object in `slot` carries an occluder.
    pub fn set_occluder(&mut self, slot: usize, has_occluder: bool) {
        self.generation += 1;
        if self.occluders.contains(slot) != has_occluder {
            self.layout_generation += 1;
        }
        self.occluders.set(slot, has_occluder);
    }

    /// The slots whose object carries an occluder.
    pub fn occluders(&self) -> &VisibleSet {
        &self.occluders
    }

    /// The box around each group of [`SOA_PADDING`] consecutive slots.
    pub fn groups(&self) -> &[GroupBounds] {
        &self.groups
    }

    /// The box around each run of [`GROUPS_PER_SUPERGROUP`] consecutive groups.
    pub fn supergroups(&self) -> &[GroupBounds] {
        &self.supergroups
    }

    /// Recomputes the boxes of all groups that were loosened by moves and removals. Group boxes are always
    /// conservative; this only makes them tight again. [`sync_bounds`] tightens [`TIGHTEN_BUDGET`] a frame.
    pub fn tighten_groups(&mut self) {
        self.tighten_some_groups(usize::MAX);
    }

    /// [`BoundsStore::tighten_groups`] for at most `budget` groups, the longest-loose first: the work of many
    /// moving objects is spread over frames, while every group box stays conservative in between.
    pub fn tighten_some_groups(&mut self, budget: usize) {
        let mut supergroups = Vec::new();
        for _ in 0..budget {
            let Some(group) = self.loose_groups.pop_front() else { break };
            let group = group as usize;
            if group >= self.groups.len() {
                continue; // Truncated away since it was queued.
            }
            self.loose_flags[group] = false;
            let slots = group * SOA_PADDING..((group + 1) * SOA_PADDING).min(self.len());
            let axes =
                [(&self.center_x, &self.extent_x), (&self.center_y, &self.extent_y), (&self.center_z, &self.extent_z)]
                    .map(|(centers, extents)| outward_range(&centers[slots.clone()], &extents[slots.clone()]));
            self.groups[group] = GroupBounds {
                min: Vec3::new(axes[0].0, axes[1].0, axes[2].0),
                max: Vec3::new(axes[0].1, axes[1].1, axes[2].1),
            };
            supergroups.push(group / GROUPS_PER_SUPERGROUP);
        }
        supergroups.sort_unstable();
        supergroups.dedup();
        for supergroup in supergroups {
            let first = supergroup * GROUPS_PER_SUPERGROUP;
            let last = (first + GROUPS_PER_SUPERGROUP).min(self.groups.len());
            self.supergroups[supergroup] =
                self.groups[first..last].iter().fold(GroupBounds::EMPTY, |acc, g| acc.union(g));
        }
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
    pub fn set(&mut self, slot: usize, bounds: &WorldBounds) {
        self.mark_loose(slot / SOA_PADDING);
        self.write(slot, bounds);
        // Past an eighth of the store, re-culling everything is as cheap as re-culling the list.
        let limit = self.len() / 8;
        if let Some(moved) = self.moved.as_mut().filter(|moved| moved.len() < limit) {
            moved.push(slot as u32);
        } else {
            self.moved = None;
        }
    }

    fn write(&mut self, slot: usize, bounds: &WorldBounds) {
        self.generation += 1;
        if self.written.len() < self.padded_len() {
            self.written.resize(self.padded_len());
        }
        self.written.set(slot, true);
        let group = &mut self.groups[slot / SOA_PADDING];
        if !group.contains(bounds) {
            group.grow(bounds);
            let group = *group;
            let supergroup = &mut self.supergroups[slot / SOA_PADDING / GROUPS_PER_SUPERGROUP];
            *supergroup = supergroup.union(&group);
        }
        self.center_x[slot] = bounds.center.x;
        self.center_y[slot] = bounds.center.y;
        self.center_z[slot] = bounds.center.z;
        self.extent_x[slot] = bounds.half_extent.x;
        self.extent_y[slot] = bounds.half_extent.y;
        self.extent_z[slot] = bounds.half_extent.z;
        self.radius[slot] = bounds.radius;
    }

    /// Stores `entity`'s bounds: overwrites its slot if it has one, else appends it. Amortized O(1).
    pub fn insert(&mut self, entity: Entity, bounds: &WorldBounds) -> usize {
        if let Some(slot) = self.slot_of(entity) {
            self.set(slot, bounds);
            return slot;
        }
        let slot = self.entities.len();
        self.layout_generation += 1;
        self.entities.push(entity);
        self.slots.insert(entity, slot as u32);
        if slot == self.padded_len() {
            let padded = slot + SOA_PADDING;
            for array in self.arrays_mut() {
                array.resize(padded, 0.0);
            }
            self.groups.push(GroupBounds::EMPTY);
            self.loose_flags.push(false);
            self.occluders.resize(padded);
            if self.groups.len() > self.supergroups.len() * GROUPS_PER_SUPERGROUP {
                self.supergroups.push(GroupBounds::EMPTY);
            }
        }
        self.write(slot, bounds);
        slot
    }

    /// Removes `entity` by moving the last object into its slot. Returns whether it was stored. O(1).
    pub fn remove(&mut self, entity: Entity) -> bool {
        let Some(slot) = self.slots.remove(&entity) else { return false };
        self.generation += 1;
        self.layout_generation += 1;
        let slot = slot as usize;
        let last = self.entities.len() - 1;
        self.entities.swap_remove(slot);
        if slot != last {
            self.slots.insert(self.entities[slot], slot as u32);
        }
        for array in self.arrays_mut() {
            array[slot] = array[last];
            array[last] = 0.0;
        }
        let last_has_occluder = self.occluders.contains(last);
        self.occluders.set(last, false);
        self.occluders.set(slot, slot != last && last_has_occluder);
        if slot != last {
            let moved = self.get(slot);
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
            self.loose_flags.truncate(padded / SOA_PADDING);
            self.occluders.resize(padded);
            self.supergroups.truncate(self.groups.len().div_ceil(GROUPS_PER_SUPERGROUP));
        }
        true
    }

    /// Validates and stores one object, or drops any bounds it had. Returns its slot, or the error.
    pub fn update(
        &mut self,
        entity: Entity,
        local: &LocalBounds,
        transform: &ObjectTransform,
    ) -> Result<usize, BoundsError> {
        match WorldBounds::from_local(entity, local, &transform.0) {
            Ok(bounds) => Ok(self.insert(entity, &bounds)),
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

    /// Drains the rejections recorded since the last call.
    pub fn take_errors(&mut self) -> Vec<BoundsError> {
        std::mem::take(&mut self.errors)
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

/// Reports the outcome of [`BoundsStore::update`]: a new error is logged, kept in [`BoundsStore::errors`] and
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
/// [`BoundsStore::errors`], and an entity that was stored before is removed from the store.
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
    let mut recomputed = 0;
    for (entity, local, transform, previous) in &changed {
        recomputed += 1;
        let outcome = store.update(entity, local, transform);
        report(&mut store, &mut commands, entity, outcome, previous);
    }
    store.tighten_some_groups(TIGHTEN_BUDGET);
    store.recomputed_last_sync = recomputed;
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
            store.set_occluder(slot, has_occluder);
        }
        report(&mut store, &mut commands, entity, outcome, previous);
    }
}

/// Observer: marks the object's slot as carrying an occluder (if it is stored already; otherwise
/// [`on_bounds_inserted`] marks it when it is).
pub fn on_occluder_inserted(event: On<Insert<Occluder>>, mut store: ResMut<BoundsStore>) {
    if let Some(slot) = store.slot_of(event.entity) {
        store.set_occluder(slot, true);
    }
}

/// Observer: clears the occluder mark of the object's slot.
pub fn on_occluder_removed(event: On<Remove<Occluder>>, mut store: ResMut<BoundsStore>) {
    if let Some(slot) = store.slot_of(event.entity) {
        store.set_occluder(slot, false);
    }
}

/// Observer: when an entity loses its [`LocalBounds`] or [`ObjectTransform`] (or is despawned), it is
/// swap-removed from the store at once. O(1).
pub fn on_bounds_removed(event: On<Remove<(LocalBounds, ObjectTransform)>>, mut store: ResMut<BoundsStore>) {
    store.remove(event.entity);
}
