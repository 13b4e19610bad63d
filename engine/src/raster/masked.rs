//! [`RasterMode::Masked`]: the covered pixel centres of
//! [`RasterMode::PixelCentres`], kept per 4x4 block of pixels as a 16-bit
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
//! Triangles are drawn as quads: two consecutive ones sharing an edge as one, tested against their four outer
//! edges, and the others alone (see [`quads`](super::setup::quads)). A centre is covered when it passes the quad's f32 edge tests,
//! the very tests of pixel-centre mode, each of which passes only on the inner side of its exact edge; so a
//! covered centre lies in one of the triangles. Each test is monotonic in `x` and in `y` (f32 rounding is), so
//! over a block's 16 centres it passes everywhere when it passes at the block's corner facing away from its
//! edge, and nowhere when it fails at the corner facing it: most blocks are decided by four tests, and only
//! the blocks an edge crosses have their centres tested one by one. A quad's depth over a block is the lesser
//! of its two planes'. Where the processor has AVX2, eight blocks of a row are decided side by side, and a
//! block's 16 centres in two registers, by the same f32 operations: the blocks come out the same bit for bit.

use super::RasterMode;
use super::binning::{BLOCK_COLUMNS, Bins, all_nearer, band_levels, reduce_band, summary_hides, update_summary};
use super::setup::{PendingOccluder, QUAD_EDGES, SetupQuad, SetupScratch, TexelRect};
use crate::depth::{DepthPyramid, ScreenView, farther};
use crate::frustum::SimdBackend;
use crate::parallel;
use rayon::prelude::*;
use std::cmp::Ordering;

/// `log2` of a block's side in pixels.
const BLOCK_SHIFT: u32 = 2;
/// A block's side in pixels.
const BLOCK: u32 = 1 << BLOCK_SHIFT;
/// Every pixel of a block covered.
const FULL: u16 = u16::MAX;
/// Block rows rasterized by one rayon task (32 pixel rows): a triangle is set up once per band it reaches, so
/// fewer bands cost less (5-8% less than 16 rows on the street view), while 1080 rows still make 34 tasks.
const BAND_BLOCK_ROWS: usize = 8;
/// Pixel centres in a block, one bit each of its mask.
const CENTRES: usize = (BLOCK * BLOCK) as usize;
/// Edges a quad is tested against; a lone triangle repeats its last.
const EDGES: usize = QUAD_EDGES;
/// Blocks of a row drawn side by side where AVX2 is available: one register of f32.
#[cfg(target_arch = "x86_64")]
const LANES: usize = 8;

/// Rasterizes the occluders (nearest first) into blocks: level 0 of `pyramid` gets one texel per 4x4 pixels of
/// `view` (the last row and column of blocks may reach past the view), and the levels above are reduced from
/// it.
pub(super) fn rasterize_blocks(view: &ScreenView, pending: &[PendingOccluder], pyramid: &mut DepthPyramid) {
    let (levels, working, mask) = pyramid.resize_masked_for_overwrite(view.width, view.height, BLOCK_SHIFT);
    if view.width == 0 || view.height == 0 {
        return;
    }
    let blocks_wide = view.width.div_ceil(BLOCK) as usize;
    let band_rows = BAND_BLOCK_ROWS * BLOCK as usize;
    let bins = Bins::new(pending, view.height, band_rows);
    let bins = bins.bands();
    let (band_levels, level_widths) = band_levels(levels, BAND_BLOCK_ROWS, bins.len());
    let fused = level_widths.len() - 1;
    let avx2 = SimdBackend::Auto.resolve() == SimdBackend::Avx2;
    let chunk = blocks_wide * BAND_BLOCK_ROWS;
    let band_blocks = band_levels.into_par_iter().zip(working.par_chunks_mut(chunk)).zip(mask.par_chunks_mut(chunk));
    // Working memory once per rayon job rather than once per band, as in the texel raster.
    let scratches = || (SetupScratch::default(), Vec::new());
    let bands = band_blocks.zip(bins.par_iter()).enumerate();
    parallel::region(|region| {
        bands.for_each_init(scratches, |(scratch, summary), (band, (((mut levels, working), mask), bin))| {
            region.task(|| {
                let known = &mut *levels[0];
                known.fill(0.0);
                working.fill(f32::INFINITY);
                mask.fill(0);
                let y0 = (band * band_rows) as u32;
                // No known depth in the band yet.
                summary.clear();
                summary.resize(blocks_wide.div_ceil(BLOCK_COLUMNS), 0.0);
                let mut blocks = Blocks {
                    known,
                    working,
                    mask,
                    blocks_wide,
                    y0,
                    y1: (y0 + band_rows as u32).min(view.height),
                    view: (view.width, view.height),
                    outside_columns: outside_columns(view.width),
                    avx2,
                    summary,
                };
                draw_band_with_backend(avx2, &mut blocks, bin, view, pending, scratch);
                reduce_band(&mut levels, &level_widths);
            })
        })
    });
    pyramid.reduce_from(fused);
}

/// [`draw_band`], compiled for AVX2 where `avx2` (detected on this processor); the arithmetic is the same, so
/// both give the same blocks.
fn draw_band_with_backend(
    avx2: bool,
    blocks: &mut Blocks<'_>,
    bin: &[u32],
    view: &ScreenView,
    pending: &[PendingOccluder],
    scratch: &mut SetupScratch,
) {
    match avx2 {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `avx2` is set only where AVX2 was detected.
        true => unsafe { draw_band_avx2(blocks, bin, view, pending, scratch) },
        _ => draw_band(blocks, bin, view, pending, scratch),
    }
}

/// [`draw_band`] with AVX2 enabled.
///
/// # Safety
/// The processor must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn draw_band_avx2(
    blocks: &mut Blocks<'_>,
    bin: &[u32],
    view: &ScreenView,
    pending: &[PendingOccluder],
    scratch: &mut SetupScratch,
) {
    draw_band(blocks, bin, view, pending, scratch)
}

/// Draws the occluders of `bin` (indices into `pending`, nearest first) into a band's blocks, skipping those
/// already hidden there, and setting up the others if no band has yet (in `scratch`).
#[inline(always)]
fn draw_band(
    blocks: &mut Blocks<'_>,
    bin: &[u32],
    view: &ScreenView,
    pending: &[PendingOccluder],
    scratch: &mut SetupScratch,
) {
    for &index in bin {
        let pending = &pending[index as usize];
        if blocks.hides(pending.rect, pending.nearest) {
            continue;
        }
        for quad in pending.setup(view, RasterMode::Masked, scratch).map_or(&[][..], |o| &o.quads) {
            blocks.draw(quad);
        }
        // Known depths only grow nearer, so the summary stays a bound until the next update.
        let columns = blocks.columns(pending.rect);
        update_summary(blocks.summary, blocks.known, blocks.blocks_wide, columns);
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
    /// AVX2 was detected on this processor.
    avx2: bool,
    /// The farthest known depth of each group of [`BLOCK_COLUMNS`] block columns over the band's rows (see
    /// [`update_summary`]).
    summary: &'a mut [f32],
}

impl Blocks<'_> {
    /// Whether every block under `rect` (pixels) within the band already knows a depth nearer than `nearest`,
    /// so that an occluder no nearer than that can add nothing there. First reads the summary; where it cannot
    /// tell, the blocks.
    #[inline(always)]
    fn hides(&self, rect: TexelRect, nearest: f32) -> bool {
        let (y0, y1) = (rect.y0.max(self.y0), rect.y1.min(self.y1));
        if y0 >= y1 {
            return true;
        }
        let columns = self.columns(rect);
        if summary_hides(self.summary, columns.clone(), nearest) {
            return true;
        }
        let rows = ((y0 - self.y0) >> BLOCK_SHIFT) as usize..((y1 - self.y0).div_ceil(BLOCK)) as usize;
        rows.into_iter().all(|row| all_nearer(&self.known[row * self.blocks_wide..][columns.clone()], nearest))
    }

    /// The columns of blocks under the pixel columns of `rect`.
    fn columns(&self, rect: TexelRect) -> std::ops::Range<usize> {
        (rect.x0 >> BLOCK_SHIFT) as usize..(rect.x1.div_ceil(BLOCK)) as usize
    }

    /// Merges the pixel centres `quad` covers within the band into its blocks (see the module documentation's
    /// coverage section).
    #[inline(always)]
    fn draw(&mut self, quad: &SetupQuad) {
        let (y0, y1) = (quad.rect.y0.max(self.y0), quad.rect.y1.min(self.y1));
        if y0 >= y1 {
            return;
        }
        let edges = quad.edges;
        let last = BLOCK - 1;
        // The least depth of each plane over a block's centres is at the corner it falls towards.
        let depth_x = quad.depth.map(|[p, _, _]| if p < 0.0 { last as f32 } else { 0.0 });
        let depth_y = quad.depth.map(|[_, q, _]| if q < 0.0 { last as f32 } else { 0.0 });
        // Per edge, the corner offsets where its test is lowest (`worst`) and highest.
        let worst = edges.map(|[a, b, _]| (if a < 0.0 { last } else { 0 }, if b < 0.0 { last } else { 0 }));
        let last_column = self.blocks_wide as u32 - 1;
        let block_rows = (y0 - self.y0) >> BLOCK_SHIFT..(y1 - self.y0).div_ceil(BLOCK);
        // One run of blocks for all the quad's rows in the band: a row's own run would save a few lanes, but
        // finding it costs more than they do (14% of the raster on the street view).
        let (top, bottom) = (self.y0 + block_rows.start * BLOCK, self.y0 + block_rows.end * BLOCK - 1);
        let (first, end) = Span::of(&edges, quad.rect).blocks(top, bottom);
        if first >= end {
            return;
        }
        // The quad's part of the tests; each block row sets its rows' part in place, as building them all
        // again took an eighth of the raster's instructions.
        let mut tests = RowTests {
            a: edges.map(|[a, _, _]| a),
            worst_x: worst.map(|w| w.0 as f32),
            best_x: worst.map(|w| (last - w.0) as f32),
            worst_rows: [0.0; EDGES],
            best_rows: [0.0; EDGES],
            b: edges.map(|[_, b, _]| b),
            c: edges.map(|[_, _, c]| c),
            centre_rows_for: None,
            centre_rows: [[0.0; CENTRES]; EDGES],
            p: quad.depth.map(|[p, _, _]| p),
            depth_x,
            rz: [0.0; 2],
        };
        let (b, c) = (tests.b, tests.c);
        let (worst_y, best_y) = (worst.map(|w| w.1 as f32), worst.map(|w| (last - w.1) as f32));
        let (q, r) = (quad.depth.map(|[_, q, _]| q), quad.depth.map(|[_, _, r]| r));
        for block_row in block_rows {
            let top = self.y0 + block_row * BLOCK;
            let y = top as f32;
            // Each edge's `b * y + c` at the rows of its worst and best corners (at each centre's row only where a
            // block is covered in part: `RowTests::partial_mask`).
            tests.worst_rows = std::array::from_fn(|e| b[e] * (y + worst_y[e]) + c[e]);
            tests.best_rows = std::array::from_fn(|e| b[e] * (y + best_y[e]) + c[e]);
            tests.rz = std::array::from_fn(|i| q[i] * (y + depth_y[i]) + r[i]);
            let outside_rows = self.outside_rows(top);
            let row = block_row as usize * self.blocks_wide;
            // The pixels of a block past the view, counted as covered.
            let outside = |block: u32| outside_rows | if block == last_column { self.outside_columns } else { 0 };
            let mut block = first;
            while block < end {
                let at = row + block as usize;
                let left = (block * BLOCK) as f32;
                // Eight blocks at once where the row holds eight from here (lanes past `end` are left alone).
                #[cfg(target_arch = "x86_64")]
                if self.avx2
                    && let Some(known) = self.known[at..row + self.blocks_wide].first_chunk_mut::<LANES>()
                    && let Some(working) = self.working[at..].first_chunk_mut::<LANES>()
                    && let Some(mask) = self.mask[at..].first_chunk_mut::<LANES>()
                {
                    let count = ((end - block) as usize).min(LANES);
                    // SAFETY: `avx2` is set only where AVX2 was detected.
                    let (partial, depth) = unsafe { avx2::draw_lanes(&tests, left, count, known, working, mask) };
                    for k in Bits(partial) {
                        let block = block + k as u32;
                        let left = (block * BLOCK) as f32;
                        if let Some(covered) = tests.partial_mask(self.avx2, y, left, outside(block)) {
                            merge(&mut known[k], &mut working[k], &mut mask[k], depth[k], covered);
                        }
                    }
                    block += count as u32;
                    continue;
                }
                let (coverage, depth) = tests.classify(left, self.known[at]);
                let mask = match coverage {
                    Coverage::Full => Some(FULL),
                    Coverage::Partial => tests.partial_mask(self.avx2, y, left, outside(block)),
                    Coverage::None => None,
                };
                if let Some(mask) = mask {
                    merge(&mut self.known[at], &mut self.working[at], &mut self.mask[at], depth, mask);
                }
                block += 1;
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

/// Where a quad's rows may hold covered centres: its rectangle, and each edge's crossing `x = origin + slope
/// * y` of a row (f32).
struct Span {
    rect: TexelRect,
    /// Per edge: `(origin, slope, a)`; `a > 0` for an edge that bounds the quad on the left, `a < 0` on the
    /// right, `a == 0` for a horizontal edge (which decides rows, not columns).
    edges: [(f32, f32, f32); EDGES],
}

impl Span {
    #[inline(always)]
    fn of(edges: &[[f32; 3]; EDGES], rect: TexelRect) -> Self {
        Self { rect, edges: edges.map(|[a, b, c]| (-c / a, -b / a, a)) }
    }

    /// Blocks `first..end` to visit in the pixel rows `top..=bottom` (whole rows of blocks): within the
    /// rectangle, and on the inner side of each edge's crossing of the top or bottom row (a line crosses the
    /// rows between the two), widened by two columns. A crossing off by more than that (an edge near horizontal,
    /// its slope huge) only leaves blocks unvisited, whose centres then stay uncovered: never more covered than
    /// the edge tests say.
    #[inline(always)]
    fn blocks(&self, top: u32, bottom: u32) -> (u32, u32) {
        let (x0, x1) = (self.rect.x0 as f32, self.rect.x1 as f32);
        let (mut lo, mut hi) = (x0, x1);
        let (y_top, y_bottom) = (top as f32, bottom as f32);
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

/// A triangle's tests over one row of blocks (see the module documentation's coverage section): each block is
/// decided by the same f32 expressions, whichever backend evaluates them.
#[derive(Debug)]
struct RowTests {
    /// Each edge's `a` (its test at `(x, y)` is `a * x + (b * y + c) >= 0`).
    a: [f32; EDGES],
    /// Per edge, the column offset within a block of its worst corner (where its test is lowest) and of its best.
    worst_x: [f32; EDGES],
    best_x: [f32; EDGES],
    /// Per edge, `b * y + c` at the row of its worst corner and of its best.
    worst_rows: [f32; EDGES],
    best_rows: [f32; EDGES],
    /// Each edge's `b` and `c`.
    b: [f32; EDGES],
    c: [f32; EDGES],
    /// The first pixel row of the block row `centre_rows` were last computed for (`None` before the first): a
    /// third of the rows have no block covered in part, and [`RowTests::partial_mask`] computes them only for
    /// one that has.
    centre_rows_for: Option<f32>,
    /// Per edge, `b * y + c` at the pixel row of each of a block's centres, in the order of their bits
    /// (`4 * row + column`): laid out as the AVX2 centre test reads them, two registers an edge, rather than
    /// shuffled from four values for each block.
    centre_rows: [[f32; CENTRES]; EDGES],
    /// Per depth plane, its `p`, the column offset where it is least over a block, and `q * y + r` at the row
    /// where it is least.
    p: [f32; 2],
    depth_x: [f32; 2],
    rz: [f32; 2],
}

/// What a triangle adds to a block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Coverage {
    /// Nothing: it covers no centre, or it is no nearer than the block's known depth.
    None,
    /// It is nearer than the block's known depth and may cover some of its centres, not all.
    Partial,
    /// It is nearer than the block's known depth and covers every centre.
    Full,
}

impl RowTests {
    /// What the triangle adds to the block whose first column is `left` (a multiple of 4 below 2^24, so every
    /// column is exact) and whose known depth is `known`, and its least depth over the block's centres.
    #[inline(always)]
    fn classify(&self, left: f32, known: f32) -> (Coverage, f32) {
        let test = |e: usize, offset: f32, row: f32| self.a[e] * (left + offset) + row >= 0.0;
        let plane = |i: usize| self.p[i] * (left + self.depth_x[i]) + self.rz[i];
        // `farther` is `a < b ? a : b`, what `_mm256_min_ps(a, b)` gives in each lane.
        let depth = farther(plane(0), plane(1));
        // A triangle no nearer than the known depth adds nothing, whatever it covers (see `merge`). Not
        // short-circuiting, so that the fixed-size tests stay branch-free.
        let adds = !matches!(depth.partial_cmp(&known), Some(Ordering::Less | Ordering::Equal));
        let all = (0..EDGES).fold(adds, |all, e| all & test(e, self.worst_x[e], self.worst_rows[e]));
        let any = (0..EDGES).fold(adds, |any, e| any & test(e, self.best_x[e], self.best_rows[e]));
        let coverage = if all {
            Coverage::Full
        } else if any {
            Coverage::Partial
        } else {
            Coverage::None
        };
        (coverage, depth)
    }

    /// The pixels the triangle covers of the block at pixel row `y` and column `left` (multiples of 4 below
    /// 2^24), with those past the view (`outside`) counted as covered; `None` where it covers none inside.
    /// Computes [`RowTests::centre_rows`] for the row first, where they are not yet. Out of line: inlined into
    /// the row loop it made the masked raster slower (docs/performance.md).
    #[inline(never)]
    fn partial_mask(&mut self, avx2: bool, y: f32, left: f32, outside: u16) -> Option<u16> {
        if self.centre_rows_for != Some(y) {
            // Row offsets within a block row as f32 (exact, as are the rows they are added to: integers below
            // 2^24), so that each row's values are computed a register at a time, written as wholes, not lane by
            // lane (a pair of depths written as two floats and read as one pair stalled the loop's store
            // forwarding).
            let centre_ys: [f32; CENTRES] = std::array::from_fn(|k| y + (k as u32 >> BLOCK_SHIFT) as f32);
            for (rows, (b, c)) in self.centre_rows.iter_mut().zip(self.b.iter().zip(&self.c)) {
                for (row, centre_y) in rows.iter_mut().zip(&centre_ys) {
                    *row = b * centre_y + c;
                }
            }
            self.centre_rows_for = Some(y);
        }
        let covered = self.centre_mask_with_backend(avx2, left) & !outside;
        (covered != 0).then_some(covered | outside)
    }

    /// [`RowTests::centre_mask`], with AVX2 where `avx2` (detected on this processor); both give the same bits.
    #[inline(always)]
    fn centre_mask_with_backend(&self, avx2: bool, left: f32) -> u16 {
        match avx2 {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `avx2` is set only where AVX2 was detected.
            true => unsafe { avx2::centre_mask(self, left) },
            _ => self.centre_mask(left),
        }
    }

    /// The bits (`4 * row + column`) of the centres of the block whose first column is `left` that pass every
    /// edge test: the same f32 expressions as [`super::texels::write_covered`].
    #[inline(always)]
    fn centre_mask(&self, left: f32) -> u16 {
        let mut mask = 0u16;
        for k in 0..CENTRES {
            // `left + column` is exact (both are integers below 2^24), as `write_covered`'s columns are.
            let x = left + (k & (BLOCK as usize - 1)) as f32;
            let inside = (0..EDGES).fold(true, |inside, e| inside & (self.a[e] * x + self.centre_rows[e][k] >= 0.0));
            mask |= (inside as u16) << k;
        }
        mask
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! [`RowTests::classify`], `merge` of a full block and [`RowTests::centre_mask`] eight lanes wide: the
    //! same operations in the same order (no fused multiply-add), so the same bits. Written without closures,
    //! which would not inherit the target feature.
    use super::{BLOCK, EDGES, LANES, RowTests};
    use std::arch::x86_64::*;

    /// Whether `a * (x + offset) + row >= 0` in each lane, as in [`RowTests::classify`].
    #[target_feature(enable = "avx2")]
    #[inline]
    fn passes(x: __m256, a: &[f32; EDGES], offsets: &[f32; EDGES], rows: &[f32; EDGES]) -> __m256 {
        let mut all = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
        for e in 0..EDGES {
            let value = _mm256_mul_ps(_mm256_set1_ps(a[e]), _mm256_add_ps(x, _mm256_set1_ps(offsets[e])));
            let value = _mm256_add_ps(value, _mm256_set1_ps(rows[e]));
            all = _mm256_and_ps(all, _mm256_cmp_ps::<_CMP_GE_OQ>(value, _mm256_setzero_ps()));
        }
        all
    }

    /// Depth plane `i`'s value at the corner of each lane's block where it is least, as in
    /// [`RowTests::classify`].
    #[target_feature(enable = "avx2")]
    #[inline]
    fn plane(tests: &RowTests, x: __m256, i: usize) -> __m256 {
        let at_depth = _mm256_add_ps(x, _mm256_set1_ps(tests.depth_x[i]));
        _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(tests.p[i]), at_depth), _mm256_set1_ps(tests.rz[i]))
    }

    /// Classifies the first `count` (at most 8) of the eight blocks whose first columns are `left`, `left + 4`,
    /// ... ([`RowTests::classify`]), merges the quad into those it covers whole, and returns the bits of those
    /// it covers in part and its least depth over each (the other lanes' depths unspecified). The lanes from
    /// `count` on are left as they are.
    ///
    /// # Safety
    /// The processor must support AVX2.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) unsafe fn draw_lanes(
        tests: &RowTests,
        left: f32,
        count: usize,
        known: &mut [f32; LANES],
        working: &mut [f32; LANES],
        mask: &mut [u16; LANES],
    ) -> (u32, [f32; LANES]) {
        debug_assert_eq!(BLOCK, 4);
        let lane = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let counted = _mm256_cmp_ps::<_CMP_LT_OQ>(lane, _mm256_set1_ps(count as f32));
        // Exact: integers below 2^24.
        let x = _mm256_add_ps(_mm256_set1_ps(left), _mm256_mul_ps(lane, _mm256_set1_ps(BLOCK as f32)));
        // `farther(plane(0), plane(1))` in each lane.
        let depth = _mm256_min_ps(plane(tests, x, 0), plane(tests, x, 1));
        // SAFETY: each array is 8 readable f32 (its type); the loads are unaligned.
        let (known_depth, working_depth) =
            unsafe { (_mm256_loadu_ps(known.as_ptr()), _mm256_loadu_ps(working.as_ptr())) };
        let adds = _mm256_and_ps(counted, _mm256_cmp_ps::<_CMP_NLE_UQ>(depth, known_depth));
        if _mm256_movemask_ps(adds) == 0 {
            // Behind every block's known depth (or past the run): nothing to merge, no edge to test.
            return (0, [0.0; LANES]);
        }
        let full = _mm256_and_ps(adds, passes(x, &tests.a, &tests.worst_x, &tests.worst_rows));
        let any = _mm256_and_ps(adds, passes(x, &tests.a, &tests.best_x, &tests.best_rows));
        let partial = _mm256_andnot_ps(full, any);
        if _mm256_movemask_ps(full) != 0 {
            // `merge` with a full mask: the known depth becomes the triangle's, and a working layer no nearer
            // is dropped (a working mask is never full between merges).
            let known_depth = _mm256_blendv_ps(known_depth, depth, full);
            let dropped = _mm256_and_ps(full, _mm256_cmp_ps::<_CMP_LE_OQ>(working_depth, known_depth));
            let working_depth = _mm256_blendv_ps(working_depth, _mm256_set1_ps(f32::INFINITY), dropped);
            // The lanes' 32-bit all-ones or zeros, packed to 16 bits each (signed saturation keeps both).
            let dropped = _mm256_castps_si256(dropped);
            let dropped = _mm_packs_epi32(_mm256_castsi256_si128(dropped), _mm256_extracti128_si256::<1>(dropped));
            // SAFETY: each array is 8 writable f32 or u16 (its type); the loads and stores are unaligned.
            unsafe {
                _mm256_storeu_ps(known.as_mut_ptr(), known_depth);
                _mm256_storeu_ps(working.as_mut_ptr(), working_depth);
                let bits = _mm_loadu_si128(mask.as_ptr().cast());
                _mm_storeu_si128(mask.as_mut_ptr().cast(), _mm_andnot_si128(dropped, bits));
            }
        }
        let mut depths = [0.0; LANES];
        // SAFETY: `depths` is 8 writable f32 (its type); the store is unaligned.
        unsafe { _mm256_storeu_ps(depths.as_mut_ptr(), depth) };
        (_mm256_movemask_ps(partial) as u32, depths)
    }

    /// [`RowTests::centre_mask`]: the 16 centres as two registers, of rows 0-1 and of rows 2-3.
    ///
    /// # Safety
    /// The processor must support AVX2.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) unsafe fn centre_mask(tests: &RowTests, left: f32) -> u16 {
        // Exact: integers below 2^24.
        let x = _mm256_add_ps(_mm256_set1_ps(left), _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 0.0, 1.0, 2.0, 3.0));
        let (mut upper, mut lower) =
            (_mm256_castsi256_ps(_mm256_set1_epi32(-1)), _mm256_castsi256_ps(_mm256_set1_epi32(-1)));
        for e in 0..EDGES {
            let ax = _mm256_mul_ps(_mm256_set1_ps(tests.a[e]), x);
            let rows = &tests.centre_rows[e];
            // SAFETY: `rows` is 16 readable f32 (its type); the loads are unaligned.
            let (rows_01, rows_23) = unsafe { (_mm256_loadu_ps(rows.as_ptr()), _mm256_loadu_ps(rows[8..].as_ptr())) };
            upper = _mm256_and_ps(upper, _mm256_cmp_ps::<_CMP_GE_OQ>(_mm256_add_ps(ax, rows_01), _mm256_setzero_ps()));
            lower = _mm256_and_ps(lower, _mm256_cmp_ps::<_CMP_GE_OQ>(_mm256_add_ps(ax, rows_23), _mm256_setzero_ps()));
        }
        _mm256_movemask_ps(upper) as u16 | (_mm256_movemask_ps(lower) as u16) << 8
    }
}

/// The bits of a block whose first column is the last block's for a view `width` pixels wide that lie past it.
fn outside_columns(width: u32) -> u16 {
    let inside = width - (width.div_ceil(BLOCK) - 1) * BLOCK;
    let row = ((1u16 << BLOCK) - 1) & !((1u16 << inside) - 1);
    (0..BLOCK).fold(0, |bits, k| bits | row << (BLOCK * k))
}

/// The indices of the set bits of a word, lowest first.
#[cfg(target_arch = "x86_64")]
struct Bits(u32);

impl Iterator for Bits {
    type Item = usize;

    #[inline(always)]
    fn next(&mut self) -> Option<usize> {
        let index = self.0.trailing_zeros() as usize;
        (self.0 != 0).then(|| {
            self.0 &= self.0 - 1;
            index
        })
    }
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

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A row of tests from arbitrary edges and depth planes, of small half-integers, so that tests land exactly
    /// on zero and depths exactly on each other as well as on either side.
    fn row_tests() -> impl Strategy<Value = RowTests> {
        let value = || (-32i32..32).prop_map(|v| v as f32 / 2.0);
        let plane = || (value(), 0u32..4, value());
        (
            prop::array::uniform4(value()),
            prop::array::uniform4(prop::array::uniform4(value())),
            prop::array::uniform4(0u32..4),
            prop::array::uniform4(0u32..4),
            [plane(), plane()],
        )
            .prop_map(|(a, rows, worst_x, worst_y, planes)| RowTests {
                a,
                worst_x: worst_x.map(|x| x as f32),
                best_x: worst_x.map(|x| (BLOCK - 1 - x) as f32),
                worst_rows: std::array::from_fn(|e| rows[e][worst_y[e] as usize]),
                best_rows: std::array::from_fn(|e| rows[e][(BLOCK - 1 - worst_y[e]) as usize]),
                b: [0.0; EDGES],
                c: [0.0; EDGES],
                centre_rows_for: None,
                centre_rows: rows.map(|rows| std::array::from_fn(|k| rows[k >> BLOCK_SHIFT])),
                p: planes.map(|(p, _, _)| p),
                depth_x: planes.map(|(_, x, _)| x as f32),
                rz: planes.map(|(_, _, rz)| rz),
            })
    }

    proptest! {
        // Cheap cases, and ties (a test exactly zero, a working depth exactly the new known one) are rare.
        #![proptest_config(ProptestConfig::with_cases(4096))]

        /// The AVX2 lanes classify, merge whole blocks and mask centres exactly as the scalar code does one
        /// block at a time.
        #[test]
        fn avx2_lanes_equal_scalar_blocks(
            tests in row_tests(),
            first_block in 0u32..4,
            count in 1usize..=LANES,
            known in prop::array::uniform8((-32i32..32).prop_map(|v| v as f32 / 2.0)),
            working in prop::array::uniform8(
                prop_oneof![Just(f32::INFINITY), (-32i32..32).prop_map(|v| v as f32 / 2.0)]
            ),
            mask in prop::array::uniform8(0u16..u16::MAX),
        ) {
            prop_assume!(std::arch::is_x86_feature_detected!("avx2"));
            let left = (first_block * BLOCK) as f32;
            let (mut scalar_known, mut scalar_working, mut scalar_mask) = (known, working, mask);
            let mut scalar_partial = 0;
            for k in 0..count {
                let (coverage, depth) = tests.classify(left + (k as u32 * BLOCK) as f32, known[k]);
                match coverage {
                    Coverage::Full => {
                        merge(&mut scalar_known[k], &mut scalar_working[k], &mut scalar_mask[k], depth, FULL)
                    }
                    Coverage::Partial => scalar_partial |= 1 << k,
                    Coverage::None => {}
                }
            }
            let (mut lane_known, mut lane_working, mut lane_mask) = (known, working, mask);
            // SAFETY: AVX2 was detected above.
            let (partial, depths) =
                unsafe { avx2::draw_lanes(&tests, left, count, &mut lane_known, &mut lane_working, &mut lane_mask) };
            prop_assert_eq!(partial, scalar_partial);
            prop_assert_eq!(lane_known.map(f32::to_bits), scalar_known.map(f32::to_bits));
            prop_assert_eq!(lane_working.map(f32::to_bits), scalar_working.map(f32::to_bits));
            prop_assert_eq!(lane_mask, scalar_mask);
            for k in 0..count {
                let (_, depth) = tests.classify(left + (k as u32 * BLOCK) as f32, known[k]);
                if partial & 1 << k != 0 {
                    prop_assert_eq!(depths[k].to_bits(), depth.to_bits());
                }
                let scalar = tests.centre_mask(left + (k as u32 * BLOCK) as f32);
                // SAFETY: AVX2 was detected above.
                prop_assert_eq!(unsafe { avx2::centre_mask(&tests, left + (k as u32 * BLOCK) as f32) }, scalar);
            }
        }
    }
}
