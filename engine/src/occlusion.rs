//! Stage 4, occlusion test: each frustum survivor's box against the [`DepthPyramid`] of the occluder raster.
//!
//! Per object (8 objects a step, SIMD-friendly lanes): bound the box's screen rectangle and nearest depth
//! (`1/w` of its nearest point, or in an orthographic view its depth row's largest value, see
//! [`crate::depth`]) from its centre and extents in clip space; a box reaching the near plane is visible.
//! Take the mip level of eq. 19.5 of seed 000, where the rectangle covers at most 2x2 texels, and read the
//! level below it (at most 3x3 texels): the object is occluded if its nearest depth is farther than the
//! farthest occluder depth of those texels; otherwise the test is refined four levels finer still (at most
//! 17x17 texels, read until one shows the object).
//!
//! Projection runs in f32; the rectangle is widened and the depth moved nearer by a bound on its rounding
//! error, so the test culls only what the pyramid provably hides.
//!
//! [`occlude`] runs the occluder raster and this test for one view whose occluders the caller chose (the
//! engine's occlusion stage and the Bevy plugin's cameras both do).

use crate::bounds::{BoundsStore, GroupBounds};
use crate::depth::{DepthPyramid, ScreenView, ceil, farther, floor};
use crate::detail::DetailTest;
use crate::frustum::SimdBackend;
use crate::occluders::OccluderInstance;
use crate::parallel::{self, Stage};
use crate::raster::{RasterMode, RasterStats, TexelRect, rasterize_within};
use crate::visible::VisibleSet;
use rayon::prelude::*;
use std::time::{Duration, Instant};

const LANES: usize = 8;
/// Bitset words (of 64 objects) handed to one rayon task.
const WORDS_PER_TASK: usize = 16;
/// Objects to test in one word above which its group's box is tested first: where more than one 8-lane step
/// would run, one box is cheap beside them. Not tuned (docs/performance.md has what it saves).
const GROUP_TEST_ABOVE: usize = LANES;
/// Levels below the eq. 19.5 level of the last, finest read of a rectangle's texels: there it spans at most
/// `2^(FINE_LEVELS + 1) + 1` texels a side. A finer last read hides more objects and the group boxes it hides
/// save the most; 4 was the best of 3 and 4 measured (docs/performance.md).
const FINE_LEVELS: usize = 4;
/// Relative rounding slack of the f32 projection (a few hundred times its error bound).
const PROJECTION_SLACK: f32 = 1.0 / (1 << 16) as f32;

/// Counts from one occlusion test.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OcclusionStats {
    /// Objects tested (the frustum survivors).
    pub tested: usize,
    /// Objects found visible.
    pub visible: usize,
    /// Objects detail culling dropped ([`DetailTest`]): neither visible nor occluded.
    pub small: usize,
}

/// Where a box lands on the screen: texel rectangle `x0..x1`, `y0..y1` of level 0, and its nearest depth.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct ScreenRect {
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
    nearest: f32,
    /// Crosses the near plane, leaves the screen in a way the rectangle cannot express, or is degenerate.
    always_visible: bool,
}

impl ScreenRect {
    /// The texels under the rectangle in a level whose texels span `2^shift` pixels a side: first and last
    /// column, first and last row (inclusive). The rectangle must not be empty.
    #[inline(always)]
    fn texels(&self, shift: u32) -> [u32; 4] {
        [self.x0 >> shift, self.y0 >> shift, (self.x1 - 1) >> shift, (self.y1 - 1) >> shift]
    }
}

/// Counts and times of one view's occluder raster and occlusion test, as [`occlude`] returns them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ViewOcclusion {
    /// Counts of the raster; all zero where nothing was rasterized.
    pub raster: RasterStats,
    /// Counts of the test.
    pub test: OcclusionStats,
    /// Time to rasterize the occluders and build the pyramid.
    pub raster_time: Duration,
    /// Time to test the frustum survivors (or, with nothing rasterized, to copy them).
    pub test_time: Duration,
}

/// The occluder raster and occlusion test of one view, for a caller that selected `occluders` itself:
/// rasterizes them with `mode` into `pyramid`, then tests every object set in `frustum_visible` against it as
/// [`test_occlusion`] does, into `visible` and `occluded`, dropping the small ones where `detail` is given.
///
/// Where there is no screen (`view` is `None`, as for a projection the depth buffer cannot express) or no
/// occluder, it rasterizes and tests nothing: `pyramid` is emptied, `visible` becomes a copy of
/// `frustum_visible` (less the small objects) and `occluded` is empty, sized to the store.
#[allow(clippy::too_many_arguments)]
pub fn occlude(
    store: &BoundsStore,
    frustum_visible: &VisibleSet,
    view: Option<&ScreenView>,
    occluders: &[OccluderInstance<'_>],
    mode: RasterMode,
    detail: Option<&DetailTest>,
    pyramid: &mut DepthPyramid,
    visible: &mut VisibleSet,
    occluded: &mut VisibleSet,
) -> ViewOcclusion {
    occlude_within(store, frustum_visible, view, occluders, mode, None, detail, pyramid, visible, occluded)
}

/// [`occlude`], the occluders drawn only within `scissor` where it is given and everything outside it hidden
/// ([`rasterize_within`]): for a caller none of whose `frustum_visible` objects can be seen outside it.
#[allow(clippy::too_many_arguments)]
pub(crate) fn occlude_within(
    store: &BoundsStore,
    frustum_visible: &VisibleSet,
    view: Option<&ScreenView>,
    occluders: &[OccluderInstance<'_>],
    mode: RasterMode,
    scissor: Option<TexelRect>,
    detail: Option<&DetailTest>,
    pyramid: &mut DepthPyramid,
    visible: &mut VisibleSet,
    occluded: &mut VisibleSet,
) -> ViewOcclusion {
    let Some(view) = view.filter(|_| !occluders.is_empty()) else {
        let start = Instant::now();
        *pyramid = DepthPyramid::default();
        visible.clone_from(frustum_visible);
        occluded.reset(store.len());
        let tested = frustum_visible.count();
        let small = detail.map_or(0, |detail| detail.cull(store, visible));
        let test = OcclusionStats { tested, visible: tested - small, small };
        return ViewOcclusion { test, test_time: start.elapsed(), ..Default::default() };
    };
    let start = Instant::now();
    let raster = rasterize_within(view, occluders, mode, scissor, pyramid);
    let raster_time = start.elapsed();
    let start = Instant::now();
    let _stage = Stage::Occlusion.enter();
    let test = test_occlusion(store, frustum_visible, view, pyramid, detail, visible, occluded);
    ViewOcclusion { raster, test, raster_time, test_time: start.elapsed() }
}

/// Tests every object set in `frustum_visible` and writes the survivors to `visible` and the hidden ones to
/// `occluded` (both resized to the store). Parallel over words of 64 objects.
///
/// With `detail`, detail culling runs in the same pass: an object it finds small is in neither set, and is
/// not tested. It is applied to the objects of the groups the pyramid does not hide whole (whose bounds the
/// test reads anyway); a small object in a hidden group is counted occluded.
pub fn test_occlusion(
    store: &BoundsStore,
    frustum_visible: &VisibleSet,
    view: &ScreenView,
    pyramid: &DepthPyramid,
    detail: Option<&DetailTest>,
    visible: &mut VisibleSet,
    occluded: &mut VisibleSet,
) -> OcclusionStats {
    if pyramid.level_count() == 0 {
        occluded.reset(store.len());
        visible.clone_from(frustum_visible);
        let tested = frustum_visible.count();
        let small = detail.map_or(0, |detail| detail.cull(store, visible));
        return OcclusionStats { tested, visible: tested - small, small };
    }
    if frustum_visible.len() == store.len() {
        // Every word of both is written below, and counted there.
        visible.resize_for_overwrite(store.len());
        occluded.resize_for_overwrite(store.len());
    } else {
        // A set of another size: the words past the shorter stay clear.
        visible.reset(store.len());
        occluded.reset(store.len());
    }
    let test = WordTest::new(store, view, pyramid, detail);
    let chunks = visible
        .words_mut()
        .par_chunks_mut(WORDS_PER_TASK)
        .zip(occluded.words_mut().par_chunks_mut(WORDS_PER_TASK))
        .zip(frustum_visible.words().par_chunks(WORDS_PER_TASK))
        .enumerate();
    parallel::region(|region| {
        chunks
            .map(|(chunk, ((visible_words, occluded_words), input_words))| {
                region.task(|| {
                    let mut stats = OcclusionStats::default();
                    let words = visible_words.iter_mut().zip(occluded_words.iter_mut()).zip(input_words);
                    for (i, ((visible_word, occluded_word), &input)) in words.enumerate() {
                        let base = (chunk * WORDS_PER_TASK + i) * 64;
                        let (kept, small) = test.word(base, input, input);
                        *visible_word = kept;
                        *occluded_word = input & !kept & !small;
                        stats.tested += input.count_ones() as usize;
                        stats.visible += kept.count_ones() as usize;
                        stats.small += small.count_ones() as usize;
                    }
                    stats
                })
            })
            .reduce(OcclusionStats::default, |a, b| OcclusionStats {
                tested: a.tested + b.tested,
                visible: a.visible + b.visible,
                small: a.small + b.small,
            })
    })
}

/// Re-tests only the objects in `slots` after their bounds changed, against the same view, pyramid and
/// `detail` as the [`test_occlusion`] call that filled `visible` and `occluded`; every other object keeps its
/// result. Each listed object ends up visible, occluded, or (outside `frustum_visible`, or small) neither,
/// exactly as a full test would leave it.
#[allow(clippy::too_many_arguments)]
pub fn retest_occlusion(
    store: &BoundsStore,
    frustum_visible: &VisibleSet,
    view: &ScreenView,
    pyramid: &DepthPyramid,
    detail: Option<&DetailTest>,
    slots: &[u32],
    visible: &mut VisibleSet,
    occluded: &mut VisibleSet,
) {
    let test = WordTest::new(store, view, pyramid, detail);
    let mut sorted = slots.to_vec();
    if !sorted.is_sorted() {
        sorted.sort_unstable();
    }
    for run in sorted.chunk_by(|a, b| a / 64 == b / 64) {
        let word = run[0] as usize / 64;
        let listed = run.iter().fold(0u64, |bits, &slot| bits | 1 << (slot % 64));
        let input = frustum_visible.words()[word] & listed;
        let (kept, small) = test.word(word * 64, input, frustum_visible.words()[word]);
        let (visible_word, occluded_word) = (&mut visible.words_mut()[word], &mut occluded.words_mut()[word]);
        *visible_word = (*visible_word & !listed) | kept;
        *occluded_word = (*occluded_word & !listed) | (input & !kept & !small);
    }
}

/// One view's test of a word of objects: what [`test_occlusion`] and [`retest_occlusion`] share.
struct WordTest<'a> {
    store: &'a BoundsStore,
    view: &'a ScreenView,
    pyramid: &'a DepthPyramid,
    detail: Option<&'a DetailTest>,
    /// The AVX2 projection was detected on this processor.
    avx2: bool,
}

impl<'a> WordTest<'a> {
    fn new(
        store: &'a BoundsStore,
        view: &'a ScreenView,
        pyramid: &'a DepthPyramid,
        detail: Option<&'a DetailTest>,
    ) -> Self {
        let avx2 = SimdBackend::Auto.resolve() == SimdBackend::Avx2;
        Self { store, view, pyramid, detail, avx2 }
    }

    /// Tests the objects set in `input`, the word of slots from `base`: returns the bits of those still
    /// visible, and of those detail culling drops. An empty pyramid hides nothing. A word whose frustum
    /// survivors (`survivors`, of which `input` is a subset) outnumber [`GROUP_TEST_ABOVE`] first tests its
    /// group's box: when that is hidden, so is every object in it. The choice depends on the survivors, not on
    /// `input`, so a re-test of some of them agrees with the full test.
    #[inline(always)]
    fn word(&self, base: usize, input: u64, survivors: u64) -> (u64, u64) {
        let Self { store, view, pyramid, detail, avx2 } = *self;
        let group = base / 64;
        let hides = pyramid.level_count() > 0;
        if hides && survivors.count_ones() as usize > GROUP_TEST_ABOVE && group_occluded(store, view, pyramid, group) {
            return (0, 0);
        }
        let small = detail.map_or(0, |detail| detail.small_in_word(store, group, input));
        let input = input & !small;
        let kept = match avx2 {
            _ if !hides => input,
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `avx2` is set only where AVX2 was detected.
            true => unsafe { test_word_avx2(store, view, pyramid, base, input) },
            _ => test_word(store, view, pyramid, base, input),
        };
        (kept, small)
    }
}

/// Whether `pyramid`, seen through `view`, hides the world box from `min` to `max` (its corners, which must
/// be finite): its screen rectangle and nearest depth, rounded so that the test culls only what the pyramid
/// provably hides, against the pyramid's texels as every object is tested. A box reaching the near plane is
/// never hidden; nor is anything by an empty pyramid.
pub fn box_occluded(view: &ScreenView, pyramid: &DepthPyramid, min: glam::Vec3, max: glam::Vec3) -> bool {
    if pyramid.level_count() == 0 {
        return false;
    }
    let half = (max - min) * 0.5;
    let centre = min + half;
    let half = half + (centre.abs() + half) * (4.0 * f32::EPSILON);
    let relative = centre - view.origin;
    let [rect] = project(view, &relative.to_array().map(|v| [v]), &half.to_array().map(|v| [v]));
    rect_occluded(&rect, pyramid)
}

/// Whether the box of group `group` (the slots of one bitset word) is hidden by the pyramid. Its centre and
/// half extent are rounded so that the box they give contains the group's corners.
fn group_occluded(store: &BoundsStore, view: &ScreenView, pyramid: &DepthPyramid, group: usize) -> bool {
    let GroupBounds { min, max } = store.groups()[group];
    box_occluded(view, pyramid, min, max)
}

/// [`test_word`] with the AVX2 projection.
///
/// # Safety
/// The processor must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn test_word_avx2(
    store: &BoundsStore,
    view: &ScreenView,
    pyramid: &DepthPyramid,
    base: usize,
    input: u64,
) -> u64 {
    // SAFETY: this function only runs where AVX2 is available.
    test_word_with(store, pyramid, base, input, |lanes| unsafe { avx2::project_boxes(store, view, base, lanes) })
}

/// Tests the objects set in `input`, the word of slots from `base`; returns the bits of those still visible.
fn test_word(store: &BoundsStore, view: &ScreenView, pyramid: &DepthPyramid, base: usize, input: u64) -> u64 {
    test_word_with(store, pyramid, base, input, |lanes| project_boxes(store, view, base, lanes))
}

#[inline(always)]
fn test_word_with(
    _store: &BoundsStore,
    pyramid: &DepthPyramid,
    _base: usize,
    input: u64,
    project: impl Fn(&[usize]) -> [ScreenRect; LANES],
) -> u64 {
    let mut kept = 0u64;
    let mut bits = input;
    while bits != 0 {
        let mut lanes = [0usize; LANES];
        let mut count = 0;
        while bits != 0 && count < LANES {
            lanes[count] = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            count += 1;
        }
        let rects = project(&lanes[..count]);
        for (lane, rect) in lanes[..count].iter().zip(&rects) {
            kept |= (!rect_occluded(rect, pyramid) as u64) << lane;
        }
    }
    kept
}

/// Projects up to 8 boxes (slots `base + lane`), one per SIMD lane.
///
/// The box's clip coordinates are its centre's plus or minus its reach along each clip axis (`|row| · extent`),
/// each widened by a bound on its rounding error. With `w > 0` over the whole box, `x / w` lies between the
/// quotients of those interval ends, which gives the screen rectangle with two reciprocals per box.
#[inline(always)]
fn project_boxes(store: &BoundsStore, view: &ScreenView, base: usize, lanes: &[usize]) -> [ScreenRect; LANES] {
    let soa = store.soa();
    let mut c = [[0f32; LANES]; 3];
    let mut e = [[0f32; LANES]; 3];
    for (i, &lane) in lanes.iter().enumerate() {
        let slot = base + lane;
        c[0][i] = soa.center_x[slot] - view.origin.x;
        c[1][i] = soa.center_y[slot] - view.origin.y;
        c[2][i] = soa.center_z[slot] - view.origin.z;
        e[0][i] = soa.extent_x[slot];
        e[1][i] = soa.extent_y[slot];
        e[2][i] = soa.extent_z[slot];
    }
    project(view, &c, &e)
}

/// The screen rectangles of `N` boxes, each given by its camera-relative centre `c[axis][i]` and half extent
/// `e[axis][i]`.
#[inline(always)]
fn project<const N: usize>(view: &ScreenView, c: &[[f32; N]; 3], e: &[[f32; N]; 3]) -> [ScreenRect; N] {
    let m = view.clip_from_relative_f32;
    let depth = view.depth_from_relative_f32();
    let orthographic = view.is_orthographic();
    let [x, y, w] = [0, 1, 3].map(|r| [m.x_axis[r], m.y_axis[r], m.z_axis[r], m.w_axis[r]]);
    // Per clip axis (x, y, w, and the depth row where it varies): centre value and reach, and the magnitude
    // that bounds rounding.
    let rows = [x, y, w, depth.to_array()];
    let axes = if orthographic { 4 } else { 3 };
    let mut centre = [[0f32; N]; 4];
    let mut reach = [[0f32; N]; 4];
    for (axis, row) in rows[..axes].iter().enumerate() {
        // Summed in the order of the AVX2 path, so both give the same rectangles.
        for i in 0..N {
            let value = row[3] + row[0] * c[0][i] + row[1] * c[1][i] + row[2] * c[2][i];
            let extent = 0.0 + row[0].abs() * e[0][i] + row[1].abs() * e[1][i] + row[2].abs() * e[2][i];
            let magnitude = row[3].abs()
                + row[0].abs() * c[0][i].abs()
                + row[1].abs() * c[1][i].abs()
                + row[2].abs() * c[2][i].abs()
                + extent;
            centre[axis][i] = value;
            reach[axis][i] = extent + PROJECTION_SLACK * magnitude;
        }
    }
    let (width, height) = (view.width as f32, view.height as f32);
    let mut rects = [ScreenRect::default(); N];
    for (i, rect) in rects.iter_mut().enumerate() {
        let w_min = centre[2][i] - reach[2][i];
        let w_max = centre[2][i] + reach[2][i];
        let (inv_near, inv_far) = (1.0 / w_min, 1.0 / w_max);
        // x / w over x in [lo, hi], w in [w_min, w_max], w > 0: the extreme quotients.
        let bounds = |lo: f32, hi: f32| {
            (lo * if lo < 0.0 { inv_near } else { inv_far }, hi * if hi > 0.0 { inv_near } else { inv_far })
        };
        let (min_x, max_x) = bounds(centre[0][i] - reach[0][i], centre[0][i] + reach[0][i]);
        let (min_y, max_y) = bounds(centre[1][i] - reach[1][i], centre[1][i] + reach[1][i]);
        // Written so that NaN falls on the visible side.
        let in_front = w_min > view.near * 0.5;
        let ordered = min_x <= max_x && min_y <= max_y;
        if !in_front || !ordered {
            rect.always_visible = true;
            continue;
        }
        let to_texel_x = |ndc: f32| ((ndc * 0.5 + 0.5) * width).clamp(0.0, width);
        let to_texel_y = |ndc: f32| ((0.5 - ndc * 0.5) * height).clamp(0.0, height);
        rect.x0 = floor(to_texel_x(min_x).into());
        rect.x1 = ceil(to_texel_x(max_x).into());
        rect.y0 = floor(to_texel_y(max_y).into());
        rect.y1 = ceil(to_texel_y(min_y).into());
        // A perspective view's depth is 1/w; an orthographic one's at most the depth row's largest value (w is
        // 1 within rounding, and w_min below it). Never 0 or less, which would read as hidden behind texels
        // no occluder covers.
        rect.nearest =
            if orthographic { (centre[3][i] + reach[3][i]).max(f32::MIN_POSITIVE) * inv_near } else { inv_near };
        // Off screen after clamping: the frustum test kept it by its slack; keeping it is free.
        rect.always_visible = rect.x0 >= rect.x1 || rect.y0 >= rect.y1;
    }
    rects
}

/// Whether `rect` is hidden by the pyramid.
///
/// Eq. 19.5 picks the level `l` where the rectangle spans at most 2x2 texels; the at most 3x3 texels it spans
/// one level finer, `l - 1`, are read (at level 0, its 2x2). A coarse texel holds the farthest depth of the
/// finer texels under it, so whatever level `l` hides `l - 1` hides too: reading `l` first only cost the
/// objects it did not hide four more reads (slower, the same objects kept: docs/performance.md). Fixed
/// windows (edge texels repeated) keep those reads free of data-dependent loops. Against a masked buffer, a
/// small rectangle is then tested pixel by pixel ([`DepthPyramid::blocks_hide`]). Last, the texels it spans
/// [`FINE_LEVELS`] below `l` (or level 0's) are read until one shows it: a rectangle whose edges only graze a
/// coarse texel that is not hidden is hidden there if the finer texels under it are. A visible object usually
/// stops at its first texels.
#[inline(always)]
fn rect_occluded(rect: &ScreenRect, pyramid: &DepthPyramid) -> bool {
    if rect.always_visible {
        return false;
    }
    let size = (rect.x1 - rect.x0).max(rect.y1 - rect.y0).max(1);
    // The rectangle is in pixels; level 0's texels may span several (a masked buffer's 4x4 blocks).
    let pixel_level = size.next_power_of_two().trailing_zeros().saturating_sub(pyramid.base().texel_shift());
    let coarse = (pixel_level as usize).min(pyramid.level_count() - 1);
    let first_read = match coarse {
        0 => farthest_in::<2>(rect, pyramid, 0),
        _ => farthest_in::<3>(rect, pyramid, coarse - 1),
    };
    rect.nearest < first_read
        || pyramid.blocks_hide([rect.x0, rect.y0, rect.x1, rect.y1], rect.nearest)
        // At `coarse` 1 the 3x3 texels of level 0 were all of the rectangle's.
        || (coarse > 1 && every_texel_hides(rect, pyramid, coarse.saturating_sub(FINE_LEVELS)))
}

/// Whether every texel of level `level` under `rect` is farther than its nearest depth, read row by row until
/// one is not.
#[inline(always)]
fn every_texel_hides(rect: &ScreenRect, pyramid: &DepthPyramid, level: usize) -> bool {
    let texels = pyramid.level(level);
    let width = texels.width() as usize;
    let [x0, y0, x1, y1] = rect.texels(texels.texel_shift());
    (y0..=y1).all(|y| {
        let row = &texels.texels()[y as usize * width..][..width];
        row[x0 as usize..=x1 as usize].iter().all(|&texel| rect.nearest < texel)
    })
}

/// The farthest depth among the texels of level `level` under `rect`, read as a `WINDOW` x `WINDOW` block from
/// its top-left texel (rows and columns past the rectangle repeat its last ones).
#[inline(always)]
fn farthest_in<const WINDOW: u32>(rect: &ScreenRect, pyramid: &DepthPyramid, level: usize) -> f32 {
    let texels = pyramid.level(level);
    let width = texels.width() as usize;
    let [x0, y0, x1, y1] = rect.texels(texels.texel_shift());
    let mut farthest = f32::INFINITY;
    for dy in 0..WINDOW {
        let start = (y0 + dy).min(y1) as usize * width;
        let row = &texels.texels()[start..start + width];
        for dx in 0..WINDOW {
            // A plain select, not `f32::min` (which pays to handle NaN): a NaN texel is skipped either way.
            farthest = farther(row[(x0 + dx).min(x1) as usize], farthest);
        }
    }
    farthest
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! The projection of [`super::project_boxes`], 8 boxes at once in AVX2 registers.
    use super::*;
    use std::arch::x86_64::*;

    /// # Safety
    /// The processor must support AVX2. (Slots are read with checked indexing: one past the store panics.)
    #[target_feature(enable = "avx2")]
    pub unsafe fn project_boxes(
        store: &BoundsStore,
        view: &ScreenView,
        base: usize,
        lanes: &[usize],
    ) -> [ScreenRect; LANES] {
        let mut gathered = [[0f32; LANES]; 6];
        let soa = store.soa();
        let arrays = [soa.center_x, soa.center_y, soa.center_z, soa.extent_x, soa.extent_y, soa.extent_z];
        if lanes.len() == LANES && lanes[LANES - 1] - lanes[0] == LANES - 1 {
            // Eight consecutive slots (a run of frustum survivors): one load per array.
            for (values, array) in gathered.iter_mut().zip(arrays) {
                values.copy_from_slice(&array[base + lanes[0]..][..LANES]);
            }
        } else {
            for (i, &lane) in lanes.iter().enumerate() {
                for (values, array) in gathered.iter_mut().zip(arrays) {
                    values[i] = array[base + lane];
                }
            }
        }
        // SAFETY: each array holds exactly the 8 lanes an unaligned load reads.
        let load = |values: &[f32; LANES]| unsafe { _mm256_loadu_ps(values.as_ptr()) };
        let splat = |value: f32| _mm256_set1_ps(value);
        let abs = |v: __m256| _mm256_andnot_ps(_mm256_set1_ps(-0.0), v);
        let c = [
            _mm256_sub_ps(load(&gathered[0]), splat(view.origin.x)),
            _mm256_sub_ps(load(&gathered[1]), splat(view.origin.y)),
            _mm256_sub_ps(load(&gathered[2]), splat(view.origin.z)),
        ];
        let e = [load(&gathered[3]), load(&gathered[4]), load(&gathered[5])];
        let m = view.clip_from_relative_f32;
        let orthographic = view.is_orthographic();
        let [x, y, w] = [0, 1, 3].map(|r| [m.x_axis[r], m.y_axis[r], m.z_axis[r], m.w_axis[r]]);
        let rows = [x, y, w, view.depth_from_relative_f32().to_array()];
        let axes = if orthographic { 4 } else { 3 };
        let mut centre = [_mm256_setzero_ps(); 4];
        let mut reach = [_mm256_setzero_ps(); 4];
        for (axis, row) in rows[..axes].iter().enumerate() {
            let mut value = splat(row[3]);
            let mut extent = _mm256_setzero_ps();
            let mut magnitude = splat(row[3].abs());
            for k in 0..3 {
                value = _mm256_add_ps(value, _mm256_mul_ps(splat(row[k]), c[k]));
                extent = _mm256_add_ps(extent, _mm256_mul_ps(splat(row[k].abs()), e[k]));
                magnitude = _mm256_add_ps(magnitude, _mm256_mul_ps(splat(row[k].abs()), abs(c[k])));
            }
            magnitude = _mm256_add_ps(magnitude, extent);
            centre[axis] = value;
            reach[axis] = _mm256_add_ps(extent, _mm256_mul_ps(splat(PROJECTION_SLACK), magnitude));
        }
        let w_min = _mm256_sub_ps(centre[2], reach[2]);
        let w_max = _mm256_add_ps(centre[2], reach[2]);
        let one = splat(1.0);
        let (inv_near, inv_far) = (_mm256_div_ps(one, w_min), _mm256_div_ps(one, w_max));
        let zero = _mm256_setzero_ps();
        // x / w over x in [lo, hi], w in [w_min, w_max], w > 0: the extreme quotients.
        let bounds = |axis: usize| {
            let lo = _mm256_sub_ps(centre[axis], reach[axis]);
            let hi = _mm256_add_ps(centre[axis], reach[axis]);
            let lo_scale = _mm256_blendv_ps(inv_far, inv_near, _mm256_cmp_ps::<_CMP_LT_OQ>(lo, zero));
            let hi_scale = _mm256_blendv_ps(inv_far, inv_near, _mm256_cmp_ps::<_CMP_GT_OQ>(hi, zero));
            (_mm256_mul_ps(lo, lo_scale), _mm256_mul_ps(hi, hi_scale))
        };
        let (min_x, max_x) = bounds(0);
        let (min_y, max_y) = bounds(1);
        // Ordered comparisons: NaN anywhere makes the lane invalid, so always visible.
        let valid = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GT_OQ>(w_min, splat(view.near * 0.5)),
            _mm256_and_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(min_x, max_x), _mm256_cmp_ps::<_CMP_LE_OQ>(min_y, max_y)),
        );
        let (width, height) = (splat(view.width as f32), splat(view.height as f32));
        let half = splat(0.5);
        let clamp = |v: __m256, limit: __m256| _mm256_min_ps(_mm256_max_ps(v, zero), limit);
        let to_x = |ndc: __m256| clamp(_mm256_mul_ps(_mm256_add_ps(_mm256_mul_ps(ndc, half), half), width), width);
        let to_y = |ndc: __m256| clamp(_mm256_mul_ps(_mm256_sub_ps(half, _mm256_mul_ps(ndc, half)), height), height);
        let x0 = _mm256_cvttps_epi32(_mm256_floor_ps(to_x(min_x)));
        let x1 = _mm256_cvttps_epi32(_mm256_ceil_ps(to_x(max_x)));
        let y0 = _mm256_cvttps_epi32(_mm256_floor_ps(to_y(max_y)));
        let y1 = _mm256_cvttps_epi32(_mm256_ceil_ps(to_y(min_y)));
        let nonempty = _mm256_and_si256(_mm256_cmpgt_epi32(x1, x0), _mm256_cmpgt_epi32(y1, y0));
        let visible_mask = !_mm256_movemask_ps(_mm256_and_ps(valid, _mm256_castsi256_ps(nonempty))) as u8;
        let store_i32 = |v: __m256i| {
            let mut out = [0i32; LANES];
            // SAFETY: `out` is 8 i32s, the 32 bytes the unaligned store writes.
            unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast(), v) };
            out
        };
        let (x0, x1, y0, y1) = (store_i32(x0), store_i32(x1), store_i32(y0), store_i32(y1));
        // As in the portable projection: 1/w, or the depth row's largest value over w.
        let nearest = if orthographic {
            let farthest_row = _mm256_max_ps(_mm256_add_ps(centre[3], reach[3]), splat(f32::MIN_POSITIVE));
            _mm256_mul_ps(farthest_row, inv_near)
        } else {
            inv_near
        };
        let mut nearest_lanes = [0f32; LANES];
        // SAFETY: `nearest_lanes` is 8 f32s, the 32 bytes the unaligned store writes.
        unsafe { _mm256_storeu_ps(nearest_lanes.as_mut_ptr(), nearest) };
        std::array::from_fn(|i| ScreenRect {
            x0: x0[i] as u32,
            x1: x1[i] as u32,
            y0: y0[i] as u32,
            y1: y1[i] as u32,
            nearest: nearest_lanes[i],
            always_visible: visible_mask >> i & 1 != 0,
        })
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::bounds::WorldBounds;
    use crate::camera::Camera;
    use crate::depth::DepthBuffer;
    use glam::Vec3;

    #[test]
    fn avx2_and_scalar_projections_agree() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("skipped: no AVX2 on this processor");
            return;
        }
        let mut store = BoundsStore::default();
        for i in 0..512u32 {
            let f = i as f32;
            let entity = bevy_ecs::entity::Entity::from_raw_u32(i + 1).unwrap();
            let bounds = WorldBounds::new(
                entity,
                Vec3::new((f * 0.37).sin() * 40.0, (f * 0.11).cos() * 10.0, -(f * 0.7) % 90.0 + 20.0),
                Vec3::new(0.1 + (f * 0.3) % 4.0, 0.2 + (f * 0.7) % 3.0, 0.05 + (f * 0.13) % 5.0),
            )
            .unwrap();
            store.insert(entity, &bounds).unwrap();
        }
        let camera = Camera::looking_at(Vec3::new(1.0, 2.0, 30.0), Vec3::new(0.0, 0.0, 0.0));
        // The camera's perspective view and a sun's orthographic cascade.
        let sun = crate::frustum::LightSource::Sun { direction: Vec3::new(0.3, -1.0, 0.2), splits: vec![0.1, 60.0] };
        let cascade = ScreenView::of_light_view(&sun.light_views(&camera).unwrap()[0], 128).unwrap();
        // Eight consecutive slots (loaded whole) and scattered ones (gathered lane by lane).
        let consecutive: Vec<usize> = (0..LANES).collect();
        let scattered = [1, 4, 5, 9, 12, 30, 63];
        for view in [ScreenView::new(&camera, 256, 144), cascade] {
            for base in (0..512).step_by(64) {
                for lanes in [&consecutive[..], &scattered[..]] {
                    let scalar = project_boxes(&store, &view, base, lanes);
                    // SAFETY: AVX2 was detected above; the slots exist.
                    let simd = unsafe { avx2::project_boxes(&store, &view, base, lanes) };
                    for (a, b) in scalar.iter().zip(&simd).take(lanes.len()) {
                        assert_eq!(a.always_visible, b.always_visible);
                        if !a.always_visible {
                            assert_eq!(a, b);
                        }
                    }
                }
            }
        }
    }

    proptest::proptest! {
        /// On a pyramid of random occluder patches, a rectangle is culled only if every texel of level 0 under
        /// it is farther than its nearest depth; and where the finest read reaches level 0 (rectangles up to
        /// `2^FINE_LEVELS` texels a side), exactly then.
        #[test]
        fn the_rectangle_test_is_conservative_and_exact_up_to_its_finest_level(
            patches in proptest::collection::vec((0u32..100, 0u32..60, 1u32..40, 1u32..30, 0.05f32..1.0), 1..12),
            rects in proptest::collection::vec((0u32..100, 0u32..60, 1u32..48, 1u32..48, 0.0f32..1.0), 32),
        ) {
            let (width, height) = (100, 60);
            let mut base = DepthBuffer::new(width, height);
            for &(x, y, w, h, depth) in &patches {
                for yy in y..(y + h).min(height) {
                    for xx in x..(x + w).min(width) {
                        let texel = &mut base.texels_mut()[(yy * width + xx) as usize];
                        *texel = texel.max(depth);
                    }
                }
            }
            let mut pyramid = DepthPyramid::default();
            pyramid.build(&base);
            for &(x0, y0, w, h, nearest) in &rects {
                let (x1, y1) = ((x0 + w).min(width), (y0 + h).min(height));
                let rect = ScreenRect { x0, y0, x1, y1, nearest, always_visible: false };
                let exact = (y0..y1).all(|y| (x0..x1).all(|x| nearest < base.get(x, y)));
                let culled = rect_occluded(&rect, &pyramid);
                proptest::prop_assert!(!culled || exact, "culled {rect:?}, which a texel shows");
                if (x1 - x0).max(y1 - y0) <= 1 << FINE_LEVELS {
                    proptest::prop_assert_eq!(culled, exact, "{:?}", rect);
                }
            }
        }
    }
}
