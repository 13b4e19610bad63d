//! Shared helpers of Cullet's integration tests: exact (f64) references that the fast paths are judged against.

use cullet::{Camera, DepthConvention, WorldBounds};
use glam::{DMat4, DVec3, DVec4};

/// The camera's clip-from-relative matrix in f64, from its parameters: the true frustum, free of the f32
/// rounding the engine's culling arithmetic works with. (The depth conventions themselves are checked by the
/// explicit near- and far-plane cases of the frustum tests.)
pub fn reference_clip_from_relative(camera: &Camera) -> DMat4 {
    camera.clip_from_relative_f64()
}

/// The frustum's half-spaces `(n, d)` (inside where `n · p + d >= 0`, p camera-relative), in f64, with planes at
/// infinity left out. Not normalized: the box test below does not need it.
pub fn reference_planes(camera: &Camera) -> Vec<DVec4> {
    let m = reference_clip_from_relative(camera).transpose();
    let (r0, r1, r2, r3) = (m.x_axis, m.y_axis, m.z_axis, m.w_axis);
    let (near, far) = match camera.depth {
        DepthConvention::Standard => (r2, r3 - r2),
        DepthConvention::Reversed => (r3 - r2, r2),
        DepthConvention::NegativeOneToOne => (r3 + r2, r3 - r2),
    };
    [near, r3 + r0, r3 - r0, r3 + r1, r3 - r1, far].into_iter().filter(|p| p.truncate().length() > 0.0).collect()
}

/// Exact box-versus-planes test in f64: kept unless the box lies entirely outside one plane.
pub fn reference_keeps(planes: &[DVec4], camera_position: DVec3, bounds: &WorldBounds) -> bool {
    let center = bounds.center.as_dvec3() - camera_position;
    let extent = bounds.half_extent.as_dvec3();
    planes.iter().all(|p| p.truncate().dot(center) + p.w + p.truncate().abs().dot(extent) >= 0.0)
}
