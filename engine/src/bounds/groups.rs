//! The culling hierarchy: a box around each group of [`SOA_PADDING`](super::SOA_PADDING) consecutive store slots, and around each
//! supergroup of [`GROUPS_PER_SUPERGROUP`] groups. The frustum stage tests them before any object.

use super::SIMD_LANES;
use super::components::WorldBounds;
use glam::Vec3;

/// Groups per supergroup, the top level of the culling hierarchy (4096 objects, one rayon task).
pub const GROUPS_PER_SUPERGROUP: usize = 64;

/// A box around a group of [`SOA_PADDING`](super::SOA_PADDING) consecutive store slots, rounded outward so that it contains every
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
pub(super) fn outward_range(centers: &[f32], extents: &[f32]) -> (f32, f32) {
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
