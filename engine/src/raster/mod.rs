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

use crate::depth::{DepthPyramid, ScreenView};
use crate::frustum::SimdBackend;
use crate::occluders::OccluderInstance;
use crate::parallel;
use rayon::prelude::*;
use std::sync::OnceLock;

mod binning;
mod masked;
mod setup;
mod texels;

use binning::{BAND_ROWS, BLOCK_COLUMNS, Band, Bins, band_levels, reduce_band};
pub(crate) use setup::TexelRect;
use setup::{PendingOccluder, SetupScratch, screen_bound};
use texels::{Scratch, raster_centres_with_backend, raster_union_with_backend};

/// Occluders a task bounds on screen: each takes a projection of its box, so tasks of one would cost more
/// to time and schedule than to run.
const BOUND_OCCLUDERS_PER_TASK: usize = 64;

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
/// Each band clears its rows just before rasterizing them and reduces them into the next levels right
/// after, while they are in its core's cache; the few rows above are reduced once every band is done.
pub fn rasterize(
    view: &ScreenView,
    occluders: &[OccluderInstance<'_>],
    mode: RasterMode,
    pyramid: &mut DepthPyramid,
) -> RasterStats {
    rasterize_within(view, occluders, mode, None, pyramid)
}

/// [`rasterize`], drawing only the texels within `scissor` where it is given: every texel outside it holds
/// [`HIDDEN_OUTSIDE_SCISSOR`], nearer than any depth, so the pyramid hides everything there. Only for a caller
/// that tests nothing that could be seen outside the scissor. The masked mode draws the whole buffer: `scissor`
/// must be `None` there.
pub(crate) fn rasterize_within(
    view: &ScreenView,
    occluders: &[OccluderInstance<'_>],
    mode: RasterMode,
    scissor: Option<TexelRect>,
    pyramid: &mut DepthPyramid,
) -> RasterStats {
    debug_assert!(scissor.is_none() || mode != RasterMode::Masked, "the masked raster has no scissor");
    let whole = TexelRect::whole(view.width, view.height);
    let within = match scissor.map(|scissor| scissor.intersect(whole)) {
        Some(_) if mode == RasterMode::Masked => whole,
        Some(scissor) if scissor.is_empty() => TexelRect { x0: 0, x1: 0, y0: 0, y1: 0 },
        Some(scissor) => scissor,
        None => whole,
    };
    let bounded: Vec<(f32, TexelRect, &OccluderInstance)> = parallel::region(|region| {
        occluders
            .par_chunks(BOUND_OCCLUDERS_PER_TASK)
            .flat_map_iter(|chunk| {
                region.task(|| {
                    let bound = |instance| {
                        let (rect, nearest) = screen_bound(view, instance)?;
                        let rect = rect.intersect(within);
                        (!rect.is_empty()).then_some((nearest, rect, instance))
                    };
                    chunk.iter().filter_map(bound).collect::<Vec<_>>()
                })
            })
            .collect()
    });
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
        rasterize_texels(view, &pending, mode, within, pyramid);
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

/// The depth [`rasterize_within`] leaves outside its scissor: nearer than any surface.
const HIDDEN_OUTSIDE_SCISSOR: f32 = f32::INFINITY;

/// Draws `pending` (nearest first) into a buffer of one texel per pixel of `view`, level 0 of `pyramid`, within
/// `scissor` ([`HIDDEN_OUTSIDE_SCISSOR`] elsewhere), and reduces the levels above.
fn rasterize_texels(
    view: &ScreenView,
    pending: &[PendingOccluder],
    mode: RasterMode,
    scissor: TexelRect,
    pyramid: &mut DepthPyramid,
) {
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
    parallel::region(|region| {
        bands.for_each_init(scratches, |(scratch, setup_scratch, blocks), (band, (mut rows, bin))| {
            region.task(|| {
                let texels = &mut *rows[0];
                let band_y0 = (band * BAND_ROWS) as u32;
                for (row, y) in texels.chunks_exact_mut(width).zip(band_y0..) {
                    let (x0, x1) = if (scissor.y0..scissor.y1).contains(&y) {
                        (scissor.x0 as usize, scissor.x1 as usize)
                    } else {
                        (0, 0)
                    };
                    row[..x0].fill(HIDDEN_OUTSIDE_SCISSOR);
                    row[x0..x1].fill(0.0);
                    row[x1..].fill(HIDDEN_OUTSIDE_SCISSOR);
                }
                blocks.fill(0.0);
                let band_y1 = band_y0 + (texels.len() / width) as u32;
                let mut band = Band { scissor, ..Band::new(texels, width, band_y0, band_y1) };
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
            })
        })
    });
    pyramid.reduce_from(fused);
}

#[cfg(test)]
mod tests {
    use super::setup::*;
    use super::texels::*;
    use super::*;
    use crate::{Camera, Occluder, mesh::Mesh};
    use glam::{Affine3A, Quat};
    use glam::{DVec3, Vec3};
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

        /// Within a scissor, the raster writes the texels the whole buffer's raster writes there, however many
        /// bands the scissor spans; outside it, every texel hides everything.
        #[test]
        fn a_scissor_draws_what_the_whole_buffer_does_within_it_and_hides_the_rest(
            scale in prop::array::uniform3(0.5f32..20.0),
            angles in prop::array::uniform3(-3.2f32..3.2),
            offset in prop::array::uniform3(-15.0f32..15.0),
            corners in prop::array::uniform4(0u32..220),
        ) {
            let (camera, occluder, transform) = placed_cube(scale, angles, offset);
            let (near, far) = (Affine3A::from_translation(Vec3::Z * 10.0) * transform, transform);
            let occluders = [near, far].map(|transform| OccluderInstance { occluder: &occluder, transform });
            let view = ScreenView::new(&camera, 203, 117);
            let scissor = TexelRect {
                x0: corners[0].min(corners[1]),
                x1: corners[0].max(corners[1]),
                y0: corners[2].min(corners[3]),
                y1: corners[2].max(corners[3]),
            };
            for mode in [RasterMode::Conservative, RasterMode::PixelCentres] {
                let (mut whole, mut within) = (DepthPyramid::default(), DepthPyramid::default());
                rasterize(&view, &occluders, mode, &mut whole);
                rasterize_within(&view, &occluders, mode, Some(scissor), &mut within);
                let inside = scissor.intersect(TexelRect::whole(view.width, view.height));
                for (y, x) in (0..view.height).flat_map(|y| (0..view.width).map(move |x| (y, x))) {
                    let texel = within.base().get(x, y);
                    if (inside.x0..inside.x1).contains(&x) && (inside.y0..inside.y1).contains(&y) {
                        prop_assert_eq!(texel.to_bits(), whole.base().get(x, y).to_bits(), "{:?} {} {}", mode, x, y);
                    } else {
                        prop_assert_eq!(texel, HIDDEN_OUTSIDE_SCISSOR, "{:?} {} {}", mode, x, y);
                    }
                }
            }
        }

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
                    let band = Band::new(&mut texels, view.width as usize, 0, view.height);
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
                    let band = Band::new(rows, view.width as usize, y0, y1);
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
