//! Stage 1, bounds: the components a user attaches to an entity, and the world-space bounds of every culled
//! object kept as linear structure-of-arrays (SoA) in the [`BoundsStore`] resource.
//!
//! The store is updated incrementally by [`sync_bounds`] through `bevy_ecs` change detection: only entities
//! whose [`LocalBounds`] or [`ObjectTransform`] changed are recomputed, and removal (by the
//! [`on_bounds_removed`] observer) is an O(1) swap-remove with the moved entity's [`BoundsSlot`] fixed up.
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

use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3, Vec3A};
use std::sync::Arc;
use std::time::{Duration, Instant};
use thiserror::Error;

/// Objects per SIMD block; every SoA array is padded to a multiple of [`SOA_PADDING`] (a visibility word).
pub const SIMD_LANES: usize = 8;
/// Every SoA array's length is a multiple of this: one 64-bit word of a visibility bitset.
pub const SOA_PADDING: usize = 64;

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
        Self {
            center: (min + max) * 0.5,
            half_extent: (max - min) * 0.5,
        }
    }

    /// The smallest box around `points`, or `None` for no points.
    pub fn from_points(points: &[Vec3]) -> Option<Self> {
        let first = *points.first()?;
        let (min, max) = points
            .iter()
            .fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p)));
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

/// Marks an object that never moves. Later stages use it to skip per-frame work (uploads, re-testing).
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct Static;

/// An artist occluder: triangles in the entity's local space, meant to lie inside the rendered geometry, that
/// the software occlusion stage rasterizes to hide what is behind them.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct Occluder {
    /// Triangle list: every three vertices form one triangle, in the entity's local space. Shared, since many
    /// objects of one shape carry the same occluder.
    pub triangles: Arc<[Vec3]>,
}

/// Where the entity's bounds live in the [`BoundsStore`] arrays. Managed by the engine; do not insert it.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoundsSlot(pub u32);

/// Inserted on an entity whose bounds were rejected, with the reason. The entity is not in the store, so no
/// stage culls or draws it; the error was also logged and kept in [`BoundsStore::errors`].
#[derive(Component, Clone, Debug, PartialEq)]
pub struct BoundsRejected(pub BoundsError);

/// Why an object's bounds were refused.
#[derive(Error, Clone, Copy, Debug, PartialEq)]
pub enum BoundsError {
    /// The local box has a NaN or infinite coordinate.
    #[error(
        "entity {entity}: local bounds are not finite (center {center}, half extent {half_extent})"
    )]
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
    pub fn from_local(
        entity: Entity,
        local: &LocalBounds,
        transform: &Affine3A,
    ) -> Result<Self, BoundsError> {
        if !local.center.is_finite() || !local.half_extent.is_finite() {
            return Err(BoundsError::NonFiniteLocal {
                entity,
                center: local.center,
                half_extent: local.half_extent,
            });
        }
        if local.half_extent.cmplt(Vec3::ZERO).any() {
            return Err(BoundsError::NegativeExtent {
                entity,
                half_extent: local.half_extent,
            });
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
        let radius = if largest > 0.0 {
            largest * (half_extent / largest).length() * (1.0 + BOUNDS_SLACK)
        } else {
            0.0
        };
        if !center.is_finite() || !half_extent.is_finite() || !radius.is_finite() {
            return Err(BoundsError::WorldOverflow { entity });
        }
        Ok(Self {
            center: center.into(),
            half_extent: half_extent.into(),
            radius,
        })
    }

    /// The smallest and largest corner of the box.
    pub fn min_max(&self) -> (Vec3, Vec3) {
        (
            self.center - self.half_extent,
            self.center + self.half_extent,
        )
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
    entities: Vec<Entity>,
    /// Objects whose bounds were recomputed (inserted or updated) by the last [`sync_bounds`] run.
    pub recomputed_last_sync: usize,
    /// Wall time of the last [`sync_bounds`] run.
    pub last_sync_time: Duration,
    /// Every rejection since the last [`BoundsStore::take_errors`].
    pub errors: Vec<BoundsError>,
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

    /// The bounds stored in `slot`.
    pub fn get(&self, slot: usize) -> WorldBounds {
        WorldBounds {
            center: Vec3::new(
                self.center_x[slot],
                self.center_y[slot],
                self.center_z[slot],
            ),
            half_extent: Vec3::new(
                self.extent_x[slot],
                self.extent_y[slot],
                self.extent_z[slot],
            ),
            radius: self.radius[slot],
        }
    }

    /// Overwrites the bounds in `slot`.
    pub fn set(&mut self, slot: usize, bounds: &WorldBounds) {
        self.center_x[slot] = bounds.center.x;
        self.center_y[slot] = bounds.center.y;
        self.center_z[slot] = bounds.center.z;
        self.extent_x[slot] = bounds.half_extent.x;
        self.extent_y[slot] = bounds.half_extent.y;
        self.extent_z[slot] = bounds.half_extent.z;
        self.radius[slot] = bounds.radius;
    }

    /// Appends an object and returns its slot. Amortized O(1).
    pub fn push(&mut self, entity: Entity, bounds: &WorldBounds) -> u32 {
        let slot = self.entities.len();
        self.entities.push(entity);
        if slot == self.padded_len() {
            let padded = slot + SOA_PADDING;
            for array in self.arrays_mut() {
                array.resize(padded, 0.0);
            }
        }
        self.set(slot, bounds);
        slot as u32
    }

    /// Removes the object in `slot` by moving the last object into it. Returns the entity that moved into
    /// `slot`, whose [`BoundsSlot`] the caller must update, or `None` if `slot` was the last one. O(1).
    pub fn swap_remove(&mut self, slot: usize) -> Option<Entity> {
        let last = self.entities.len() - 1;
        self.entities.swap_remove(slot);
        for array in self.arrays_mut() {
            array[slot] = array[last];
            array[last] = 0.0;
        }
        // Shrink only when a whole padding word is free, so the arrays stay a multiple of SOA_PADDING.
        let padded = last.div_ceil(SOA_PADDING) * SOA_PADDING;
        if padded + SOA_PADDING <= self.padded_len() {
            for array in self.arrays_mut() {
                array.truncate(padded);
            }
        }
        (slot != last).then(|| self.entities[slot])
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

/// Inserts new objects and recomputes the bounds of those whose [`LocalBounds`] or [`ObjectTransform`]
/// changed since the last run. A frame in which nothing changed touches no bounds.
///
/// Invalid input is never stored: the entity gets [`BoundsRejected`], the error is logged and kept in
/// [`BoundsStore::errors`], and an entity that was stored before is removed from the store.
#[allow(clippy::type_complexity)]
pub fn sync_bounds(
    mut commands: Commands,
    mut store: ResMut<BoundsStore>,
    mut queries: ParamSet<(
        Query<
            (Entity, &LocalBounds, &ObjectTransform, Option<&BoundsSlot>),
            Or<(Changed<LocalBounds>, Changed<ObjectTransform>)>,
        >,
        Query<&mut BoundsSlot>,
    )>,
) {
    let start = Instant::now();
    let mut recomputed = 0;
    let mut removed_slots = Vec::new();
    for (entity, local, transform, slot) in &queries.p0() {
        recomputed += 1;
        match (WorldBounds::from_local(entity, local, &transform.0), slot) {
            (Ok(bounds), Some(slot)) => store.set(slot.0 as usize, &bounds),
            (Ok(bounds), None) => {
                let slot = store.push(entity, &bounds);
                commands
                    .entity(entity)
                    .insert(BoundsSlot(slot))
                    .remove::<BoundsRejected>();
            }
            (Err(error), slot) => {
                tracing::warn!("{error}");
                store.errors.push(error);
                commands
                    .entity(entity)
                    .insert(BoundsRejected(error))
                    .remove::<BoundsSlot>();
                if let Some(slot) = slot {
                    removed_slots.push(slot.0);
                }
            }
        }
    }
    // Remove from the highest slot down, so no pending slot is moved by an earlier removal.
    removed_slots.sort_unstable_by(|a, b| b.cmp(a));
    let mut slots = queries.p1();
    for slot in removed_slots {
        if let Some(moved) = store.swap_remove(slot as usize)
            && let Ok(mut moved_slot) = slots.get_mut(moved)
        {
            moved_slot.0 = slot;
        }
    }
    store.recomputed_last_sync = recomputed;
    store.last_sync_time = start.elapsed();
}

/// Observer: when an entity loses its [`LocalBounds`] or [`ObjectTransform`] (or is despawned), its slot is
/// swap-removed from the store at once and the entity that moved into the slot is re-pointed. O(1).
pub fn on_bounds_removed(
    event: On<Remove<(LocalBounds, ObjectTransform)>>,
    mut commands: Commands,
    mut store: ResMut<BoundsStore>,
    mut slots: Query<&mut BoundsSlot>,
) {
    let entity = event.entity;
    let Ok(mut slot) = slots.get_mut(entity) else {
        return;
    };
    if slot.0 == u32::MAX {
        return; // Already removed by the other component's trigger.
    }
    let freed = slot.0;
    slot.0 = u32::MAX;
    if let Some(moved) = store.swap_remove(freed as usize)
        && let Ok(mut moved_slot) = slots.get_mut(moved)
    {
        moved_slot.0 = freed;
    }
    if let Ok(mut entity_commands) = commands.get_entity(entity) {
        entity_commands.try_remove::<BoundsSlot>();
    }
}
