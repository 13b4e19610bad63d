//! One view's culling state, and the one call that culls that view against a store.

use super::adaptive::{BenefitGate, RetestCost};
use super::settings::{SettingsError, ViewSettings};
use crate::bounds::{BoundsStore, StoreMoves};
use crate::camera::Camera;
use crate::depth::{DepthBuffer, DepthPyramid};
use crate::detail::DetailTest;
use crate::frustum::{Frustum, FrustumError, FrustumOptions, PlaneCoherence, View, cull_frustum, cull_views};
use crate::occluders::{OccluderInstance, select_occluders};
use crate::occlusion::{occlude, retest_occlusion};
use crate::parallel::Stage;
use crate::visible::VisibleSet;
use std::borrow::Cow;
use std::time::{Duration, Instant};

/// What a view is culled through: its frustum (or why it has none) and, for the occlusion stage, its
/// perspective camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewInput {
    /// The culling frustum, or why the view has none: then the view keeps every object, in both stages.
    pub frustum: Result<Frustum, FrustumError>,
    /// The camera the occlusion stage rasterizes and tests through; `None` for a view without one (an
    /// orthographic or custom projection), which gets frustum culling only.
    pub camera: Option<Camera>,
}

impl ViewInput {
    /// The view of a perspective `camera`: its frustum ([`Camera::frustum`], which refuses an invalid camera)
    /// and the camera itself for occlusion.
    pub fn of_camera(camera: &Camera) -> Self {
        Self { frustum: camera.frustum(), camera: Some(*camera) }
    }
}

/// What one frame of a view is culled with, besides the store.
#[derive(Clone, Copy, Debug)]
pub struct ViewFrame<'a> {
    /// The view.
    pub view: ViewInput,
    /// The settings.
    pub settings: ViewSettings,
    /// The slots whose bounds changed in place since the store's generation `moves.from`
    /// ([`BoundsStore::take_moves`]), where the caller keeps them: where they are all the store changed since
    /// this view's last cull, only they are re-tested. `None` re-tests nothing alone.
    pub moves: Option<&'a StoreMoves>,
    /// Something this culler cannot see changed since its last cull (the views culled with it; an occluder
    /// replaced without [`BoundsStore::replace_occluder`] telling the store): the frame runs in full.
    pub changed: bool,
}

impl<'a> ViewFrame<'a> {
    /// A frame of `view` with `settings`, nothing known of what moved.
    pub fn new(view: ViewInput, settings: ViewSettings) -> Self {
        Self { view, settings, moves: None, changed: false }
    }
}

/// Counts and times of one view's last cull.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ViewStats {
    /// Objects in the store.
    pub objects: usize,
    /// Objects kept by the frustum stage.
    pub after_frustum: usize,
    /// Objects kept by both stages (equal to `after_frustum` where occlusion did not run).
    pub after_occlusion: usize,
    /// Occluders chosen to rasterize.
    pub occluders: usize,
    /// Occluder triangles rasterized (after clipping, front faces only; none of the hidden occluders').
    pub occluder_triangles: usize,
    /// Occluders skipped before setup, found hidden behind nearer ones wherever they reach.
    pub occluders_hidden: usize,
    /// Nothing moved and neither the view nor a setting changed: last cull's result stands
    /// ([`super::AdaptiveSettings::reuse_unchanged`]).
    pub reused: bool,
    /// Objects re-tested alone because only they moved: the view, the settings, which objects are stored where
    /// and every occluder were unchanged, so both stages re-tested just these against the last cull's planes
    /// and depth pyramid. 0 when the frame ran in full or was reused.
    pub retested: usize,
    /// The occlusion stage was skipped because it had removed too little lately
    /// ([`super::AdaptiveSettings::min_occlusion_benefit`]), or a judge outside the view asked
    /// ([`ViewCuller::skip_occlusion_once`]).
    pub occlusion_gated: bool,
    /// Objects the frustum kept that detail culling dropped ([`ViewSettings::detail`]; already left out of
    /// `after_frustum`). Inside the occlusion test it judges only the groups the pyramid does not hide whole:
    /// a small object in a hidden group is counted occluded.
    pub detail_culled: usize,
    /// Time of the frustum stage (the whole call, where the result was reused).
    pub frustum_time: Duration,
    /// Time selecting and rasterizing occluders and building the depth pyramid.
    pub raster_time: Duration,
    /// Time testing the frustum survivors against the pyramid.
    pub occlusion_time: Duration,
    /// Why the view kept every object: it has no valid frustum (an invalid camera).
    pub frustum_error: Option<FrustumError>,
    /// Why the occlusion stage did not run: its settings are invalid ([`super::OcclusionSettings::validate`]).
    pub occlusion_error: Option<SettingsError>,
}

impl ViewStats {
    /// Objects the frustum stage removed.
    pub fn frustum_removed(&self) -> usize {
        self.objects - self.after_frustum
    }

    /// Objects the occlusion stage removed.
    pub fn occlusion_removed(&self) -> usize {
        self.after_frustum - self.after_occlusion
    }
}

/// What the last cull was computed from.
#[derive(Clone, Copy, Debug, PartialEq)]
struct LastCull {
    view: ViewInput,
    settings: ViewSettings,
    generation: u64,
    layout: u64,
}

/// How this frame's cull runs, decided at its start.
#[derive(Clone, Debug, Default, PartialEq)]
enum Plan {
    /// Last cull's result stands.
    Reuse,
    /// Only these slots moved: re-test them.
    Retest(Vec<u32>),
    /// Both stages over the whole store.
    #[default]
    Full,
}

/// One view's culling: the frustum stage, then the occluder selection, raster and occlusion test, with the
/// state they keep between frames (plane coherence, the occlusion benefit gate, the re-test bookkeeping, the
/// occluder depth pyramid, the visible sets). A plain type, no ECS: the pipeline's camera
/// ([`crate::pipeline`]) and the Bevy plugin's cameras each wrap one.
///
/// Each frame, [`ViewCuller::cull`] culls the view against the store, reusing the last result where nothing
/// changed and re-testing only the objects that moved where nothing else did. Culling is conservative: an
/// object is removed only where it lies outside the frustum or wholly behind the occluders. A view without a
/// valid frustum keeps every object in both stages and says why in [`ViewStats::frustum_error`]; invalid
/// occlusion settings skip the occlusion stage ([`ViewStats::occlusion_error`]).
///
/// # Example
/// ```
/// use cullet::bounds::{BoundsStore, LocalBounds, WorldBounds};
/// use cullet::culler::{ViewCuller, ViewFrame, ViewInput, ViewSettings};
/// use cullet::Camera;
/// use glam::{Affine3A, Vec3};
///
/// let mut store = BoundsStore::default();
/// let unit = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) };
/// for (index, z) in [0.0, 50.0].into_iter().enumerate() {
///     let entity = bevy_ecs::entity::Entity::from_raw_u32(index as u32).unwrap();
///     let transform = Affine3A::from_translation(Vec3::new(0.0, 0.0, z));
///     store.insert(entity, &WorldBounds::from_local(entity, &unit, &transform).unwrap()).unwrap();
/// }
/// let camera = Camera::looking_at(Vec3::new(0.0, 2.0, 10.0), Vec3::ZERO);
/// let mut culler = ViewCuller::default();
/// let frame = ViewFrame::new(ViewInput::of_camera(&camera), ViewSettings::default());
/// let stats = culler.cull(&store, &frame, |_| None);
/// assert_eq!((stats.objects, stats.after_frustum), (2, 1));
/// assert!(culler.visible().contains(0) && !culler.visible().contains(1));
/// ```
#[derive(Clone, Debug, Default)]
pub struct ViewCuller {
    /// What the frustum kept: the occlusion stage's input.
    frustum_visible: VisibleSet,
    /// `frustum_visible` less the objects detail culling dropped (in the occlusion test), where it ran: what
    /// [`ViewCuller::frustum_visible`] gives then.
    detail_visible: Option<VisibleSet>,
    coherence: PlaneCoherence,
    pyramid: DepthPyramid,
    visible: VisibleSet,
    occluded: VisibleSet,
    occluder_slots: Vec<u32>,
    last: Option<LastCull>,
    plan: Plan,
    occlusion_gate: BenefitGate,
    /// The next cull that is not reused skips the occlusion stage ([`ViewCuller::skip_occlusion_once`]).
    occlusion_held: bool,
    retest_cost: RetestCost,
    stats: ViewStats,
}

impl ViewCuller {
    /// Culls `frame`'s view against `store`: the frustum stage, then the occlusion stage with occluders looked
    /// up by store slot through `occluder_of` (an object whose slot gives `None` occludes nothing). Returns the
    /// counts and times; the kept objects are in [`ViewCuller::visible`].
    pub fn cull<'a>(
        &mut self,
        store: &BoundsStore,
        frame: &ViewFrame,
        occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>> + Sync,
    ) -> &ViewStats {
        self.cull_frustum(store, frame, &[], &mut Vec::new());
        self.cull_occlusion(store, occluder_of);
        &self.stats
    }

    /// The first half of [`ViewCuller::cull`], for a schedule that runs the stages as systems of their own:
    /// decides whether the frame is reused, re-tested or run in full, and runs the frustum stage. `also` are
    /// more views culled in the same pass over the bounds (a camera's light views), into `also_visible`; their
    /// counts are returned where they were culled this frame, `None` where they were not (the frame was
    /// reused, or the view has no valid frustum or the stage is off: then they keep what they had, or
    /// everything, as the caller decides). With views in `also`, a frame where only objects moved runs in
    /// full. Call [`ViewCuller::cull_occlusion`] next.
    pub fn cull_frustum(
        &mut self,
        store: &BoundsStore,
        frame: &ViewFrame,
        also: &[View],
        also_visible: &mut Vec<VisibleSet>,
    ) -> Option<Vec<usize>> {
        let start = Instant::now();
        let _stage = Stage::Frustum.enter();
        let settings = &frame.settings;
        self.plan = self.plan(store, frame, also.is_empty());
        self.stats.retested = 0;
        match &self.plan {
            Plan::Reuse => {
                // The last cull's counts stand; only the times are this frame's.
                let stats = &mut self.stats;
                (stats.frustum_time, stats.raster_time, stats.occlusion_time) =
                    (start.elapsed(), Duration::ZERO, Duration::ZERO);
                return None;
            }
            Plan::Retest(moved) => {
                if let Ok(frustum) = &frame.view.frustum {
                    let coherence = settings.adaptive.plane_coherence.then_some(&mut self.coherence);
                    self.retest_cost.retest_frustum(store, frustum, moved, coherence, &mut self.frustum_visible);
                }
                self.stats.retested = moved.len();
                self.stats.after_frustum = self.frustum_visible.count();
                self.stats.frustum_time = start.elapsed();
                return None;
            }
            Plan::Full => {}
        }
        // Until this frame's occlusion stage runs detail culling, the frustum's set is the frustum's alone.
        self.detail_visible = None;
        self.stats.objects = store.len();
        self.stats.frustum_error = None;
        let mut also_kept = None;
        // The stage's passes count what they keep: no pass over the set to count it again.
        self.stats.after_frustum = match &frame.view.frustum {
            Ok(_) if !settings.frustum => {
                self.frustum_visible = VisibleSet::all(store.len());
                store.len()
            }
            Ok(frustum) if !also.is_empty() => {
                let views: Vec<View> = std::iter::once(View::new(*frustum)).chain(also.iter().cloned()).collect();
                also_visible.insert(0, std::mem::take(&mut self.frustum_visible));
                let mut counts = cull_views(store, &views, also_visible);
                self.frustum_visible = also_visible.remove(0);
                let kept = counts.remove(0);
                also_kept = Some(counts);
                kept
            }
            Ok(frustum) => {
                let pass = Instant::now();
                let coherence = settings.adaptive.plane_coherence.then_some(&mut self.coherence);
                let options = FrustumOptions { coherence, ..Default::default() };
                let kept = cull_frustum(store, frustum, options, &mut self.frustum_visible);
                self.retest_cost.record_full(pass.elapsed(), store.len());
                kept
            }
            Err(error) => {
                tracing::warn!("a view keeps every object: {error}");
                self.stats.frustum_error = Some(*error);
                self.frustum_visible = VisibleSet::all(store.len());
                store.len()
            }
        };
        self.stats.frustum_time = start.elapsed();
        also_kept
    }

    /// The second half of [`ViewCuller::cull`]: the occluder selection, raster and occlusion test of the
    /// frame [`ViewCuller::cull_frustum`] began, through its view and with its settings (or, where that frame
    /// re-tests, the moved objects alone against the last pyramid). Before any frame, it does nothing.
    pub fn cull_occlusion<'a>(
        &mut self,
        store: &BoundsStore,
        occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>> + Sync,
    ) {
        let start = Instant::now();
        let _stage = Stage::Raster.enter();
        let Some(LastCull { view, settings, .. }) = self.last else { return };
        let settings = &settings;
        match std::mem::take(&mut self.plan) {
            Plan::Reuse => return,
            Plan::Retest(moved) => {
                let _stage = Stage::Occlusion.enter();
                self.retest_occlusion(store, &view, settings, &moved);
                self.stats.occlusion_time = start.elapsed();
                self.plan = Plan::Retest(moved);
                return;
            }
            Plan::Full => {}
        }
        let stats = &mut self.stats;
        // Only where the frustum stage culled through a valid view: an invalid camera culls nothing anywhere.
        let camera = view.camera.filter(|_| view.frustum.is_ok());
        let detail = detail_test(&view, settings);
        let runs = camera.is_some() && settings.occlusion.enabled && stats.occlusion_error.is_none();
        let chosen: Vec<(u32, OccluderInstance)> = match camera {
            Some(camera) if runs && !stats.occlusion_gated => {
                // Occluders hidden last frame are left out: `occluded` still holds last frame's hidden objects.
                let candidates =
                    if settings.adaptive.skip_hidden_occluders && self.occluded.len() == self.frustum_visible.len() {
                        let mut candidates = self.frustum_visible.clone();
                        candidates.and_not(&self.occluded);
                        Cow::Owned(candidates)
                    } else {
                        Cow::Borrowed(&self.frustum_visible)
                    };
                let budget = settings.occlusion.triangle_budget;
                let mut chosen = select_occluders(store, &candidates, camera.position, budget, occluder_of);
                // An object too small to draw hides nothing (few are chosen: they rank last).
                if let Some(detail) = &detail {
                    chosen.retain(|(slot, _)| !detail.is_small(store, *slot as usize));
                }
                chosen
            }
            _ => Vec::new(),
        };
        let instances: Vec<OccluderInstance> = chosen.iter().map(|(_, instance)| *instance).collect();
        self.occluder_slots.clear();
        self.occluder_slots.extend(chosen.iter().map(|(slot, _)| *slot));
        stats.occluders = instances.len();
        let selection_time = start.elapsed();
        // Without a camera (or occluders) the stage costs the selection and a copy.
        let screen = camera.filter(|_| runs).map(|camera| settings.occlusion.view(&camera));
        let run = occlude(
            store,
            &self.frustum_visible,
            screen.as_ref(),
            &instances,
            settings.occlusion.mode,
            detail.as_ref(),
            &mut self.pyramid,
            &mut self.visible,
            &mut self.occluded,
        );
        (stats.occluder_triangles, stats.occluders_hidden) =
            (run.raster.triangles_rasterized, run.raster.occluders_hidden);
        stats.after_occlusion = run.test.visible;
        // Detail culling ran in the test; the frustum stage's set and count leave out what it dropped.
        stats.detail_culled = run.test.small;
        stats.after_frustum -= run.test.small;
        match detail {
            Some(_) => {
                let into = self.detail_visible.get_or_insert_default();
                leave_out_dropped(&self.frustum_visible, &self.visible, &self.occluded, into, None);
            }
            None => self.detail_visible = None,
        }
        (stats.raster_time, stats.occlusion_time) = (selection_time + run.raster_time, run.test_time);
        // A frame that rasterized nothing says nothing of what occlusion is worth here.
        if !instances.is_empty() {
            self.occlusion_gate.record_occlusion(stats.occlusion_removed(), stats.after_frustum, &settings.adaptive);
        }
    }

    /// Decides how this frame runs, ticking the occlusion gate on every frame not reused.
    fn plan(&mut self, store: &BoundsStore, frame: &ViewFrame, can_retest: bool) -> Plan {
        let settings = &frame.settings;
        let same_view = self.same_view(store, frame);
        self.stats.reused = self.reuses(store, frame);
        let (generation, layout) = (store.generation(), store.layout_generation());
        let current = LastCull { view: frame.view, settings: *settings, generation, layout };
        let last = self.last.replace(current);
        if self.stats.reused {
            return Plan::Reuse;
        }
        self.stats.occlusion_error = settings.occlusion.validate().err().filter(|_| settings.occlusion.enabled);
        if let Some(error) = self.stats.occlusion_error {
            tracing::warn!("occlusion skipped: {error}");
        }
        let occlusion = settings.occlusion.enabled && self.stats.occlusion_error.is_none();
        let was_gated = self.stats.occlusion_gated;
        // The gate ticks only on frames where occlusion would run; a hold is spent either way.
        let held = std::mem::take(&mut self.occlusion_held);
        self.stats.occlusion_gated = occlusion && (self.occlusion_gate.skip_this_frame() | held);
        // Only objects without occluders moved since the last cull: the planes and the depth pyramid stand.
        let moved = frame.moves.filter(|moves| {
            can_retest
                && same_view
                && settings.frustum
                && frame.view.frustum.is_ok()
                && was_gated == self.stats.occlusion_gated
                && last.is_some_and(|last| (moves.from, moves.to) == (last.generation, generation))
                && moves.slots.iter().all(|&slot| !store.occluders().contains(slot as usize))
        });
        match moved {
            Some(moves) => Plan::Retest(moves.slots.clone()),
            None => Plan::Full,
        }
    }

    /// Whether the last cull was of the same view with the same settings, on a store of the same layout, with
    /// nothing else changed ([`ViewFrame::changed`]) and reuse allowed: what moved since may then be re-tested
    /// alone.
    fn same_view(&self, store: &BoundsStore, frame: &ViewFrame) -> bool {
        let layout = store.layout_generation();
        frame.settings.adaptive.reuse_unchanged
            && !frame.changed
            && self
                .last
                .is_some_and(|last| (last.view, last.settings, last.layout) == (frame.view, frame.settings, layout))
            && self.visible.len() == store.len()
    }

    /// Whether culling `frame` now would keep the last cull's result whole ([`ViewStats::reused`]): the same
    /// view and settings, and nothing in the store or elsewhere changed since. A caller may then skip building
    /// what only a cull reads (the pipeline skips building its light views).
    pub fn reuses(&self, store: &BoundsStore, frame: &ViewFrame) -> bool {
        self.same_view(store, frame) && self.last.is_some_and(|last| last.generation == store.generation())
    }

    /// Re-tests the store slots `moved` alone against the last cull's depth pyramid, which still holds for
    /// this frame's view and settings, after the frustum stage re-tested them; every other slot keeps its
    /// result.
    fn retest_occlusion(&mut self, store: &BoundsStore, view: &ViewInput, settings: &ViewSettings, moved: &[u32]) {
        match view.camera.filter(|_| self.pyramid.level_count() > 0) {
            Some(camera) => {
                let screen = settings.occlusion.view(&camera);
                let (visible, occluded) = (&mut self.visible, &mut self.occluded);
                let (frustum_visible, pyramid) = (&self.frustum_visible, &self.pyramid);
                let detail = detail_test(view, settings);
                retest_occlusion(store, frustum_visible, &screen, pyramid, detail.as_ref(), moved, visible, occluded);
            }
            // Nothing was rasterized: what the frustum keeps is visible, less what detail culling drops.
            None => {
                let detail = detail_test(view, settings);
                for &slot in moved {
                    let slot = slot as usize;
                    let small = detail.is_some_and(|detail| detail.is_small(store, slot));
                    self.visible.set(slot, self.frustum_visible.contains(slot) && !small);
                }
            }
        }
        // The same settings as the last full cull: detail culling ran there too where it runs here.
        if let Some(into) = &mut self.detail_visible {
            leave_out_dropped(&self.frustum_visible, &self.visible, &self.occluded, into, Some(moved));
        }
        self.stats.after_frustum = self.frustum_visible().count();
        (self.stats.after_occlusion, self.stats.raster_time) = (self.visible.count(), Duration::ZERO);
    }

    /// Skips the occlusion stage on the next cull that is not reused: it then keeps every object the frustum
    /// kept, and [`ViewStats::occlusion_gated`] says so. For a judge outside the view that finds the stage
    /// does not pay, such as two-phase GPU occlusion (`GpuGating::min_occluder_benefit`, feature `gpu`). Adds
    /// no false negative.
    pub fn skip_occlusion_once(&mut self) {
        self.occlusion_held = true;
    }

    /// The view of the last cull, if any.
    pub fn last_view(&self) -> Option<ViewInput> {
        self.last.map(|last| last.view)
    }

    /// Counts and times of the last cull.
    pub fn stats(&self) -> &ViewStats {
        &self.stats
    }

    /// The last frame's result as a [`Culled`](super::Culled): both stages, `frustum` and `occlusion` (which
    /// keeps what the frustum stage kept where occlusion is off), and the stats. For judging the view as any
    /// [`Culler`](super::Culler)'s result is judged.
    pub fn culled(&self) -> super::Culled<'_> {
        super::Culled {
            stages: vec![("frustum", self.frustum_visible()), ("occlusion", self.visible())],
            stats: self.stats,
        }
    }

    /// Store slots kept by the frustum stage (less those detail culling dropped, where it runs).
    pub fn frustum_visible(&self) -> &VisibleSet {
        self.detail_visible.as_ref().unwrap_or(&self.frustum_visible)
    }

    /// Store slots kept by both stages: the result.
    pub fn visible(&self) -> &VisibleSet {
        &self.visible
    }

    /// Store slots the frustum stage kept and the occlusion stage hid. It stays until the next cull's
    /// occlusion stage runs, so a caller may use it before then (to test last frame's hidden objects first).
    pub fn occluded(&self) -> &VisibleSet {
        &self.occluded
    }

    /// Store slots of the occluders rasterized in the last full cull, best first.
    pub fn occluder_slots(&self) -> &[u32] {
        &self.occluder_slots
    }

    /// The farthest-depth pyramid of the last cull's occluder depth buffer (its level 0); empty where nothing
    /// was rasterized.
    pub fn pyramid(&self) -> &DepthPyramid {
        &self.pyramid
    }

    /// The occluder depth buffer of the last cull (`1/w` of the farthest occluder per texel, 0 for none): the
    /// pyramid's level 0, or an empty (0x0) buffer where nothing was rasterized.
    pub fn depth(&self) -> &DepthBuffer {
        self.pyramid.base()
    }
}

/// Detail culling's test for a cull of `view` with `settings`: only where a valid view's frustum culled, as
/// with no frustum every object is kept.
fn detail_test(view: &ViewInput, settings: &ViewSettings) -> Option<DetailTest> {
    let camera = view.camera.filter(|_| settings.frustum && view.frustum.is_ok())?;
    DetailTest::new(&camera, &settings.detail)
}

/// Writes to `into` the objects of `frustum_visible` that the occlusion stage left in `visible` or `occluded`,
/// leaving out those detail culling dropped: every word, or only the words of the slots in `only` (the rest
/// of `into` standing).
fn leave_out_dropped(
    frustum_visible: &VisibleSet,
    visible: &VisibleSet,
    occluded: &VisibleSet,
    into: &mut VisibleSet,
    only: Option<&[u32]>,
) {
    let (frustum, kept, hidden) = (frustum_visible.words(), visible.words(), occluded.words());
    let word = |w: usize| frustum[w] & (kept.get(w).copied().unwrap_or(0) | hidden.get(w).copied().unwrap_or(0));
    match only {
        Some(slots) => {
            for w in slots.iter().map(|&slot| slot as usize / 64) {
                into.words_mut()[w] = word(w);
            }
        }
        None => {
            into.resize_for_overwrite(frustum_visible.len());
            for (w, out) in into.words_mut().iter_mut().enumerate() {
                *out = word(w);
            }
        }
    }
}
