//! The ideal the software occlusion buffer is measured against: the same occluders rasterized exactly at full
//! resolution, and the same box test (the box's projected rectangle at its nearest depth) sampled at every
//! pixel centre. The engine's low-resolution buffer can at best cull what this culls.

use crate::render::{BAND_ROWS, bin_by_band};
use crate::triangle::{Faces, ReferenceView, ScreenTriangle, world_triangle};
use cullet::Camera;
use glam::{Affine3A, DVec3, Vec3};
use rayon::prelude::*;

/// An exact full-resolution depth buffer of occluders: per pixel the `1/w` of the nearest front-facing occluder
/// surface at the pixel centre (0 where there is none), the engine's depth convention, with a pyramid of
/// per-region minima that lets a box test skip regions at once.
#[derive(Clone, Debug)]
pub struct ExactOccluderDepth {
    view: ReferenceView,
    camera: Camera,
    /// Level 0 is the buffer; level `k` halves `k - 1` rounding up, each texel the minimum of those it covers.
    levels: Vec<(u32, u32, Vec<f64>)>,
}

impl ExactOccluderDepth {
    /// Rasterizes `occluders` (local-space triangle lists, three corners a triangle, with their world
    /// transforms) as `camera` sees them at `width` x `height`.
    pub fn rasterize(camera: &Camera, occluders: &[(&[Vec3], Affine3A)], width: u32, height: u32) -> Self {
        let view = ReferenceView::new(camera, width, height);
        let triangles: Vec<ScreenTriangle> = occluders
            .par_iter()
            .flat_map_iter(|(triangles, transform)| {
                let transform = transform.as_daffine3();
                let mut out = Vec::new();
                for corners in triangles.chunks_exact(3) {
                    let local = [corners[0], corners[1], corners[2]];
                    view.project(world_triangle(&transform, local), Faces::Front, |t| out.push(t));
                }
                out
            })
            .collect();
        let mut depth = vec![0.0f64; (width * height) as usize];
        let bins = bin_by_band(triangles.iter(), height);
        depth.par_chunks_mut((width * BAND_ROWS) as usize).zip(bins.par_iter()).enumerate().for_each(
            |(band, (depths, bin))| {
                let y0 = band as u32 * BAND_ROWS;
                let y1 = (y0 + BAND_ROWS).min(height);
                for &index in bin {
                    triangles[index as usize].cover(width, (y0, y1), |x, y, d| {
                        let pixel = &mut depths[((y - y0) * width + x) as usize];
                        *pixel = (*pixel).max(d);
                    });
                }
            },
        );
        let mut levels = vec![(width, height, depth)];
        while let Some((w, h, fine)) = levels.last().filter(|(w, h, _)| *w > 1 || *h > 1) {
            let (cw, ch) = (w.div_ceil(2), h.div_ceil(2));
            let mut coarse = vec![f64::INFINITY; (cw * ch) as usize];
            for y in 0..*h {
                for x in 0..*w {
                    let texel = &mut coarse[((y / 2) * cw + x / 2) as usize];
                    *texel = texel.min(fine[(y * w + x) as usize]);
                }
            }
            levels.push((cw, ch, coarse));
        }
        Self { view, camera: *camera, levels }
    }

    /// Depth `1/w` of the nearest occluder at pixel `(x, y)`, 0 for none.
    pub fn depth_at(&self, x: u32, y: u32) -> f64 {
        let (width, _, depth) = &self.levels[0];
        depth[(y * width + x) as usize]
    }

    /// Whether a world box could show at some pixel: it reaches the near plane, or at some pixel centre
    /// inside its projected bounding rectangle its nearest depth is not behind the occluders. (The rectangle is
    /// a superset of the pixels the box covers, as in the engine's own test.)
    pub fn box_visible(&self, center: Vec3, extent: Vec3) -> bool {
        let matrix = self.camera.clip_from_relative_f64();
        let relative = center.as_dvec3() - self.camera.position.as_dvec3();
        let (width, height) = (self.view.width as f64, self.view.height as f64);
        let mut min = DVec3::splat(f64::INFINITY);
        let mut max = DVec3::splat(f64::NEG_INFINITY);
        for corner in 0..8 {
            let sign = DVec3::new(
                if corner & 1 == 0 { -1.0 } else { 1.0 },
                if corner & 2 == 0 { -1.0 } else { 1.0 },
                if corner & 4 == 0 { -1.0 } else { 1.0 },
            );
            let v = matrix * (relative + extent.as_dvec3() * sign).extend(1.0);
            if v.w <= self.camera.near as f64 || !v.is_finite() {
                return true;
            }
            let screen = DVec3::new((v.x / v.w * 0.5 + 0.5) * width, (0.5 - v.y / v.w * 0.5) * height, 1.0 / v.w);
            min = min.min(screen);
            max = max.max(screen);
        }
        let x0 = (min.x - 0.5).ceil().max(0.0);
        let y0 = (min.y - 0.5).ceil().max(0.0);
        let x1 = (max.x - 0.5).floor().min(width - 1.0);
        let y1 = (max.y - 0.5).floor().min(height - 1.0);
        if x0 > x1 || y0 > y1 {
            return false; // No pixel centre inside: it covers no sample.
        }
        let rect = [x0 as u32, y0 as u32, x1 as u32, y1 as u32];
        self.any_unhidden(self.levels.len() - 1, 0, 0, rect, max.z)
    }

    /// Whether some pixel under texel `(x, y)` of `level` and inside `rect` (inclusive, level-0 pixels) has an
    /// occluder depth not nearer than `nearest`.
    fn any_unhidden(&self, level: usize, x: u32, y: u32, rect: [u32; 4], nearest: f64) -> bool {
        let (width, _, depth) = &self.levels[level];
        if depth[(y * width + x) as usize] > nearest {
            return false;
        }
        if level == 0 {
            return true;
        }
        let (fine_width, fine_height, _) = self.levels[level - 1];
        let shift = level - 1;
        (2 * y..(2 * y + 2).min(fine_height)).any(|fy| {
            (2 * x..(2 * x + 2).min(fine_width)).any(|fx| {
                let overlaps = (fx << shift) <= rect[2]
                    && ((fx + 1) << shift) > rect[0]
                    && (fy << shift) <= rect[3]
                    && ((fy + 1) << shift) > rect[1];
                overlaps && self.any_unhidden(level - 1, fx, fy, rect, nearest)
            })
        })
    }
}
