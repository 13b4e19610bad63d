//! Stage 4, occlusion test: each frustum survivor's box against the [`DepthPyramid`] of the occluder raster.
//!
//! Per object: project the 8 corners of its box (8 objects a step, SIMD-friendly lanes), take the screen
//! rectangle and the nearest depth (`1/w` of its nearest corner); a box reaching the near plane is visible.
//! Pick the mip level of eq. 19.5 of seed 000, where the rectangle covers at most 2x2 texels; the object is
//! occluded if its nearest depth is farther than the farthest occluder depth of those texels. If that is
//! inconclusive, the test is repeated one level finer (at most 3x3 texels).
//!
//! Projection runs in f32; the rectangle is widened and the depth moved nearer by a bound on its rounding
//! error, so the test culls only what the pyramid provably hides.

use crate::bounds::BoundsStore;
use crate::raster::{DepthPyramid, ScreenView};
use crate::visible::VisibleSet;
use rayon::prelude::*;

const LANES: usize = 8;
/// Relative rounding slack of the f32 projection (a few hundred times its error bound).
const PROJECTION_SLACK: f32 = 1.0 / (1 << 16) as f32;

/// Counts from one occlusion test.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OcclusionStats {
    /// Objects tested (the frustum survivors).
    pub tested: usize,
    /// Objects found visible.
    pub visible: usize,
    /// Objects decided at the coarse level (the rest needed the finer level or were visible).
    pub decided_coarse: usize,
}

/// Where a box lands on the screen: texel rectangle `x0..x1`, `y0..y1` of level 0, and its nearest `1/w`.
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

/// Tests every object set in `frustum_visible` and writes the survivors to `visible` and the hidden ones to
/// `occluded` (both resized to the store). Parallel over words of 64 objects.
pub fn test_occlusion(
    store: &BoundsStore,
    frustum_visible: &VisibleSet,
    view: &ScreenView,
    pyramid: &DepthPyramid,
    visible: &mut VisibleSet,
    occluded: &mut VisibleSet,
) -> OcclusionStats {
    visible.reset(store.len());
    occluded.reset(store.len());
    if pyramid.level_count() == 0 {
        visible.clone_from(frustum_visible);
        let tested = frustum_visible.count();
        return OcclusionStats { tested, visible: tested, decided_coarse: 0 };
    }
    let (tested, coarse) = visible
        .words_mut()
        .par_chunks_mut(16)
        .zip(occluded.words_mut().par_chunks_mut(16))
        .zip(frustum_visible.words().par_chunks(16))
        .enumerate()
        .map(|(chunk, ((visible_words, occluded_words), input_words))| {
            let mut tested = 0;
            let mut coarse = 0;
            for (i, ((visible_word, occluded_word), &input)) in
                visible_words.iter_mut().zip(occluded_words.iter_mut()).zip(input_words).enumerate()
            {
                let base = (chunk * 16 + i) * 64;
                let (kept, decided) = test_word(store, view, pyramid, base, input);
                *visible_word = kept;
                *occluded_word = input & !kept;
                tested += input.count_ones() as usize;
                coarse += decided;
            }
            (tested, coarse)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    OcclusionStats { tested, visible: visible.count(), decided_coarse: coarse }
}

/// Tests the objects of one 64-object word; returns the bits of those still visible and how many were
/// decided at the coarse level.
fn test_word(store: &BoundsStore, view: &ScreenView, pyramid: &DepthPyramid, base: usize, input: u64) -> (u64, usize) {
    let mut kept = 0u64;
    let mut decided = 0;
    let mut bits = input;
    while bits != 0 {
        let mut lanes = [0usize; LANES];
        let mut count = 0;
        while bits != 0 && count < LANES {
            lanes[count] = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            count += 1;
        }
        let rects = project_boxes(store, view, base, &lanes[..count]);
        for (lane, rect) in lanes[..count].iter().zip(&rects) {
            let (occluded, coarse) = rect_occluded(rect, pyramid);
            decided += coarse as usize;
            if !occluded {
                kept |= 1 << lane;
            }
        }
    }
    (kept, decided)
}

/// Projects up to 8 boxes (slots `base + lane`), one per SIMD lane.
fn project_boxes(store: &BoundsStore, view: &ScreenView, base: usize, lanes: &[usize]) -> [ScreenRect; LANES] {
    let mut cx = [0f32; LANES];
    let mut cy = [0f32; LANES];
    let mut cz = [0f32; LANES];
    let mut ex = [0f32; LANES];
    let mut ey = [0f32; LANES];
    let mut ez = [0f32; LANES];
    for (i, &lane) in lanes.iter().enumerate() {
        let slot = base + lane;
        cx[i] = store.center_x[slot] - view.origin.x;
        cy[i] = store.center_y[slot] - view.origin.y;
        cz[i] = store.center_z[slot] - view.origin.z;
        ex[i] = store.extent_x[slot];
        ey[i] = store.extent_y[slot];
        ez[i] = store.extent_z[slot];
    }
    let m = view.clip_from_relative_f32;
    let row = |r: usize| [m.x_axis[r], m.y_axis[r], m.z_axis[r], m.w_axis[r]];
    let (rx, ry, rw) = (row(0), row(1), row(3));

    let mut rects = [ScreenRect::default(); LANES];
    for i in 0..LANES {
        // Clip coordinates of the centre and the reach of the box along each clip axis.
        let dot = |r: [f32; 4]| r[0] * cx[i] + r[1] * cy[i] + r[2] * cz[i] + r[3];
        let reach = |r: [f32; 4]| r[0].abs() * ex[i] + r[1].abs() * ey[i] + r[2].abs() * ez[i];
        let magnitude = |r: [f32; 4]| {
            r[0].abs() * (cx[i].abs() + ex[i])
                + r[1].abs() * (cy[i].abs() + ey[i])
                + r[2].abs() * (cz[i].abs() + ez[i])
                + r[3].abs()
        };
        let (wc, wr) = (dot(rw), reach(rw));
        // Every clip coordinate is off by at most `slack` from its exact value.
        let slack = PROJECTION_SLACK * (magnitude(rx) + magnitude(ry) + magnitude(rw));
        let w_min = wc - wr - slack;
        let mut min_x = f32::INFINITY;
        let mut max_x = f32::NEG_INFINITY;
        let mut min_y = f32::INFINITY;
        let mut max_y = f32::NEG_INFINITY;
        for corner in 0..8 {
            let s = |bit: usize| if corner & bit == 0 { -1.0 } else { 1.0 };
            let p = [cx[i] + s(1) * ex[i], cy[i] + s(2) * ey[i], cz[i] + s(4) * ez[i]];
            let x = rx[0] * p[0] + rx[1] * p[1] + rx[2] * p[2] + rx[3];
            let y = ry[0] * p[0] + ry[1] * p[1] + ry[2] * p[2] + ry[3];
            let w = rw[0] * p[0] + rw[1] * p[1] + rw[2] * p[2] + rw[3];
            // The widest NDC interval any (x, w) within `slack` of this corner can give, w > 0 assumed.
            let (w_lo, w_hi) = (w - slack, w + slack);
            for (lo, hi, value) in [(&mut min_x, &mut max_x, x), (&mut min_y, &mut max_y, y)] {
                let (v_lo, v_hi) = (value - slack, value + slack);
                *lo = lo.min(v_lo / if v_lo < 0.0 { w_lo } else { w_hi });
                *hi = hi.max(v_hi / if v_hi > 0.0 { w_lo } else { w_hi });
            }
        }
        let rect = &mut rects[i];
        // Written so that NaN falls on the visible side.
        let in_front = w_min > view.near * 0.5;
        let ordered = min_x <= max_x && min_y <= max_y;
        if !in_front || !ordered {
            rect.always_visible = true;
            continue;
        }
        let (width, height) = (view.width as f32, view.height as f32);
        let to_texel_x = |ndc: f32| ((ndc * 0.5 + 0.5) * width).clamp(0.0, width);
        let to_texel_y = |ndc: f32| ((0.5 - ndc * 0.5) * height).clamp(0.0, height);
        rect.x0 = to_texel_x(min_x).floor() as u32;
        rect.x1 = to_texel_x(max_x).ceil() as u32;
        rect.y0 = to_texel_y(max_y).floor() as u32;
        rect.y1 = to_texel_y(min_y).ceil() as u32;
        rect.nearest = 1.0 / w_min;
        // Off screen after clamping: the frustum test kept it by its slack; keeping it is free.
        rect.always_visible = rect.x0 >= rect.x1 || rect.y0 >= rect.y1;
    }
    rects
}

/// Whether `rect` is hidden by the pyramid, and whether the coarse level decided it.
fn rect_occluded(rect: &ScreenRect, pyramid: &DepthPyramid) -> (bool, bool) {
    if rect.always_visible {
        return (false, false);
    }
    let size = (rect.x1 - rect.x0).max(rect.y1 - rect.y0).max(1);
    // Eq. 19.5: the lowest level at which the rectangle spans at most 2x2 texels.
    let coarse = (size.next_power_of_two().trailing_zeros() as usize).min(pyramid.level_count() - 1);
    let hidden_at = |level: usize| {
        let farthest =
            pyramid.farthest(level, rect.x0 >> level, rect.y0 >> level, (rect.x1 - 1) >> level, (rect.y1 - 1) >> level);
        rect.nearest < farthest
    };
    if hidden_at(coarse) {
        (true, true)
    } else if coarse > 0 && hidden_at(coarse - 1) {
        (true, false)
    } else {
        (false, false)
    }
}
