//! [`RasterMode::Masked`](super::RasterMode::Masked): the covered pixel centres of
//! [`RasterMode::PixelCentres`](super::RasterMode::PixelCentres), kept per 4x4 block of pixels as a 16-bit
//! coverage mask and depths, as Intel's Masked Occlusion Culling keeps them per tile.
//!
//! # Per block
//! Each block holds two depths (larger is nearer, as in the rest of the raster):
//! - `z0`, the *known* depth: every pixel centre of the block is covered by an occluder no farther than it.
//!   This is what the block's texel of level 0 holds.
//! - a *working layer*: `z1` and `mask`, the centres covered by the triangles merged into it and the farthest
//!   of their depths. When its mask fills, every centre is covered no farther than `z1`, so `z0` becomes `z1`
//!   and the layer starts again empty.
//!
//! A triangle covering centres `m` of a block is merged with `t`, the least depth its plane has over the
//! block's centres (less the same rounding margin as in pixel-centre mode): nothing it covers there is farther.
//! A triangle no nearer than `z0` adds nothing; one covering the whole block sets `z0` alone; a working layer
//! no nearer than `z0` is dropped. So `z0` only ever takes a depth that bounds every centre of the block, which
//! is what the occlusion test needs, and a block's texel is never nearer than the pixel-centre buffer's pixels
//! under it.
//!
//! The working layer stays after the raster: the occlusion test reads it for small rectangles
//! ([`crate::depth::DepthPyramid`]), so that a box behind the covered part of a block is hidden even where the
//! block as a whole is not known.
//!
//! # Coverage
//! A centre is covered when it passes the triangle's three f32 edge tests, the very tests of pixel-centre mode.
//! Each test is monotonic in `x` and in `y` (f32 rounding is), so over a block's 16 centres it passes
//! everywhere when it passes at the block's corner facing away from its edge, and nowhere when it fails at
//! the corner facing it: most blocks are decided by three tests, and only the blocks an edge crosses have
//! their centres tested one by one. So a block's mask never holds a centre pixel-centre mode leaves uncovered.

use super::{PendingOccluder, RasterMode, SetupScratch, SetupTriangle, TexelRect, all_nearer, bin_by_band};
use crate::depth::{DepthPyramid, ScreenView};
use crate::frustum::SimdBackend;
use rayon::prelude::*;

/// `log2` of a block's side in pixels.
const BLOCK_SHIFT: u32 = 2;
/// A block's side in pixels.
const BLOCK: u32 = 1 << BLOCK_SHIFT;
/// Every pixel of a block covered.
const FULL: u16 = u16::MAX;
/// Block rows rasterized by one rayon task (32 pixel rows): a triangle is set up once per band it reaches, so
/// fewer bands cost less (5-8% less than 16 rows on the street view), while 1080 rows still make 34 tasks.
const BAND_BLOCK_ROWS: usize = 8;

/// Rasterizes the occluders (nearest first) into blocks: level 0 of `pyramid` gets one texel per 4x4 pixels of
/// `view` (the last row and column of blocks may reach past the view), and the levels above are reduced from
/// it.
pub(super) fn rasterize_blocks(view: &ScreenView, pending: &[PendingOccluder], pyramid: &mut DepthPyramid) {
    pyramid.resize_blocks_for_overwrite(view.width, view.height, BLOCK_SHIFT);
    if view.width == 0 || view.height == 0 {
        return;
    }
    let blocks_wide = view.width.div_ceil(BLOCK) as usize;
    let band_rows = BAND_BLOCK_ROWS * BLOCK as usize;
    let bins = bin_by_band(pending, view.height, band_rows);
    let avx2 = SimdBackend::Auto.resolve() == SimdBackend::Avx2;
    let (known, working, mask) = pyramid.blocks_mut();
    let chunk = blocks_wide * BAND_BLOCK_ROWS;
    let band_blocks = known.par_chunks_mut(chunk).zip(working.par_chunks_mut(chunk)).zip(mask.par_chunks_mut(chunk));
    band_blocks.zip(bins.par_iter()).enumerate().for_each(|(band, (((known, working), mask), bin))| {
        known.fill(0.0);
        working.fill(f32::INFINITY);
        mask.fill(0);
        let y0 = (band * band_rows) as u32;
        let mut blocks = Blocks {
            known,
            working,
            mask,
            blocks_wide,
            y0,
            y1: (y0 + band_rows as u32).min(view.height),
            view: (view.width, view.height),
            outside_columns: outside_columns(view.width),
        };
        draw_band_with_backend(avx2, &mut blocks, bin, view, pending);
    });
    pyramid.reduce_from(0);
}

/// [`draw_band`], compiled for AVX2 where `avx2` (detected on this processor); the arithmetic is the same, so
/// both give the same blocks.
fn draw_band_with_backend(
    avx2: bool,
    blocks: &mut Blocks<'_>,
    bin: &[u32],
    view: &ScreenView,
    pending: &[PendingOccluder],
) {
    match avx2 {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `avx2` is set only where AVX2 was detected.
        true => unsafe { draw_band_avx2(blocks, bin, view, pending) },
        _ => draw_band(blocks, bin, view, pending),
    }
}

/// [`draw_band`] with AVX2 enabled.
///
/// # Safety
/// The processor must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn draw_band_avx2(blocks: &mut Blocks<'_>, bin: &[u32], view: &ScreenView, pending: &[PendingOccluder]) {
    draw_band(blocks, bin, view, pending)
}

/// Draws the occluders of `bin` (indices into `pending`, nearest first) into a band's blocks, skipping those
/// already hidden there, and setting up the others if no band has yet.
#[inline(always)]
fn draw_band(blocks: &mut Blocks<'_>, bin: &[u32], view: &ScreenView, pending: &[PendingOccluder]) {
    let mut scratch = SetupScratch::default();
    for &index in bin {
        let pending = &pending[index as usize];
        if blocks.hides(pending.rect, pending.nearest) {
            continue;
        }
        for triangle in pending.setup(view, RasterMode::Masked, &mut scratch).map_or(&[][..], |o| &o.triangles) {
            blocks.draw(triangle);
        }
    }
}

/// The blocks of one band of pixel rows `y0..y1`, row-major, `blocks_wide` a row.
struct Blocks<'a> {
    /// `z0` of each block: level 0's texels.
    known: &'a mut [f32],
    /// `z1` of each block's working layer; infinity where it is empty.
    working: &'a mut [f32],
    /// The pixels the working layer covers, bit `4 * row + column`.
    mask: &'a mut [u16],
    blocks_wide: usize,
    y0: u32,
    y1: u32,
    /// The view's width and height in pixels.
    view: (u32, u32),
    /// The bits of the last column of blocks that lie past the view's last column.
    outside_columns: u16,
}

impl Blocks<'_> {
    /// Whether every block under `rect` (pixels) within the band already knows a depth nearer than `nearest`,
    /// so that an occluder no nearer than that can add nothing there.
    #[inline(always)]
    fn hides(&self, rect: TexelRect, nearest: f32) -> bool {
        let (y0, y1) = (rect.y0.max(self.y0), rect.y1.min(self.y1));
        if y0 >= y1 {
            return true;
        }
        let columns = (rect.x0 >> BLOCK_SHIFT) as usize..(rect.x1.div_ceil(BLOCK)) as usize;
        let rows = ((y0 - self.y0) >> BLOCK_SHIFT) as usize..((y1 - self.y0).div_ceil(BLOCK)) as usize;
        rows.into_iter().all(|row| all_nearer(&self.known[row * self.blocks_wide..][columns.clone()], nearest))
    }

    /// Merges the pixel centres `triangle` covers within the band into its blocks (see the module
    /// documentation's coverage section).
    #[inline(always)]
    fn draw(&mut self, triangle: &SetupTriangle) {
        let (y0, y1) = (triangle.rect.y0.max(self.y0), triangle.rect.y1.min(self.y1));
        if y0 >= y1 {
            return;
        }
        let [p, q, r] = triangle.depth;
        let edges = triangle.edges.map(|[a, b, c, _]| [a, b, c]);
        let last = BLOCK - 1;
        // The least depth over a block's centres is at the corner its plane falls towards.
        let (depth_x, depth_y) = (if p < 0.0 { last } else { 0 }, if q < 0.0 { last } else { 0 });
        // Per edge, the corner offsets where its test is lowest (`worst`) and highest.
        let worst = edges.map(|[a, b, _]| (if a < 0.0 { last } else { 0 }, if b < 0.0 { last } else { 0 }));
        // The column offsets as f32, converted once.
        let (worst_x, best_x) = (worst.map(|w| w.0 as f32), worst.map(|w| (last - w.0) as f32));
        let depth_x = depth_x as f32;
        let span = Span::of(&edges, triangle.rect);
        let blocks_wide = self.blocks_wide as u32;
        for block_row in (y0 - self.y0) >> BLOCK_SHIFT..(y1 - self.y0).div_ceil(BLOCK) {
            let top = self.y0 + block_row * BLOCK;
            let (first, end) = span.blocks(top);
            if first >= end {
                continue;
            }
            // Each edge's `b * y + c` at the rows of its worst and best corners, and at every row.
            let worst_rows: [f32; 3] = std::array::from_fn(|e| edges[e][1] * (top + worst[e].1) as f32 + edges[e][2]);
            let best_rows: [f32; 3] =
                std::array::from_fn(|e| edges[e][1] * (top + last - worst[e].1) as f32 + edges[e][2]);
            let rows: [[f32; BLOCK as usize]; 3] =
                std::array::from_fn(|e| std::array::from_fn(|k| edges[e][1] * (top + k as u32) as f32 + edges[e][2]));
            let rz = q * (top + depth_y) as f32 + r;
            let outside_rows = self.outside_rows(top);
            let row = block_row as usize * self.blocks_wide;
            // The block's first column; every column is an integer below 2^24, so `left + offset` is exact.
            let mut left = (first * BLOCK) as i32 as f32 - BLOCK as f32;
            for block in first..end {
                left += BLOCK as f32;
                let test = |e: usize, offset: f32, row: f32| edges[e][0] * (left + offset) + row >= 0.0;
                let depth = p * (left + depth_x) + rz;
                let i = row + block as usize;
                if depth <= self.known[i] {
                    continue; // Adds nothing here, whatever it covers (see `merge`).
                }
                let full = test(0, worst_x[0], worst_rows[0])
                    & test(1, worst_x[1], worst_rows[1])
                    & test(2, worst_x[2], worst_rows[2]);
                let mask = if full {
                    FULL
                } else if !(test(0, best_x[0], best_rows[0])
                    & test(1, best_x[1], best_rows[1])
                    & test(2, best_x[2], best_rows[2]))
                {
                    continue;
                } else {
                    let outside = outside_rows | if block + 1 == blocks_wide { self.outside_columns } else { 0 };
                    let covered = centre_mask(&edges, &rows, left) & !outside;
                    if covered == 0 {
                        continue;
                    }
                    covered | outside
                };
                merge(&mut self.known[i], &mut self.working[i], &mut self.mask[i], depth, mask);
            }
        }
    }

    /// The bits of the block row at pixel row `top` that lie past the view's last row: never seen, so counted
    /// as covered.
    fn outside_rows(&self, top: u32) -> u16 {
        let inside = self.view.1.saturating_sub(top).min(BLOCK);
        if inside == BLOCK { 0 } else { FULL << (BLOCK * inside) }
    }
}

/// Where a triangle's rows may hold covered centres: its rectangle, and each edge's crossing `x = origin + slope
/// * y` of a row (f32, set up once a triangle).
struct Span {
    rect: TexelRect,
    /// Per edge: `(origin, slope, a)`; `a > 0` for an edge that bounds the triangle on the left, `a < 0` on the
    /// right, `a == 0` for a horizontal edge (which decides rows, not columns).
    edges: [(f32, f32, f32); 3],
}

impl Span {
    #[inline(always)]
    fn of(edges: &[[f32; 3]; 3], rect: TexelRect) -> Self {
        Self { rect, edges: edges.map(|[a, b, c]| (-c / a, -b / a, a)) }
    }

    /// Blocks `first..end` of the block row whose pixel rows start at `top` to visit: within the rectangle, and
    /// on the inner side of each edge's crossing of the row's top or bottom row (a line crosses the rows
    /// between the two), widened by two columns. A crossing off by more than that (an edge near horizontal, its
    /// slope huge) only leaves blocks unvisited, whose centres then stay uncovered: never more covered than
    /// the edge tests say.
    #[inline(always)]
    fn blocks(&self, top: u32) -> (u32, u32) {
        let (x0, x1) = (self.rect.x0 as f32, self.rect.x1 as f32);
        let (mut lo, mut hi) = (x0, x1);
        let (y_top, y_bottom) = (top as f32, (top + BLOCK - 1) as f32);
        for &(origin, slope, a) in &self.edges {
            let crossing = |y: f32| (origin + slope * y).clamp(x0 - 4.0, x1 + 4.0);
            let (at_top, at_bottom) = (crossing(y_top), crossing(y_bottom));
            if a > 0.0 {
                lo = lo.max(at_top.min(at_bottom) - 2.0);
            } else if a < 0.0 {
                hi = hi.min(at_top.max(at_bottom) + 2.0);
            }
        }
        // Also maps NaN to an empty run.
        if lo < hi {
            ((lo.max(0.0) as u32) >> BLOCK_SHIFT, (hi.ceil() as u32).min(self.rect.x1).div_ceil(BLOCK))
        } else {
            (0, 0)
        }
    }
}

/// The bits (`4 * row + column`) of the centres of the block whose first column is `left` that pass all three
/// edge tests, given each edge's `b * y + c` at the block's four rows: the same f32 expressions as
/// [`super::write_covered`].
#[inline(always)]
fn centre_mask(edges: &[[f32; 3]; 3], rows: &[[f32; BLOCK as usize]; 3], left: f32) -> u16 {
    let mut mask = 0u16;
    for k in 0..(BLOCK * BLOCK) as usize {
        // `left + column` is exact (both are integers below 2^24), as `write_covered`'s columns are.
        let x = left + (k & (BLOCK as usize - 1)) as f32;
        let row = k >> BLOCK_SHIFT;
        let inside = (edges[0][0] * x + rows[0][row] >= 0.0)
            & (edges[1][0] * x + rows[1][row] >= 0.0)
            & (edges[2][0] * x + rows[2][row] >= 0.0);
        mask |= (inside as u16) << k;
    }
    mask
}

/// The bits of a block whose first column is the last block's for a view `width` pixels wide that lie past it.
fn outside_columns(width: u32) -> u16 {
    let inside = width - (width.div_ceil(BLOCK) - 1) * BLOCK;
    let row = ((1u16 << BLOCK) - 1) & !((1u16 << inside) - 1);
    (0..BLOCK).fold(0, |bits, k| bits | row << (BLOCK * k))
}

/// Merges a triangle covering `mask` of a block with depth `depth` (no nearer than any centre it covers) into
/// the block's known depth, working depth and working mask. See the module documentation.
#[inline(always)]
fn merge(known: &mut f32, working: &mut f32, working_mask: &mut u16, depth: f32, mask: u16) {
    if depth <= *known {
        return;
    }
    if mask == FULL {
        *known = depth;
    } else {
        *working = working.min(depth);
        *working_mask |= mask;
        if *working_mask == FULL {
            *known = *working;
        }
    }
    if *working_mask == FULL || *working <= *known {
        (*working, *working_mask) = (f32::INFINITY, 0);
    }
}
