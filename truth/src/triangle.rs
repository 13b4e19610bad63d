//! The exact triangle rasterizer both reference buffers share: f64 projection, homogeneous clipping against the
//! near (and finite far) plane, and pixel-centre coverage by exact edge functions with the top-left fill rule.
//!
//! Depth is `d / w`, `d` an affine function of the position: `d = 1` (depth `1/w`) for a perspective view, the
//! distance towards the light for an orthographic light view (as in `cullet::depth`); either is affine in
//! screen space.

use crate::half_spaces::depth_half_spaces;
use cullet::frustum::LightView;
use cullet::{Camera, DepthConvention};
use glam::{Affine3A, DAffine3, DMat4, DVec3, DVec4, Vec3};
use std::ops::{Add, Mul, Sub};

/// The camera (or a light view) as a reference buffer sees it, in f64.
#[derive(Clone, Debug)]
pub(crate) struct ReferenceView {
    /// World position everything is made relative to.
    origin: DVec3,
    clip_from_relative: DMat4,
    /// `d` of the depth `d / w`, from an `origin`-relative point: `d = depth_row · (p, 1)`.
    depth_row: DVec4,
    near: f64,
    far: Option<f64>,
    /// Half-spaces `n · p + c >= 0` of `origin`-relative points that geometry is clipped to before projection
    /// (a light view's near and far planes).
    clip_planes: Vec<DVec4>,
    pub width: u32,
    pub height: u32,
}

/// A triangle on the screen: `(x, y)` in pixels (y down, pixel centres at `+0.5`) and `z` its depth (larger is
/// nearer), wound so that its interior is on the positive side of each edge.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ScreenTriangle {
    v: [DVec3; 3],
    /// Twice the signed area, > 0.
    area: f64,
}

/// Which faces a buffer draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Faces {
    /// Counter-clockwise triangles (seen from the camera) only, as a renderer with back-face culling draws.
    Front,
    /// Both windings.
    Both,
}

impl ReferenceView {
    pub fn new(camera: &Camera, width: u32, height: u32) -> Self {
        Self {
            origin: camera.position.as_dvec3(),
            clip_from_relative: camera.clip_from_relative_f64(),
            depth_row: DVec4::W,
            near: camera.near as f64,
            far: camera.far.map(f64::from),
            clip_planes: Vec::new(),
            width,
            height,
        }
    }

    /// A light view on a `size` x `size` buffer. A lamp's face is a perspective view clipped to its near and
    /// far planes. A sun's cascade is orthographic: depth `2 - z` (`z` from 0 at its near plane to 1 at its
    /// far plane), clipped to its far plane only, since its shadow map clamps the depth of what lies nearer
    /// the light instead of clipping it.
    pub fn of_light_view(light_view: &LightView, size: u32) -> Self {
        let matrix = light_view.clip_from_relative;
        let (near_plane, far_plane) = depth_half_spaces(matrix, light_view.depth);
        // Depth 0 at the near plane to 1 at the far plane (w = 1 in an orthographic view), as a row: the near
        // half-space's distance, which spans 2 in clip space from -1 to 1.
        let z01 = if light_view.depth == DepthConvention::NegativeOneToOne { near_plane * 0.5 } else { near_plane };
        let mut clip_planes: Vec<DVec4> = Vec::new();
        if light_view.near.is_some() {
            clip_planes.push(near_plane);
        }
        if far_plane.truncate() != DVec3::ZERO {
            clip_planes.push(far_plane);
        }
        Self {
            origin: light_view.origin.as_dvec3(),
            clip_from_relative: matrix,
            depth_row: if light_view.near.is_some() { DVec4::W } else { DVec4::W * 2.0 - z01 },
            // The near plane (if any) is among the clip planes; this only keeps `w` positive.
            near: 0.0,
            far: None,
            clip_planes,
            width: size,
            height: size,
        }
    }

    /// Homogeneous clip coordinates of a world point given in f64.
    fn clip(&self, world: DVec3) -> DVec4 {
        self.clip_from_relative * (world - self.origin).extend(1.0)
    }

    /// Whether the box `local_center ± local_extent` under `transform` may reach the view volume: false only
    /// when all eight corners are outside one clip plane, so every triangle inside the box is too.
    pub fn may_see_box(&self, transform: &Affine3A, local_center: Vec3, local_extent: Vec3) -> bool {
        let transform = transform.as_daffine3();
        let mut outside = [true; 6];
        let mut outside_planes = vec![true; self.clip_planes.len()];
        for corner in 0..8 {
            let sign = DVec3::new(
                if corner & 1 == 0 { -1.0 } else { 1.0 },
                if corner & 2 == 0 { -1.0 } else { 1.0 },
                if corner & 4 == 0 { -1.0 } else { 1.0 },
            );
            let local = local_center.as_dvec3() + local_extent.as_dvec3() * sign;
            let world = transform.transform_point3(local);
            let c = self.clip(world);
            let tests =
                [c.x < -c.w, c.x > c.w, c.y < -c.w, c.y > c.w, c.w < self.near, self.far.is_some_and(|far| c.w > far)];
            for (out, test) in outside.iter_mut().zip(tests) {
                *out &= test;
            }
            let relative = world - self.origin;
            for (out, plane) in outside_planes.iter_mut().zip(&self.clip_planes) {
                *out &= plane.truncate().dot(relative) + plane.w < 0.0;
            }
        }
        !outside.iter().chain(&outside_planes).any(|&out| out)
    }

    /// Projects the world-space triangle `world`, clips it to the view's clip planes and to `near <= w <= far`
    /// and calls `emit` with each piece drawn with `faces`. Degenerate and non-finite triangles emit nothing.
    pub fn project(&self, world: [DVec3; 3], faces: Faces, mut emit: impl FnMut(ScreenTriangle)) {
        let mut relative: Vec<DVec3> = world.iter().map(|&p| p - self.origin).collect();
        for plane in &self.clip_planes {
            relative = clip_polygon(&relative, |p| plane.truncate().dot(p) + plane.w);
        }
        // Homogeneous (x, y, w, d).
        let mut polygon: Vec<DVec4> = relative
            .iter()
            .map(|&p| {
                let c = self.clip_from_relative * p.extend(1.0);
                DVec4::new(c.x, c.y, c.w, self.depth_row.dot(p.extend(1.0)))
            })
            .collect();
        if !polygon.iter().all(|v| v.is_finite()) {
            return;
        }
        polygon = clip_polygon(&polygon, |v| v.z - self.near);
        if let Some(far) = self.far {
            polygon = clip_polygon(&polygon, |v| far - v.z);
        }
        let screen: Vec<DVec3> = polygon
            .iter()
            .map(|v| {
                DVec3::new(
                    (v.x / v.z * 0.5 + 0.5) * self.width as f64,
                    (0.5 - v.y / v.z * 0.5) * self.height as f64,
                    v.w / v.z,
                )
            })
            .collect();
        for i in 1..screen.len().saturating_sub(1) {
            let (a, mut b, mut c) = (screen[0], screen[i], screen[i + 1]);
            let mut area = edge(a, b, c.x, c.y);
            // Counter-clockwise in NDC (y up) is clockwise on the y-down screen: negative area.
            if area < 0.0 {
                std::mem::swap(&mut b, &mut c);
                area = -area;
            } else if faces == Faces::Front {
                continue;
            }
            if area > 0.0 && area.is_finite() {
                emit(ScreenTriangle { v: [a, b, c], area });
            }
        }
    }
}

/// Sutherland-Hodgman clipping of a convex polygon to `distance(v) >= 0`.
fn clip_polygon<V>(polygon: &[V], distance: impl Fn(V) -> f64) -> Vec<V>
where
    V: Copy + Add<Output = V> + Sub<Output = V> + Mul<f64, Output = V>,
{
    let mut out = Vec::with_capacity(polygon.len() + 1);
    for (i, &a) in polygon.iter().enumerate() {
        let b = polygon[(i + 1) % polygon.len()];
        let (da, db) = (distance(a), distance(b));
        if da >= 0.0 {
            out.push(a);
        }
        if (da >= 0.0) != (db >= 0.0) {
            out.push(a + (b - a) * (da / (da - db)));
        }
    }
    out
}

/// The edge function of `a -> b` at `(x, y)`: positive on the side the interior of a triangle wound as
/// [`ScreenTriangle`] lies. Always evaluated from the lower endpoint (in `(y, x)` order), so that the two
/// triangles sharing an edge get exactly opposite values and no pixel centre on it is lost or drawn twice.
fn edge(a: DVec3, b: DVec3, x: f64, y: f64) -> f64 {
    let from = |p: DVec3, q: DVec3| (q.x - p.x) * (y - p.y) - (q.y - p.y) * (x - p.x);
    if (a.y, a.x) <= (b.y, b.x) { from(a, b) } else { -from(b, a) }
}

/// Top-left rule: a pixel centre exactly on an edge belongs to the triangle whose interior is below a
/// horizontal edge, or right of any other edge. Of the two directions an edge is walked in by the triangles
/// sharing it, exactly one passes.
fn owns_edge(a: DVec3, b: DVec3) -> bool {
    let d = b - a;
    d.y < 0.0 || (d.y == 0.0 && d.x > 0.0)
}

impl ScreenTriangle {
    /// Pixel rows `y0..y1` the triangle may cover, clamped to `0..height`.
    pub fn rows(&self, height: u32) -> (u32, u32) {
        let min = self.v[0].y.min(self.v[1].y).min(self.v[2].y);
        let max = self.v[0].y.max(self.v[1].y).max(self.v[2].y);
        pixel_range(min, max, height)
    }

    /// Calls `visit(x, y, depth)` for each pixel in rows `rows` whose centre the triangle covers, with the
    /// triangle's `1/w` there.
    pub fn cover(&self, width: u32, rows: (u32, u32), mut visit: impl FnMut(u32, u32, f64)) {
        let [a, b, c] = self.v;
        let (x0, x1) = pixel_range(a.x.min(b.x).min(c.x), a.x.max(b.x).max(c.x), width);
        let (y0, y1) = self.rows(rows.1);
        let owns = [owns_edge(b, c), owns_edge(c, a), owns_edge(a, b)];
        for y in y0.max(rows.0)..y1 {
            let py = y as f64 + 0.5;
            for x in x0..x1 {
                let px = x as f64 + 0.5;
                let e = [edge(b, c, px, py), edge(c, a, px, py), edge(a, b, px, py)];
                if (0..3).all(|i| e[i] > 0.0 || (e[i] == 0.0 && owns[i])) {
                    let depth = (e[0] * a.z + e[1] * b.z + e[2] * c.z) / self.area;
                    visit(x, y, depth);
                }
            }
        }
    }
}

/// Pixels `first..end` whose centres `i + 0.5` may lie in `[min, max]`, clamped to `0..size`.
fn pixel_range(min: f64, max: f64, size: u32) -> (u32, u32) {
    let first = (min - 0.5).ceil().clamp(0.0, size as f64);
    let end = ((max - 0.5).floor() + 1.0).clamp(0.0, size as f64);
    (first as u32, (end as u32).max(first as u32))
}

/// The world-space corners of a local triangle, in f64.
pub(crate) fn world_triangle(transform: &DAffine3, local: [Vec3; 3]) -> [DVec3; 3] {
    local.map(|p| transform.transform_point3(p.as_dvec3()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn triangle(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> ScreenTriangle {
        let v = [DVec3::new(a[0], a[1], 1.0), DVec3::new(b[0], b[1], 1.0), DVec3::new(c[0], c[1], 1.0)];
        let area = edge(v[0], v[1], v[2].x, v[2].y);
        assert!(area > 0.0, "test triangles are wound with positive area");
        ScreenTriangle { v, area }
    }

    /// A square whose corners and diagonals run through pixel centres, split into 8 triangles around its
    /// centre: each pixel centre inside is covered exactly once; on the border, the top and left edges are
    /// in and the bottom and right edges out.
    #[test]
    fn shared_edges_cover_each_pixel_centre_once() {
        let (lo, hi, mid) = (2.5, 10.5, 6.5);
        let ring = [[lo, lo], [mid, lo], [hi, lo], [hi, mid], [hi, hi], [mid, hi], [lo, hi], [lo, mid]];
        let mut count = [[0u32; 16]; 16];
        for i in 0..8 {
            let (a, b) = (ring[i], ring[(i + 1) % 8]);
            // Ring order is clockwise on the y-down screen: positive area with the centre last.
            triangle(a, b, [mid, mid]).cover(16, (0, 16), |x, y, depth| {
                assert_eq!(depth, 1.0);
                count[y as usize][x as usize] += 1;
            });
        }
        for (y, row) in count.iter().enumerate() {
            for (x, &n) in row.iter().enumerate() {
                let inside = (2..10).contains(&x) && (2..10).contains(&y);
                assert_eq!(n, u32::from(inside), "pixel ({x}, {y})");
            }
        }
    }

    /// Two triangles sharing a diagonal that is not axis-aligned and passes between and through centres.
    #[test]
    fn a_split_quad_covers_like_the_quad() {
        let mut count = [[0u32; 8]; 8];
        for t in [triangle([0.3, 0.7], [7.1, 1.5], [6.2, 6.9]), triangle([0.3, 0.7], [6.2, 6.9], [1.5, 5.5])] {
            t.cover(8, (0, 8), |x, y, _| count[y as usize][x as usize] += 1);
        }
        assert!(count.iter().flatten().all(|&n| n <= 1), "{count:?}");
        assert!(count.iter().flatten().filter(|&&n| n == 1).count() > 20);
    }

    #[test]
    fn clipping_keeps_the_part_in_front_of_the_near_plane() {
        let square = [DVec3::new(0.0, 0.0, 0.0), DVec3::new(1.0, 0.0, 2.0), DVec3::new(0.0, 1.0, 4.0)];
        let clipped = clip_polygon(&square, |v| v.z - 1.0);
        assert_eq!(clipped.len(), 4);
        assert!(clipped.iter().all(|v| v.z >= 1.0 - 1e-12));
    }
}
