//! The texel loops of the per-texel modes: pixel- and texel-centre sampling, and the conservative mode's
//! whole-texel coverage of an occluder's union (its boundary segments, or its hull's lines where convex), each
//! compiled once portable and once for AVX2 with the same arithmetic.

use super::binning::Band;
use super::setup::{EVAL_MARGIN, SetupOccluder, SetupTriangle, TexelRect};
use crate::depth::{farther, nearer};

/// Per-occluder working memory of the conservative mode, over the occluder's rectangle within a band.
#[derive(Default)]
pub(super) struct Scratch {
    /// Some triangle covers the texel centre (1, else 0: 32 bits, as the depths, so that the texel loop
    /// vectorizes).
    pub(super) covered: Vec<u32>,
    /// A boundary segment touches the texel.
    pub(super) blocked: Vec<bool>,
    /// The farthest depth of every triangle that may overlap the texel.
    pub(super) farthest: Vec<f32>,
    /// Each row's columns drawn.
    pub(super) runs: Vec<(u32, u32)>,
}

/// [`raster_centres`], compiled for AVX2 where `avx2` (detected on this processor): its texel loop then runs 8
/// lanes wide. The arithmetic is the same (Rust never fuses a multiply and an add by itself), so both give the
/// same texels.
#[inline]
pub(super) fn raster_centres_with_backend(avx2: bool, triangles: &[SetupTriangle], band: Band<'_>) {
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
pub(super) unsafe fn raster_centres_avx2(triangles: &[SetupTriangle], band: Band<'_>) {
    raster_centres(triangles, band)
}

/// Centre-sampled modes ([`RasterMode::PixelCentres`](super::RasterMode::PixelCentres),
/// [`RasterMode::Fast`](super::RasterMode::Fast)): each triangle writes its depth at the texel centre wherever
/// its three edge tests pass there.
#[inline(always)]
pub(super) fn raster_centres(triangles: &[SetupTriangle], band: Band<'_>) {
    for tri in triangles {
        let rect = band.clip(tri.rect);
        if rect.is_empty() {
            continue;
        }
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
pub(super) fn candidate_columns(a: [f32; 3], rows: [f32; 3], lo: u32, hi: u32) -> (u32, u32) {
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
pub(super) const COLUMN_OFFSETS: [f32; 8] = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];

/// Raises each texel of `row` (whose first column is `x0`) whose centre passes the three edge tests
/// `a[i]*x + rows[i] >= 0` to the plane depth `p*x + rz` where that is nearer. Groups of 8 columns go through
/// fixed-width loops the compiler vectorizes; every test and depth is the same f32 expression as for a single
/// texel (`x0 + k` is exact in f32 for any buffer width).
#[inline(always)]
pub(super) fn write_covered(row: &mut [f32], x0: u32, a: [f32; 3], rows: [f32; 3], p: f32, rz: f32) {
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
#[inline]
pub(super) fn raster_union_with_backend(avx2: bool, occluder: &SetupOccluder, band: Band<'_>, scratch: &mut Scratch) {
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
pub(super) unsafe fn raster_union_avx2(occluder: &SetupOccluder, band: Band<'_>, scratch: &mut Scratch) {
    raster_union(occluder, band, scratch)
}

/// Conservative mode: a texel is written when the occluder's front faces cover its centre and no boundary
/// segment of their union touches it (so the union covers it whole), with the farthest depth of every
/// triangle that may overlap it. An occluder whose boundary bounds a convex region is drawn from its lines
/// instead ([`raster_hull`]), where that decides.
#[inline(always)]
pub(super) fn raster_union(occluder: &SetupOccluder, mut band: Band<'_>, scratch: &mut Scratch) {
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
pub(super) fn raster_hull(occluder: &SetupOccluder, band: Band<'_>, rect: TexelRect, scratch: &mut Scratch) -> bool {
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
pub(super) fn draw_triangles<const CENTRES: bool>(
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
pub(super) const SEGMENT_GROW: f64 = 1e-3;

/// Marks every texel of `rect` that the segment touches, each texel grown by a margin for rounding.
#[inline(always)]
pub(super) fn block_segment(segment: &[f64; 4], rect: TexelRect, w: usize, blocked: &mut [bool]) {
    block_segment_rows(segment, rect, segment_rows(segment, rect), w, blocked);
}

/// The rows of `rect` a segment can touch: those its height reaches, a row more each side. Ends that are not
/// finite keep every row, as [`block_segment_rows`] blocks them all.
#[inline(always)]
pub(super) fn segment_rows(segment: &[f64; 4], rect: TexelRect) -> std::ops::Range<u32> {
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
pub(super) fn block_segment_rows(
    segment: &[f64; 4],
    rect: TexelRect,
    rows: std::ops::Range<u32>,
    w: usize,
    blocked: &mut [bool],
) {
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
