//! Stage 3, occluder raster: a software rasterizer of occluder triangles into a small depth buffer, and its
//! farthest-depth mip pyramid (a CPU HiZ). Testing occludees against it is the next stage,
//! [`crate::occlusion`]; the two are kept apart as in Intel's Masked Occlusion Culling.
//!
//! # Depth convention
//! A texel holds `1/w`, the reciprocal of view-space distance along the view axis, of the *farthest* occluder
//! surface known to cover it: larger is nearer, and `0` (infinitely far) means no occluder. This is reversed
//! depth with an infinite far plane, independent of the camera's own depth convention; `1/w` is affine in
//! screen space, so a triangle's depth over a texel is bounded exactly by its plane.
//!
//! # Modes
//! - [`RasterMode::Conservative`] (default): a texel is written only where a triangle covers the *whole*
//!   texel, with the triangle's farthest depth over that texel, shrunk by a bound on rounding error. So
//!   anything the buffer calls hidden is hidden behind the occluders at any finer resolution.
//! - [`RasterMode::Fast`]: sampled at texel centres like Collin's 256x144 buffer; not conservative.
//!
//! Triangle setup (transform, clipping against the near plane and the viewport, edge and depth planes) runs
//! in f64; only the per-texel loop runs in f32, with margins that cover its rounding. Back faces are skipped:
//! a closed occluder's front faces hide everything its back faces would, and from inside an occluder nothing
//! is hidden by it.

use crate::camera::Camera;
use glam::{DAffine3, DMat4, DVec3, DVec4, Mat4, Vec3};
use rayon::prelude::*;

/// Rows of the depth buffer rasterized by one rayon task; each band is a contiguous slice, so tasks never share
/// a texel and need no locks.
const BAND_ROWS: usize = 8;
/// Relative margin covering the f32 evaluation of an edge or depth plane (4x its rounding-error bound).
const EVAL_MARGIN: f64 = 1.0 / (1u64 << 20) as f64;

/// How texels are sampled. See the module documentation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
pub enum RasterMode {
    /// Whole-texel coverage and farthest depth: never hides a visible object.
    #[default]
    Conservative,
    /// Texel-centre sampling: hides more, and may hide what is visible.
    Fast,
}

/// The camera as the depth buffer sees it: camera-relative clip matrices and the buffer size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScreenView {
    /// World position everything is made relative to.
    pub origin: Vec3,
    /// Clip from camera-relative world space, f64 (for occluder setup).
    pub clip_from_relative: DMat4,
    /// The same in f32 (for the SIMD occludee projection).
    pub clip_from_relative_f32: Mat4,
    /// Near-plane distance: geometry at `w < near` is clipped (occluders) or kept (occludees).
    pub near: f32,
    /// Buffer width in texels.
    pub width: u32,
    /// Buffer height in texels.
    pub height: u32,
}

impl ScreenView {
    /// The view of `camera` on a `width` x `height` buffer.
    pub fn new(camera: &Camera, width: u32, height: u32) -> Self {
        let view = glam::dcamera::rh::view::look_to_mat4(DVec3::ZERO, camera.forward.as_dvec3(), camera.up.as_dvec3());
        let clip_from_relative = camera.clip_from_view_f64() * view;
        Self {
            origin: camera.position,
            clip_from_relative,
            clip_from_relative_f32: clip_from_relative.as_mat4(),
            near: camera.near,
            width,
            height,
        }
    }
}

/// A `width` x `height` buffer of `1/w` depths, row-major, row 0 at the top of the screen.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DepthBuffer {
    width: u32,
    height: u32,
    texels: Vec<f32>,
}

impl DepthBuffer {
    /// A buffer with no occluder anywhere (all zeros).
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, texels: vec![0.0; width as usize * height as usize] }
    }

    /// Width in texels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Depth (`1/w` of the farthest covering occluder, 0 for none) at texel `(x, y)`.
    pub fn get(&self, x: u32, y: u32) -> f32 {
        self.texels[y as usize * self.width as usize + x as usize]
    }

    /// All texels, row-major.
    pub fn texels(&self) -> &[f32] {
        &self.texels
    }

    /// Resizes to `width` x `height` and clears to "no occluder".
    pub fn reset(&mut self, width: u32, height: u32) {
        self.width = width;
        self.height = height;
        self.texels.clear();
        self.texels.resize(width as usize * height as usize, 0.0);
    }
}

/// A triangle ready for the per-texel loop: three edge functions and a depth plane, in f32, with each
/// function's sampling offset and error margin folded into its constant term.
#[derive(Clone, Copy, Debug)]
struct SetupTriangle {
    /// Per edge `(a, b, c)`: texel `(x, y)` passes the edge when `a*x + b*y + c >= 0`.
    edges: [[f32; 3]; 3],
    /// `(p, q, r)`: the depth written at texel `(x, y)` is `p*x + q*y + r`.
    depth: [f32; 3],
    /// Texel bounds: columns `x0..x1`, rows `y0..y1`.
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
}

/// Counts from one rasterization.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RasterStats {
    /// Triangles submitted.
    pub triangles_in: usize,
    /// Triangles (after clipping and fan splitting) that reached the texel loop.
    pub triangles_rasterized: usize,
    /// Triangles skipped as back-facing, degenerate, or clipped away entirely.
    pub triangles_rejected: usize,
}

/// One occluder to rasterize: its local triangle list and its world transform.
#[derive(Clone, Copy, Debug)]
pub struct OccluderInstance<'a> {
    /// Local-space triangle list, three vertices per triangle.
    pub triangles: &'a [Vec3],
    /// Local-to-world transform.
    pub transform: glam::Affine3A,
}

/// Rasterizes `occluders` into `buffer` (cleared first, resized to the view), in parallel over bands of rows.
pub fn rasterize(
    view: &ScreenView,
    occluders: &[OccluderInstance<'_>],
    mode: RasterMode,
    buffer: &mut DepthBuffer,
) -> RasterStats {
    buffer.reset(view.width, view.height);
    let triangles_in = occluders.iter().map(|o| o.triangles.len() / 3).sum();
    let setups: Vec<SetupTriangle> = occluders
        .par_iter()
        .flat_map_iter(|occluder| {
            let mut setups = Vec::new();
            setup_occluder(view, occluder, mode, &mut setups);
            setups
        })
        .collect();
    let stats = RasterStats {
        triangles_in,
        triangles_rasterized: setups.len(),
        triangles_rejected: triangles_in.saturating_sub(setups.len()),
    };
    if setups.is_empty() {
        return stats;
    }

    let width = view.width as usize;
    let bands = (view.height as usize).div_ceil(BAND_ROWS);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (index, tri) in setups.iter().enumerate() {
        let bands = tri.y0 as usize / BAND_ROWS..(tri.y1 as usize).div_ceil(BAND_ROWS);
        for bin in &mut bins[bands] {
            bin.push(index as u32);
        }
    }
    buffer.texels.par_chunks_mut(width * BAND_ROWS).zip(bins.par_iter()).enumerate().for_each(
        |(band, (texels, bin))| {
            let band_y0 = (band * BAND_ROWS) as u32;
            let band_y1 = band_y0 + (texels.len() / width) as u32;
            for &index in bin {
                let tri = &setups[index as usize];
                for y in tri.y0.max(band_y0)..tri.y1.min(band_y1) {
                    let row = &mut texels[(y - band_y0) as usize * width..][..width];
                    raster_row(tri, y, &mut row[tri.x0 as usize..tri.x1 as usize]);
                }
            }
        },
    );
    stats
}

/// The inner loop: one row of one triangle, written so the compiler vectorizes it (no branches, a select and
/// a max per texel).
#[inline(always)]
fn raster_row(tri: &SetupTriangle, y: u32, row: &mut [f32]) {
    let yf = y as f32;
    let [[a0, b0, c0], [a1, b1, c1], [a2, b2, c2]] = tri.edges;
    let (r0, r1, r2) = (b0 * yf + c0, b1 * yf + c1, b2 * yf + c2);
    let [p, q, r] = tri.depth;
    let rz = q * yf + r;
    for (i, texel) in row.iter_mut().enumerate() {
        let xf = (tri.x0 + i as u32) as f32;
        let inside = (a0 * xf + r0 >= 0.0) & (a1 * xf + r1 >= 0.0) & (a2 * xf + r2 >= 0.0);
        let depth = p * xf + rz;
        *texel = if inside { texel.max(depth) } else { *texel };
    }
}

/// Transforms, clips and sets up every front-facing triangle of one occluder.
fn setup_occluder(view: &ScreenView, occluder: &OccluderInstance<'_>, mode: RasterMode, out: &mut Vec<SetupTriangle>) {
    let transform = DAffine3::from_mat3_translation(
        glam::Mat3::from(occluder.transform.matrix3).as_dmat3(),
        DVec3::from(Vec3::from(occluder.transform.translation)) - view.origin.as_dvec3(),
    );
    let m = view.clip_from_relative;
    let clip = |p: Vec3| {
        let v = m * transform.transform_point3(p.as_dvec3()).extend(1.0);
        DVec3::new(v.x, v.y, v.w)
    };
    for tri in occluder.triangles.chunks_exact(3) {
        let mut polygon = [DVec3::ZERO; 9];
        polygon[..3].copy_from_slice(&[clip(tri[0]), clip(tri[1]), clip(tri[2])]);
        let count = clip_polygon(&mut polygon, 3, view.near as f64);
        if count < 3 {
            continue;
        }
        let screen: Vec<DVec3> = polygon[..count].iter().map(|&v| to_screen(view, v)).collect();
        for i in 1..count - 1 {
            if let Some(setup) = setup_triangle([screen[0], screen[i], screen[i + 1]], view, mode) {
                out.push(setup);
            }
        }
    }
}

/// Clips a homogeneous `(x, y, w)` polygon against `w >= near` and the viewport `-w <= x, y <= w`
/// (Sutherland-Hodgman). Returns the new vertex count (0 when nothing is left).
fn clip_polygon(polygon: &mut [DVec3; 9], mut count: usize, near: f64) -> usize {
    let planes = [
        DVec4::new(0.0, 0.0, 1.0, -near),
        DVec4::new(1.0, 0.0, 1.0, 0.0),
        DVec4::new(-1.0, 0.0, 1.0, 0.0),
        DVec4::new(0.0, 1.0, 1.0, 0.0),
        DVec4::new(0.0, -1.0, 1.0, 0.0),
    ];
    let mut scratch = [DVec3::ZERO; 9];
    for plane in planes {
        let distance = |v: DVec3| plane.truncate().dot(v) + plane.w;
        let mut out = 0;
        for i in 0..count {
            let (a, b) = (polygon[i], polygon[(i + 1) % count]);
            let (da, db) = (distance(a), distance(b));
            if da >= 0.0 {
                scratch[out] = a;
                out += 1;
            }
            if (da >= 0.0) != (db >= 0.0) {
                scratch[out] = a + (b - a) * (da / (da - db));
                out += 1;
            }
        }
        count = out.min(9);
        polygon[..count].copy_from_slice(&scratch[..count]);
        if count < 3 {
            return 0;
        }
    }
    count
}

/// Homogeneous `(x, y, w)` to screen texel coordinates and `1/w`, y down.
fn to_screen(view: &ScreenView, v: DVec3) -> DVec3 {
    let inv_w = 1.0 / v.z;
    DVec3::new((v.x * inv_w * 0.5 + 0.5) * view.width as f64, (0.5 - v.y * inv_w * 0.5) * view.height as f64, inv_w)
}

/// Edge and depth planes of a screen-space triangle, or `None` if it is back-facing, degenerate, or covers no
/// texel row or column.
fn setup_triangle(v: [DVec3; 3], view: &ScreenView, mode: RasterMode) -> Option<SetupTriangle> {
    // Counter-clockwise in y-up NDC is clockwise on the y-down screen: negative area here is front-facing.
    let area = (v[1].x - v[0].x) * (v[2].y - v[0].y) - (v[1].y - v[0].y) * (v[2].x - v[0].x);
    if area >= 0.0 || !area.is_finite() {
        return None;
    }
    let v = [v[0], v[2], v[1]]; // Now counter-clockwise on screen: edge functions are positive inside.
    let (width, height) = (view.width as f64, view.height as f64);
    let min = v[0].min(v[1]).min(v[2]);
    let max = v[0].max(v[1]).max(v[2]);
    let x0 = min.x.floor().clamp(0.0, width) as u32;
    let x1 = max.x.ceil().clamp(0.0, width) as u32;
    let y0 = min.y.floor().clamp(0.0, height) as u32;
    let y1 = max.y.ceil().clamp(0.0, height) as u32;
    if x0 >= x1 || y0 >= y1 {
        return None;
    }
    let conservative = mode == RasterMode::Conservative;
    // Texel (x, y) spans [x, x+1] x [y, y+1]. Fast mode samples its centre; conservative mode takes the
    // minimum over the texel (the centre less half the plane's slope on each axis), less a rounding margin.
    let fold = |a: f64, b: f64, c: f64| {
        let centre = c + 0.5 * (a + b);
        if conservative {
            let margin = EVAL_MARGIN * (a.abs() * width + b.abs() * height + c.abs() + 1.0);
            centre - 0.5 * (a.abs() + b.abs()) - margin
        } else {
            centre
        }
    };
    let mut edges = [[0.0f32; 3]; 3];
    for (i, edge) in edges.iter_mut().enumerate() {
        let (p, q) = (v[i], v[(i + 1) % 3]);
        let (a, b) = (-(q.y - p.y), q.x - p.x);
        let c = -(a * p.x + b * p.y);
        *edge = [a as f32, b as f32, fold(a, b, c) as f32];
    }
    // Depth plane z = p*x + q*y + r through the three vertices (Cramer's rule on the edge vectors).
    let (e1, e2) = (v[1] - v[0], v[2] - v[0]);
    let det = e1.x * e2.y - e1.y * e2.x;
    let p = (e1.z * e2.y - e2.z * e1.y) / det;
    let q = (e2.z * e1.x - e1.z * e2.x) / det;
    let r = v[0].z - p * v[0].x - q * v[0].y;
    let depth = [p as f32, q as f32, fold(p, q, r) as f32];
    (edges.iter().flatten().chain(&depth).all(|c| c.is_finite())).then_some(SetupTriangle {
        edges,
        depth,
        x0,
        x1,
        y0,
        y1,
    })
}

/// A farthest-depth mip pyramid of a [`DepthBuffer`]: level `k + 1` has `ceil(size / 2)` texels per axis and
/// each texel holds the minimum `1/w` (farthest depth) of the up to 2x2 texels of level `k` it covers, so a
/// coarse texel never claims more occlusion than every fine texel under it. Odd sizes keep their last row and
/// column (a coarse texel over the edge takes the texels that exist; off-screen parts are never tested).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DepthPyramid {
    levels: Vec<DepthBuffer>,
}

impl DepthPyramid {
    /// Rebuilds the pyramid from `base`, reusing allocations. Level 0 is a copy of `base`.
    pub fn build(&mut self, base: &DepthBuffer) {
        let mut count = 1;
        let (mut w, mut h) = (base.width, base.height);
        while w > 1 || h > 1 {
            (w, h) = (w.div_ceil(2), h.div_ceil(2));
            count += 1;
        }
        self.levels.resize_with(count, DepthBuffer::default);
        self.levels[0].clone_from(base);
        for level in 1..count {
            let (fine, coarse) = self.levels.split_at_mut(level);
            let fine = &fine[level - 1];
            let coarse = &mut coarse[0];
            coarse.reset(fine.width.div_ceil(2), fine.height.div_ceil(2));
            for y in 0..coarse.height {
                let (fy0, fy1) = (2 * y, (2 * y + 1).min(fine.height - 1));
                for x in 0..coarse.width {
                    let (fx0, fx1) = (2 * x, (2 * x + 1).min(fine.width - 1));
                    let farthest =
                        fine.get(fx0, fy0).min(fine.get(fx1, fy0)).min(fine.get(fx0, fy1)).min(fine.get(fx1, fy1));
                    coarse.texels[(y * coarse.width + x) as usize] = farthest;
                }
            }
        }
    }

    /// Number of levels (level 0 is the full buffer).
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Level `k`.
    pub fn level(&self, k: usize) -> &DepthBuffer {
        &self.levels[k]
    }

    /// Farthest depth over texels `x0..=x1`, `y0..=y1` of level `k` (inclusive, must be in range).
    pub fn farthest(&self, k: usize, x0: u32, y0: u32, x1: u32, y1: u32) -> f32 {
        let level = &self.levels[k];
        let mut farthest = f32::INFINITY;
        for y in y0..=y1 {
            let row = &level.texels[(y * level.width) as usize..][..level.width as usize];
            for &texel in &row[x0 as usize..=x1 as usize] {
                farthest = farthest.min(texel);
            }
        }
        farthest
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pyramid_keeps_odd_edges() {
        let mut base = DepthBuffer::new(5, 3);
        base.texels.iter_mut().for_each(|t| *t = 1.0);
        base.texels[4] = 0.25; // the last column of row 0
        base.texels[14] = 0.5; // the last texel
        let mut pyramid = DepthPyramid::default();
        pyramid.build(&base);
        assert_eq!(pyramid.level_count(), 4); // 5x3, 3x2, 2x1, 1x1
        assert_eq!(pyramid.level(1).width(), 3);
        assert_eq!(pyramid.level(1).get(2, 0), 0.25);
        assert_eq!(pyramid.level(1).get(2, 1), 0.5);
        assert_eq!(pyramid.level(3).get(0, 0), 0.25);
    }
}
