//! Triangle culling (`shaders/triangle_cull.wgsl`): one workgroup per surviving cluster, one thread per
//! triangle. In order: degenerate (zero area in mesh space, so in any view); any vertex at `w <= 0` keeps the
//! triangle (screen tests need all three in front of the eye); back-facing (clearly clockwise on screen, by
//! more than the rasterizer's vertex snapping could change); outside the viewport; and small (eq. 19.4: its
//! pixel bounding box holds no pixel centre, with the snapping margin). Each test only removes triangles that
//! cover no sample, so culling stays conservative. Survivors are compacted into the draw index buffer and each
//! cluster with survivors becomes one `DrawIndexedIndirectArgs` whose first instance names its instance.
//!
//! [`cull_triangle`] is the same test on the CPU.

use super::frame::{GpuView, VIEW_BACKFACE, VIEW_SMALL_TRIANGLE, VIEW_TRIANGLE_FRUSTUM};
use super::scene::GpuInstance;
use glam::{Vec2, Vec3, Vec4};

/// Pixels a vertex may move when the rasterizer snaps it (must match `triangle_cull.wgsl`).
const SNAP: f32 = 1.0 / 128.0;

/// What the triangle test decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TriangleVerdict {
    /// May cover a sample: drawn.
    Keep,
    /// Zero area in mesh space.
    Degenerate,
    /// Faces away from the camera.
    Backface,
    /// Wholly outside the viewport.
    Frustum,
    /// Covers no pixel centre.
    Small,
}

/// The GPU's triangle test on the CPU, for mesh-space corners `p` of a triangle of `instance`.
pub fn cull_triangle(view: &GpuView, instance: &GpuInstance, p: [Vec3; 3]) -> TriangleVerdict {
    if (p[1] - p[0]).cross(p[2] - p[0]) == Vec3::ZERO {
        return TriangleVerdict::Degenerate;
    }
    let camera = Vec3::from_slice(&view.camera[..3]);
    let matrix = view.clip_from_relative();
    let clip: [Vec4; 3] = p.map(|p| matrix * instance.relative_point(p, camera).extend(1.0));
    if clip.iter().any(|c| c.w <= 0.0) {
        return TriangleVerdict::Keep;
    }
    let viewport = Vec2::from(view.viewport);
    let [s0, s1, s2] = clip.map(|c| (Vec2::new(c.x, c.y) / c.w * 0.5 + 0.5) * viewport);
    if view.flags & VIEW_BACKFACE != 0 {
        let (e0, e1) = (s1 - s0, s2 - s0);
        let area = e0.x * e1.y - e0.y * e1.x;
        let perimeter = e0.length() + e1.length() + (s2 - s1).length();
        if area < -2.0 * SNAP * perimeter {
            return TriangleVerdict::Backface;
        }
    }
    let lo = s0.min(s1.min(s2));
    let hi = s0.max(s1.max(s2));
    if view.flags & VIEW_TRIANGLE_FRUSTUM != 0
        && (hi.cmplt(Vec2::splat(-SNAP)).any() || lo.cmpgt(viewport + Vec2::splat(SNAP)).any())
    {
        return TriangleVerdict::Frustum;
    }
    let no_sample_between = |lo: f32, hi: f32| (lo - SNAP - 0.5).ceil() > (hi + SNAP - 0.5).floor();
    if view.flags & VIEW_SMALL_TRIANGLE != 0 && (no_sample_between(lo.x, hi.x) || no_sample_between(lo.y, hi.y)) {
        return TriangleVerdict::Small;
    }
    TriangleVerdict::Keep
}
