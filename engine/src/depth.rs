//! The occlusion stages' screen: the [`ScreenView`] a depth buffer is seen through, the [`DepthBuffer`] the
//! raster stage writes (`1/w` of the farthest occluder covering each texel, 0 for none) and the farthest-depth
//! [`DepthPyramid`] the occlusion test and the GPU's HZB read.

use crate::camera::Camera;
use glam::{DMat4, Mat4, Vec3};

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
        let clip_from_relative = camera.clip_from_relative_f64();
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

    /// All texels, row-major, writable (to load a buffer made elsewhere).
    pub fn texels_mut(&mut self) -> &mut [f32] {
        &mut self.texels
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
