//! The occlusion stages' screen: the [`ScreenView`] a depth buffer is seen through, the [`DepthBuffer`] the
//! raster stage writes (the depth of the farthest occluder covering each texel, larger is nearer, 0 for none)
//! and the farthest-depth [`DepthPyramid`] the occlusion test and the GPU's HZB read.
//!
//! # Depth
//! A buffer's depth is `d / w`, with `w` the clip `w` of the view's matrix and `d` an affine function of the
//! position ([`ScreenView::depth_from_relative`]); both are affine in homogeneous coordinates, so `d / w` is
//! affine in screen space and a triangle's depth over a texel is bounded exactly by its plane.
//! - Perspective views (the camera, a lamp's cube faces): `d = 1`, so the depth is `1/w`, reversed depth with
//!   an infinite far plane whatever the camera's own convention.
//! - Orthographic views (a sun's cascades), where `w = 1` everywhere: `d = 2 - z`, with `z` the matrix's depth
//!   from 0 at its near plane to 1 at its far plane. Larger is still nearer (nearer the light); what lies
//!   between the light and the near plane is not clipped (a cascade's shadow map clamps its depth there) and
//!   gets depths above 2.

use crate::DepthConvention;
use crate::camera::Camera;
use crate::frustum::LightView;
use crate::parallel;
use glam::{DMat4, DVec4, Mat4, Vec3, Vec4};
use rayon::prelude::*;

/// A view as a depth buffer sees it: camera-relative clip matrices, the depth the buffer stores and the
/// buffer size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScreenView {
    /// World position everything is made relative to.
    pub origin: Vec3,
    /// Clip from camera-relative world space, f64 (for occluder setup).
    pub clip_from_relative: DMat4,
    /// The same in f32 (for the SIMD occludee projection).
    pub clip_from_relative_f32: Mat4,
    /// The row giving `d` of the stored depth `d / w` from an `origin`-relative point `p`: `d = row · (p, 1)`
    /// (see the module documentation). `(0, 0, 0, 1)` for a perspective view.
    pub depth_from_relative: DVec4,
    /// Near-plane distance: geometry at `w < near` is clipped (occluders) or kept (occludees). Below 1 in an
    /// orthographic view, where nothing is clipped.
    pub near: f32,
    /// Buffer width in texels.
    pub width: u32,
    /// Buffer height in texels.
    pub height: u32,
    /// How far from a buffer pixel's centre, in buffer pixels along `x` and `y`, reach the pixel centres of
    /// the frame it stands for ([`ScreenView::for_frame`]): the pixel-centre and masked rasters move each edge
    /// test and depth plane that far inward, so that a sample covers only where all of them are covered. Zero
    /// where the buffer is the frame's own size (as [`ScreenView::new`] makes it).
    pub sample_reach: [f64; 2],
}

impl ScreenView {
    /// This view with each buffer pixel standing for every pixel centre of a `frame`-pixel (width, height)
    /// rendering of the same camera that lies in its square. Along an axis where the frame is a whole multiple
    /// `k` of the buffer, those centres lie within `0.5 - 0.5 / k` buffer pixels of its centre (a quarter at
    /// half the frame's resolution, none at the frame's own); elsewhere a centre may lie on the square's edge,
    /// half a buffer pixel away (two thirds of the frame's resolution is no better than a third). A buffer
    /// larger than the frame gets none, and stands for nothing.
    pub fn for_frame(self, frame: (u32, u32)) -> Self {
        let reach = |buffer: u32, frame: u32| {
            if buffer == 0 || buffer >= frame {
                0.0
            } else if frame.is_multiple_of(buffer) {
                0.5 - 0.5 * buffer as f64 / frame as f64
            } else {
                0.5
            }
        };
        Self { sample_reach: [reach(self.width, frame.0), reach(self.height, frame.1)], ..self }
    }

    /// The view of `camera` on a `width` x `height` buffer.
    pub fn new(camera: &Camera, width: u32, height: u32) -> Self {
        Self::perspective(camera.position, camera.clip_from_relative_f64(), camera.near, width, height)
    }

    /// A perspective view: `clip_from_relative` (relative to `origin`) gives `w` as the distance along the view
    /// axis, and geometry nearer than `near` is clipped.
    fn perspective(origin: Vec3, clip_from_relative: DMat4, near: f32, width: u32, height: u32) -> Self {
        Self {
            origin,
            clip_from_relative,
            clip_from_relative_f32: clip_from_relative.as_mat4(),
            depth_from_relative: DVec4::W,
            near,
            width,
            height,
            sample_reach: [0.0; 2],
        }
    }

    /// An orthographic view on a `width` x `height` buffer: `clip_from_relative` (relative to `origin`) has
    /// `w = 1` everywhere and depth convention `depth`. Returns `None` for a matrix that is not orthographic
    /// (its `w` row is not `(0, 0, 0, 1)`), whose depth does not vary, or that is not finite.
    pub fn orthographic(
        origin: Vec3,
        clip_from_relative: DMat4,
        depth: DepthConvention,
        width: u32,
        height: u32,
    ) -> Option<Self> {
        let rows = clip_from_relative.transpose();
        if rows.w_axis != DVec4::W || !clip_from_relative.is_finite() || rows.z_axis.truncate() == glam::DVec3::ZERO {
            return None;
        }
        // Depth from 0 at the near plane to 1 at the far plane, as a row.
        let z01 = match depth {
            DepthConvention::Standard => rows.z_axis,
            DepthConvention::Reversed => DVec4::W - rows.z_axis,
            DepthConvention::NegativeOneToOne => (rows.z_axis + DVec4::W) * 0.5,
        };
        // `w` is 1 everywhere: a near distance below it clips nothing.
        let view = Self::perspective(origin, clip_from_relative, 0.5, width, height);
        Some(Self { depth_from_relative: DVec4::W * 2.0 - z01, ..view })
    }

    /// The view of a light view on a `size` x `size` buffer: perspective with the face's near plane for a
    /// lamp's cube face (`near` set), orthographic for a sun's cascade. `None` for a light view without a near
    /// plane whose matrix is not orthographic ([`ScreenView::orthographic`]), which
    /// [`crate::frustum::LightSource::light_views`] never makes.
    pub fn of_light_view(light_view: &LightView, size: u32) -> Option<Self> {
        let (origin, matrix) = (light_view.origin, light_view.clip_from_relative);
        match light_view.near {
            Some(near) => Some(Self::perspective(origin, matrix, near, size, size)),
            None => Self::orthographic(origin, matrix, light_view.depth, size, size),
        }
    }

    /// Whether the view is orthographic (its depth varies with position rather than with `1/w`).
    pub fn is_orthographic(&self) -> bool {
        self.depth_from_relative.truncate() != glam::DVec3::ZERO
    }

    /// The depth row in f32, for the occludee projection.
    pub(crate) fn depth_from_relative_f32(&self) -> Vec4 {
        self.depth_from_relative.as_vec4()
    }

    /// The direction, `origin`-relative and homogeneous, the view looks from: `(0, 0, 0, 1)` (the origin) for
    /// a perspective view, `(t, 0)` with `t` towards the light for an orthographic one. A face is front-facing
    /// when its outward normal `n` has `n · (e.xyz - p e.w) > 0` for a point `p` of it.
    pub(crate) fn eye(&self) -> DVec4 {
        if self.is_orthographic() { self.depth_from_relative.truncate().extend(0.0) } else { DVec4::W }
    }
}

/// A `width` x `height` buffer of depths (see the module documentation), row-major, row 0 at the top of the screen.
///
/// A texel covers [`DepthBuffer::texel_size`] pixels of its view on each side: one, except for a buffer
/// rasterized in [`crate::raster::RasterMode::Masked`], whose texels are 4x4 pixel blocks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DepthBuffer {
    width: u32,
    height: u32,
    /// `log2` of the pixels of the view a texel spans on each side.
    texel_shift: u32,
    /// The view's size in pixels (`width`, `height` for a buffer of one texel a pixel; the last row and column
    /// of texels may reach past it otherwise).
    view_size: (u32, u32),
    texels: Vec<f32>,
}

impl DepthBuffer {
    /// A buffer with no occluder anywhere (all zeros).
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            texel_shift: 0,
            view_size: (width, height),
            texels: vec![0.0; width as usize * height as usize],
        }
    }

    /// Width in texels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Pixels of the view a texel spans on each side (a power of two): 1, or 4 in
    /// [`crate::raster::RasterMode::Masked`].
    pub fn texel_size(&self) -> u32 {
        1 << self.texel_shift
    }

    /// `log2` of [`DepthBuffer::texel_size`].
    pub(crate) fn texel_shift(&self) -> u32 {
        self.texel_shift
    }

    /// The size in texels of the view the buffer covers, `view pixels / texel_size` per axis: the buffer's own
    /// size when that divides evenly, otherwise a fraction less (the last texels reach past the view). Maps
    /// normalized device coordinates to texels: `x = (ndc_x * 0.5 + 0.5) * screen_size[0]`.
    pub fn screen_size(&self) -> [f32; 2] {
        let scale = self.texel_size() as f32;
        [self.view_size.0 as f32 / scale, self.view_size.1 as f32 / scale]
    }

    /// Depth (of the farthest covering occluder, 0 for none) at texel `(x, y)`.
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

    /// Resizes to `width` x `height`, leaving the texels' values unspecified (finite): for a caller that then
    /// writes every texel.
    pub(crate) fn resize_for_overwrite(&mut self, width: u32, height: u32) {
        self.width = width;
        self.height = height;
        (self.texel_shift, self.view_size) = (0, (width, height));
        self.texels.resize(width as usize * height as usize, 0.0);
    }

    /// Resizes to `width` x `height` and clears to "no occluder", one texel a pixel.
    pub fn reset(&mut self, width: u32, height: u32) {
        self.width = width;
        self.height = height;
        (self.texel_shift, self.view_size) = (0, (width, height));
        self.texels.clear();
        self.texels.resize(width as usize * height as usize, 0.0);
    }
}

/// A farthest-depth mip pyramid of a [`DepthBuffer`]: level `k + 1` has `ceil(size / 2)` texels per axis and
/// each texel holds the minimum depth (farthest) of the up to 2x2 texels of level `k` it covers, so a
/// coarse texel never claims more occlusion than every fine texel under it. Odd sizes keep their last row and
/// column (a coarse texel over the edge takes the texels that exist; off-screen parts are never tested).
///
/// A pyramid rasterized in [`crate::raster::RasterMode::Masked`] also keeps, per level-0 texel (a 4x4 block of
/// pixels), the pixels known covered no farther than a second depth (the block's working layer), which the
/// occlusion test reads for rectangles of a few blocks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DepthPyramid {
    levels: Vec<DepthBuffer>,
    /// Per level-0 texel of a masked pyramid: a depth, and the pixels (bit `4 * row + column`) covered by
    /// occluders no farther than it. Empty otherwise.
    partial: (Vec<f32>, Vec<u16>),
}

impl DepthPyramid {
    /// Rebuilds the pyramid from `base`, reusing allocations. Level 0 is a copy of `base`.
    /// [`crate::raster::rasterize`] fills a pyramid directly, without the copy.
    pub fn build(&mut self, base: &DepthBuffer) {
        self.resize_blocks_for_overwrite(base.view_size.0, base.view_size.1, base.texel_shift);
        self.levels[0].texels.copy_from_slice(&base.texels);
        self.reduce_from(0);
    }

    /// Sizes the levels for a `width` x `height` base, leaving their texels unspecified (finite), for a caller
    /// that then writes level 0 and reduces the rest.
    pub(crate) fn resize_for_overwrite(&mut self, width: u32, height: u32) {
        self.resize_blocks_for_overwrite(width, height, 0);
    }

    /// [`DepthPyramid::resize_for_overwrite`] for a view of `width` x `height` pixels whose level 0 has a texel
    /// a block of `2^shift` pixels on each side (`ceil(size / 2^shift)` texels per axis). Drops the partial
    /// coverage.
    pub(crate) fn resize_blocks_for_overwrite(&mut self, width: u32, height: u32, shift: u32) {
        self.partial.0.clear();
        self.partial.1.clear();
        self.size_levels(width, height, shift);
    }

    /// [`DepthPyramid::resize_blocks_for_overwrite`] for [`crate::raster::rasterize`] in masked mode: returns
    /// the levels and the partial coverage of each texel of level 0 (see [`DepthPyramid`]), sized for them,
    /// their contents unspecified (finite), for the raster to write every one. Kept at their size from one
    /// frame to the next, so that nothing is written twice.
    pub(crate) fn resize_masked_for_overwrite(
        &mut self,
        width: u32,
        height: u32,
        shift: u32,
    ) -> (&mut [DepthBuffer], &mut [f32], &mut [u16]) {
        self.size_levels(width, height, shift);
        let count = self.levels[0].texels.len();
        self.partial.0.resize(count, 0.0);
        self.partial.1.resize(count, 0);
        (&mut self.levels, &mut self.partial.0, &mut self.partial.1)
    }

    /// Sizes the levels for a view of `width` x `height` pixels and level-0 texels of `2^shift` pixels on each
    /// side, leaving their texels unspecified (finite).
    fn size_levels(&mut self, width: u32, height: u32, shift: u32) {
        let (mut w, mut h) = (width.div_ceil(1 << shift), height.div_ceil(1 << shift));
        let mut sizes = vec![(w, h)];
        while w > 1 || h > 1 {
            (w, h) = (w.div_ceil(2), h.div_ceil(2));
            sizes.push((w, h));
        }
        self.levels.resize_with(sizes.len(), DepthBuffer::default);
        for (k, (level, (w, h))) in self.levels.iter_mut().zip(sizes).enumerate() {
            level.resize_for_overwrite(w, h);
            (level.texel_shift, level.view_size) = (shift + k as u32, (width, height));
        }
    }

    /// Whether the blocks of a masked pyramid's level 0 under the pixel rectangle `x0..x1`, `y0..y1` (non-empty,
    /// within the view) hide everything there no nearer than `nearest`: in each, the block's depth is nearer,
    /// or the rectangle's pixels are all among those its partial coverage holds and that depth is nearer.
    /// `false` for a pyramid without partial coverage, and for rectangles over more than 3x3 blocks (left to
    /// the levels).
    #[inline]
    pub(crate) fn blocks_hide(&self, [x0, y0, x1, y1]: [u32; 4], nearest: f32) -> bool {
        let (Some(level), false) = (self.levels.first(), self.partial.0.is_empty()) else {
            return false;
        };
        let shift = level.texel_shift;
        let (bx0, by0, bx1, by1) = (x0 >> shift, y0 >> shift, (x1 - 1) >> shift, (y1 - 1) >> shift);
        if bx1 - bx0 > 2 || by1 - by0 > 2 {
            return false;
        }
        // The pixels of `from..to` (clamped) within block `block` of a side of `1 << shift` pixels, as bit
        // offsets `start..end` of a mask's row (a column's bits) or of its rows.
        let within = |from: u32, to: u32, block: u32| {
            let start = block << shift;
            (from.max(start) - start, to.min(start + (1 << shift)) - start)
        };
        // Bits `start..end`, each `stride` apart.
        let bits = |(start, end): (u32, u32), stride: u32| (1u32 << (end * stride)) - (1u32 << (start * stride));
        // A 4x4 block's mask (the only size a pyramid keeps partial coverage for) repeats a row's bits every 4.
        let every_row = 0x1111;
        let width = level.width as usize;
        for by in by0..by1 + 1 {
            let rows = bits(within(y0, y1, by), 4) as u16;
            for bx in bx0..bx1 + 1 {
                let pixels = rows & (bits(within(x0, x1, bx), 1) * every_row) as u16;
                let i = by as usize * width + bx as usize;
                let hidden =
                    nearest < level.texels[i] || (nearest < self.partial.0[i] && pixels & !self.partial.1[i] == 0);
                if !hidden {
                    return false;
                }
            }
        }
        true
    }

    /// All levels, writable, for [`crate::raster::rasterize`].
    pub(crate) fn levels_mut(&mut self) -> &mut [DepthBuffer] {
        &mut self.levels
    }

    /// Recomputes every level above `level` from the one below it.
    pub(crate) fn reduce_from(&mut self, level: usize) {
        for coarse in level + 1..self.levels.len() {
            let (fine, rest) = self.levels.split_at_mut(coarse);
            let (fine, coarse) = (&fine[coarse - 1], &mut rest[0]);
            let (fine_width, coarse_width) = (fine.width as usize, coarse.width as usize);
            if coarse.texels.is_empty() {
                continue; // A buffer with no column (or no row) has nothing to reduce.
            }
            if coarse.texels.len() > PARALLEL_REDUCE_ABOVE {
                let pairs = fine.texels.par_chunks(2 * fine_width).zip(coarse.texels.par_chunks_mut(coarse_width));
                parallel::region(|region| {
                    pairs.for_each(|(fine, coarse)| region.task(|| reduce_rows(fine, fine_width, coarse)))
                });
            } else {
                reduce_rows(&fine.texels, fine_width, &mut coarse.texels);
            }
        }
    }

    /// Level 0, the depth buffer the pyramid was built from; an empty (0x0) buffer for a pyramid never built.
    pub fn base(&self) -> &DepthBuffer {
        static EMPTY: DepthBuffer =
            DepthBuffer { width: 0, height: 0, texel_shift: 0, view_size: (0, 0), texels: Vec::new() };
        self.levels.first().unwrap_or(&EMPTY)
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

/// Coarse texels of a level below which one task reduces the whole level.
const PARALLEL_REDUCE_ABOVE: usize = 1 << 15;

/// Reduces whole rows of one level, `fine` (`fine_width` texels a row), into the rows of the next one over them,
/// `coarse` (`ceil(fine rows / 2)` rows of `ceil(fine_width / 2)`): each texel the farthest (least) of the up
/// to 2x2 fine texels under it. The inner loop is branch-free so that it vectorizes.
pub(crate) fn reduce_rows(fine: &[f32], fine_width: usize, coarse: &mut [f32]) {
    let coarse_width = fine_width.div_ceil(2);
    let fine_rows = fine.len() / fine_width;
    for (y, out) in coarse.chunks_exact_mut(coarse_width).enumerate() {
        let row = |y: usize| &fine[y * fine_width..][..fine_width];
        let (top, bottom) = (row(2 * y), row((2 * y + 1).min(fine_rows - 1)));
        for ((out, top), bottom) in out.iter_mut().zip(top.chunks_exact(2)).zip(bottom.chunks_exact(2)) {
            *out = farther(farther(top[0], top[1]), farther(bottom[0], bottom[1]));
        }
        if fine_width % 2 == 1 {
            out[coarse_width - 1] = farther(top[fine_width - 1], bottom[fine_width - 1]);
        }
    }
}

/// The farther (lesser) of two depths. Depths are never NaN, so the plain comparison (one `minps`) serves where
/// `f32::min`'s NaN handling would not vectorize as well.
#[inline(always)]
pub(crate) fn farther(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// The nearer (greater) of two depths, by the same plain comparison as [`farther`] (one `maxps`).
#[inline(always)]
pub(crate) fn nearer(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// `x.floor()` for `0 <= x < 2^32` (and 0 for NaN), without a libm call (baseline x86-64 has no rounding
/// instruction). An f32 converts exactly.
#[inline(always)]
pub(crate) fn floor(x: f64) -> u32 {
    x as u32
}

/// `x.ceil()` for `0 <= x < 2^32` (and 0 for NaN), without a libm call.
#[inline(always)]
pub(crate) fn ceil(x: f64) -> u32 {
    let truncated = x as u32;
    truncated + ((truncated as f64) < x) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_without_texels_give_empty_pyramids() {
        let mut pyramid = DepthPyramid::default();
        assert_eq!(pyramid.base().width(), 0);
        for (width, height) in [(0, 0), (0, 5), (7, 0)] {
            pyramid.build(&DepthBuffer::new(width, height));
            assert_eq!((pyramid.base().width(), pyramid.base().height()), (width, height));
            assert!((0..pyramid.level_count()).all(|k| pyramid.level(k).texels().is_empty()));
        }
    }

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

    /// `blocks_hide` against its definition read pixel by pixel: every pixel of the rectangle lies in a block
    /// whose depth is nearer than `nearest`, or is among the block's partially covered pixels whose depth is.
    #[test]
    fn blocks_hide_reads_each_pixel_of_the_rectangle() {
        let (width, height) = (22, 19); // 6x5 blocks, the last column and row in part past the view
        let mut pyramid = DepthPyramid::default();
        let (levels, working, mask) = pyramid.resize_masked_for_overwrite(width, height, 2);
        let mut seed = 0x9e37_79b9_u32;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        };
        for texel in &mut levels[0].texels {
            *texel = [0.1, 0.5, 0.9][next() as usize % 3];
        }
        for (depth, bits) in working.iter_mut().zip(mask.iter_mut()) {
            *depth = [0.3, 0.7, f32::INFINITY][next() as usize % 3];
            // Mostly full rows or columns, so that some rectangles fall wholly within the covered pixels.
            *bits = [0xffff, 0x0fff, 0x7777, 0x00ff, 0x3333, next() as u16][next() as usize % 6];
        }
        let (known, partial) = (pyramid.levels[0].texels.clone(), pyramid.partial.clone());
        let blocks_wide = width.div_ceil(4);
        let (mut hidden, mut tested) = (0, 0);
        for (x0, x1) in (0..width).flat_map(|x0| (x0 + 1..=width).map(move |x1| (x0, x1))) {
            for (y0, y1) in (0..height).flat_map(|y0| (y0 + 1..=height).map(move |y1| (y0, y1))) {
                for nearest in [0.2, 0.4, 0.6, 0.8] {
                    let small = (x1 - 1) / 4 - x0 / 4 <= 2 && (y1 - 1) / 4 - y0 / 4 <= 2;
                    let expected = small
                        && (y0..y1).all(|y| {
                            (x0..x1).all(|x| {
                                let i = ((y / 4) * blocks_wide + x / 4) as usize;
                                let bit = 1u16 << (4 * (y % 4) + x % 4);
                                nearest < known[i] || (nearest < partial.0[i] && partial.1[i] & bit != 0)
                            })
                        });
                    assert_eq!(pyramid.blocks_hide([x0, y0, x1, y1], nearest), expected, "{x0}..{x1}, {y0}..{y1}");
                    (hidden, tested) = (hidden + usize::from(expected), tested + usize::from(small));
                }
            }
        }
        assert!(hidden * 10 > tested && hidden * 10 < 9 * tested, "{hidden} of {tested} hidden");
    }
}
