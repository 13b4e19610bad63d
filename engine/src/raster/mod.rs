//! Stage 4, occluder raster: a software rasterizer of occluder triangles into a small depth buffer, level 0 of
//! the farthest-depth mip pyramid ([`crate::depth::DepthPyramid`], a CPU HiZ) it builds as it goes. Testing
//! occludees against it is the next stage, [`crate::occlusion`]; the two are kept apart as in Intel's Masked
//! Occlusion Culling.
//!
//! # Depth convention
//! A texel holds the depth (see [`crate::depth`]: `1/w` in a perspective view, the distance towards the light
//! in an orthographic one) of the *farthest* occluder surface known to cover it: larger is nearer, and `0`
//! means no occluder. The depth is affine in screen space, so a triangle's depth over a texel is bounded
//! exactly by its plane.
//!
//! # Modes
//! - [`RasterMode::Conservative`] (default): a texel is written only where an occluder covers the *whole*
//!   texel, with the farthest depth the occluder can have over that texel, less a bound on rounding error. So
//!   anything the buffer calls hidden is hidden behind the occluders at any finer resolution. Coverage is
//!   that of the union of an occluder's front faces, not of single triangles, so the shared edges inside a
//!   mesh (a quad's diagonal, the edge between two walls) leave no holes: a texel is covered whole when some
//!   front face covers its centre and no boundary edge of the union (silhouette, open border, near-plane
//!   cut) touches it.
//! - [`RasterMode::PixelCentres`]: a texel is written where an occluder's front face covers its *centre*, with
//!   the face's depth there less a bound on rounding error. That is how a rasterizer samples a pixel, so for
//!   a buffer at the viewport's resolution it is conservative against the rendering it will draw: an object
//!   seen at some pixel centre has a point nearer than every occluder there. It is not conservative for
//!   renderings finer than the buffer: at 256x144 it would hide what a 1920x1080 frame shows.
//! - [`RasterMode::Masked`]: the pixel centres [`RasterMode::PixelCentres`] covers, kept as a coverage mask
//!   and one depth per 4x4 block of pixels rather than a depth per pixel, after Intel's Masked Occlusion
//!   Culling (`raster/masked.rs`). Level 0 of the pyramid is the blocks' depths, so a buffer at the viewport's
//!   resolution costs a sixteenth of the memory to clear, write and reduce; it is conservative where
//!   pixel centres are, a block holding a depth no nearer than the occluders at any of its pixel centres. Two
//!   triangles sharing an edge are drawn as one quad, which also covers the centres along that edge that
//!   pixel-centre mode's margins leave out.
//! - [`RasterMode::Fast`]: sampled at texel centres like Collin's 256x144 buffer, with no margins; lossy
//!   below the viewport's resolution.
//!
//! Occluders are first bounded on screen from the corners of their local boxes, and drawn nearest first. A band
//! skips an occluder that the ones drawn before it already hide there, and an occluder's triangles are set up
//! only when some band does not skip it: from a street between buildings, most occluders cost only their bound.
//!
//! Triangle setup (transform, clipping against the near plane, edge and depth planes) runs in f64, each distinct
//! vertex of an occluder transformed and projected once; only the per-texel loop runs in f32, with margins that
//! cover its rounding. Nothing is clipped against the sides of the screen: f64 setup is precise far outside it,
//! and texel loops are clamped to the buffer. Back faces (seen from the eye, or from the light in an
//! orthographic view) are skipped: a closed occluder's front faces hide everything its back faces would, and
//! from inside an occluder nothing is hidden by it.

use crate::depth::{DepthBuffer, DepthPyramid, ScreenView, ceil, farther, floor, nearer, reduce_rows};
use crate::frustum::SimdBackend;
use crate::occluders::{NO_NEIGHBOUR, OccluderInstance};
use glam::{DAffine3, DMat4, DVec3, DVec4, Vec3};
use rayon::prelude::*;
use std::sync::OnceLock;

mod masked;

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
    /// Texel-centre sampling with rounding margins: never hides an object visible at a pixel centre of a
    /// rendering at the buffer's own resolution. Meant for a buffer as large as the viewport.
    PixelCentres,
    /// The pixel centres of [`RasterMode::PixelCentres`] (and those along the edge two triangles of a quad
    /// share), kept as a coverage mask and one depth per 4x4 block of pixels: level 0 of the pyramid has a
    /// texel per block ([`crate::depth::DepthBuffer::texel_size`] 4). Conservative at the viewport's own
    /// resolution, like pixel centres, for less work a pixel.
    Masked,
    /// Texel-centre sampling: hides more, and may hide what is visible.
    Fast,
}

impl RasterMode {
    /// Whether a `buffer` (width, height) in this mode never hides an object that a rendering of `viewport`
    /// pixels shows at some pixel centre (given occluders that lie inside the geometry they stand for):
    /// always for [`RasterMode::Conservative`], only at the viewport's own resolution for
    /// [`RasterMode::PixelCentres`] and [`RasterMode::Masked`] (below it, only through a view made for the
    /// viewport's frame: [`crate::culler::OcclusionSettings::frame`]), never for [`RasterMode::Fast`].
    pub fn is_conservative_for(self, buffer: (u32, u32), viewport: (u32, u32)) -> bool {
        match self {
            Self::Conservative => true,
            Self::PixelCentres | Self::Masked => buffer == viewport,
            Self::Fast => false,
        }
    }

    /// Whether the mode samples the pixel centres of a buffer as large as the viewport
    /// ([`RasterMode::PixelCentres`] and [`RasterMode::Masked`]): conservative only at the viewport's own size,
    /// so its buffer should follow the viewport's size.
    pub fn samples_pixel_centres(self) -> bool {
        matches!(self, Self::PixelCentres | Self::Masked)
    }

    /// A short lowercase name for tables and logs: `conservative`, `pixel-centres`, `masked` or `fast`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Conservative => "conservative",
            Self::PixelCentres => "pixel-centres",
            Self::Masked => "masked",
            Self::Fast => "fast",
        }
    }
}

/// A triangle ready for the per-texel loop, in f32, all offsets and margins folded into constant terms.
#[derive(Clone, Copy, Debug)]
struct SetupTriangle {
    /// Per edge `(a, b, c_centre, c_outer)`: the texel centre is inside the edge when `a*x + b*y + c_centre >= 0`;
    /// the texel may overlap the triangle only if `a*x + b*y + c_outer >= 0`.
    edges: [[f32; 4]; 3],
    /// `(p, q, r)`: the depth written for texel `(x, y)` is `p*x + q*y + r` (the plane's minimum over the texel
    /// less a margin in conservative mode, its value at the centre in fast mode).
    depth: [f32; 3],
    /// Texel bounds.
    rect: TexelRect,
}

/// Columns `x0..x1`, rows `y0..y1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct TexelRect {
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
}

impl TexelRect {
    const EMPTY: Self = Self { x0: u32::MAX, x1: 0, y0: u32::MAX, y1: 0 };

    fn union(self, other: Self) -> Self {
        Self {
            x0: self.x0.min(other.x0),
            x1: self.x1.max(other.x1),
            y0: self.y0.min(other.y0),
            y1: self.y1.max(other.y1),
        }
    }

    fn is_empty(&self) -> bool {
        self.x0 >= self.x1 || self.y0 >= self.y1
    }
}

/// One occluder after setup: its front-facing triangles, and the screen segments that bound their union.
#[derive(Clone, Debug)]
struct SetupOccluder {
    triangles: Vec<SetupTriangle>,
    /// Silhouette, open-boundary and near-clip edges `(x0, y0, x1, y1)`: the union of the triangles has no other
    /// boundary, so a texel whose centre is covered and that no such segment touches is covered whole. Only
    /// the conservative mode reads them; empty in the others.
    boundary: Vec<[f64; 4]>,
    /// Where every boundary segment's ends lie on one side of every boundary segment's line (conservative mode
    /// only): those lines `(a, b, c)`, the union on the side where `a*x + b*y + c >= 0`. The union is then the
    /// convex region they bound, and [`raster_hull`] draws it from them. Empty otherwise.
    hull: Vec<[f64; 3]>,
    /// The triangles as the masked mode draws them: consecutive ones sharing an edge paired into one quad
    /// (see [`masked::quads`]). Empty in the other modes.
    quads: Vec<masked::SetupQuad>,
    rect: TexelRect,
}

/// An occluder to draw, bounded on screen before its triangles are set up. A band sets it up the first time
/// it finds the occluder not hidden behind nearer ones, so an occluder hidden in every band it reaches (most
/// of them, from a street between buildings) costs only its bound.
struct PendingOccluder<'a> {
    instance: &'a OccluderInstance<'a>,
    /// Texels its triangles may cover: a superset of the set-up occluder's rectangle.
    rect: TexelRect,
    /// Nothing of the occluder is nearer: at least the largest depth of any of its set-up vertices.
    nearest: f32,
    setup: OnceLock<Option<SetupOccluder>>,
}

impl PendingOccluder<'_> {
    /// Its set-up triangles, made by the first caller; `None` when none is drawn (all back-facing, clipped
    /// away or degenerate, or in conservative mode too small to cover a texel whole).
    fn setup(&self, view: &ScreenView, mode: RasterMode, scratch: &mut SetupScratch) -> Option<&SetupOccluder> {
        self.setup.get_or_init(|| setup_occluder(view, self.instance, mode, scratch)).as_ref()
    }
}

/// Counts from one rasterization.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RasterStats {
    /// Triangles submitted.
    pub triangles_in: usize,
    /// Triangles (after clipping and fan splitting) that reached the texel loop: those of the occluders set up,
    /// the ones not hidden behind nearer occluders everywhere they reach.
    pub triangles_rasterized: usize,
    /// Triangles skipped: back-facing, degenerate, off screen or clipped away entirely, or in an occluder
    /// hidden behind nearer ones before it was set up.
    pub triangles_rejected: usize,
    /// Occluders on screen but never set up: hidden behind nearer occluders everywhere they reach.
    pub occluders_hidden: usize,
}

/// Rasterizes `occluders` into level 0 of `pyramid` (resized to the view and cleared first), in parallel over
/// bands of rows, and builds the pyramid's other levels from it.
///
/// Each band clears its rows just before rasterizing them and reduces them into the next three levels right
/// after, while they are in its core's cache; the few rows above are reduced once every band is done.
pub fn rasterize(
    view: &ScreenView,
    occluders: &[OccluderInstance<'_>],
    mode: RasterMode,
    pyramid: &mut DepthPyramid,
) -> RasterStats {
    let bounded: Vec<(f32, TexelRect, &OccluderInstance)> = occluders
        .par_iter()
        .with_min_len(64)
        .filter_map(|instance| screen_bound(view, instance).map(|(rect, nearest)| (nearest, rect, instance)))
        .collect();
    // Nearest first, so that occluders hidden behind nearer ones can be skipped: sorted as one integer each, the
    // depth's key above the index, which moves 8 bytes an occluder instead of 32 (street view: 2.5% of the raster).
    let mut order: Vec<u64> =
        bounded.iter().enumerate().map(|(i, b)| u64::from(nearest_first_key(b.0)) << 32 | i as u64).collect();
    order.sort_unstable();
    let pending: Vec<PendingOccluder> = order
        .into_iter()
        .map(|key| {
            let (nearest, rect, instance) = bounded[key as u32 as usize];
            PendingOccluder { instance, rect, nearest, setup: OnceLock::new() }
        })
        .collect();
    if mode == RasterMode::Masked {
        masked::rasterize_blocks(view, &pending, pyramid);
    } else {
        rasterize_texels(view, &pending, mode, pyramid);
    }
    let triangles_in = occluders.iter().map(|o| o.occluder.triangle_count()).sum();
    let set_up = pending.iter().filter_map(|occluder| occluder.setup.get()?.as_ref());
    let triangles_rasterized = set_up.map(|occluder| occluder.triangles.len()).sum();
    RasterStats {
        triangles_in,
        triangles_rasterized,
        triangles_rejected: triangles_in.saturating_sub(triangles_rasterized),
        occluders_hidden: pending.iter().filter(|occluder| occluder.setup.get().is_none()).count(),
    }
}

/// A key that orders depths nearest (largest) first, as `f32::total_cmp` reversed does: the total order's
/// integer form (negative values' bits flipped, the others' sign bit set), flipped.
fn nearest_first_key(depth: f32) -> u32 {
    let bits = depth.to_bits();
    !(if bits >> 31 == 1 { !bits } else { bits | 1 << 31 })
}

/// Draws `pending` (nearest first) into a buffer of one texel per pixel of `view`, level 0 of `pyramid`, and
/// reduces the levels above.
fn rasterize_texels(view: &ScreenView, pending: &[PendingOccluder], mode: RasterMode, pyramid: &mut DepthPyramid) {
    pyramid.resize_for_overwrite(view.width, view.height);
    if view.width == 0 || view.height == 0 {
        return; // No texel to write, at any level.
    }

    let width = view.width as usize;
    let bins = Bins::new(pending, view.height, BAND_ROWS);
    let bins = bins.bands();
    let (band_rows, level_widths) = band_levels(pyramid.levels_mut(), BAND_ROWS, bins.len());
    let fused = level_widths.len() - 1;
    let avx2 = SimdBackend::Auto.resolve() == SimdBackend::Avx2;
    // Working memory once per rayon job rather than once per band: it grows to the largest occluder drawn.
    let scratches = || (Scratch::default(), SetupScratch::default(), vec![0.0; width.div_ceil(BLOCK_COLUMNS)]);
    let bands = band_rows.into_par_iter().zip(bins.par_iter()).enumerate();
    bands.for_each_init(scratches, |(scratch, setup_scratch, blocks), (band, (mut rows, bin))| {
        let texels = &mut *rows[0];
        texels.fill(0.0);
        blocks.fill(0.0);
        let band_y0 = (band * BAND_ROWS) as u32;
        let band_y1 = band_y0 + (texels.len() / width) as u32;
        let mut band = Band { texels, width, y0: band_y0, y1: band_y1 };
        for &index in *bin {
            let pending = &pending[index as usize];
            if band.hides(blocks, pending.rect, pending.nearest) {
                continue;
            }
            let Some(occluder) = pending.setup(view, mode, setup_scratch) else {
                continue;
            };
            match mode {
                RasterMode::Conservative => raster_union_with_backend(avx2, occluder, band.reborrow(), scratch),
                RasterMode::PixelCentres | RasterMode::Masked | RasterMode::Fast => {
                    raster_centres_with_backend(avx2, &occluder.triangles, band.reborrow())
                }
            }
            band.update_blocks(blocks, occluder.rect);
        }
        reduce_band(&mut rows, &level_widths);
    });
    pyramid.reduce_from(fused);
}

/// Each of `bands` bands' rows in level 0 (`band_rows` rows a band) and in the [`FUSED_LEVELS`] levels above
/// it, which level `k` holds `band_rows >> k` of (ceil-halving sizes give every band its share, the last band
/// a shorter one), and those levels' widths. A band rasterizes its rows of level 0, then reduces them into the
/// others while they are in its core's cache ([`reduce_band`]).
fn band_levels(levels: &mut [DepthBuffer], band_rows: usize, bands: usize) -> (Vec<Vec<&mut [f32]>>, Vec<usize>) {
    let fused = FUSED_LEVELS.min(levels.len() - 1);
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
fn reduce_band(rows: &mut [&mut [f32]], level_widths: &[usize]) {
    for k in 1..rows.len() {
        let (fine, coarse) = rows.split_at_mut(k);
        reduce_rows(fine[k - 1], level_widths[k - 1], coarse[0]);
    }
}

/// The indices of occluders (in their order) whose rectangles reach each band of a buffer's rows, in one array:
/// counted first, then written once (a vector a band, grown one push at a time, took most of binning's time).
struct Bins {
    indices: Vec<u32>,
    /// Band `b`'s indices are `indices[starts[b]..starts[b + 1]]`.
    starts: Vec<usize>,
}

impl Bins {
    /// The occluders whose rectangles reach each band of `band_rows` rows (a power of two) of a buffer `height`
    /// rows high.
    fn new(occluders: &[PendingOccluder], height: u32, band_rows: usize) -> Self {
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
    fn bands(&self) -> Vec<&[u32]> {
        self.starts.windows(2).map(|ends| &self.indices[ends[0]..ends[1]]).collect()
    }
}

/// Whether every depth of `depths` is nearer (larger) than `nearest`. Counting the ones that are not
/// vectorizes; an early exit per group of 32 keeps the common case (a visible occluder) short.
#[inline(always)]
fn all_nearer(depths: &[f32], nearest: f32) -> bool {
    depths.chunks(32).all(|group| group.iter().map(|&depth| (depth <= nearest) as u32).sum::<u32>() == 0)
}

/// Pyramid levels above level 0 that each band reduces its own rows into (`BAND_ROWS >> FUSED_LEVELS` >= 1, and
/// so for the masked raster's bands).
const FUSED_LEVELS: usize = 3;

/// Columns of a band summarised by one farthest depth, which [`Band::hides`] reads.
const BLOCK_COLUMNS: usize = 8;

/// Whether every group of [`BLOCK_COLUMNS`] columns that `columns` reaches has a farthest depth (`summary`, kept
/// by [`update_summary`]) nearer than `nearest`: then so has every cell of those columns in every row the summary
/// covers.
#[inline(always)]
fn summary_hides(summary: &[f32], columns: std::ops::Range<usize>, nearest: f32) -> bool {
    summary[columns.start / BLOCK_COLUMNS..columns.end.div_ceil(BLOCK_COLUMNS)]
        .iter()
        .all(|&farthest| farthest > nearest)
}

/// Recomputes `summary`, the farthest depth of each group of [`BLOCK_COLUMNS`] columns over every row of
/// `cells` (rows of `width`: a band's texels, or a masked band's blocks), for the groups `columns` reaches.
#[inline(always)]
fn update_summary(summary: &mut [f32], cells: &[f32], width: usize, columns: std::ops::Range<usize>) {
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

/// The rows `y0..y1` of the depth buffer one task owns.
struct Band<'a> {
    texels: &'a mut [f32],
    width: usize,
    y0: u32,
    y1: u32,
}

impl Band<'_> {
    fn reborrow(&mut self) -> Band<'_> {
        Band { texels: self.texels, width: self.width, y0: self.y0, y1: self.y1 }
    }

    /// Whether every texel of `rect` within the band already holds a depth nearer than `nearest`, so that an
    /// occluder no nearer than that can add nothing there. First reads `blocks`, the farthest depth of each
    /// [`BLOCK_COLUMNS`] columns of the band's rows (kept by [`Band::update_blocks`]): a block covers at least
    /// the texels of `rect` in its columns, so when every block is nearer, so is every texel. Where the blocks
    /// cannot tell (they also cover rows and columns outside `rect`), the texels are read.
    fn hides(&self, blocks: &[f32], rect: TexelRect, nearest: f32) -> bool {
        if summary_hides(blocks, rect.x0 as usize..rect.x1 as usize, nearest) {
            return true;
        }
        let rect = self.clip(rect);
        (rect.y0..rect.y1).all(|y| {
            all_nearer(&self.texels[(y - self.y0) as usize * self.width..][rect.x0 as usize..rect.x1 as usize], nearest)
        })
    }

    /// Recomputes the farthest depth of the blocks under `rect`'s columns after an occluder was drawn there.
    fn update_blocks(&self, blocks: &mut [f32], rect: TexelRect) {
        update_summary(blocks, self.texels, self.width, rect.x0 as usize..rect.x1 as usize);
    }

    /// The part of `rect` inside the band.
    fn clip(&self, rect: TexelRect) -> TexelRect {
        TexelRect { y0: rect.y0.max(self.y0), y1: rect.y1.min(self.y1), ..rect }
    }
}

/// Per-occluder working memory of the conservative mode, over the occluder's rectangle within a band.
#[derive(Default)]
struct Scratch {
    /// Some triangle covers the texel centre (1, else 0: 32 bits, as the depths, so that the texel loop
    /// vectorizes).
    covered: Vec<u32>,
    /// A boundary segment touches the texel.
    blocked: Vec<bool>,
    /// The farthest depth of every triangle that may overlap the texel.
    farthest: Vec<f32>,
    /// Each row's columns drawn.
    runs: Vec<(u32, u32)>,
}

/// [`raster_centres`], compiled for AVX2 where `avx2` (detected on this processor): its texel loop then runs 8
/// lanes wide. The arithmetic is the same (Rust never fuses a multiply and an add by itself), so both give the
/// same texels.
fn raster_centres_with_backend(avx2: bool, triangles: &[SetupTriangle], band: Band<'_>) {
    match avx2 {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `avx2` is set only where AVX2 was detected.
        true => unsafe { raster_centres_avx2(triangles, band) },
        _ => raster_centres(triangles, band),
    }
}

/// [`raster_centres`] with AVX2 enabled.
///
/// # Safety
/// The processor must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn raster_centres_avx2(triangles: &[SetupTriangle], band: Band<'_>) {
    raster_centres(triangles, band)
}

/// Centre-sampled modes ([`RasterMode::PixelCentres`], [`RasterMode::Fast`]): each triangle writes its depth at
/// the texel centre wherever its three edge tests pass there.
#[inline(always)]
fn raster_centres(triangles: &[SetupTriangle], band: Band<'_>) {
    for tri in triangles {
        let rect = band.clip(tri.rect);
        let [p, q, r] = tri.depth;
        let [[a0, b0, c0, _], [a1, b1, c1, _], [a2, b2, c2, _]] = tri.edges;
        for y in rect.y0..rect.y1 {
            let yf = y as f32;
            let rows = [b0 * yf + c0, b1 * yf + c1, b2 * yf + c2];
            let (x0, x1) = candidate_columns([a0, a1, a2], rows, rect.x0, rect.x1);
            if x0 >= x1 {
                continue;
            }
            let row = &mut band.texels[(y - band.y0) as usize * band.width..][x0 as usize..x1 as usize];
            write_covered(row, x0, [a0, a1, a2], rows, p, q * yf + r);
        }
    }
}

/// A run of columns within `lo..hi` outside which no centre passes the edge tests `a[i]*x + rows[i] >= 0` of
/// one row: each edge's zero crossing `-rows[i]/a[i]` widened by 2 columns. The f32 test and the division
/// each place the crossing within a few ulps of `x` of the exact one, far less than 2 columns for any column
/// the clamp lets through, so the run is a superset and [`write_covered`] decides each texel.
#[inline(always)]
fn candidate_columns(a: [f32; 3], rows: [f32; 3], lo: u32, hi: u32) -> (u32, u32) {
    let (mut x0, mut x1) = (lo as f32, hi as f32);
    for (a, row) in a.into_iter().zip(rows) {
        let crossing = (-row / a).clamp(lo as f32 - 4.0, hi as f32 + 4.0);
        if a > 0.0 {
            x0 = x0.max(crossing - 2.0);
        } else if a < 0.0 {
            x1 = x1.min(crossing + 2.0);
        } else if row < 0.0 {
            return (0, 0);
        }
    }
    // Also maps a NaN crossing (there is none for finite set-up planes) to an empty run.
    if x0 < x1 { (x0.max(lo as f32) as u32, (x1.ceil() as u32).min(hi)) } else { (0, 0) }
}

/// The column offsets within a group of 8 columns that the texel loops handle as one.
const COLUMN_OFFSETS: [f32; 8] = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];

/// Raises each texel of `row` (whose first column is `x0`) whose centre passes the three edge tests
/// `a[i]*x + rows[i] >= 0` to the plane depth `p*x + rz` where that is nearer. Groups of 8 columns go through
/// fixed-width loops the compiler vectorizes; every test and depth is the same f32 expression as for a single
/// texel (`x0 + k` is exact in f32 for any buffer width).
#[inline(always)]
fn write_covered(row: &mut [f32], x0: u32, a: [f32; 3], rows: [f32; 3], p: f32, rz: f32) {
    let texel = |texel: &mut f32, x: f32| {
        let inside = (a[0] * x + rows[0] >= 0.0) & (a[1] * x + rows[1] >= 0.0) & (a[2] * x + rows[2] >= 0.0);
        // Written unconditionally as a maximum: a conditional write becomes a masked store, slow on many cores.
        let depth = if inside { p * x + rz } else { f32::NEG_INFINITY };
        *texel = texel.max(depth);
    };
    let mut chunks = row.chunks_exact_mut(8);
    let mut base = x0 as f32;
    for chunk in &mut chunks {
        for (t, offset) in chunk.iter_mut().zip(COLUMN_OFFSETS) {
            texel(t, base + offset);
        }
        base += 8.0;
    }
    for (t, offset) in chunks.into_remainder().iter_mut().zip(COLUMN_OFFSETS) {
        texel(t, base + offset);
    }
}

/// [`raster_union`], compiled for AVX2 where `avx2` (detected on this processor); the arithmetic is the same,
/// so both give the same texels.
fn raster_union_with_backend(avx2: bool, occluder: &SetupOccluder, band: Band<'_>, scratch: &mut Scratch) {
    match avx2 {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `avx2` is set only where AVX2 was detected.
        true => unsafe { raster_union_avx2(occluder, band, scratch) },
        _ => raster_union(occluder, band, scratch),
    }
}

/// [`raster_union`] with AVX2 enabled.
///
/// # Safety
/// The processor must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn raster_union_avx2(occluder: &SetupOccluder, band: Band<'_>, scratch: &mut Scratch) {
    raster_union(occluder, band, scratch)
}

/// Conservative mode: a texel is written when the occluder's front faces cover its centre and no boundary
/// segment of their union touches it (so the union covers it whole), with the farthest depth of every
/// triangle that may overlap it. An occluder whose boundary bounds a convex region is drawn from its lines
/// instead ([`raster_hull`]), where that decides.
#[inline(always)]
fn raster_union(occluder: &SetupOccluder, mut band: Band<'_>, scratch: &mut Scratch) {
    let rect = band.clip(occluder.rect);
    if rect.is_empty() || (!occluder.hull.is_empty() && raster_hull(occluder, band.reborrow(), rect, scratch)) {
        return;
    }
    let (w, h) = ((rect.x1 - rect.x0) as usize, (rect.y1 - rect.y0) as usize);
    scratch.covered.clear();
    scratch.covered.resize(w * h, 0);
    scratch.blocked.clear();
    scratch.blocked.resize(w * h, false);
    scratch.farthest.clear();
    scratch.farthest.resize(w * h, f32::INFINITY);
    scratch.runs.clear();
    scratch.runs.resize(h, (rect.x0, rect.x1));
    let Scratch { covered, farthest, runs, .. } = scratch;
    draw_triangles::<true>(&occluder.triangles, rect, runs, covered, farthest);
    for segment in &occluder.boundary {
        block_segment(segment, rect, w, &mut scratch.blocked);
    }
    let scratch_rows =
        scratch.covered.chunks_exact(w).zip(scratch.blocked.chunks_exact(w)).zip(scratch.farthest.chunks_exact(w));
    for (y, ((covered, blocked), farthest)) in (rect.y0..rect.y1).zip(scratch_rows) {
        let row = &mut band.texels[(y - band.y0) as usize * band.width..][rect.x0 as usize..rect.x1 as usize];
        for (((texel, &covered), &blocked), &farthest) in row.iter_mut().zip(covered).zip(blocked).zip(farthest) {
            // Written unconditionally as a maximum, so that the loop vectorizes (no depth is NaN: one `maxps`).
            *texel = nearer(if covered != 0 && !blocked { farthest } else { f32::NEG_INFINITY }, *texel);
        }
    }
}

/// Conservative mode for an occluder whose boundary lines bound a convex region ([`SetupOccluder::hull`]).
/// A texel whose square, grown by the segments' margin, lies inside every boundary line meets no boundary
/// segment; all such texels of the band lie in one convex region that meets none, so the union of the
/// triangles, whose only boundary is those segments, covers either all of them whole or none of them. One
/// whose centre a triangle covers decides: then each is written with the farthest depth of every triangle that
/// may overlap it. Returns whether that decided (nothing written otherwise: the caller draws the occluder as
/// any other). This holds for any lines; that the boundary is convex only makes them draw as much as the
/// segments would. Inlined, so that the raster's AVX2 build rounds with one instruction, not a call.
#[inline(always)]
fn raster_hull(occluder: &SetupOccluder, band: Band<'_>, rect: TexelRect, scratch: &mut Scratch) -> bool {
    // Each row's columns `x0..x1` whose grown squares lie inside every line `a*x + b*y + c >= 0`: the line's
    // least value over the square of texel (x, y), `a*x + k`, is at least 0. Coordinates are bounded
    // ([`hull_lines`]), so the rounding here is far below the margin.
    scratch.runs.clear();
    scratch.runs.resize((rect.y1 - rect.y0) as usize, (rect.x0, rect.x0));
    for (run, y) in scratch.runs.iter_mut().zip(rect.y0..rect.y1) {
        let (mut lo, mut hi) = (rect.x0 as f64, rect.x1 as f64 - 1.0);
        for &[a, b, c] in &occluder.hull {
            let k = a.min(0.0) + b * y as f64 + b.min(0.0) + c - SEGMENT_GROW * (a.abs() + b.abs());
            if a > 0.0 {
                lo = lo.max((-k / a).ceil());
            } else if a < 0.0 {
                hi = hi.min((-k / a).floor());
            } else if k < 0.0 {
                hi = -1.0;
            }
        }
        if lo <= hi {
            *run = (lo as u32, hi as u32 + 1);
        }
    }
    let rows = &scratch.runs;
    let drawn = || rows.iter().enumerate().filter(|(_, run)| run.0 < run.1).map(|(row, _)| row);
    let Some(middle) = drawn().nth(drawn().count() / 2) else {
        return true; // No texel of the band is covered whole.
    };
    let (x, y) = ((rows[middle].0 + rows[middle].1) / 2, rect.y0 + middle as u32);
    // Inside a triangle by more than the f32 evaluation can be off (the coefficients' rounding to f32 included),
    // so that the centre surely lies in it: a test that merely passes could, for a sliver, pass far from it.
    let (xf, yf) = (x as f32, y as f32);
    let inside = |[a, b, c, _]: [f32; 4]| {
        let (ax, by) = (a * xf, b * yf);
        ax + (by + c) > EVAL_MARGIN as f32 * (ax.abs() + by.abs() + c.abs())
    };
    if !occluder.triangles.iter().any(|tri| tri.edges.map(inside) == [true; 3]) {
        return false;
    }
    let w = (rect.x1 - rect.x0) as usize;
    scratch.farthest.clear();
    scratch.farthest.resize(w * rows.len(), f32::INFINITY);
    draw_triangles::<false>(&occluder.triangles, rect, rows, &mut [], &mut scratch.farthest);
    for ((&(x0, x1), y), farthest) in rows.iter().zip(rect.y0..rect.y1).zip(scratch.farthest.chunks_exact(w)) {
        let row = &mut band.texels[(y - band.y0) as usize * band.width..][x0 as usize..x1 as usize];
        let farthest = &farthest[(x0 - rect.x0) as usize..(x1 - rect.x0) as usize];
        for (texel, &depth) in row.iter_mut().zip(farthest) {
            *texel = nearer(depth, *texel);
        }
    }
    true
}

/// Tests `triangles` over `rect` (a band's part of an occluder's rectangle; `covered` and `farthest` hold its
/// texels, row by row), in row `y0 + i` only the columns `runs[i]`: each texel's farthest depth over the
/// triangles that may overlap it into `farthest`, and where `CENTRES`, whether one covers its centre into
/// `covered` (unused otherwise).
#[inline(always)]
fn draw_triangles<const CENTRES: bool>(
    triangles: &[SetupTriangle],
    rect: TexelRect,
    runs: &[(u32, u32)],
    covered: &mut [u32],
    farthest: &mut [f32],
) {
    let w = (rect.x1 - rect.x0) as usize;
    for tri in triangles {
        let [[a0, b0, c0, o0], [a1, b1, c1, o1], [a2, b2, c2, o2]] = tri.edges;
        let [p, q, r] = tri.depth;
        // Reciprocals once a triangle rather than a division a row: they only place the skipped columns, whose
        // texel of widening covers a relative rounding of far more than the reciprocal's.
        let inverse = [-1.0 / a0, -1.0 / a1, -1.0 / a2];
        for y in tri.rect.y0.max(rect.y0)..tri.rect.y1.min(rect.y1) {
            let run = runs[(y - rect.y0) as usize];
            let yf = y as f32;
            let (r0, r1, r2) = (b0 * yf + c0, b1 * yf + c1, b2 * yf + c2);
            let (s0, s1, s2) = (b0 * yf + o0, b1 * yf + o1, b2 * yf + o2);
            // Columns where the outer tests can pass, widened by a texel for rounding: the loop below still
            // tests every texel, this only skips the ones that cannot pass.
            let (mut lo, mut hi) = (tri.rect.x0.max(run.0) as f32, tri.rect.x1.min(run.1) as f32);
            for ((a, s), inverse) in [(a0, s0), (a1, s1), (a2, s2)].into_iter().zip(inverse) {
                if a > 0.0 {
                    lo = lo.max(s * inverse - 1.0);
                } else if a < 0.0 {
                    hi = hi.min(s * inverse + 2.0);
                }
            }
            // Also skips NaN.
            if lo.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
                continue;
            }
            let x_lo = (lo as u32).max(tri.rect.x0).max(run.0);
            let x_hi = (hi as u32).min(tri.rect.x1).min(run.1);
            if x_lo >= x_hi {
                continue;
            }
            let rz = q * yf + r;
            // Each test the same f32 expression for every column; the centre and overlap tests in two loops
            // of one output each, which the compiler vectorizes.
            let centre = |xf: f32| (a0 * xf + r0 >= 0.0) & (a1 * xf + r1 >= 0.0) & (a2 * xf + r2 >= 0.0);
            let overlap_depth = |xf: f32| {
                let overlaps = (a0 * xf + s0 >= 0.0) & (a1 * xf + s1 >= 0.0) & (a2 * xf + s2 >= 0.0);
                if overlaps { p * xf + rz } else { f32::INFINITY }
            };
            let row = (y - rect.y0) as usize * w;
            if w < 8 {
                for x in x_lo..x_hi {
                    let at = row + (x - rect.x0) as usize;
                    if CENTRES {
                        covered[at] |= centre(x as f32) as u32;
                    }
                    farthest[at] = farther(overlap_depth(x as f32), farthest[at]);
                }
                continue;
            }
            // Whole groups of 8 columns; the last group ends at the run's end or the row's, overlapping the one
            // before. Columns outside the run are tested like any other (their tests and depths are exact per
            // column), and testing a column twice changes nothing.
            let mut x = x_lo;
            while x < x_hi {
                let group = x.min(rect.x1 - 8);
                let at = row + (group - rect.x0) as usize;
                if CENTRES {
                    let covered = covered[at..].first_chunk_mut::<8>().expect("8 columns of the row");
                    for (covered, offset) in covered.iter_mut().zip(COLUMN_OFFSETS) {
                        *covered |= centre(group as f32 + offset) as u32;
                    }
                }
                let farthest = farthest[at..].first_chunk_mut::<8>().expect("8 columns of the row");
                for (farthest, offset) in farthest.iter_mut().zip(COLUMN_OFFSETS) {
                    *farthest = farther(overlap_depth(group as f32 + offset), *farthest);
                }
                x += 8;
            }
        }
    }
}

/// Half the width of the margin a texel is grown by before a boundary segment is tested against it.
const SEGMENT_GROW: f64 = 1e-3;

/// Marks every texel of `rect` that the segment touches, each texel grown by a margin for rounding.
#[inline(always)]
fn block_segment(segment: &[f64; 4], rect: TexelRect, w: usize, blocked: &mut [bool]) {
    block_segment_rows(segment, rect, segment_rows(segment, rect), w, blocked);
}

/// The rows of `rect` a segment can touch: those its height reaches, a row more each side. Ends that are not
/// finite keep every row, as [`block_segment_rows`] blocks them all.
#[inline(always)]
fn segment_rows(segment: &[f64; 4], rect: TexelRect) -> std::ops::Range<u32> {
    let [_, y0, _, y1] = *segment;
    let mut rows = rect.y0..rect.y1;
    if segment.iter().all(|end| end.is_finite()) {
        let (top, bottom) = (y0.min(y1) - SEGMENT_GROW - 1.0, y0.max(y1) + SEGMENT_GROW + 1.0);
        rows.start = rows.start.max(top.max(0.0).floor().min(rect.y1 as f64) as u32);
        rows.end = rows.end.min(bottom.max(0.0).ceil().min(u32::MAX as f64) as u32);
    }
    rows
}

/// [`block_segment`] over `rows` of `rect` only. A segment with an end that is not finite blocks every texel
/// of those rows. Inlined, so that the raster's AVX2 build rounds with one instruction, not a call.
#[inline(always)]
fn block_segment_rows(segment: &[f64; 4], rect: TexelRect, rows: std::ops::Range<u32>, w: usize, blocked: &mut [bool]) {
    let [x0, y0, x1, y1] = *segment;
    if !segment.iter().all(|end| end.is_finite()) {
        for y in rows {
            let row = (y - rect.y0) as usize * w;
            blocked[row..row + w].fill(true);
        }
        return;
    }
    let (top, bottom) = (y0.min(y1), y0.max(y1));
    // Near horizontal: the whole segment in the rows its height reaches. Otherwise its part within each row's
    // slab `lo <= y <= hi`, from its slope (rounded by far less than the margin).
    let horizontal = (y1 - y0).abs() < 1e-12;
    let slope = (x1 - x0) / (y1 - y0);
    for y in rows {
        let (lo, hi) = (y as f64 - SEGMENT_GROW, y as f64 + 1.0 + SEGMENT_GROW);
        let (xa, xb) = if horizontal {
            if y0 < lo || y0 > hi {
                continue;
            }
            (x0, x1)
        } else {
            let (ya, yb) = (lo.max(top), hi.min(bottom));
            if ya > yb {
                continue;
            }
            (x0 + (ya - y0) * slope, x0 + (yb - y0) * slope)
        };
        let (left, right) = ((xa.min(xb) - SEGMENT_GROW).floor(), (xa.max(xb) + SEGMENT_GROW).floor());
        // Compared before converting: a column left of the rectangle would saturate to column 0.
        if right < rect.x0 as f64 || left >= rect.x1 as f64 {
            continue;
        }
        let (first, last) = (left.max(rect.x0 as f64) as u32, right.min(rect.x1 as f64 - 1.0) as u32);
        let row = (y - rect.y0) as usize * w;
        blocked[row + (first - rect.x0) as usize..=row + (last - rect.x0) as usize].fill(true);
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
fn screen_bound(view: &ScreenView, instance: &OccluderInstance<'_>) -> Option<(TexelRect, f32)> {
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
fn relative_transform(view: &ScreenView, instance: &OccluderInstance<'_>) -> DAffine3 {
    DAffine3::from_mat3_translation(
        glam::Mat3::from(instance.transform.matrix3).as_dmat3(),
        DVec3::from(Vec3::from(instance.transform.translation)) - view.origin.as_dvec3(),
    )
}

/// The occluder's local position to homogeneous `(x, y, w, d)` ([`to_clip`] of its camera-relative position),
/// as one matrix whose rows are clip `x`, `y`, `w` and the depth row.
fn local_to_clip(view: &ScreenView, instance: &OccluderInstance<'_>) -> DMat4 {
    let relative = DMat4::from(relative_transform(view, instance));
    let clip = view.clip_from_relative * relative;
    let depth = relative.transpose() * view.depth_from_relative;
    DMat4::from_cols(clip.row(0), clip.row(1), clip.row(3), depth).transpose()
}

/// Transforms, clips against the near plane and sets up the front faces of one occluder, with the boundary of
/// their union (conservative mode only): edges whose neighbour is missing or back-facing, and edges made by
/// near clipping. `None` when no triangle is left to draw.
fn setup_occluder(
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
        setup.quads = masked::quads(&setup.triangles, oriented);
    }
    setup.hull = hull_lines(&setup.boundary);
    (!setup.triangles.is_empty() && !too_small).then_some(setup)
}

/// Most boundary segments [`hull_lines`] checks (its check takes their count squared).
const HULL_MAX_SEGMENTS: usize = 32;
/// Farthest a boundary segment's end may lie from the screen's origin, in texels, for [`hull_lines`]: keeps the
/// rounding of [`raster_hull`]'s f64 line tests far below [`SEGMENT_GROW`].
const HULL_MAX_COORDINATE: f64 = 1e6;

/// The lines of `boundary`'s segments, each `(a, b, c)` with the other segments' first ends where
/// `a*x + b*y + c >= 0` ([`SetupOccluder::hull`]), where all of them lie on one side of each line: a closed
/// boundary (every end of a segment the first end of another) that is then convex. Empty where they do not,
/// where a segment has no length, or where there are more than [`HULL_MAX_SEGMENTS`] or an end lies beyond
/// [`HULL_MAX_COORDINATE`] (or is not finite). Only how much is drawn depends on this check: [`raster_hull`] is
/// conservative for any lines it gets, so the first ends, half the points, serve as well as all of them.
fn hull_lines(boundary: &[[f64; 4]]) -> Vec<[f64; 3]> {
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
struct SetupScratch {
    relative: Vec<DVec3>,
    front: Vec<bool>,
    projected: Vec<(DVec4, DVec3)>,
    /// Each set-up triangle's screen vertices, counter-clockwise (masked mode only).
    oriented: Vec<[DVec3; 3]>,
}

/// Clips a triangle of homogeneous `(x, y, w, d)` vertices, each flagged when the edge leaving it is a
/// boundary, against `w >= near`. Edges along the clipping plane are boundaries. Returns the polygon and its
/// size.
fn clip_near(triangle: &[(DVec4, bool); 4], near: f64) -> ([(DVec4, bool); 4], usize) {
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
fn to_clip(view: &ScreenView, relative: DVec3) -> DVec4 {
    let point = relative.extend(1.0);
    let v = view.clip_from_relative * point;
    DVec4::new(v.x, v.y, v.w, view.depth_from_relative.dot(point))
}

/// Homogeneous `(x, y, w, d)` to screen texel coordinates and depth `d/w`, y down.
fn to_screen(view: &ScreenView, v: DVec4) -> DVec3 {
    let inv_w = 1.0 / v.z;
    let (x, y) = ((v.x * inv_w * 0.5 + 0.5) * view.width as f64, (0.5 - v.y * inv_w * 0.5) * view.height as f64);
    DVec3::new(x, y, v.w * inv_w)
}

/// Edge and depth planes of a screen-space triangle, and its vertices in the order of its edges (counter-clockwise:
/// edge `i` runs from vertex `i` to vertex `i + 1`); `None` if it is degenerate or off screen.
fn setup_triangle(v: [DVec3; 3], view: &ScreenView, mode: RasterMode) -> Option<(SetupTriangle, [DVec3; 3])> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Camera, Occluder, mesh::Mesh};
    use glam::{Affine3A, Quat};
    use proptest::prelude::*;

    /// A view's sample reach moves the pixel-centre tests and depth inward; one below zero or NaN (a field set
    /// by hand) moves nothing outward.
    #[test]
    fn sample_reach_moves_centre_tests_inward_only() {
        let camera = Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z);
        let view = ScreenView::new(&camera, 64, 36);
        let triangle = [DVec3::new(3.2, 2.7, 0.5), DVec3::new(40.1, 5.3, 0.4), DVec3::new(12.8, 30.6, 0.3)];
        let setup = |reach: [f64; 2]| {
            setup_triangle(triangle, &ScreenView { sample_reach: reach, ..view }, RasterMode::Masked).unwrap().0
        };
        let (own, inward) = (setup([0.0; 2]), setup([0.25; 2]));
        for (own, inward) in own.edges.iter().zip(&inward.edges) {
            assert!(inward[2] < own[2], "{inward:?} {own:?}");
        }
        assert!(inward.depth[2] < own.depth[2]);
        for bad in [[-0.5, -0.5], [f64::NAN, f64::NAN]] {
            let bad = setup(bad);
            assert_eq!((bad.edges, bad.depth), (own.edges, own.depth));
        }
    }

    /// A box in front is bounded tightly, by its own texels and its nearest corner's depth; one reaching behind
    /// the near plane by the whole buffer; one behind the camera is kept for setup to reject.
    #[test]
    fn the_bound_before_setup_is_tight_in_front() {
        let camera = Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z);
        let view = ScreenView::new(&camera, 320, 180);
        let occluder = Occluder::new(Mesh::unit_cube(1).triangle_soup());
        let bound = |translation: Vec3| {
            screen_bound(
                &view,
                &OccluderInstance { occluder: &occluder, transform: Affine3A::from_translation(translation) },
            )
        };
        let (rect, nearest) = bound(Vec3::new(0.0, 0.0, -10.0)).unwrap();
        assert!(rect.x1 - rect.x0 < 40 && rect.y1 - rect.y0 < 40 && rect.x0 > 100, "{rect:?}");
        // The unit cube spans -0.5..0.5: its nearest face is 9.5 in front of the camera.
        assert!((1.0 / 9.5..1.0 / 9.49).contains(&nearest), "{nearest}");
        let whole = TexelRect { x0: 0, x1: 320, y0: 0, y1: 180 };
        assert_eq!(bound(Vec3::ZERO), Some((whole, f32::INFINITY)));
        let behind = bound(Vec3::new(0.0, 0.0, 10.0));
        let setup = setup_occluder(
            &view,
            &OccluderInstance { occluder: &occluder, transform: Affine3A::from_translation(Vec3::new(0.0, 0.0, 10.0)) },
            RasterMode::Conservative,
            &mut SetupScratch::default(),
        );
        assert!(behind.is_some() && setup.is_none());
    }

    #[test]
    fn nearest_first_keys_order_depths_as_total_cmp_reversed() {
        let depths =
            [f32::NAN, f32::INFINITY, 1e30, 1.0, 0.5, f32::MIN_POSITIVE, 1e-45, 0.0, -0.0, -1.0, f32::NEG_INFINITY];
        for (a, b) in depths.iter().flat_map(|a| depths.iter().map(move |b| (a, b))) {
            assert_eq!(nearest_first_key(*a).cmp(&nearest_first_key(*b)), b.total_cmp(a), "{a} {b}");
        }
    }

    /// Lines only for a boundary that is convex: an L-shaped outline, a segment of no length, or too few
    /// segments get none.
    #[test]
    fn only_a_convex_boundary_gets_lines() {
        let outline = |points: &[(f64, f64)]| -> Vec<[f64; 4]> {
            (0..points.len())
                .map(|i| {
                    let (a, b) = (points[i], points[(i + 1) % points.len()]);
                    [a.0, a.1, b.0, b.1]
                })
                .collect()
        };
        let square = outline(&[(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 4.0)]);
        let lines = hull_lines(&square);
        assert_eq!(lines.len(), 4);
        // The square's centre is inside every line.
        assert!(lines.iter().all(|&[a, b, c]| a * 2.0 + b * 2.0 + c > 0.0));
        let l_shape = outline(&[(0.0, 0.0), (4.0, 0.0), (4.0, 2.0), (2.0, 2.0), (2.0, 4.0), (0.0, 4.0)]);
        assert!(hull_lines(&l_shape).is_empty());
        let with_point = [square.clone(), vec![[4.0, 4.0, 4.0, 4.0]]].concat();
        assert!(hull_lines(&with_point).is_empty());
        assert!(hull_lines(&square[..2]).is_empty());
        let far = outline(&[(0.0, 0.0), (4e6, 0.0), (0.0, 4.0)]);
        assert!(hull_lines(&far).is_empty());
    }

    /// A subdivided cube, scaled, turned and moved from 25 in front of a camera at the origin looking down -Z,
    /// as the property tests draw it: the camera, the occluder and its transform.
    fn placed_cube(scale: [f32; 3], angles: [f32; 3], offset: [f32; 3]) -> (Camera, Occluder, Affine3A) {
        let camera = Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z);
        let occluder = Occluder::new(Mesh::unit_cube(2).triangle_soup());
        let rotation = Quat::from_euler(glam::EulerRot::XYZ, angles[0], angles[1], angles[2]);
        let translation = Vec3::from(offset) + Vec3::new(0.0, 0.0, -25.0);
        let transform = Affine3A::from_scale_rotation_translation(Vec3::from(scale), rotation, translation);
        (camera, occluder, transform)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// The AVX2 builds of the per-texel rasters write the very texels of the portable ones: the same f32
        /// arithmetic, compiled wider.
        #[cfg(target_arch = "x86_64")]
        #[test]
        fn the_avx2_texel_rasters_agree_with_the_portable_ones(
            scale in prop::array::uniform3(0.5f32..20.0),
            angles in prop::array::uniform3(-3.2f32..3.2),
            offset in prop::array::uniform3(-15.0f32..15.0),
        ) {
            if !std::arch::is_x86_feature_detected!("avx2") {
                return Ok(()); // Nothing to compare with.
            }
            let (camera, occluder, transform) = placed_cube(scale, angles, offset);
            let instance = OccluderInstance { occluder: &occluder, transform };
            let view = ScreenView::new(&camera, 203, 117);
            for mode in [RasterMode::Conservative, RasterMode::PixelCentres] {
                let Some(setup) = setup_occluder(&view, &instance, mode, &mut SetupScratch::default()) else {
                    continue;
                };
                let draw = |avx2: bool| {
                    let mut texels = vec![0.0f32; (view.width * view.height) as usize];
                    let band = Band { texels: &mut texels, width: view.width as usize, y0: 0, y1: view.height };
                    match mode {
                        RasterMode::Conservative => {
                            raster_union_with_backend(avx2, &setup, band, &mut Scratch::default())
                        }
                        _ => raster_centres_with_backend(avx2, &setup.triangles, band),
                    }
                    texels
                };
                let (portable, avx2) = (draw(false), draw(true));
                prop_assert!(portable.iter().zip(&avx2).all(|(a, b)| a.to_bits() == b.to_bits()), "{mode:?}");
            }
        }

        /// A convex occluder drawn from its boundary's lines writes the texels the segments' test writes, with
        /// the same depths, but for a few along its outline (the two grow a texel by the same margin, one
        /// against each segment, the other against its whole line); and a boundary that is not convex gets no
        /// lines.
        #[test]
        fn a_convex_occluder_drawn_from_its_lines_writes_what_its_segments_allow(
            scale in prop::array::uniform3(0.5f32..20.0),
            angles in prop::array::uniform3(-3.2f32..3.2),
            offset in prop::array::uniform3(-15.0f32..15.0),
        ) {
            let (camera, occluder, transform) = placed_cube(scale, angles, offset);
            let instance = OccluderInstance { occluder: &occluder, transform };
            let view = ScreenView::new(&camera, 203, 117);
            let mode = RasterMode::Conservative;
            let Some(with_lines) = setup_occluder(&view, &instance, mode, &mut SetupScratch::default()) else {
                return Ok(());
            };
            // A box wholly in front of the near plane has a convex outline (one clipped may not).
            let [low, high] = occluder.local_box();
            let corners = (0..8).map(|i| Vec3::select(glam::BVec3::new(i & 1 != 0, i & 2 != 0, i & 4 != 0), high, low));
            let in_front = corners.map(|corner| transform.transform_point3(corner)).all(|p| -p.z > camera.near + 0.1);
            prop_assert!(with_lines.hull.len() >= 3 || !in_front);
            let with_segments = SetupOccluder { hull: Vec::new(), ..with_lines.clone() };
            let draw = |setup: &SetupOccluder| {
                let mut texels = vec![0.0f32; (view.width * view.height) as usize];
                for (band, rows) in texels.chunks_mut(BAND_ROWS * view.width as usize).enumerate() {
                    let y0 = (band * BAND_ROWS) as u32;
                    let y1 = y0 + (rows.len() / view.width as usize) as u32;
                    let band = Band { texels: rows, width: view.width as usize, y0, y1 };
                    raster_union(setup, band, &mut Scratch::default());
                }
                texels
            };
            let (lines, segments) = (draw(&with_lines), draw(&with_segments));
            let written = |texels: &[f32]| texels.iter().filter(|&&depth| depth > 0.0).count();
            let both = lines.iter().zip(&segments).filter(|&(&a, &b)| a > 0.0 && b > 0.0);
            prop_assert!(both.clone().all(|(a, b)| a.to_bits() == b.to_bits()));
            let differ = written(&lines) + written(&segments) - 2 * both.count();
            let outline = (with_lines.rect.x1 - with_lines.rect.x0 + with_lines.rect.y1 - with_lines.rect.y0) as usize;
            prop_assert!(differ <= outline / 8, "{differ} texels differ along an outline of {outline}");
        }

        /// A boundary segment blocks the same texels whether every row of the rectangle is tested or only the
        /// rows its height reaches: the rows left out can block nothing, and ends that are not finite keep
        /// every row.
        #[test]
        fn a_segment_blocks_the_same_texels_from_its_own_rows(
            ends in prop::array::uniform4(-20.0f64..60.0),
            special in prop::sample::select(vec![None, Some(f64::NAN), Some(f64::INFINITY), Some(-f64::INFINITY)]),
            which in 0usize..4,
            near_horizontal in prop::bool::ANY,
        ) {
            let mut segment = ends;
            if near_horizontal {
                segment[3] = segment[1] + 1e-13; // Below the test's slope threshold.
            }
            if let Some(value) = special {
                segment[which] = value;
            }
            let rect = TexelRect { x0: 3, x1: 37, y0: 5, y1: 41 };
            let w = (rect.x1 - rect.x0) as usize;
            let blocked = |rows| {
                let mut blocked = vec![false; w * (rect.y1 - rect.y0) as usize];
                block_segment_rows(&segment, rect, rows, w, &mut blocked);
                blocked
            };
            prop_assert_eq!(blocked(segment_rows(&segment, rect)), blocked(rect.y0..rect.y1));
        }

        /// Every texel a boundary segment passes through is blocked: points along it, the ends included, each
        /// lie in a blocked texel (steep, shallow and near-horizontal segments alike).
        #[test]
        fn a_segment_blocks_every_texel_it_passes_through(
            ends in prop::array::uniform4(-20.0f64..60.0),
            near_horizontal in prop::bool::ANY,
        ) {
            let mut segment = ends;
            if near_horizontal {
                segment[3] = segment[1] + 1e-13;
            }
            let rect = TexelRect { x0: 3, x1: 37, y0: 5, y1: 41 };
            let w = (rect.x1 - rect.x0) as usize;
            let mut blocked = vec![false; w * (rect.y1 - rect.y0) as usize];
            block_segment(&segment, rect, w, &mut blocked);
            let [x0, y0, x1, y1] = segment;
            for k in 0..=512 {
                let t = k as f64 / 512.0;
                let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
                let (column, row) = (x.floor(), y.floor());
                let inside = |v: f64, lo: u32, hi: u32| v >= lo as f64 && v < hi as f64;
                if inside(column, rect.x0, rect.x1) && inside(row, rect.y0, rect.y1) {
                    let at = (row as u32 - rect.y0) as usize * w + (column as u32 - rect.x0) as usize;
                    prop_assert!(blocked[at], "texel ({column}, {row}) at t = {t} not blocked");
                }
            }
        }

        /// The bound made before setup holds every texel the set-up triangles reach, whether the box lies in
        /// front, crosses the near plane or lies behind the camera; and an occluder with no texel on screen is
        /// dropped before setup only when setup would draw nothing either.
        #[test]
        fn the_bound_before_setup_holds_the_set_up_triangles(
            scale in prop::array::uniform3(0.01f32..30.0),
            angles in prop::array::uniform3(-3.2f32..3.2),
            offset in prop::array::uniform3(-40.0f32..40.0),
            far_away in prop::bool::ANY,
        ) {
            let camera = Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z);
            let occluder = Occluder::new(Mesh::unit_cube(1).triangle_soup());
            let rotation = Quat::from_euler(glam::EulerRot::XYZ, angles[0], angles[1], angles[2]);
            let translation = Vec3::from(offset) + if far_away { Vec3::new(1e5, 0.0, -2e5) } else { Vec3::ZERO };
            let transform = Affine3A::from_scale_rotation_translation(Vec3::from(scale), rotation, translation);
            let instance = OccluderInstance { occluder: &occluder, transform };
            for mode in [RasterMode::Conservative, RasterMode::PixelCentres] {
                let view = ScreenView::new(&camera, 333, 187);
                let setup = setup_occluder(&view, &instance, mode, &mut SetupScratch::default());
                match (setup, screen_bound(&view, &instance)) {
                    (None, _) => {}
                    (Some(setup), Some((rect, _))) => {
                        let inside = rect.x0 <= setup.rect.x0 && setup.rect.x1 <= rect.x1;
                        prop_assert!(inside && rect.y0 <= setup.rect.y0 && setup.rect.y1 <= rect.y1);
                    }
                    (Some(setup), None) => prop_assert!(false, "set up over {:?}, bounded off screen", setup.rect),
                }
            }
        }
    }
}
