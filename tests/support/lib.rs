//! Shared helpers of Cullet's integration tests: exact (f64) references that the fast paths are judged against.

use cullet::{Camera, DepthConvention, WorldBounds};
use glam::dcamera::rh::proj::{directx, opengl};
use glam::dcamera::rh::view;
use glam::{DMat4, DVec3, DVec4};

/// The camera's clip-from-relative matrix built entirely in f64 from its parameters: the true frustum, free of
/// the f32 rounding of [`Camera::clip_from_relative`].
pub fn reference_clip_from_relative(camera: &Camera) -> DMat4 {
    let (fov, aspect, near) = (camera.fov_y as f64, camera.aspect as f64, camera.near as f64);
    let far = camera.far.map(f64::from);
    let projection = match (camera.depth, far) {
        (DepthConvention::Reversed, None) => directx::perspective_infinite_reverse(fov, aspect, near),
        (DepthConvention::Reversed, Some(far)) => directx::perspective(fov, aspect, far, near),
        (DepthConvention::Standard, None) => directx::perspective_infinite(fov, aspect, near),
        (DepthConvention::Standard, Some(far)) => directx::perspective(fov, aspect, near, far),
        (DepthConvention::NegativeOneToOne, Some(far)) => opengl::perspective(fov, aspect, near, far),
        (DepthConvention::NegativeOneToOne, None) => {
            let f = 1.0 / (0.5 * fov).tan();
            DMat4::from_cols_array(&[
                f / aspect,
                0.0,
                0.0,
                0.0, //
                0.0,
                f,
                0.0,
                0.0,
                0.0,
                0.0,
                -1.0,
                -1.0,
                0.0,
                0.0,
                -2.0 * near,
                0.0,
            ])
        }
    };
    projection * view::look_to_mat4(DVec3::ZERO, camera.forward.as_dvec3(), camera.up.as_dvec3())
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
