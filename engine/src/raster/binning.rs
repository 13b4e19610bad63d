//! Binning: the buffer's rows cut into bands that rayon tasks own whole, each band's occluders in one array,
//! and the per-band block summaries through which a band skips an occluder the ones drawn before it hide.

use super::setup::{PendingOccluder, TexelRect};
use crate::depth::{DepthBuffer, farther, reduce_rows};

/// Rows of the depth buffer rasterized by one rayon task; each band is a contiguous slice, so tasks never share
/// a texel and need no locks. Few rows a band: a view's occluders crowd a few bands about the horizon, and the
/// slowest band bounds the raster's time on any number of cores.
pub(super) const BAND_ROWS: usize = 4;
/// Each of `bands` bands' rows in level 0 (`band_rows` rows a band) and in the levels above it that each band
/// still has a row of (at most [`FUSED_LEVELS`]), which level `k` holds `band_rows >> k` of (ceil-halving sizes
/// give every band its share, the last band a shorter one), and those levels' widths. A band rasterizes its
/// rows of level 0, then reduces them into the others while they are in its core's cache ([`reduce_band`]).
pub(super) fn band_levels(
    levels: &mut [DepthBuffer],
    band_rows: usize,
    bands: usize,
) -> (Vec<Vec<&mut [f32]>>, Vec<usize>) {
    let fused = FUSED_LEVELS.min(levels.len() - 1).min(band_rows.trailing_zeros() as usize);
    let level_widths: Vec<usize> = levels[..=fused].iter().map(|level| level.width() as usize).collect();
    let mut rows: Vec<Vec<&mut [f32]>> = (0..bands).map(|_| Vec::with_capacity(fused + 1)).collect();
    for (k, level) in levels[..=fused].iter_mut().enumerate() {
        let chunk = level.width() as usize * (band_rows >> k);
        for (rows, slice) in rows.iter_mut().zip(level.texels_mut().chunks_mut(chunk)) {
            rows.push(slice);
        }
    }
    (rows, level_widths)
}

/// Reduces a band's rows of level 0 into its rows of the levels above ([`band_levels`]).
#[inline]
pub(super) fn reduce_band(rows: &mut [&mut [f32]], level_widths: &[usize]) {
    for k in 1..rows.len() {
        let (fine, coarse) = rows.split_at_mut(k);
        reduce_rows(fine[k - 1], level_widths[k - 1], coarse[0]);
    }
}

/// The indices of occluders (in their order) whose rectangles reach each band of a buffer's rows, in one array:
/// counted first, then written once (a vector a band, grown one push at a time, took most of binning's time).
pub(super) struct Bins {
    pub(super) indices: Vec<u32>,
    /// Band `b`'s indices are `indices[starts[b]..starts[b + 1]]`.
    pub(super) starts: Vec<usize>,
}

impl Bins {
    /// The occluders whose rectangles reach each band of `band_rows` rows (a power of two) of a buffer `height`
    /// rows high.
    pub(super) fn new(occluders: &[PendingOccluder], height: u32, band_rows: usize) -> Self {
        debug_assert!(band_rows.is_power_of_two());
        let bands = (height as usize).div_ceil(band_rows);
        // Shifts, not divisions by a size known only at run time.
        let shift = band_rows.trailing_zeros();
        let rows = |occluder: &PendingOccluder| {
            (occluder.rect.y0 as usize >> shift)..((occluder.rect.y1 as usize + band_rows - 1) >> shift).min(bands)
        };
        let mut starts = vec![0; bands + 1];
        for occluder in occluders {
            for band in rows(occluder) {
                starts[band + 1] += 1;
            }
        }
        for band in 0..bands {
            starts[band + 1] += starts[band];
        }
        let mut next = starts.clone();
        let mut indices = vec![0; starts[bands]];
        for (index, occluder) in occluders.iter().enumerate() {
            for band in rows(occluder) {
                indices[next[band]] = index as u32;
                next[band] += 1;
            }
        }
        Self { indices, starts }
    }

    /// Each band's occluder indices.
    pub(super) fn bands(&self) -> Vec<&[u32]> {
        self.starts.windows(2).map(|ends| &self.indices[ends[0]..ends[1]]).collect()
    }
}

/// Whether every depth of `depths` is nearer (larger) than `nearest`. Counting the ones that are not
/// vectorizes; an early exit per group of 32 keeps the common case (a visible occluder) short.
#[inline(always)]
pub(super) fn all_nearer(depths: &[f32], nearest: f32) -> bool {
    depths.chunks(32).all(|group| group.iter().map(|&depth| (depth <= nearest) as u32).sum::<u32>() == 0)
}

/// Pyramid levels above level 0 that each band reduces its own rows into, at most: fewer where a band has too
/// few rows ([`band_levels`]); the levels above are reduced once every band is done.
pub(super) const FUSED_LEVELS: usize = 3;

/// Columns of a band summarised by one farthest depth, which [`Band::hides`] reads.
pub(super) const BLOCK_COLUMNS: usize = 8;

/// Whether every group of [`BLOCK_COLUMNS`] columns that `columns` reaches has a farthest depth (`summary`, kept
/// by [`update_summary`]) nearer than `nearest`: then so has every cell of those columns in every row the summary
/// covers.
#[inline(always)]
pub(super) fn summary_hides(summary: &[f32], columns: std::ops::Range<usize>, nearest: f32) -> bool {
    summary[columns.start / BLOCK_COLUMNS..columns.end.div_ceil(BLOCK_COLUMNS)]
        .iter()
        .all(|&farthest| farthest > nearest)
}

/// Recomputes `summary`, the farthest depth of each group of [`BLOCK_COLUMNS`] columns over every row of
/// `cells` (rows of `width`: a band's texels, or a masked band's blocks), for the groups `columns` reaches.
#[inline(always)]
pub(super) fn update_summary(summary: &mut [f32], cells: &[f32], width: usize, columns: std::ops::Range<usize>) {
    let groups = columns.start / BLOCK_COLUMNS..columns.end.div_ceil(BLOCK_COLUMNS);
    for (farthest, group) in summary[groups.clone()].iter_mut().zip(groups) {
        let start = group * BLOCK_COLUMNS;
        let rows = cells.chunks_exact(width);
        *farthest = if start + BLOCK_COLUMNS <= width {
            // A whole group: the farthest of each column over the rows, in one register, then of the columns.
            let mut lanes = [f32::INFINITY; BLOCK_COLUMNS];
            for row in rows {
                let group: &[f32; BLOCK_COLUMNS] = row[start..].first_chunk().expect("a whole group fits the row");
                lanes = std::array::from_fn(|i| farther(group[i], lanes[i]));
            }
            lanes.into_iter().fold(f32::INFINITY, farther)
        } else {
            rows.flat_map(|row| &row[start..]).copied().fold(f32::INFINITY, farther)
        };
    }
}

/// The rows `y0..y1` of the depth buffer one task owns, drawn only within `scissor`.
pub(super) struct Band<'a> {
    pub(super) texels: &'a mut [f32],
    pub(super) width: usize,
    pub(super) y0: u32,
    pub(super) y1: u32,
    pub(super) scissor: TexelRect,
}

impl<'a> Band<'a> {
    /// Rows `y0..y1` (of `texels`, `width` texels each), drawn wherever they lie.
    pub(super) fn new(texels: &'a mut [f32], width: usize, y0: u32, y1: u32) -> Self {
        Band { texels, width, y0, y1, scissor: TexelRect::whole(width as u32, y1) }
    }

    #[inline]
    pub(super) fn reborrow(&mut self) -> Band<'_> {
        Band { texels: self.texels, ..*self }
    }

    /// Whether every texel of `rect` within the band already holds a depth nearer than `nearest`, so that an
    /// occluder no nearer than that can add nothing there. First reads `blocks`, the farthest depth of each
    /// [`BLOCK_COLUMNS`] columns of the band's rows (kept by [`Band::update_blocks`]): a block covers at least
    /// the texels of `rect` in its columns, so when every block is nearer, so is every texel. Where the blocks
    /// cannot tell (they also cover rows and columns outside `rect`), the texels are read.
    #[inline]
    pub(super) fn hides(&self, blocks: &[f32], rect: TexelRect, nearest: f32) -> bool {
        if summary_hides(blocks, rect.x0 as usize..rect.x1 as usize, nearest) {
            return true;
        }
        let rect = self.clip(rect);
        rect.is_empty()
            || (rect.y0..rect.y1).all(|y| {
                all_nearer(
                    &self.texels[(y - self.y0) as usize * self.width..][rect.x0 as usize..rect.x1 as usize],
                    nearest,
                )
            })
    }

    /// Recomputes the farthest depth of the blocks under `rect`'s columns after an occluder was drawn there.
    #[inline]
    pub(super) fn update_blocks(&self, blocks: &mut [f32], rect: TexelRect) {
        update_summary(blocks, self.texels, self.width, rect.x0 as usize..rect.x1 as usize);
    }

    /// The part of `rect` inside the band and its scissor.
    #[inline]
    pub(super) fn clip(&self, rect: TexelRect) -> TexelRect {
        TexelRect { y0: rect.y0.max(self.y0), y1: rect.y1.min(self.y1), ..rect }.intersect(self.scissor)
    }
}
