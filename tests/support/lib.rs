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

/// An exact full-resolution depth buffer of occluders, the judge of the software occlusion stage: f64
/// throughout, sampled at pixel centres, keeping per pixel the nearest front-facing occluder's `1/w` (0 where
/// there is none), the same depth convention as the engine's buffer.
pub struct ReferenceDepth {
    width: usize,
    height: usize,
    depth: Vec<f64>,
}

/// Homogeneous `(x, y, w)` of a camera-relative point.
fn reference_clip(matrix: &DMat4, relative: DVec3) -> DVec3 {
    let v = *matrix * relative.extend(1.0);
    DVec3::new(v.x, v.y, v.w)
}

impl ReferenceDepth {
    /// Rasterizes `occluders` (local triangle lists and transforms) as `camera` sees them.
    pub fn rasterize(
        camera: &Camera,
        occluders: &[(Vec<glam::Vec3>, glam::Affine3A)],
        width: u32,
        height: u32,
    ) -> Self {
        let (width, height) = (width as usize, height as usize);
        let mut buffer = Self { width, height, depth: vec![0.0; width * height] };
        let matrix = reference_clip_from_relative(camera);
        let origin = camera.position.as_dvec3();
        let near = camera.near as f64;
        for (triangles, transform) in occluders {
            let linear = transform.matrix3.as_dmat3();
            let translation = glam::Vec3::from(transform.translation).as_dvec3();
            for tri in triangles.chunks_exact(3) {
                let clip: Vec<DVec3> =
                    tri.iter().map(|p| reference_clip(&matrix, linear * p.as_dvec3() + translation - origin)).collect();
                // Clip against w >= near.
                let mut polygon = Vec::new();
                for i in 0..3 {
                    let (a, b) = (clip[i], clip[(i + 1) % 3]);
                    let (da, db) = (a.z - near, b.z - near);
                    if da >= 0.0 {
                        polygon.push(a);
                    }
                    if (da >= 0.0) != (db >= 0.0) {
                        polygon.push(a + (b - a) * (da / (da - db)));
                    }
                }
                let screen: Vec<DVec3> = polygon
                    .iter()
                    .map(|v| {
                        DVec3::new(
                            (v.x / v.z * 0.5 + 0.5) * width as f64,
                            (0.5 - v.y / v.z * 0.5) * height as f64,
                            1.0 / v.z,
                        )
                    })
                    .collect();
                for i in 1..screen.len().saturating_sub(1) {
                    buffer.fill([screen[0], screen[i], screen[i + 1]]);
                }
            }
        }
        buffer
    }

    fn fill(&mut self, v: [DVec3; 3]) {
        let edge = |a: DVec3, b: DVec3, x: f64, y: f64| (b.x - a.x) * (y - a.y) - (b.y - a.y) * (x - a.x);
        let area = edge(v[0], v[1], v[2].x, v[2].y);
        // Front faces are clockwise on the y-down screen (counter-clockwise in NDC): negative area.
        if area >= 0.0 {
            return;
        }
        let min = v[0].min(v[1]).min(v[2]);
        let max = v[0].max(v[1]).max(v[2]);
        let x0 = (min.x - 0.5).ceil().max(0.0) as usize;
        let y0 = (min.y - 0.5).ceil().max(0.0) as usize;
        let x1 = ((max.x - 0.5).floor() as i64).min(self.width as i64 - 1);
        let y1 = ((max.y - 0.5).floor() as i64).min(self.height as i64 - 1);
        for y in y0 as i64..=y1 {
            for x in x0 as i64..=x1 {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let w0 = edge(v[1], v[2], px, py) / area;
                let w1 = edge(v[2], v[0], px, py) / area;
                let w2 = edge(v[0], v[1], px, py) / area;
                if w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0 {
                    let depth = w0 * v[0].z + w1 * v[1].z + w2 * v[2].z;
                    let texel = &mut self.depth[y as usize * self.width + x as usize];
                    *texel = texel.max(depth);
                }
            }
        }
    }

    /// Whether a box could show at some pixel: it reaches the near plane, or at some pixel centre inside its
    /// projected bounding rectangle its nearest depth is not behind the occluders. (A superset of the pixels
    /// the box really covers, so this errs towards visible: a stricter judge.)
    pub fn box_visible(&self, camera: &Camera, center: glam::Vec3, extent: glam::Vec3) -> bool {
        let matrix = reference_clip_from_relative(camera);
        let relative = center.as_dvec3() - camera.position.as_dvec3();
        let mut min = DVec3::splat(f64::INFINITY);
        let mut max = DVec3::splat(f64::NEG_INFINITY);
        for corner in 0..8 {
            let sign = DVec3::new(
                if corner & 1 == 0 { -1.0 } else { 1.0 },
                if corner & 2 == 0 { -1.0 } else { 1.0 },
                if corner & 4 == 0 { -1.0 } else { 1.0 },
            );
            let v = reference_clip(&matrix, relative + extent.as_dvec3() * sign);
            if v.z <= camera.near as f64 {
                return true;
            }
            let screen = DVec3::new(
                (v.x / v.z * 0.5 + 0.5) * self.width as f64,
                (0.5 - v.y / v.z * 0.5) * self.height as f64,
                1.0 / v.z,
            );
            min = min.min(screen);
            max = max.max(screen);
        }
        let nearest = max.z;
        let x0 = (min.x - 0.5).ceil().max(0.0) as i64;
        let y0 = (min.y - 0.5).ceil().max(0.0) as i64;
        let x1 = ((max.x - 0.5).floor() as i64).min(self.width as i64 - 1);
        let y1 = ((max.y - 0.5).floor() as i64).min(self.height as i64 - 1);
        (y0..=y1).any(|y| (x0..=x1).any(|x| nearest >= self.depth[y as usize * self.width + x as usize]))
    }
}
