//! Occluder shadow frusta (after Hudson et al., the reference texts' seeds 002 and 004): each frame, for the
//! occluders the depth-buffer stage would choose, the region each one hides from the eye as a set of planes,
//! and every frustum survivor wholly inside one such region culled. No depth buffer, no raster: a test of a
//! box against a few planes. Without occluder fusion, an object hidden only by two occluders together stays.
//!
//! # The region an occluder hides
//! A closed convex occluder (every edge shared by two triangles, every vertex on the inner side of every
//! face) gives one region; any other, one region for each of its triangles that faces the eye (no fusion
//! between them either). For a closed convex occluder seen from an eye outside it, a point is hidden where it
//! lies
//! - inside the *cone* from the eye over the occluder: the intersection of the half-spaces bounded by the
//!   planes through the eye and an edge of the occluder that have every vertex on one side (the supporting
//!   planes; the silhouette edges' are among them, and every facet of the cone is one of them), and
//! - on the inner side of every face that faces the eye: the ray from the eye to the point enters the
//!   occluder through one of those faces, so the point lies beyond the occluder's surface there, which lies
//!   inside the geometry it stands for.
//!
//! A single triangle facing the eye hides the points inside the planes through the eye and its edges and
//! behind its own plane: the ray to such a point crosses the triangle. One facing away hides nothing, as
//! neither the occluder raster nor the draw pass draws back faces.
//!
//! Every plane is built in f64 around the eye, and a box must clear each by a margin well above the
//! rounding of its test, so the culler is conservative: it never removes an object a rendering shows.
//!
//! Occluders are binned into a grid over the screen by the rectangle their vertices project to; a box can be
//! inside a region only where its centre is, so each box is tested against the regions of its centre's cell
//! only.

use super::adaptive::BenefitGate;
use super::{AdaptiveSettings, CullScene, Culled, Culler, ViewStats};
use crate::bounds::{BoundsStore, SoaSlices};
use crate::camera::Camera;
use crate::frustum::SimdBackend;
use crate::frustum::{FrustumOptions, cull_frustum};
use crate::occluders::{NO_NEIGHBOUR, OccluderInstance, select_occluders};
use crate::parallel::{self, Stage};
use crate::visible::VisibleSet;
use glam::{DMat4, DVec3, DVec4, Vec3};
use rayon::prelude::*;
use std::time::Instant;

/// Cells per side of the screen grid the regions are binned into.
const GRID: usize = 32;
/// How far (relative to the occluder's size and the plane's scale) a vertex may lie outside a face's plane or
/// on the wrong side of an edge's plane and still count as on it: the rounding of the f64 transform.
const PLANE_TOLERANCE: f64 = 1e-9;
/// How far inside each plane a box must lie, relative to the size of the test's terms (the box's distance and
/// size, the plane's offset, its normal of unit length): far above the rounding of the f32 test and of its
/// inputs (about a dozen roundings of 2^-24 each), far below any distance a rendering resolves.
const TEST_MARGIN: f32 = 4e-6;
/// Planes a block of [`PlaneBlock`] holds: one AVX register of f32.
const LANES: usize = 8;
/// Objects a rayon task tests.
const TASK_OBJECTS: usize = 1024;

/// What [`ShadowFrustaCuller`] culls with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadowFrustaSettings {
    /// Occluder triangles per frame: the occluders chosen as the depth-buffer stage chooses them
    /// ([`crate::occluders::select_occluders`]), best first while they fit.
    pub triangle_budget: usize,
    /// When the regions are skipped for removing too little lately: the occlusion stage's benefit gate
    /// ([`AdaptiveSettings::min_occlusion_benefit`], its frames and re-probes); [`AdaptiveSettings::fixed`]
    /// never skips.
    pub adaptive: AdaptiveSettings,
}

impl Default for ShadowFrustaSettings {
    /// The depth-buffer stage's default budget ([`super::OcclusionSettings::default`]) and benefit gate.
    fn default() -> Self {
        let triangle_budget = super::OcclusionSettings::default().triangle_budget;
        Self { triangle_budget, adaptive: AdaptiveSettings::default() }
    }
}

/// The frustum stage, then the occluders' shadow frusta (see the module documentation): a [`Culler`] that is
/// conservative at any resolution. Keeps its visible sets from frame to frame, nothing else.
///
/// # Example
/// ```
/// use cullet::culler::{CullScene, Culler, ShadowFrustaCuller};
/// # use bevy_ecs::prelude::*;
/// # use cullet::prelude::*;
/// # use glam::{Affine3A, Vec3};
/// # let (mut world, mut schedule) = (World::new(), Schedule::default());
/// # cullet::install(&mut world, &mut schedule, PipelineSettings::default());
/// # world.insert_resource(Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z));
/// # schedule.run(&mut world);
/// let mut culler = ShadowFrustaCuller::default();
/// let camera = *world.resource::<Camera>();
/// let culled = culler.cull(&CullScene::new(&world), &camera);
/// println!("kept {} of {}", culled.kept().count(), culled.stats.objects);
/// ```
#[derive(Clone, Debug, Default)]
pub struct ShadowFrustaCuller {
    /// What it culls with; change it between frames.
    pub settings: ShadowFrustaSettings,
    frustum_visible: VisibleSet,
    visible: VisibleSet,
    /// Skips the regions where they have removed too little lately.
    gate: BenefitGate,
}

impl ShadowFrustaCuller {
    /// A culler with `settings`.
    pub fn new(settings: ShadowFrustaSettings) -> Self {
        Self { settings, ..Self::default() }
    }
}

impl Culler for ShadowFrustaCuller {
    fn name(&self) -> String {
        format!("shadow frusta {}", self.settings.triangle_budget)
    }

    fn is_conservative(&self, _viewport: (u32, u32)) -> bool {
        true
    }

    fn cull(&mut self, scene: &CullScene, camera: &Camera) -> Culled<'_> {
        let store = scene.store();
        let mut stats = ViewStats { objects: store.len(), ..ViewStats::default() };
        let start = Instant::now();
        match camera.frustum() {
            Ok(frustum) => {
                let _stage = Stage::Frustum.enter();
                cull_frustum(store, &frustum, FrustumOptions::default(), &mut self.frustum_visible);
            }
            Err(error) => {
                stats.frustum_error = Some(error);
                self.frustum_visible = VisibleSet::all(store.len());
            }
        }
        stats.after_frustum = self.frustum_visible.count();
        stats.frustum_time = start.elapsed();
        self.visible.clone_from(&self.frustum_visible);
        stats.occlusion_gated = stats.frustum_error.is_none() && self.gate.skip_this_frame();
        if stats.frustum_error.is_none() && !stats.occlusion_gated {
            let start = Instant::now();
            let stage = Stage::Raster.enter();
            let chosen = select_occluders(
                store,
                &self.frustum_visible,
                camera.position,
                self.settings.triangle_budget,
                |slot| scene.occluder_of(slot),
            );
            let frusta = ShadowFrusta::new(&chosen, camera);
            let chosen_none = chosen.is_empty();
            drop(stage);
            (stats.occluders, stats.occluder_triangles) = (frusta.rects.len(), frusta.triangles);
            stats.raster_time = start.elapsed();
            let start = Instant::now();
            if !frusta.rects.is_empty() {
                let _stage = Stage::Occlusion.enter();
                for slot in frusta.hidden(store, &self.frustum_visible) {
                    self.visible.set(slot as usize, false);
                }
            }
            stats.occlusion_time = start.elapsed();
            // A frame without occluders says nothing of what the regions are worth here.
            if !chosen_none {
                let removed = stats.after_frustum - self.visible.count();
                self.gate.record_occlusion(removed, stats.after_frustum, &self.settings.adaptive);
            }
        }
        stats.after_occlusion = self.visible.count();
        Culled { stages: vec![("frustum", &self.frustum_visible), ("shadow frusta", &self.visible)], stats }
    }
}

/// Up to [`LANES`] half-spaces `n.x + d >= 0` of one region, lane by lane, in f32, to test a box against all of
/// them at once: the normals (of unit length) and their absolute values, and the offsets less the test's
/// margin for their size. Unused lanes always pass.
#[derive(Clone, Copy, Debug)]
struct PlaneBlock {
    normal: [[f32; LANES]; 3],
    normal_abs: [[f32; LANES]; 3],
    offset: [f32; LANES],
}

impl PlaneBlock {
    /// `planes` (at most [`LANES`]) as a block.
    fn new(planes: &[DVec4]) -> Self {
        let mut block = Self { normal: [[0.0; LANES]; 3], normal_abs: [[0.0; LANES]; 3], offset: [f32::MAX; LANES] };
        for (lane, plane) in planes.iter().enumerate() {
            for axis in 0..3 {
                block.normal[axis][lane] = plane[axis] as f32;
                block.normal_abs[axis][lane] = (plane[axis] as f32).abs();
            }
            block.offset[lane] = (plane.w - f64::from(TEST_MARGIN) * plane.w.abs()) as f32;
        }
        block
    }

    /// Whether the box of `centre` and half-extents `extent` (around the eye) lies inside every plane by
    /// `margin` more than [`TEST_MARGIN`] of the plane's offset. Branch free, so that it runs lane-parallel.
    #[inline(always)]
    fn holds(&self, centre: [f32; 3], extent: [f32; 3], margin: f32) -> bool {
        let mut inside = 0u32;
        for lane in 0..LANES {
            let [nx, ny, nz] = [self.normal[0][lane], self.normal[1][lane], self.normal[2][lane]];
            let [ax, ay, az] = [self.normal_abs[0][lane], self.normal_abs[1][lane], self.normal_abs[2][lane]];
            let least = nx * centre[0] + ny * centre[1] + nz * centre[2] + self.offset[lane]
                - (ax * extent[0] + ay * extent[1] + az * extent[2]);
            // NaN counts as outside.
            inside += u32::from(least >= margin);
        }
        inside == LANES as u32
    }
}

/// The shadow frusta of one frame, binned over the screen.
struct ShadowFrusta {
    /// Each region's half-spaces, [`LANES`] to a block: region `r`'s blocks are
    /// `blocks[block_starts[r]..block_starts[r + 1]]`.
    blocks: Vec<PlaneBlock>,
    block_starts: Vec<usize>,
    /// Each region's rectangle in normalized device coordinates `[x0, x1, y0, y1]`, widened for rounding: the
    /// projection of every point inside it lies in it.
    rects: Vec<[f64; 4]>,
    /// The regions whose screen rectangle reaches cell `c` (row-major, [`GRID`] by [`GRID`]):
    /// `cells[starts[c]..starts[c + 1]]`.
    cells: Vec<u32>,
    starts: Vec<usize>,
    /// The occluders' triangles, summed.
    triangles: usize,
    eye: DVec3,
    /// Rows `x`, `y` and `w` of the camera's clip-from-relative matrix.
    clip_rows: [DVec4; 3],
}

impl ShadowFrusta {
    /// The regions `occluders` hide from `camera`'s eye: one for a closed convex occluder the eye is outside
    /// of, else one for each of its triangles that faces the eye; none that reaches behind the eye.
    fn new(occluders: &[(u32, OccluderInstance<'_>)], camera: &Camera) -> Self {
        let eye = camera.position.as_dvec3();
        let clip_from_relative = camera.clip_from_relative_f64();
        let regions_of = |instance: &OccluderInstance| {
            let vertices = relative_vertices(instance, eye);
            let regions = match region_planes(instance, &vertices) {
                Some(planes) => vec![(planes, vertices, instance.occluder.triangle_count())],
                None => triangle_regions(instance, &vertices),
            };
            let on_screen = |(planes, corners, triangles): (Vec<DVec4>, Vec<DVec3>, usize)| {
                Some((planes, screen_rect(&corners, &clip_from_relative)?, triangles))
            };
            regions.into_iter().filter_map(on_screen).collect::<Vec<_>>()
        };
        let built: Vec<(Vec<DVec4>, [f64; 4], usize)> = parallel::region(|region| {
            occluders.par_iter().flat_map_iter(|(_, instance)| region.task(|| regions_of(instance))).collect()
        });
        let cells_of = |&[x0, x1, y0, y1]: &[f64; 4]| [grid_index(x0), grid_index(x1), grid_index(y0), grid_index(y1)];
        let mut starts = vec![0; GRID * GRID + 1];
        for (_, rect, _) in &built {
            let [x0, x1, y0, y1] = cells_of(rect);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    starts[y * GRID + x + 1] += 1;
                }
            }
        }
        for cell in 0..GRID * GRID {
            starts[cell + 1] += starts[cell];
        }
        let (mut next, mut cells) = (starts.clone(), vec![0; starts[GRID * GRID]]);
        for (region, (_, rect, _)) in built.iter().enumerate() {
            let [x0, x1, y0, y1] = cells_of(rect);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    cells[next[y * GRID + x]] = region as u32;
                    next[y * GRID + x] += 1;
                }
            }
        }
        let triangles = built.iter().map(|(_, _, triangles)| triangles).sum();
        let rects = built.iter().map(|(_, rect, _)| *rect).collect();
        let mut block_starts = vec![0];
        let mut blocks = Vec::new();
        for (planes, _, _) in &built {
            blocks.extend(planes.chunks(LANES).map(PlaneBlock::new));
            block_starts.push(blocks.len());
        }
        let clip_rows = [0, 1, 3].map(|r| clip_from_relative.row(r));
        Self { blocks, block_starts, rects, cells, starts, triangles, eye, clip_rows }
    }

    /// The store slots of `visible` whose boxes lie wholly inside one region, in parallel.
    fn hidden(&self, store: &BoundsStore, visible: &VisibleSet) -> Vec<u32> {
        let slots: Vec<u32> = visible.iter().map(|slot| slot as u32).collect();
        let soa = store.soa();
        let avx2 = SimdBackend::Auto.resolve() == SimdBackend::Avx2;
        parallel::region(|region| {
            let hidden_of = |chunk: &[u32]| region.task(|| self.hidden_of_with_backend(avx2, &soa, chunk));
            slots.par_chunks(TASK_OBJECTS).flat_map_iter(hidden_of).collect()
        })
    }

    /// [`ShadowFrusta::hidden_of`], compiled for AVX2 where `avx2` (detected on this processor): a block's
    /// lanes then run in one register. The arithmetic is the same, so both keep the same objects.
    fn hidden_of_with_backend(&self, avx2: bool, soa: &SoaSlices<'_>, slots: &[u32]) -> Vec<u32> {
        match avx2 {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `avx2` is set only where AVX2 was detected.
            true => unsafe { self.hidden_of_avx2(soa, slots) },
            _ => self.hidden_of(soa, slots),
        }
    }

    /// [`ShadowFrusta::hidden_of`] with AVX2 enabled.
    ///
    /// # Safety
    /// The processor must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn hidden_of_avx2(&self, soa: &SoaSlices<'_>, slots: &[u32]) -> Vec<u32> {
        self.hidden_of(soa, slots)
    }

    /// The store slots of `slots` whose boxes lie wholly inside one region.
    #[inline(always)]
    fn hidden_of(&self, soa: &SoaSlices<'_>, slots: &[u32]) -> Vec<u32> {
        let bounds = |i: usize| {
            let centre = DVec3::new(soa.center_x[i].into(), soa.center_y[i].into(), soa.center_z[i].into());
            let extent = DVec3::new(soa.extent_x[i].into(), soa.extent_y[i].into(), soa.extent_z[i].into());
            (centre - self.eye, extent)
        };
        slots
            .iter()
            .copied()
            .filter(|&slot| {
                let (centre, extent) = bounds(slot as usize);
                self.box_hidden(centre, extent)
            })
            .collect()
    }

    /// Whether the box of `centre` (around the eye) and half-extents `extent` lies wholly inside one region.
    #[inline(always)]
    fn box_hidden(&self, centre: DVec3, extent: DVec3) -> bool {
        let Some((x, y)) = self.project(centre) else {
            return false;
        };
        let cell = grid_index(y) * GRID + grid_index(x);
        // The planes have unit normals, so this bounds the size of the box's terms of a test.
        let margin = TEST_MARGIN * (centre.abs() + extent).element_sum() as f32;
        let (centre, extent) = (centre.as_vec3().to_array(), extent.as_vec3().to_array());
        self.cells[self.starts[cell]..self.starts[cell + 1]].iter().any(|&region| {
            let region = region as usize;
            let [x0, x1, y0, y1] = self.rects[region];
            (x0 <= x) & (x <= x1) & (y0 <= y) & (y <= y1)
                && self.blocks[self.block_starts[region]..self.block_starts[region + 1]]
                    .iter()
                    .all(|block| block.holds(centre, extent, margin))
        })
    }

    /// The normalized device coordinates `point` (around the eye) projects to; `None` where it is not in front
    /// of the eye, so in no region (every region lies in front of it).
    #[inline(always)]
    fn project(&self, point: DVec3) -> Option<(f64, f64)> {
        let row = |r: usize| self.clip_rows[r].truncate().dot(point) + self.clip_rows[r].w;
        let w = row(2);
        if w.is_nan() || w <= 0.0 {
            return None;
        }
        Some((row(0) / w, row(1) / w))
    }
}

/// The grid column (or row) of a normalized device coordinate, clamped to the grid: clamping keeps a point
/// inside a rectangle in the cells the rectangle is clamped to.
fn grid_index(ndc: f64) -> usize {
    let cell = ((ndc + 1.0) * 0.5 * GRID as f64).floor();
    if cell.is_nan() { 0 } else { cell.clamp(0.0, (GRID - 1) as f64) as usize }
}

/// The occluder's distinct vertices in world space around the eye, in f64.
fn relative_vertices(instance: &OccluderInstance<'_>, eye: DVec3) -> Vec<DVec3> {
    let linear = glam::Mat3::from(instance.transform.matrix3).as_dmat3();
    let translation = DVec3::from(Vec3::from(instance.transform.translation)) - eye;
    instance.occluder.indexed().0.iter().map(|p| linear * p.as_dvec3() + translation).collect()
}

/// The half-spaces of the region the occluder (its `vertices` around the eye) hides from the eye: the
/// supporting planes through the eye and its edges, and the inner sides of the faces facing the eye. `None`
/// where it is not closed, not convex, degenerate, or where the eye is not outside it.
fn region_planes(instance: &OccluderInstance<'_>, vertices: &[DVec3]) -> Option<Vec<DVec4>> {
    let occluder = instance.occluder;
    if occluder.triangle_count() == 0 || occluder.neighbours().contains(&NO_NEIGHBOUR) {
        return None;
    }
    let corners = occluder.indexed().1;
    let (min, max) =
        vertices.iter().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let (size, reach) = ((max - min).length(), min.abs().max(max.abs()).length());
    if !(size > 0.0 && reach.is_finite()) {
        return None;
    }
    // A mirroring transform turns counter-clockwise faces clockwise.
    let outward = if glam::Mat3::from(instance.transform.matrix3).determinant() < 0.0 { -1.0 } else { 1.0 };
    let mut planes = Vec::new();
    for triangle in corners.chunks_exact(3) {
        let [a, b, c] = [0, 1, 2].map(|k| vertices[triangle[k] as usize]);
        let normal = outward * (b - a).cross(c - a);
        let scale = normal.length();
        if !scale.is_normal() {
            continue; // No face: its neighbours' planes bound the occluder there.
        }
        let d = -normal.dot(a);
        let tolerance = PLANE_TOLERANCE * scale * (size + reach);
        if vertices.iter().any(|&v| normal.dot(v) + d > tolerance) {
            return None; // Not convex.
        }
        // The eye (the origin) outside the face's plane: the face faces it.
        if d > tolerance {
            planes.push((-normal).extend(-d));
        }
    }
    if planes.is_empty() {
        return None; // The eye is inside the occluder, or on its surface.
    }
    let faces = planes.len();
    for triangle in corners.chunks_exact(3) {
        for k in 0..3 {
            let (i, j) = (triangle[k], triangle[(k + 1) % 3]);
            // Each edge once: its two triangles list it in opposite directions.
            if i > j {
                continue;
            }
            let normal = vertices[i as usize].cross(vertices[j as usize]);
            let scale = normal.length();
            if !scale.is_normal() {
                continue; // The edge points at the eye: no plane through both.
            }
            let tolerance = PLANE_TOLERANCE * scale * reach;
            let (mut above, mut below) = (false, false);
            for &v in vertices {
                let side = normal.dot(v);
                above |= side > tolerance;
                below |= side < -tolerance;
            }
            match (above, below) {
                (true, false) => planes.push(normal.extend(0.0)),
                (false, true) => planes.push((-normal).extend(0.0)),
                (false, false) => return None, // The occluder is flat and seen edge-on.
                (true, true) => {}             // An edge inside the cone.
            }
        }
    }
    // A cone needs at least three sides.
    if planes.len() < faces + 3 {
        return None;
    }
    for plane in &mut planes {
        *plane /= plane.truncate().length();
    }
    // The triangles of one face give one plane (within far less than the test's margin).
    let mut distinct: Vec<DVec4> = Vec::with_capacity(planes.len());
    for plane in planes {
        let same = |other: &DVec4| (plane - *other).abs().max_element() <= PLANE_TOLERANCE * (1.0 + plane.w.abs());
        if !distinct.iter().any(same) {
            distinct.push(plane);
        }
    }
    Some(distinct)
}

/// The region each triangle of the occluder (its `vertices` around the eye) that faces the eye hides: the
/// planes through the eye and its edges, and the inner side of its own plane (seen from the eye, what lies
/// behind it), each with the triangle's corners and a count of one triangle. A triangle facing away hides
/// nothing: neither the occluder raster nor the draw pass draws back faces.
fn triangle_regions(instance: &OccluderInstance<'_>, vertices: &[DVec3]) -> Vec<(Vec<DVec4>, Vec<DVec3>, usize)> {
    let outward = if glam::Mat3::from(instance.transform.matrix3).determinant() < 0.0 { -1.0 } else { 1.0 };
    let mut regions = Vec::new();
    for triangle in instance.occluder.indexed().1.chunks_exact(3) {
        let corners = [0, 1, 2].map(|k| vertices[triangle[k] as usize]);
        let [a, b, c] = corners;
        let normal = outward * (b - a).cross(c - a);
        let d = -normal.dot(a);
        let reach = a.length().max(b.length()).max(c.length());
        let scale = normal.length();
        // Facing the eye (the origin) by more than rounding, and not degenerate.
        if !scale.is_normal() || d <= PLANE_TOLERANCE * scale * reach {
            continue;
        }
        let mut planes = vec![(-normal).extend(-d)];
        for k in 0..3 {
            let (p, q, other) = (corners[k], corners[(k + 1) % 3], corners[(k + 2) % 3]);
            let edge = p.cross(q);
            let side = edge.dot(other);
            // The third corner on the plane through the eye and this edge: seen edge-on, it hides nothing.
            if !edge.length().is_normal() || side.abs() <= PLANE_TOLERANCE * edge.length() * reach {
                planes.clear();
                break;
            }
            planes.push(if side > 0.0 { edge } else { -edge }.extend(0.0));
        }
        if planes.is_empty() {
            continue;
        }
        for plane in &mut planes {
            *plane /= plane.truncate().length();
        }
        regions.push((planes, corners.to_vec(), 1));
    }
    regions
}

/// The rectangle `[x0, x1, y0, y1]` in normalized device coordinates that the vertices' projections span,
/// widened for rounding; `None` where a vertex is not in front of the eye (the region would reach around it).
fn screen_rect(vertices: &[DVec3], clip_from_relative: &DMat4) -> Option<[f64; 4]> {
    let (mut min, mut max) = (glam::DVec2::INFINITY, glam::DVec2::NEG_INFINITY);
    for &v in vertices {
        let clip = *clip_from_relative * v.extend(1.0);
        let least = PLANE_TOLERANCE * v.length();
        if clip.w.is_nan() || clip.w <= least {
            return None;
        }
        let ndc = clip.truncate().truncate() / clip.w;
        (min, max) = (min.min(ndc), max.max(ndc));
    }
    let widen = 1e-6;
    Some([min.x - widen, max.x + widen, min.y - widen, max.y + widen])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::occluders::Occluder;
    use glam::Affine3A;

    /// A unit cube's triangles, counter-clockwise seen from outside.
    fn cube() -> Occluder {
        let p = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) - Vec3::splat(0.5);
        let faces = [
            [p(0., 0., 1.), p(1., 0., 1.), p(1., 1., 1.), p(0., 1., 1.)],
            [p(1., 0., 0.), p(0., 0., 0.), p(0., 1., 0.), p(1., 1., 0.)],
            [p(0., 0., 0.), p(0., 0., 1.), p(0., 1., 1.), p(0., 1., 0.)],
            [p(1., 0., 1.), p(1., 0., 0.), p(1., 1., 0.), p(1., 1., 1.)],
            [p(0., 1., 1.), p(1., 1., 1.), p(1., 1., 0.), p(0., 1., 0.)],
            [p(0., 0., 0.), p(1., 0., 0.), p(1., 0., 1.), p(0., 0., 1.)],
        ];
        Occluder::new(faces.iter().flat_map(|[a, b, c, d]| [*a, *b, *c, *a, *c, *d]).collect::<Vec<_>>())
    }

    fn planes_of(occluder: &Occluder, transform: Affine3A, eye: Vec3) -> Option<Vec<DVec4>> {
        let instance = OccluderInstance { occluder, transform };
        region_planes(&instance, &relative_vertices(&instance, eye.as_dvec3()))
    }

    fn inside(planes: &[DVec4], point: DVec3) -> bool {
        planes.iter().all(|plane| plane.truncate().dot(point) + plane.w >= 0.0)
    }

    /// Seen face on, a cube hides the points straight behind it, not those beside, before or inside it.
    #[test]
    fn a_cube_hides_what_lies_behind_it() {
        let cube = cube();
        let eye = Vec3::new(0.0, 0.0, 10.0);
        let planes = planes_of(&cube, Affine3A::IDENTITY, eye).expect("a closed convex occluder");
        let relative = |p: Vec3| (p - eye).as_dvec3();
        assert!(inside(&planes, relative(Vec3::new(0.0, 0.0, -5.0))));
        assert!(inside(&planes, relative(Vec3::new(0.4, 0.4, -1.0))));
        assert!(!inside(&planes, relative(Vec3::new(0.0, 2.0, -5.0))));
        assert!(!inside(&planes, relative(Vec3::new(0.0, 0.0, 2.0))));
        assert!(!inside(&planes, relative(Vec3::new(0.0, 0.0, 0.6))));
    }

    /// Behind a wall of cubes, a grid of boxes: the AVX2 and portable tests keep the same ones, and hide some.
    #[test]
    fn the_avx2_test_agrees_with_the_portable_one() {
        use bevy_ecs::entity::Entity;
        let cube = cube();
        let camera = Camera::looking_at(Vec3::new(0.3, 1.2, 20.0), Vec3::new(0.0, 0.0, -10.0));
        let walls: Vec<(u32, OccluderInstance)> = (0..9)
            .map(|i| {
                let transform = Affine3A::from_scale_rotation_translation(
                    Vec3::new(3.0, 4.0, 1.0),
                    glam::Quat::from_rotation_y(0.1 * i as f32),
                    Vec3::new(i as f32 * 3.5 - 14.0, 0.0, 0.0),
                );
                (i, OccluderInstance { occluder: &cube, transform })
            })
            .collect();
        let frusta = ShadowFrusta::new(&walls, &camera);
        let mut store = BoundsStore::default();
        for i in 0..2000u32 {
            let entity = Entity::from_raw_u32(i + 1).unwrap();
            let centre =
                Vec3::new((i % 50) as f32 * 0.7 - 17.0, (i / 50 % 8) as f32 * 0.6 - 2.0, -1.0 - (i / 400) as f32 * 3.3);
            let half = Vec3::new(0.1 + (i % 7) as f32 * 0.05, 0.2, 0.15);
            store.insert(entity, &crate::WorldBounds::new(entity, centre, half).unwrap()).unwrap();
        }
        let slots: Vec<u32> = (0..2000).collect();
        let portable = frusta.hidden_of(&store.soa(), &slots);
        assert!(portable.len() > 100 && portable.len() < 2000, "{} hidden", portable.len());
        if SimdBackend::Auto.resolve() == SimdBackend::Avx2 {
            assert_eq!(frusta.hidden_of_with_backend(true, &store.soa(), &slots), portable);
        }
    }

    /// A lone triangle facing the eye hides what lies behind it within its edges; facing away, nothing.
    #[test]
    fn a_triangle_facing_the_eye_hides_what_lies_behind_it() {
        let triangle =
            Occluder::new(vec![Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)]);
        let instance = OccluderInstance { occluder: &triangle, transform: Affine3A::IDENTITY };
        let eye = DVec3::new(0.0, 0.0, 5.0);
        let regions = triangle_regions(&instance, &relative_vertices(&instance, eye));
        assert_eq!(regions.len(), 1);
        let planes = &regions[0].0;
        assert!(inside(planes, DVec3::new(0.0, 0.0, -10.0) - eye));
        assert!(!inside(planes, DVec3::new(0.0, 0.0, 1.0) - eye));
        assert!(!inside(planes, DVec3::new(3.0, 0.0, -10.0) - eye));
        let behind = DVec3::new(0.0, 0.0, -5.0);
        assert!(triangle_regions(&instance, &relative_vertices(&instance, behind)).is_empty());
    }

    /// Open, non-convex or surrounding the eye, an occluder gives no region; mirrored, it gives the same one.
    #[test]
    fn only_closed_convex_occluders_outside_the_eye_give_a_region() {
        let cube = cube();
        let eye = Vec3::new(3.0, 1.0, 10.0);
        let open = Occluder::new(cube.triangles()[..30].to_vec());
        assert!(planes_of(&open, Affine3A::IDENTITY, eye).is_none());
        let mut dented = cube.triangles().to_vec();
        for v in dented.iter_mut().filter(|v| **v == Vec3::splat(0.5)) {
            *v = Vec3::splat(0.2);
        }
        assert!(planes_of(&Occluder::new(dented), Affine3A::IDENTITY, eye).is_none());
        assert!(planes_of(&cube, Affine3A::IDENTITY, Vec3::new(0.1, 0.0, 0.0)).is_none());
        let mirrored = planes_of(&cube, Affine3A::from_scale(Vec3::new(-2.0, 1.0, 1.0)), eye).unwrap();
        let scaled = planes_of(&cube, Affine3A::from_scale(Vec3::new(2.0, 1.0, 1.0)), eye).unwrap();
        for point in [DVec3::new(-3.0, -1.0, -20.0), DVec3::new(-3.0, 1.0, -20.0), DVec3::new(-4.1, -1.0, -20.0)] {
            assert_eq!(inside(&mirrored, point), inside(&scaled, point), "{point}");
        }
    }
}
