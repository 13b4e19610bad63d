//! Occluder setup, in f64: each occluder bounded on screen from its local box, then its vertices transformed
//! once, its front faces clipped against the near plane and turned into f32 edge and depth planes with margins
//! that cover the texel loops' rounding, and the boundary of their union found for the conservative mode.

use super::RasterMode;
use crate::depth::{ScreenView, ceil, floor};
use crate::occluders::{NO_NEIGHBOUR, OccluderInstance};
use glam::{DAffine3, DMat4, DVec3, DVec4, Vec3};
use std::sync::OnceLock;

/// Relative margin covering the f32 evaluation of an edge or depth plane (4x its rounding-error bound).
pub(super) const EVAL_MARGIN: f64 = 1.0 / (1u64 << 20) as f64;

/// A triangle ready for the per-texel loop, in f32, all offsets and margins folded into constant terms.
#[derive(Clone, Copy, Debug)]
pub(super) struct SetupTriangle {
    /// Per edge `(a, b, c_centre, c_outer)`: the texel centre is inside the edge when `a*x + b*y + c_centre >= 0`;
    /// the texel may overlap the triangle only if `a*x + b*y + c_outer >= 0`.
    pub(super) edges: [[f32; 4]; 3],
    /// `(p, q, r)`: the depth written for texel `(x, y)` is `p*x + q*y + r` (the plane's minimum over the texel
    /// less a margin in conservative mode, its value at the centre in fast mode).
    pub(super) depth: [f32; 3],
    /// Texel bounds.
    pub(super) rect: TexelRect,
}

/// Columns `x0..x1`, rows `y0..y1` of a depth buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct TexelRect {
    pub(crate) x0: u32,
    pub(crate) x1: u32,
    pub(crate) y0: u32,
    pub(crate) y1: u32,
}

impl TexelRect {
    pub(super) const EMPTY: Self = Self { x0: u32::MAX, x1: 0, y0: u32::MAX, y1: 0 };

    /// Every texel of a `width` by `height` buffer.
    pub(crate) fn whole(width: u32, height: u32) -> Self {
        Self { x0: 0, x1: width, y0: 0, y1: height }
    }

    #[inline]
    pub(super) fn intersect(self, other: Self) -> Self {
        Self {
            x0: self.x0.max(other.x0),
            x1: self.x1.min(other.x1),
            y0: self.y0.max(other.y0),
            y1: self.y1.min(other.y1),
        }
    }

    #[inline]
    pub(super) fn union(self, other: Self) -> Self {
        Self {
            x0: self.x0.min(other.x0),
            x1: self.x1.max(other.x1),
            y0: self.y0.min(other.y0),
            y1: self.y1.max(other.y1),
        }
    }

    #[inline]
    pub(crate) fn is_empty(&self) -> bool {
        self.x0 >= self.x1 || self.y0 >= self.y1
    }
}

/// One occluder after setup: its front-facing triangles, and the screen segments that bound their union.
#[derive(Clone, Debug)]
pub(super) struct SetupOccluder {
    pub(super) triangles: Vec<SetupTriangle>,
    /// Silhouette, open-boundary and near-clip edges `(x0, y0, x1, y1)`: the union of the triangles has no other
    /// boundary, so a texel whose centre is covered and that no such segment touches is covered whole. Only
    /// the conservative mode reads them; empty in the others.
    pub(super) boundary: Vec<[f64; 4]>,
    /// Where every boundary segment's ends lie on one side of every boundary segment's line (conservative mode
    /// only): those lines `(a, b, c)`, the union on the side where `a*x + b*y + c >= 0`. The union is then the
    /// convex region they bound, and [`raster_hull`](super::texels::raster_hull) draws it from them. Empty otherwise.
    pub(super) hull: Vec<[f64; 3]>,
    /// The triangles as the masked mode draws them: consecutive ones sharing an edge paired into one quad
    /// (see [`quads`]). Empty in the other modes.
    pub(super) quads: Vec<SetupQuad>,
    pub(super) rect: TexelRect,
}

/// An occluder to draw, bounded on screen before its triangles are set up. A band sets it up the first time
/// it finds the occluder not hidden behind nearer ones, so an occluder hidden in every band it reaches (most
/// of them, from a street between buildings) costs only its bound.
pub(super) struct PendingOccluder<'a> {
    pub(super) instance: &'a OccluderInstance<'a>,
    /// Texels its triangles may cover: a superset of the set-up occluder's rectangle.
    pub(super) rect: TexelRect,
    /// Nothing of the occluder is nearer: at least the largest depth of any of its set-up vertices.
    pub(super) nearest: f32,
    pub(super) setup: OnceLock<Option<SetupOccluder>>,
}

impl PendingOccluder<'_> {
    /// Its set-up triangles, made by the first caller; `None` when none is drawn (all back-facing, clipped
    /// away or degenerate, or in conservative mode too small to cover a texel whole).
    #[inline]
    pub(super) fn setup(
        &self,
        view: &ScreenView,
        mode: RasterMode,
        scratch: &mut SetupScratch,
    ) -> Option<&SetupOccluder> {
        self.setup.get_or_init(|| setup_occluder(view, self.instance, mode, scratch)).as_ref()
    }
}

/// The texels an occluder may cover and a depth nothing of it is nearer than, from the corners of its local
/// box: `None` when it covers no texel. A box reaching behind the near plane is bounded by the whole buffer
/// and an infinite depth.
///
/// Every vertex lies in the box, and with `w` at least the near plane's over the box, its projection lies in
/// the corners' hull and its depth `d/w` is at most theirs; the bound is widened by far more than f64
/// rounding moves either. It only decides which occluders are skipped (as hidden, or off a band), and
/// drawing fewer occluders never hides more, so even a bound too tight would cost culling, not correctness.
pub(super) fn screen_bound(view: &ScreenView, instance: &OccluderInstance<'_>) -> Option<(TexelRect, f32)> {
    let [low, high] = instance.occluder.local_box();
    if !(low.cmple(high).all()) {
        return None; // No triangle.
    }
    let near = view.near as f64;
    // Local position to homogeneous `(x, y, w, d)` in one affine map, so that each corner costs additions: the
    // centre's image plus or minus each half-axis's (instead of two matrix products a corner).
    let xywd = local_to_clip(view, instance);
    let (low, high) = (low.as_dvec3(), high.as_dvec3());
    let (centre, half) = ((low + high) * 0.5, (high - low) * 0.5);
    let centre = xywd * centre.extend(1.0);
    let axes = [xywd.x_axis * half.x, xywd.y_axis * half.y, xywd.z_axis * half.z];
    let (mut min, mut max) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    let mut in_front = true;
    for corner in 0..8 {
        let signed = |bit: usize, axis: DVec4| if corner & bit != 0 { axis } else { -axis };
        let clip = centre + signed(1, axes[0]) + signed(2, axes[1]) + signed(4, axes[2]);
        // Written so that NaN counts as behind.
        in_front &= clip.z - near >= 0.0;
        let screen = to_screen(view, clip);
        (min, max) = (min.min(screen), max.max(screen));
    }
    let (width, height) = (view.width as f64, view.height as f64);
    if !(in_front && min.is_finite() && max.is_finite()) {
        let whole = TexelRect { x0: 0, x1: view.width, y0: 0, y1: view.height };
        return (!whole.is_empty()).then_some((whole, f32::INFINITY));
    }
    let widen = |v: f64| 1e-3 + 1e-9 * v.abs();
    let rect = TexelRect {
        x0: floor((min.x - widen(min.x)).clamp(0.0, width)),
        x1: ceil((max.x + widen(max.x)).clamp(0.0, width)),
        y0: floor((min.y - widen(min.y)).clamp(0.0, height)),
        y1: ceil((max.y + widen(max.y)).clamp(0.0, height)),
    };
    (!rect.is_empty()).then_some((rect, (max.z as f32).next_up()))
}

/// The occluder's local-to-camera-relative transform, in f64.
pub(super) fn relative_transform(view: &ScreenView, instance: &OccluderInstance<'_>) -> DAffine3 {
    DAffine3::from_mat3_translation(
        glam::Mat3::from(instance.transform.matrix3).as_dmat3(),
        DVec3::from(Vec3::from(instance.transform.translation)) - view.origin.as_dvec3(),
    )
}

/// The occluder's local position to homogeneous `(x, y, w, d)` ([`to_clip`] of its camera-relative position),
/// as one matrix whose rows are clip `x`, `y`, `w` and the depth row.
pub(super) fn local_to_clip(view: &ScreenView, instance: &OccluderInstance<'_>) -> DMat4 {
    let relative = DMat4::from(relative_transform(view, instance));
    let clip = view.clip_from_relative * relative;
    let depth = relative.transpose() * view.depth_from_relative;
    DMat4::from_cols(clip.row(0), clip.row(1), clip.row(3), depth).transpose()
}

/// Transforms, clips against the near plane and sets up the front faces of one occluder, with the boundary of
/// their union (conservative mode only): edges whose neighbour is missing or back-facing, and edges made by
/// near clipping. `None` when no triangle is left to draw.
pub(super) fn setup_occluder(
    view: &ScreenView,
    instance: &OccluderInstance<'_>,
    mode: RasterMode,
    scratch: &mut SetupScratch,
) -> Option<SetupOccluder> {
    let transform = relative_transform(view, instance);
    let occluder = instance.occluder;
    let (vertices, corners) = occluder.indexed();
    let neighbours = occluder.neighbours();
    let SetupScratch { relative, front, projected, oriented } = scratch;
    oriented.clear();
    let (mut screen_min, mut screen_max) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    // Each distinct vertex is transformed and projected once; the triangles read them through `corners`.
    relative.clear();
    relative.extend(vertices.iter().map(|p| transform.transform_point3(p.as_dvec3())));
    // Front-facing in 3D: the eye (the origin, or the light's direction in an orthographic view) is on the
    // outer side of the counter-clockwise face.
    let eye = view.eye();
    front.clear();
    front.extend(corners.chunks_exact(3).map(|t| {
        let (a, b, c) = (relative[t[0] as usize], relative[t[1] as usize], relative[t[2] as usize]);
        (b - a).cross(c - a).dot(eye.truncate() - a * eye.w) > 0.0
    }));
    let near = view.near as f64;
    // Homogeneous `(x, y, w, d)` and screen position of each vertex; the latter is used only where the
    // vertex is on the near plane's visible side.
    projected.clear();
    projected.extend(relative.iter().map(|&corner| {
        let clip = to_clip(view, corner);
        (clip, to_screen(view, clip))
    }));
    let mut setup = SetupOccluder {
        triangles: Vec::with_capacity(occluder.triangle_count()),
        boundary: Vec::with_capacity(if mode == RasterMode::Conservative { 8 } else { 0 }),
        hull: Vec::new(),
        quads: Vec::new(),
        rect: TexelRect::EMPTY,
    };
    for (t, triangle) in corners.chunks_exact(3).enumerate() {
        if !front[t] {
            continue;
        }
        let mut polygon = [(DVec4::ZERO, false); 4];
        for (e, &corner) in triangle.iter().enumerate() {
            let neighbour = neighbours[3 * t + e];
            let boundary = neighbour == NO_NEIGHBOUR || !front[neighbour as usize];
            polygon[e] = (projected[corner as usize].0, boundary);
        }
        let mut screen = [DVec3::ZERO; 4];
        let [a, b, c] =
            [&projected[triangle[0] as usize], &projected[triangle[1] as usize], &projected[triangle[2] as usize]];
        // Wholly on the near plane's visible side, the clip would return the triangle as it is.
        let count = if (a.0.z - near >= 0.0) & (b.0.z - near >= 0.0) & (c.0.z - near >= 0.0) {
            screen[..3].copy_from_slice(&[a.1, b.1, c.1]);
            3
        } else {
            let count;
            (polygon, count) = clip_near(&polygon, near);
            for (screen, &(v, _)) in screen.iter_mut().zip(&polygon[..count]) {
                *screen = to_screen(view, v);
            }
            count
        };
        if count < 3 {
            continue;
        }
        let screen = &screen[..count];
        for v in screen {
            (screen_min, screen_max) = (screen_min.min(*v), screen_max.max(*v));
        }
        // Only the conservative mode reads the boundary.
        for (i, &(_, boundary)) in polygon[..count].iter().enumerate() {
            if boundary && mode == RasterMode::Conservative {
                let (a, b) = (screen[i], screen[(i + 1) % count]);
                setup.boundary.push([a.x, a.y, b.x, b.y]);
            }
        }
        for i in 1..count - 1 {
            if let Some((tri, vertices)) = setup_triangle([screen[0], screen[i], screen[i + 1]], view, mode) {
                setup.rect = setup.rect.union(tri.rect);
                setup.triangles.push(tri);
                if mode == RasterMode::Masked {
                    oriented.push(vertices);
                }
            }
        }
    }
    // In conservative mode a texel is written only where the occluder covers it whole: one less than a texel
    // across on screen (before clamping to the buffer) can write none.
    let extent = screen_max - screen_min;
    let too_small = mode == RasterMode::Conservative && (extent.x < 1.0 || extent.y < 1.0);
    if mode == RasterMode::Masked {
        setup.quads = quads(&setup.triangles, oriented);
    }
    setup.hull = hull_lines(&setup.boundary);
    (!setup.triangles.is_empty() && !too_small).then_some(setup)
}

/// Most boundary segments [`hull_lines`] checks (its check takes their count squared).
pub(super) const HULL_MAX_SEGMENTS: usize = 32;
/// Farthest a boundary segment's end may lie from the screen's origin, in texels, for [`hull_lines`]: keeps the
/// rounding of [`raster_hull`](super::texels::raster_hull)'s f64 line tests far below [`SEGMENT_GROW`](super::texels::SEGMENT_GROW).
pub(super) const HULL_MAX_COORDINATE: f64 = 1e6;

/// The lines of `boundary`'s segments, each `(a, b, c)` with the other segments' first ends where
/// `a*x + b*y + c >= 0` ([`SetupOccluder::hull`]), where all of them lie on one side of each line: a closed
/// boundary (every end of a segment the first end of another) that is then convex. Empty where they do not,
/// where a segment has no length, or where there are more than [`HULL_MAX_SEGMENTS`] or an end lies beyond
/// [`HULL_MAX_COORDINATE`] (or is not finite). Only how much is drawn depends on this check: [`raster_hull`](super::texels::raster_hull) is
/// conservative for any lines it gets, so the first ends, half the points, serve as well as all of them.
pub(super) fn hull_lines(boundary: &[[f64; 4]]) -> Vec<[f64; 3]> {
    let bounded = boundary.as_flattened().iter().all(|v| v.abs() <= HULL_MAX_COORDINATE);
    if boundary.len() < 3 || boundary.len() > HULL_MAX_SEGMENTS || !bounded {
        return Vec::new();
    }
    let mut lines = Vec::with_capacity(boundary.len());
    for &[x0, y0, x1, y1] in boundary {
        let (a, b) = (y0 - y1, x1 - x0);
        if a == 0.0 && b == 0.0 {
            return Vec::new();
        }
        let c = -(a * x0 + b * y0);
        // Ends on the line itself (a neighbouring segment's) are rounded to either side by about 1e-16 of the
        // coordinates' size; this says nothing about soundness, only about which occluders are drawn this way.
        let tolerance = 1e-9 * (a.abs() + b.abs()) * HULL_MAX_COORDINATE;
        let (mut inside, mut outside) = (false, false);
        for &[x, y, _, _] in boundary {
            let side = a * x + b * y + c;
            inside |= side > tolerance;
            outside |= side < -tolerance;
        }
        match (inside, outside) {
            (true, false) => lines.push([a, b, c]),
            (false, true) => lines.push([-a, -b, -c]),
            _ => return Vec::new(),
        }
    }
    lines
}

/// Reused buffers of [`setup_occluder`], one per band.
#[derive(Default)]
pub(super) struct SetupScratch {
    pub(super) relative: Vec<DVec3>,
    pub(super) front: Vec<bool>,
    pub(super) projected: Vec<(DVec4, DVec3)>,
    /// Each set-up triangle's screen vertices, counter-clockwise (masked mode only).
    pub(super) oriented: Vec<[DVec3; 3]>,
}

/// Clips a triangle of homogeneous `(x, y, w, d)` vertices, each flagged when the edge leaving it is a
/// boundary, against `w >= near`. Edges along the clipping plane are boundaries. Returns the polygon and its
/// size.
pub(super) fn clip_near(triangle: &[(DVec4, bool); 4], near: f64) -> ([(DVec4, bool); 4], usize) {
    let mut out = [(DVec4::ZERO, false); 4];
    let mut count = 0;
    for i in 0..3 {
        let ((a, boundary), (b, _)) = (triangle[i], triangle[(i + 1) % 3]);
        let (da, db) = (a.z - near, b.z - near);
        let crossing = (da >= 0.0) != (db >= 0.0);
        let cut = a + (b - a) * (da / (da - db));
        if da >= 0.0 {
            out[count] = (a, boundary);
            count += 1;
            if crossing {
                out[count] = (cut, true); // Leaves along the near plane.
                count += 1;
            }
        } else if crossing {
            out[count] = (cut, boundary);
            count += 1;
        }
    }
    (out, count)
}

/// A camera-relative point's homogeneous `(x, y, w, d)`: clip `x`, `y` and `w`, and its depth row `d`.
pub(super) fn to_clip(view: &ScreenView, relative: DVec3) -> DVec4 {
    let point = relative.extend(1.0);
    let v = view.clip_from_relative * point;
    DVec4::new(v.x, v.y, v.w, view.depth_from_relative.dot(point))
}

/// Homogeneous `(x, y, w, d)` to screen texel coordinates and depth `d/w`, y down.
pub(super) fn to_screen(view: &ScreenView, v: DVec4) -> DVec3 {
    let inv_w = 1.0 / v.z;
    let (x, y) = ((v.x * inv_w * 0.5 + 0.5) * view.width as f64, (0.5 - v.y * inv_w * 0.5) * view.height as f64);
    DVec3::new(x, y, v.w * inv_w)
}

/// Edge and depth planes of a screen-space triangle, and its vertices in the order of its edges (counter-clockwise:
/// edge `i` runs from vertex `i` to vertex `i + 1`); `None` if it is degenerate or off screen.
pub(super) fn setup_triangle(
    v: [DVec3; 3],
    view: &ScreenView,
    mode: RasterMode,
) -> Option<(SetupTriangle, [DVec3; 3])> {
    let area = (v[1].x - v[0].x) * (v[2].y - v[0].y) - (v[1].y - v[0].y) * (v[2].x - v[0].x);
    if area == 0.0 || !area.is_finite() {
        return None;
    }
    // Make the triangle counter-clockwise in these coordinates, so edge functions are positive inside.
    let v = if area > 0.0 { v } else { [v[0], v[2], v[1]] };
    let (width, height) = (view.width as f64, view.height as f64);
    let min = v[0].min(v[1]).min(v[2]);
    let max = v[0].max(v[1]).max(v[2]);
    let rect = TexelRect {
        x0: floor(min.x.clamp(0.0, width)),
        x1: ceil(max.x.clamp(0.0, width)),
        y0: floor(min.y.clamp(0.0, height)),
        y1: ceil(max.y.clamp(0.0, height)),
    };
    if rect.is_empty() {
        return None;
    }
    // Texel (x, y) spans [x, x+1] x [y, y+1]. The margin covers the f32 evaluation of a plane over the buffer.
    let margin = |a: f64, b: f64, c: f64| EVAL_MARGIN * (a.abs() * width + b.abs() * height + c.abs()) + 1e-9;
    // A reach below zero or NaN (the field set by hand) would move the tests outward, past the pixel centres
    // sampled: none is taken.
    let reach = view.sample_reach.map(|r| r.max(0.0));
    let mut edges = [[0.0f32; 4]; 3];
    for (i, edge) in edges.iter_mut().enumerate() {
        let (p, q) = (v[i], v[(i + 1) % 3]);
        let (a, b) = (-(q.y - p.y), q.x - p.x);
        let c = -(a * p.x + b * p.y);
        let centre = c + 0.5 * (a + b);
        let outer = centre + 0.5 * (a.abs() + b.abs()) + margin(a, b, c);
        // Pixel centres count as covered only when the f32 test cannot pass for a centre outside, nor for a
        // centre of the frame's the sample stands for (within `reach` of it).
        let inward = margin(a, b, c) + reach[0] * a.abs() + reach[1] * b.abs();
        let centre = if mode.samples_pixel_centres() { centre - inward } else { centre };
        *edge = [a as f32, b as f32, centre as f32, outer as f32];
    }
    // Depth plane z = p*x + q*y + r through the three vertices (Cramer's rule on the edge vectors).
    let (e1, e2) = (v[1] - v[0], v[2] - v[0]);
    let det = e1.x * e2.y - e1.y * e2.x;
    let p = (e1.z * e2.y - e2.z * e1.y) / det;
    let q = (e2.z * e1.x - e1.z * e2.x) / det;
    let r = v[0].z - p * v[0].x - q * v[0].y;
    let centre = r + 0.5 * (p + q);
    let r_written = match mode {
        RasterMode::Conservative => centre - 0.5 * (p.abs() + q.abs()) - margin(p, q, r),
        RasterMode::PixelCentres | RasterMode::Masked => {
            centre - margin(p, q, r) - reach[0] * p.abs() - reach[1] * q.abs()
        }
        RasterMode::Fast => centre,
    };
    let depth = [p as f32, q as f32, r_written as f32];
    // Not short-circuiting, so that the fixed-size loops unroll.
    let finite = edges.as_flattened().iter().chain(&depth).fold(true, |finite, c| finite & c.is_finite());
    finite.then_some((SetupTriangle { edges, depth, rect }, v))
}

/// Outer edges of a [`SetupQuad`]: a lone triangle repeats its last.
pub(super) const QUAD_EDGES: usize = 4;

/// A set-up triangle, or two sharing an edge, as the masked raster ([`RasterMode::Masked`]) draws them (see
/// [`quads`]).
#[derive(Clone, Debug)]
pub(super) struct SetupQuad {
    /// Per outer edge `(a, b, c)`: a pixel centre `(x, y)` passes when `a * x + (b * y + c) >= 0` in f32, the
    /// set-up triangle's own test.
    pub(super) edges: [[f32; 3]; QUAD_EDGES],
    /// Each triangle's depth plane `(p, q, r)` (a lone triangle's twice): a block takes the farther of the two.
    pub(super) depth: [[f32; 3]; 2],
    pub(super) rect: TexelRect,
}

/// Pairs consecutive set-up triangles that share an edge in opposite directions (`vertices`: each one's
/// counter-clockwise screen vertices, edge `i` from vertex `i`) into quads tested against their four other
/// edges; a triangle paired with neither neighbour stays alone. Meshes list a quad's two triangles together,
/// and near-plane clipping splits a triangle into two such.
///
/// Still no centre outside the triangles is covered: each f32 edge test passes only for centres on the inner
/// side of its exact edge line (setup's margin), and a point on the inner side of all four outer lines lies
/// in one of the two triangles: on the first's side of the shared line it is inside all three of the first's,
/// otherwise all three of the second's (whose shared line is the same one, reversed). But the quad covers the
/// centres along the shared edge that the margins leave uncovered in both triangles, and a band draws it once:
/// one row of tests, no partial blocks along the diagonal. A pair is left apart where rounding could have
/// flipped either triangle's orientation.
pub(super) fn quads(triangles: &[SetupTriangle], vertices: &[[DVec3; 3]]) -> Vec<SetupQuad> {
    let outer = |triangle: &SetupTriangle, edge: usize| {
        let [a, b, c, _] = triangle.edges[edge % 3];
        [a, b, c]
    };
    let mut quads = Vec::with_capacity(triangles.len());
    let mut i = 0;
    while let Some(first) = triangles.get(i) {
        if let Some(second) = triangles.get(i + 1)
            && let Some((k1, k2)) = shared_edge(&vertices[i], &vertices[i + 1])
        {
            quads.push(SetupQuad {
                edges: [outer(first, k1 + 1), outer(first, k1 + 2), outer(second, k2 + 1), outer(second, k2 + 2)],
                depth: [first.depth, second.depth],
                rect: first.rect.union(second.rect),
            });
            i += 2;
        } else {
            quads.push(SetupQuad {
                edges: [outer(first, 0), outer(first, 1), outer(first, 2), outer(first, 2)],
                depth: [first.depth; 2],
                rect: first.rect,
            });
            i += 1;
        }
    }
    quads
}

/// The edges `(k1, k2)` by which two counter-clockwise triangles meet: edge `k1` of `u` is edge `k2` of `v`
/// reversed (the same screen positions). `None` where there is none, or where either triangle is so thin that
/// the f64 sign of its area, which decided its orientation, could be wrong.
fn shared_edge(u: &[DVec3; 3], v: &[DVec3; 3]) -> Option<(usize, usize)> {
    let same = |p: DVec3, q: DVec3| p.x == q.x && p.y == q.y;
    let (k1, k2) = (0..3)
        .flat_map(|k1| (0..3).map(move |k2| (k1, k2)))
        .find(|&(k1, k2)| same(u[k1], v[(k2 + 1) % 3]) && same(u[(k1 + 1) % 3], v[k2]))?;
    (well_oriented(u) && well_oriented(v)).then_some((k1, k2))
}

/// Whether a counter-clockwise triangle's doubled area is far above the rounding of the cross product that
/// computes it (a few ulps of the product of two edge lengths), so its orientation is certain.
fn well_oriented(t: &[DVec3; 3]) -> bool {
    let (e1, e2) = ((t[1] - t[0]).truncate(), (t[2] - t[0]).truncate());
    e1.perp_dot(e2) > 1e-9 * e1.length() * e2.length()
}
