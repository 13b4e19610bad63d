//! Exact half-spaces in f64: a view's frustum as the planes of its clip matrix, which the exact frustum
//! reference, the light views' judge and the exact triangle raster all test against.

use cullet::{Camera, DepthConvention};
use glam::{DMat4, DVec3, DVec4};

/// The frustum's half-spaces `(n, d)` in f64 from the camera's exact clip matrix, inside where
/// `n · p + d >= 0` (p camera-relative), planes at infinity left out; not normalized (sign tests do not need it).
/// The exact reference both for the stress report and for the frustum tests.
pub fn exact_half_spaces(camera: &Camera) -> Vec<DVec4> {
    half_spaces(camera.clip_from_relative_f64(), camera.depth)
}

/// The half-spaces `(n, d)` of a clip-from-relative matrix, inside where `n · p + d >= 0` for `p` in the
/// matrix's input frame; planes at infinity left out; not normalized.
pub fn half_spaces(clip_from_relative: DMat4, depth: DepthConvention) -> Vec<DVec4> {
    let m = clip_from_relative.transpose();
    let (r0, r1, r3) = (m.x_axis, m.y_axis, m.w_axis);
    let (near, far) = depth_half_spaces(clip_from_relative, depth);
    [near, r3 + r0, r3 - r0, r3 + r1, r3 - r1, far].into_iter().filter(|p| p.truncate().length() > 0.0).collect()
}

/// The near and far half-spaces `(n, d)` of a clip-from-relative matrix with depth convention `depth`, as in
/// [`half_spaces`] (a far plane at infinity has `n = 0`).
pub fn depth_half_spaces(clip_from_relative: DMat4, depth: DepthConvention) -> (DVec4, DVec4) {
    let m = clip_from_relative.transpose();
    let (r2, r3) = (m.z_axis, m.w_axis);
    match depth {
        DepthConvention::Standard => (r2, r3 - r2),
        DepthConvention::Reversed => (r3 - r2, r2),
        DepthConvention::NegativeOneToOne => (r3 + r2, r3 - r2),
    }
}

/// `half_spaces` given relative to the point `from`, re-expressed relative to the point `to`.
pub fn moved(half_spaces: &[DVec4], from: DVec3, to: DVec3) -> Vec<DVec4> {
    half_spaces.iter().map(|p| DVec4::from((p.truncate(), p.w + p.truncate().dot(to - from)))).collect()
}
