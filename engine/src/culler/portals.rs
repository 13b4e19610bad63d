//! Cells and portals (seed 000 section 19.5): the view narrowed through each portal it sees, recursively, and
//! each cell's objects tested against the narrowed view; then the occlusion stage over what the portals kept.
//!
//! Each portal's vertices are clipped to the near plane and projected; the box around them on screen,
//! intersected with the rectangle the portal is seen through, is the rectangle of the region behind it. A
//! region reached through several portals (or around a cycle of cells) keeps the box around its rectangles,
//! grown until nothing grows: a traversal of finitely many steps, however the cells are joined. The regions
//! the view starts in are every cell within the near plane's reach of the eye (both rooms, in a doorway), and
//! the outside unless one cell's box holds that reach whole.
//!
//! Why nothing visible is lost, under the contract of [`crate::cells`]: a visible point is seen along a ray from
//! the near plane; the ray leaves each region it crosses through a portal, at a point beyond the near plane,
//! which the clipped portal's projection holds; so the point's pixel lies in every rectangle along the way, and
//! its object, listed in every region its box touches, is tested against a view that holds it.
//!
//! The same argument bounds the occlusion stage's work from inside the cells: an object listed in no region
//! the view starts in is seen, if at all, within the rectangle around the regions seen through portals, so for
//! those objects the buffer is drawn within that rectangle only and hides everything outside it.

use super::adaptive::BenefitGate;
use super::{
    AdaptiveSettings, CullScene, Culled, Culler, OcclusionSettings, StoreChange, ViewStats, frustum_or_keep_everything,
};
use crate::bounds::{BoundsStore, SIMD_LANES};
use crate::camera::Camera;
use crate::cells::Cells;
use crate::depth::{DepthPyramid, ScreenView};
use crate::frustum::{Frustum, FrustumOptions, cull_frustum};
use crate::occlusion::occlude_within;
use crate::parallel::{self, Stage};
use crate::raster::{RasterMode, TexelRect};
use crate::visible::{SharedVisibleSet, VisibleSet};
use glam::{DMat4, DVec2, DVec3, DVec4};
use rayon::prelude::*;
use std::time::Instant;

/// Slots of a region tested by one rayon task.
const SLOTS_PER_TASK: usize = 4096;

/// Objects the portal stage keeps below which a frame's growth does not reopen the occlusion stage's gate.
const MIN_REOPEN_GROWTH: usize = 32;

/// Margin added to every side of a projected portal's rectangle, in NDC units: covers the rounding of the
/// projection, which is in f64 from f32 vertices.
const RECT_MARGIN: f64 = 1e-6;

/// What the portal culler culls with.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PortalSettings {
    /// The occlusion stage run over what the portals keep (`enabled: false` for the portals alone).
    pub occlusion: OcclusionSettings,
    /// When occlusion is skipped for removing too little of what the portals keep lately: the occlusion
    /// stage's benefit gate ([`AdaptiveSettings::min_occlusion_benefit`], its frames and re-probes);
    /// [`AdaptiveSettings::fixed`] never skips.
    pub adaptive: AdaptiveSettings,
}

/// Counts of the last frame's traversal.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PortalStats {
    /// Regions (cells and the outside) the view started in.
    pub start_regions: usize,
    /// Regions seen, those it started in included.
    pub regions_seen: usize,
    /// Regions in the scene: its cells and the outside; 1 for a world without [`Cells`].
    pub regions: usize,
    /// Portals looked through (whose rectangle grew the region behind them).
    pub portals_passed: usize,
    /// Region memberships looked at: each object once per seen region it is listed in (of these, the objects
    /// that pass the camera's frustum in a region seen through portals are tested again, against its narrowed
    /// view).
    pub objects_tested: usize,
}

/// A rectangle of the screen in normalized device coordinates, `min` to `max`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Rect {
    min: DVec2,
    max: DVec2,
}

impl Rect {
    const SCREEN: Rect = Rect { min: DVec2::splat(-1.0), max: DVec2::splat(1.0) };

    fn intersect(self, other: Rect) -> Option<Rect> {
        let (min, max) = (self.min.max(other.min), self.max.min(other.max));
        (min.x <= max.x && min.y <= max.y).then_some(Rect { min, max })
    }

    fn union(self, other: Rect) -> Rect {
        Rect { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    fn contains(self, other: Rect) -> bool {
        self.min.cmple(other.min).all() && self.max.cmpge(other.max).all()
    }

    /// The texels of `view`'s buffer the rectangle reaches, a texel more each side for rounding.
    fn texels(self, view: &ScreenView) -> TexelRect {
        let (width, height) = (view.width as f64, view.height as f64);
        let x = |ndc: f64| ((ndc * 0.5 + 0.5) * width).clamp(0.0, width);
        let y = |ndc: f64| ((0.5 - ndc * 0.5) * height).clamp(0.0, height);
        let (x0, x1) = ((x(self.min.x) - 1.0).max(0.0), (x(self.max.x) + 1.0).min(width));
        let (y0, y1) = ((y(self.max.y) - 1.0).max(0.0), (y(self.min.y) + 1.0).min(height));
        TexelRect { x0: x0.floor() as u32, x1: x1.ceil() as u32, y0: y0.floor() as u32, y1: y1.ceil() as u32 }
    }

    /// The camera's clip-from-relative matrix narrowed to this rectangle: its x and y remapped so that the
    /// rectangle spans -1 to 1.
    fn narrow(self, clip_from_relative: DMat4) -> DMat4 {
        // Degenerate rectangles keep a sliver of width, so the remap stays finite.
        let size = (self.max - self.min).max(DVec2::splat(1e-9));
        let scale = 2.0 / size;
        let offset = -(self.min + self.max) / size;
        let remap = DMat4::from_cols(
            DVec4::new(scale.x, 0.0, 0.0, 0.0),
            DVec4::new(0.0, scale.y, 0.0, 0.0),
            DVec4::Z,
            DVec4::new(offset.x, offset.y, 0.0, 1.0),
        );
        remap * clip_from_relative
    }
}

/// Per object, the regions its box touches, and per region its objects.
#[derive(Clone, Debug, Default)]
struct Membership {
    of_slot: Vec<Vec<u32>>,
    of_region: Vec<Vec<u32>>,
}

impl Membership {
    fn build(store: &BoundsStore, cells: &Cells) -> Self {
        let regions_of = |slot: usize| {
            let mut regions = Vec::new();
            if let Some((min, max)) = slot_box(store, slot) {
                cells.regions_of_box(min, max, &mut regions);
            } else {
                regions.push(cells.outside() as u32);
            }
            regions
        };
        let of_slot = parallel::map_range(store.len(), SLOTS_PER_TASK, regions_of);
        let mut of_region = vec![Vec::new(); cells.region_count()];
        for (slot, regions) in of_slot.iter().enumerate() {
            for &region in regions {
                of_region[region as usize].push(slot as u32);
            }
        }
        Self { of_slot, of_region }
    }

    /// Lists `slots` again where their boxes now lie.
    fn moved(&mut self, store: &BoundsStore, cells: &Cells, slots: &[u32]) {
        let mut regions = Vec::new();
        for &slot in slots {
            regions.clear();
            match slot_box(store, slot as usize) {
                Some((min, max)) => cells.regions_of_box(min, max, &mut regions),
                None => regions.push(cells.outside() as u32),
            }
            let Some(old) = self.of_slot.get_mut(slot as usize) else { continue };
            if *old == regions {
                continue;
            }
            for &region in old.iter() {
                let members = &mut self.of_region[region as usize];
                if let Some(at) = members.iter().position(|&member| member == slot) {
                    members.swap_remove(at);
                }
            }
            for &region in &regions {
                self.of_region[region as usize].push(slot);
            }
            old.clone_from(&regions);
        }
    }
}

/// The box of the object in `slot`, or `None` for a slot not stored or not finite.
fn slot_box(store: &BoundsStore, slot: usize) -> Option<(glam::Vec3, glam::Vec3)> {
    let bounds = store.get(slot)?;
    let (min, max) = (bounds.center - bounds.half_extent, bounds.center + bounds.half_extent);
    (min.is_finite() && max.is_finite()).then_some((min, max))
}

/// What the view sees of the regions this frame.
struct Traversal {
    /// The rectangle each region is seen through (`None` for a region not seen).
    seen: Vec<Option<Rect>>,
    /// Whether the view starts in each region (seen whole, not through portals).
    started: Vec<bool>,
    stats: PortalStats,
}

/// The regions the view sees, and through which rectangles.
fn traverse(cells: &Cells, camera: &Camera) -> Traversal {
    let mut stats = PortalStats { regions: cells.region_count(), ..PortalStats::default() };
    let mut seen: Vec<Option<Rect>> = vec![None; cells.region_count()];
    let eye = camera.position;
    // The farthest point of the near plane from the eye: what the view shows starts within this distance.
    let half_height = (0.5 * camera.fov_y as f64).tan();
    let reach = (camera.near as f64 * (1.0 + half_height * half_height * (1.0 + (camera.aspect as f64).powi(2))).sqrt())
        as f32
        * 1.001
        + 1e-6 * eye.abs().max_element();
    let mut held_whole = false;
    let mut queue = Vec::new();
    for (index, cell) in cells.cells().iter().enumerate() {
        let near =
            |(min, max): &(glam::Vec3, glam::Vec3)| eye.cmpge(*min - reach).all() && eye.cmple(*max + reach).all();
        if cell.boxes.iter().any(near) {
            seen[index] = Some(Rect::SCREEN);
            queue.push(index);
        }
        held_whole |=
            cell.boxes.iter().any(|(min, max)| eye.cmpge(*min + reach).all() && eye.cmple(*max - reach).all());
    }
    if !held_whole {
        seen[cells.outside()] = Some(Rect::SCREEN);
        queue.push(cells.outside());
    }
    stats.start_regions = queue.len();
    let mut started = vec![false; cells.region_count()];
    queue.iter().for_each(|&region| started[region] = true);

    let view_from_relative = camera.view_from_relative_f64();
    let clip_from_view = camera.clip_from_view_f64();
    let mut portal_rects: Vec<Option<Option<Rect>>> = vec![None; cells.portals().len()];
    let mut in_view = Vec::new();
    while let Some(region) = queue.pop() {
        let Some(through) = seen[region] else { continue };
        for (index, portal) in cells.portals_of(region) {
            let rect = *portal_rects[index].get_or_insert_with(|| {
                let near = camera.near as f64;
                project_portal(&portal.vertices, eye, &view_from_relative, &clip_from_view, near, &mut in_view)
            });
            let Some(rect) = rect.and_then(|rect| rect.intersect(through)) else { continue };
            let behind = cells.across(portal, region);
            let grown = match seen[behind] {
                Some(old) if old.contains(rect) => continue,
                Some(old) => old.union(rect),
                None => rect,
            };
            seen[behind] = Some(grown);
            stats.portals_passed += 1;
            if !queue.contains(&behind) {
                queue.push(behind);
            }
        }
    }
    stats.regions_seen = seen.iter().flatten().count();
    Traversal { seen, started, stats }
}

/// The screen rectangle of a portal's vertices clipped to the near plane, in NDC with a margin; `None` where
/// all of it lies nearer than the near plane.
fn project_portal(
    vertices: &[glam::Vec3],
    eye: glam::Vec3,
    view_from_relative: &DMat4,
    clip_from_view: &DMat4,
    near: f64,
    in_view: &mut Vec<DVec3>,
) -> Option<Rect> {
    in_view.clear();
    in_view
        .extend(vertices.iter().map(|vertex| view_from_relative.transform_point3(vertex.as_dvec3() - eye.as_dvec3())));
    // Depth along the view direction: -z in a right-handed view.
    let depth = |p: &DVec3| -p.z;
    let mut rect = Rect { min: DVec2::splat(f64::INFINITY), max: DVec2::splat(f64::NEG_INFINITY) };
    let mut add = |point: DVec3| {
        let clip = *clip_from_view * point.extend(1.0);
        let ndc = DVec2::new(clip.x, clip.y) / clip.w;
        (rect.min, rect.max) = (rect.min.min(ndc), rect.max.max(ndc));
    };
    // The convex hull's part beyond the near plane is spanned by its vertices there and the crossings of every
    // segment between a vertex beyond and one before it.
    let mut beyond_near = false;
    for a in in_view.iter().filter(|p| depth(p) >= near) {
        beyond_near = true;
        add(*a);
        for b in in_view.iter().filter(|p| depth(p) < near) {
            let t = (depth(a) - near) / (depth(a) - depth(b));
            let mut crossing = a.lerp(*b, t);
            crossing.z = -near;
            add(crossing);
        }
    }
    if !beyond_near {
        return None;
    }
    let margin = DVec2::splat(RECT_MARGIN) + (rect.max.abs().max(rect.min.abs())) * 1e-9;
    let rect = Rect { min: rect.min - margin, max: rect.max + margin };
    (rect.min.is_finite() && rect.max.is_finite()).then_some(rect)
}

/// Culls through cells and portals ([`crate::cells`]), then runs the occlusion stage over what they keep: the
/// occluders chosen among the objects of the cells seen, so the cells behind closed walls cost neither tests
/// nor raster. Where the view starts only in cells, the stage tests only the objects seen through portals and
/// draws its occluders only within the rectangle those are seen through; the objects of the cells around the
/// eye are kept untested (the masked raster, which has no such scissor, tests everything).
///
/// The cells come from the world's [`Cells`] resource; a world without one (or without cells) is culled by the
/// frustum alone, then occlusion. Per object, the regions its box touches are listed once, and again for the
/// objects that move (from the scene's moves, or for every object where they are not listed). Conservative
/// wherever the scene keeps the contract of [`crate::cells`], with conservative occlusion settings.
///
/// # Example
/// ```
/// use cullet::cells::{Cell, Cells};
/// use cullet::culler::{CullScene, Culler, PortalCuller};
/// use cullet::scene::flight::Flight;
/// use glam::Vec3;
///
/// let cells = Cells::joined_by_position(
///     vec![Cell { name: "hall".into(), boxes: vec![(Vec3::new(-5.0, 0.0, -5.0), Vec3::new(5.0, 3.0, 5.0))] }],
///     Vec::new(),
/// )
/// .unwrap();
/// let path = cullet::CameraPath { fov_y_deg: 60.0, near: 0.1, far: None, keys: Vec::new() };
/// let mut flight = Flight::for_cullers(path, 1.0, 1, |world| {
///     world.insert_resource(cells);
/// });
/// flight.schedule.run(&mut flight.world);
/// let camera = cullet::Camera::looking_at(Vec3::new(0.0, 1.5, 0.0), Vec3::new(0.0, 1.5, -4.0));
/// let mut culler = PortalCuller::default();
/// let culled = culler.cull(&CullScene::new(&flight.world), &camera);
/// assert_eq!(culled.stats.objects, 0);
/// assert_eq!(culler.portal_stats().regions_seen, 1, "the hall; the outside lies beyond its walls");
/// ```
#[derive(Clone, Debug, Default)]
pub struct PortalCuller {
    /// What it culls with; change it between frames.
    pub settings: PortalSettings,
    membership: Membership,
    /// The cells' id and the store's generations the membership was made for.
    synced: Option<(u64, (u64, u64))>,
    /// What the camera's whole frustum keeps, before the portals narrow it.
    in_frustum: VisibleSet,
    portal_visible: VisibleSet,
    kept: VisibleSet,
    occluded: VisibleSet,
    pyramid: DepthPyramid,
    portal_stats: PortalStats,
    /// Where the view starts only in cells: the rectangle around the regions it sees through portals
    /// (`Some(None)` where it sees none). `None` where it starts outside, or the scene has no cells.
    window: Option<Option<Rect>>,
    /// Where `window` is given: the kept objects listed in a region the view starts in.
    in_start_regions: VisibleSet,
    /// The kept objects listed only in regions seen through portals.
    through_portals: VisibleSet,
    /// Skips occlusion where it has removed too little lately.
    gate: BenefitGate,
    /// What the portal stage kept the frame before.
    kept_last_frame: usize,
}

impl PortalCuller {
    /// A culler with `settings`.
    pub fn new(settings: PortalSettings) -> Self {
        Self { settings, ..Self::default() }
    }

    /// The last frame's traversal counts.
    pub fn portal_stats(&self) -> PortalStats {
        self.portal_stats
    }

    /// Brings the per-object region lists up to date with the store and the cells.
    fn sync(&mut self, scene: &CullScene, cells: &Cells) {
        let store = scene.store();
        let synced = self.synced.filter(|(id, _)| *id == cells.id()).map(|(_, generations)| generations);
        match scene.change_since(synced) {
            StoreChange::None => {}
            StoreChange::Moved(Some(slots)) => self.membership.moved(store, cells, slots),
            StoreChange::Moved(None) | StoreChange::Layout => self.membership = Membership::build(store, cells),
        }
        self.synced = Some((cells.id(), scene.generations()));
    }

    /// The portal stage: the slots kept into `portal_visible`, and the traversal counts.
    fn cull_portals(&mut self, scene: &CullScene, camera: &Camera, frustum: &Frustum) {
        let store = scene.store();
        let cells = scene.world.get_resource::<Cells>().filter(|cells| !cells.cells().is_empty());
        let Some(cells) = cells else {
            (self.synced, self.window) = (None, None);
            cull_frustum(store, frustum, FrustumOptions::default(), &mut self.portal_visible);
            let len = store.len();
            self.portal_stats =
                PortalStats { start_regions: 1, regions_seen: 1, regions: 1, portals_passed: 0, objects_tested: len };
            return;
        };
        self.sync(scene, cells);
        let Traversal { seen, started, mut stats } = traverse(cells, camera);
        // The camera's frustum first, over the whole store at once: a region seen whole keeps its members that
        // pass it, and only the members that pass it of a region seen through portals are tested again, against
        // the view narrowed to that region's rectangle.
        cull_frustum(store, frustum, FrustumOptions::default(), &mut self.in_frustum);
        let clip_from_relative = camera.clip_from_relative_f64();
        let views: Vec<(Option<Frustum>, &[u32])> = seen
            .iter()
            .zip(&self.membership.of_region)
            .filter_map(|(rect, members)| {
                let rect = (*rect)?;
                let narrowed = (!rect.contains(Rect::SCREEN)).then(|| {
                    let matrix = rect.intersect(Rect::SCREEN).unwrap_or(rect).narrow(clip_from_relative);
                    Frustum::from_clip_from_relative_f64(camera.position, matrix, camera.depth).unwrap_or(*frustum)
                });
                Some((narrowed, members.as_slice()))
            })
            .collect();
        stats.objects_tested = views.iter().map(|(_, members)| members.len()).sum();
        let (kept, in_frustum) = (SharedVisibleSet::new(store.len()), &self.in_frustum);
        let test = |(narrowed, chunk): (&Option<Frustum>, &[u32])| {
            let passing = chunk.iter().copied().filter(|&slot| in_frustum.contains(slot as usize));
            let Some(narrowed) = narrowed else {
                passing.for_each(|slot| kept.set(slot));
                return;
            };
            // Eight at a time, so that the narrowed view's tests run in SIMD lanes.
            let mut batch = Vec::with_capacity(SIMD_LANES);
            let test_batch = |batch: &mut Vec<u32>| {
                let inside = narrowed.intersects_slots(store, batch);
                batch
                    .iter()
                    .enumerate()
                    .filter(|&(lane, _)| inside >> lane & 1 != 0)
                    .for_each(|(_, &slot)| kept.set(slot));
                batch.clear();
            };
            for slot in passing {
                batch.push(slot);
                if batch.len() == SIMD_LANES {
                    test_batch(&mut batch);
                }
            }
            if !batch.is_empty() {
                test_batch(&mut batch);
            }
        };
        // Fewer tests than one task holds cost less than waking the pool.
        if stats.objects_tested <= SLOTS_PER_TASK {
            views.iter().for_each(|(frustum, members)| test((frustum, members)));
        } else {
            parallel::region(|region| {
                views
                    .par_iter()
                    .flat_map(|(frustum, members)| {
                        members.par_chunks(SLOTS_PER_TASK).map(move |chunk| (frustum, chunk))
                    })
                    .for_each(|task| region.task(|| test(task)));
            });
        }
        kept.copy_to(store.len(), &mut self.portal_visible);
        // From inside the cells, what lies beyond them is seen only through portals, within the rectangles
        // those regions are seen through.
        self.window = None;
        if !started[cells.outside()] {
            let through_portals = seen.iter().zip(&started).filter(|(_, started)| !**started);
            let rects = through_portals.filter_map(|(rect, _)| rect.and_then(|rect| rect.intersect(Rect::SCREEN)));
            self.window = Some(rects.reduce(Rect::union));
            self.in_start_regions.reset(store.len());
            let start_members = self.membership.of_region.iter().zip(&started).filter(|(_, started)| **started);
            for &slot in start_members.flat_map(|(members, _)| members) {
                if self.portal_visible.contains(slot as usize) {
                    self.in_start_regions.set(slot as usize, true);
                }
            }
        }
        self.portal_stats = stats;
    }
}

impl Culler for PortalCuller {
    fn name(&self) -> String {
        "portals".into()
    }

    fn is_conservative(&self, viewport: (u32, u32)) -> bool {
        self.settings.occlusion.is_conservative_for(viewport)
    }

    fn cull(&mut self, scene: &CullScene, camera: &Camera) -> Culled<'_> {
        let start = Instant::now();
        let store = scene.store();
        let mut stats = ViewStats { objects: store.len(), ..ViewStats::default() };
        let Some(frustum) = frustum_or_keep_everything(
            camera,
            store.len(),
            &mut self.portal_visible,
            &mut self.kept,
            &mut stats,
            start,
        ) else {
            return Culled { stages: vec![("portals", &self.portal_visible), ("occlusion", &self.kept)], stats };
        };
        let stage = Stage::Frustum.enter();
        self.cull_portals(scene, camera, &frustum);
        drop(stage);
        stats.after_frustum = self.portal_visible.count();
        stats.frustum_time = start.elapsed();

        // A view that suddenly keeps far more than the frame before (through a door, turning to a window) is
        // another view: what occlusion removed lately says nothing of it.
        if stats.after_frustum > 2 * self.kept_last_frame.max(MIN_REOPEN_GROWTH) {
            self.gate.reopen();
        }
        self.kept_last_frame = stats.after_frustum;
        let occlusion = self.settings.occlusion;
        let runs = occlusion.enabled && occlusion.validate().is_ok();
        stats.occlusion_gated = runs && self.gate.skip_this_frame();
        if runs && !stats.occlusion_gated {
            let start = Instant::now();
            let _stage = Stage::Raster.enter();
            let view = occlusion.view(camera);
            // From inside the cells, only the objects seen through portals are tested, against occluders drawn
            // only within the rectangle around the regions they are seen through; the objects of the cells around
            // the eye are kept. The masked raster draws the whole buffer, so it tests everything.
            let (tested, scissor) = match self.window.filter(|_| occlusion.mode != RasterMode::Masked) {
                None => (&self.portal_visible, None),
                Some(window) => {
                    self.through_portals.clone_from(&self.portal_visible);
                    self.through_portals.and_not(&self.in_start_regions);
                    let nothing = TexelRect { x0: 0, x1: 0, y0: 0, y1: 0 };
                    (&self.through_portals, Some(window.map_or(nothing, |rect| rect.texels(&view))))
                }
            };
            // Nothing seen through portals: no occluder is chosen, as an empty test would only clear the buffer.
            let occluders = if tested.count() == 0 {
                Vec::new()
            } else {
                scene.occluders_among(&self.portal_visible, camera.position, occlusion.triangle_budget)
            };
            let selection_time = start.elapsed();
            let run = occlude_within(
                store,
                tested,
                Some(&view),
                &occluders,
                occlusion.mode,
                scissor,
                None,
                &mut self.pyramid,
                &mut self.kept,
                &mut self.occluded,
            );
            if scissor.is_some() {
                self.kept.or(&self.in_start_regions);
            }
            (stats.occluders, stats.occluder_triangles) = (occluders.len(), run.raster.triangles_rasterized);
            stats.occluders_hidden = run.raster.occluders_hidden;
            (stats.raster_time, stats.occlusion_time) = (selection_time + run.raster_time, run.test_time);
            stats.after_occlusion = self.kept.count();
            // A frame without occluders says nothing of what occlusion is worth here.
            if !occluders.is_empty() {
                let removed = stats.after_frustum - stats.after_occlusion;
                self.gate.record_occlusion(removed, stats.after_frustum, &self.settings.adaptive);
            }
        } else {
            if stats.occlusion_gated {
                self.kept.clone_from(&self.portal_visible);
            }
            stats.after_occlusion = stats.after_frustum;
        }
        let mut stages = vec![("portals", &self.portal_visible)];
        if runs {
            stages.push(("occlusion", &self.kept));
        }
        Culled { stages, stats }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rectangles_narrow_the_view_to_themselves() {
        let camera = Camera::looking_at(glam::Vec3::new(1e5, 3.0, 0.0), glam::Vec3::new(1e5, 3.0, -10.0));
        let rect = Rect { min: DVec2::new(-0.2, -0.5), max: DVec2::new(0.4, 0.1) };
        let narrowed = rect.narrow(camera.clip_from_relative_f64());
        let frustum = Frustum::from_clip_from_relative_f64(camera.position, narrowed, camera.depth).unwrap();
        let clip_from_relative = camera.clip_from_relative_f64();
        // Points along rays through NDC positions inside and outside the rectangle.
        for (ndc, inside) in [((0.0, -0.2), true), ((-0.19, 0.09), true), ((0.5, 0.0), false), ((0.0, -0.6), false)] {
            let inverse = clip_from_relative.inverse();
            let point = inverse.project_point3(DVec3::new(ndc.0, ndc.1, 0.5));
            let world = (point + camera.position.as_dvec3()).as_vec3();
            let bounds =
                crate::bounds::WorldBounds { center: world, half_extent: glam::Vec3::splat(1e-3), radius: 1.7e-3 };
            assert_eq!(frustum.intersects(&bounds), inside, "{ndc:?}");
        }
    }

    /// A rectangle's texels reach a texel past it each side, within the buffer; NDC's y points up, texels' down.
    #[test]
    fn a_rectangle_reaches_its_texels_and_one_more() {
        let view = ScreenView::new(&Camera::looking_at(glam::Vec3::ZERO, -glam::Vec3::Z), 256, 144);
        let rect = Rect { min: DVec2::new(-0.5, 0.0), max: DVec2::new(0.5, 1.0) };
        assert_eq!(rect.texels(&view), TexelRect { x0: 63, x1: 193, y0: 0, y1: 73 });
        assert_eq!(Rect::SCREEN.texels(&view), TexelRect::whole(256, 144));
    }

    #[test]
    fn a_portal_crossing_the_near_plane_is_clipped_to_it() {
        let camera = Camera::looking_at(glam::Vec3::ZERO, -glam::Vec3::Z);
        let (view, clip) = (camera.view_from_relative_f64(), camera.clip_from_view_f64());
        // A door frame beside the eye, reaching from behind it to 2 units ahead.
        let door = [
            glam::Vec3::new(0.5, -1.0, 1.0),
            glam::Vec3::new(0.5, 1.0, 1.0),
            glam::Vec3::new(0.5, 1.0, -2.0),
            glam::Vec3::new(0.5, -1.0, -2.0),
        ];
        let mut scratch = Vec::new();
        let rect = project_portal(&door, camera.position, &view, &clip, camera.near as f64, &mut scratch).unwrap();
        assert!(rect.max.x > 1.0, "its near edge reaches far right of the screen: {rect:?}");
        let behind = door.map(|v| v + glam::Vec3::Z * 5.0);
        assert_eq!(project_portal(&behind, camera.position, &view, &clip, camera.near as f64, &mut scratch), None);
    }
}
