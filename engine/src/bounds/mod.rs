//! Stage 1, bounds: the components a user attaches to an entity, and the world-space bounds of every culled
//! object kept as linear structure-of-arrays (SoA) in the [`BoundsStore`] resource.
//!
//! - [`components`]: [`LocalBounds`], [`ObjectTransform`], [`Static`], and their validation into
//!   [`WorldBounds`] (every write of the store is validated so; bad input is a [`BoundsError`]);
//! - [`store`]: the [`BoundsStore`], seven `f32` arrays padded for SIMD, private and read through slices;
//! - [`groups`]: the two-level hierarchy of group boxes the frustum stage tests first;
//!
//! The store is updated incrementally:
//! - inserting [`LocalBounds`] or [`ObjectTransform`] (spawning, or replacing either) stores the object at once,
//!   through an observer of the pipeline ([`crate::pipeline`]);
//! - the pipeline's bounds stage recomputes, through `bevy_ecs` change detection, only non-[`Static`] entities whose
//!   components were mutated since its last run; static objects are never scanned nor recomputed;
//! - removing either component or despawning is an O(1) swap-remove, the moved object's slot fixed up
//!   (again an observer).
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

/// Objects per SIMD block; every SoA array is padded to a multiple of [`SOA_PADDING`] (a visibility word).
pub const SIMD_LANES: usize = 8;

pub mod components;
pub mod groups;
pub mod store;

pub use components::{
    BoundsError, BoundsRejected, LocalBounds, ObjectTransform, Static, WorldBounds, largest_axis_scale,
};
pub use groups::{GROUPS_PER_SUPERGROUP, GroupBounds};
pub use store::{BoundsStore, SOA_PADDING, SoaSlices, StoreMoves, UpdatePiece};
