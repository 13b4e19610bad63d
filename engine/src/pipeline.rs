//! The culling pipeline as `bevy_ecs` systems, one per stage, in a fixed order: data flows one way, each stage
//! narrowing the [`VisibleSet`] of the stage before. [`install`] puts it into a world and a schedule.

use crate::bounds::{
    BoundsStore, ObjectTransform, on_bounds_inserted, on_bounds_removed, on_occluder_inserted, on_occluder_removed,
    sync_bounds,
};
use crate::camera::Camera;
use crate::depth::{DepthBuffer, DepthPyramid, ScreenView};
use crate::frustum::{
    Frustum, FrustumError, LightSource, LightView, PlaneCoherence, View, ViewError, cull_frustum_with_coherence,
    cull_views, retest_frustum,
};
use crate::occluder::{Occluder, OccluderInstance, select_occluders, select_occluders_for_view};
use crate::occlusion::{occlude, retest_occlusion};
use crate::raster::RasterMode;
use crate::visible::VisibleSet;
use bevy_ecs::prelude::*;
use rayon::prelude::*;
use std::time::{Duration, Instant};

/// The stages, in the order they run.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CullStage {
    /// Bring the SoA bounds up to date with changed entities.
    Bounds,
    /// Cull against the view frustum.
    Frustum,
    /// Rasterize artist occluders and test the frustum survivors against them; then the same for each light
    /// view, as its light sees them.
    Occlusion,
}

/// Output of the frustum stage: store slots whose boxes touch the frustum.
#[derive(Resource, Default, Debug, Clone)]
pub struct FrustumVisible(pub VisibleSet);

/// Lights whose views the frustum stage culls with the camera, in the same pass over the bounds: a sun's
/// cascades, a lamp's cube faces ([`LightSource`]). Each light view keeps the shadow casters whose shadows can
/// fall inside the camera's frustum ([`View::shadow_casters`]); the results are in [`LightViewsVisible`].
/// Empty by default.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct LightViews(pub Vec<LightSource>);

/// One light view's result of the frame.
#[derive(Clone, Debug, PartialEq)]
pub struct LightViewVisible {
    /// The light in [`LightViews`] it belongs to.
    pub light: usize,
    /// Its view and the matrix to draw its shadow map with.
    pub view: LightView,
    /// Store slots of the shadow casters it keeps.
    pub visible: VisibleSet,
    /// How many.
    pub kept: usize,
    /// How many of the casters its frustum kept its occlusion then hid from the light
    /// ([`LightOcclusionSettings`]); already left out of `visible` and `kept`.
    pub occluded: usize,
}

/// Output of the frustum stage for the [`LightViews`], narrowed by each view's occlusion
/// ([`light_occlusion_stage`]): every light view of the frame, lights in order. Where the frustum stage does
/// not cull (turned off), each view keeps every object its occlusion does not hide; a light whose views cannot
/// be built (or a camera without a valid frustum) has none, and [`CullStats::light_view_error`] says why.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct LightViewsVisible(pub Vec<LightViewVisible>);

impl LightViewsVisible {
    /// Each light view's name ([`LightSource::view_name`]) and the casters it kept this frame, in order.
    pub fn kept_by_view(&self, lights: &LightViews) -> Vec<(String, usize)> {
        let mut index_in_light = 0;
        self.0
            .iter()
            .enumerate()
            .map(|(i, view)| {
                index_in_light = if i > 0 && self.0[i - 1].light == view.light { index_in_light + 1 } else { 0 };
                let name = lights.0.get(view.light).map_or_else(String::new, |light| light.view_name(index_in_light));
                (name, view.kept)
            })
            .collect()
    }
}

/// Per-frame counts and timings of each stage.
#[derive(Resource, Default, Debug, Clone, Copy, PartialEq)]
pub struct CullStats {
    /// Objects in the store.
    pub objects: usize,
    /// Objects whose bounds were recomputed this frame.
    pub bounds_recomputed: usize,
    /// Objects left after frustum culling.
    pub after_frustum: usize,
    /// Time spent bringing bounds up to date.
    pub bounds_time: Duration,
    /// Time spent frustum culling.
    pub frustum_time: Duration,
    /// Set when the camera could not produce a frustum; the stage then keeps every object.
    pub frustum_error: Option<FrustumError>,
    /// Light views culled with the camera this frame ([`LightViews`]).
    pub light_views: usize,
    /// Shadow casters those views keep, summed over the views.
    pub light_view_casters: usize,
    /// Set when a light of [`LightViews`] gave no views this frame (it is left out, and reported here).
    pub light_view_error: Option<ViewError>,
    /// Casters the light views' occlusion hid from their lights this frame, summed over the views (already
    /// left out of `light_view_casters`).
    pub light_view_occluded: usize,
    /// Light views whose occlusion was skipped this frame for removing too little lately.
    pub light_occlusion_gated: usize,
    /// Time spent on the light views' occlusion: selecting and rasterizing their occluders and testing their
    /// casters.
    pub light_occlusion_time: Duration,
    /// Occluders rasterized this frame.
    pub occluders: usize,
    /// Occluder triangles rasterized this frame (after clipping, front faces only; none of the hidden
    /// occluders').
    pub occluder_triangles: usize,
    /// Occluders skipped without setting up their triangles, found hidden behind nearer ones wherever they
    /// reach ([`RasterStats::occluders_hidden`](crate::raster::RasterStats::occluders_hidden)).
    pub occluders_hidden: usize,
    /// Objects left after occlusion culling.
    pub after_occlusion: usize,
    /// Time spent selecting and rasterizing occluders and building the depth pyramid.
    pub raster_time: Duration,
    /// Time spent testing occludees.
    pub occlusion_time: Duration,
    /// Nothing moved and neither the camera nor a setting changed: the frustum and occlusion stages kept last
    /// frame's result without running ([`AdaptiveSettings::reuse_unchanged`]).
    pub reused: bool,
    /// Objects culled alone this frame because only they moved: the camera, the settings, which objects are
    /// stored where and every occluder were unchanged, so the frustum and occlusion stages re-tested just these
    /// against last frame's planes and depth pyramid. 0 when the frame ran in full or was reused.
    pub retested: usize,
    /// The occlusion stage was skipped because it had removed too little lately
    /// ([`AdaptiveSettings::min_occlusion_benefit`]); everything the frustum kept stays visible.
    pub occlusion_gated: bool,
}

impl CullStats {
    /// Objects the frustum stage removed this frame.
    pub fn frustum_removed(&self) -> usize {
        self.objects - self.after_frustum
    }

    /// Objects the occlusion stage removed this frame.
    pub fn occlusion_removed(&self) -> usize {
        self.after_frustum - self.after_occlusion
    }
}

/// How the pipeline skips work a scene does not need. Gating only ever skips a stage (keeping everything that
/// stage would have tested) or reuses a result whose inputs did not change, so it cannot add false negatives.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveSettings {
    /// Reuse last frame's frustum and occlusion results when no bounds changed, the camera is the same and so
    /// are the settings; when only a few objects without occluders moved, re-test just those
    /// ([`CullStats::retested`]).
    pub reuse_unchanged: bool,
    /// The occlusion stage is skipped once it has removed less than this fraction of the frustum survivors for
    /// [`AdaptiveSettings::low_benefit_frames`] frames in a row (an open field), then run again to re-probe
    /// every [`AdaptiveSettings::reprobe_every`] frames. 0 never skips.
    pub min_occlusion_benefit: f32,
    /// The same for each light view's occlusion ([`LightOcclusionSettings`]), as a fraction of the view's
    /// casters: a higher bar than the camera's, since a hidden caster saves a shadow map less than a hidden
    /// object saves the frame. Measured on the city (`cargo bench -p cullet-benches --bench light_occlusion`):
    /// under the game's high sun the light views hide 4% of their casters (1% of their triangles) for 0.5 ms
    /// a frame, under a low sun 27% (6% of the triangles) for 0.7 ms. 0 never skips.
    pub min_light_occlusion_benefit: f32,
    /// See `min_occlusion_benefit`.
    pub low_benefit_frames: u32,
    /// See `min_occlusion_benefit`.
    pub reprobe_every: u32,
    /// Occluders whose object the occlusion stage hid last frame are not selected: they would most likely be
    /// hidden again, and the triangle budget goes to the ones in front (temporal coherence). Off by default:
    /// on the city's fly-through at 30 frames a second it saved 5% of the CPU stages' time but left the GPU
    /// 5% more triangles (an occluder hidden last frame may show this frame), so it does not pay.
    pub skip_hidden_occluders: bool,
    /// The frustum stage tests first, for each block of 8 objects, the plane that rejected the whole block last
    /// frame ([`PlaneCoherence`]). The same result either way.
    pub plane_coherence: bool,
}

impl Default for AdaptiveSettings {
    /// Reuse of unchanged frames; occlusion skipped after 8 frames under 1% removed (a light view's under
    /// 10%), re-probed every 30 frames;
    /// plane coherence on; hidden occluders are still selected.
    fn default() -> Self {
        Self {
            reuse_unchanged: true,
            min_occlusion_benefit: 0.01,
            min_light_occlusion_benefit: 0.1,
            low_benefit_frames: 8,
            reprobe_every: 30,
            skip_hidden_occluders: false,
            plane_coherence: true,
        }
    }
}

impl AdaptiveSettings {
    /// No gating at all: every stage runs every frame (the fixed pipeline, for comparison).
    pub fn fixed() -> Self {
        Self {
            reuse_unchanged: false,
            min_occlusion_benefit: 0.0,
            min_light_occlusion_benefit: 0.0,
            low_benefit_frames: u32::MAX,
            reprobe_every: 0,
            skip_hidden_occluders: false,
            plane_coherence: false,
        }
    }
}

/// Skips a stage that keeps removing too little: after `low_benefit_frames` frames in a row under the benefit
/// threshold, the stage is skipped for `reprobe_every` frames, then runs again to re-probe.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BenefitGate {
    /// Consecutive frames the stage removed less than the threshold.
    low_frames: u32,
    /// Frames left to skip the stage before re-probing it.
    skip_left: u32,
}

impl BenefitGate {
    /// Whether the stage is skipped this frame; call once a frame.
    pub fn skip_this_frame(&mut self) -> bool {
        let skip = self.skip_left > 0;
        self.skip_left = self.skip_left.saturating_sub(1);
        skip
    }

    /// Records a frame the stage ran, removing `removed` of the `tested` items, against `min_benefit` (a
    /// fraction): after `low_benefit_frames` such frames in a row the stage is skipped for `reprobe_every`
    /// frames. A frame with nothing tested says nothing and is not counted.
    pub fn record(
        &mut self,
        removed: usize,
        tested: usize,
        min_benefit: f32,
        low_benefit_frames: u32,
        reprobe_every: u32,
    ) {
        if tested == 0 {
            return;
        }
        if (removed as f32) < min_benefit * tested as f32 {
            self.low_frames += 1;
            if self.low_frames >= low_benefit_frames {
                self.low_frames = 0;
                self.skip_left = reprobe_every;
            }
        } else {
            self.low_frames = 0;
        }
    }
}

/// How the frustum stage re-tests a frame where only some objects moved: each moved object alone
/// ([`crate::frustum::retest_frustum`]), or the full pass over the store, which gives the others their results
/// again. Each costs what it last cost. One by one, a moved object's bounds come from scattered slots, which costs more
/// per object once the store outgrows the caches; the full pass reads the store in order and skips whole
/// groups outside the view. In the game with a still camera over the city's moving cars (`cullet-game
/// --headless --cpu-only --static-camera`), one by one took 19.5 us against 61-63 us for the full pass at 1e5
/// objects (465 moved), and 328-332 us against 150-151 us at 1e6 (4,689 moved): neither wins at both sizes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RetestCost {
    /// What re-testing one by one costs, per moved object.
    alone: WayCost,
    /// What the full pass costs, per stored object.
    full: WayCost,
    /// Choices made so far.
    choices: u32,
}

/// What one way of re-testing costs per object, in seconds, smoothed; none before two measurements.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct WayCost {
    per_object: Option<f64>,
    measured: u32,
}

impl WayCost {
    /// Folds `time` over `count` objects in, half and half, so that one disturbed frame moves the choice less.
    /// The first measurement is dropped: it runs on cold caches (at 1e6 objects the first full pass took
    /// several times the next ones).
    fn record(&mut self, time: Duration, count: usize) {
        if count == 0 {
            return;
        }
        self.measured += 1;
        if self.measured > 1 {
            let sample = time.as_secs_f64() / count as f64;
            self.per_object = Some(self.per_object.map_or(sample, |cost| (cost + sample) * 0.5));
        }
    }
}

/// Every this many choices [`RetestCost`] takes the way that costs more, to keep its cost current: one
/// measured for another view would otherwise keep the choice wrong.
const RETEST_PROBE_EVERY: u32 = 32;

impl RetestCost {
    /// Chooses, for a frame that re-tests `moved` of `objects` objects, between testing them one by one (`true`)
    /// and the full pass. Until each way has a cost, the one without (one by one first); then the way that cost
    /// less, except every 32nd call, which takes the other. Call once a frame that re-tests, then record what
    /// the way taken cost.
    pub fn choose_alone(&mut self, moved: usize, objects: usize) -> bool {
        self.choices = self.choices.wrapping_add(1);
        match (self.alone.per_object, self.full.per_object) {
            (None, _) => true,
            (_, None) => false,
            (Some(alone), Some(full)) => {
                let cheaper = moved as f64 * alone <= objects as f64 * full;
                cheaper != self.choices.is_multiple_of(RETEST_PROBE_EVERY)
            }
        }
    }

    /// Records a re-test of `moved` objects one by one that took `time`.
    pub fn record_alone(&mut self, time: Duration, moved: usize) {
        self.alone.record(time, moved);
    }

    /// Records a full pass over `objects` that took `time`.
    pub fn record_full(&mut self, time: Duration, objects: usize) {
        self.full.record(time, objects);
    }

    /// Re-tests the store slots `moved` against `frustum` into `visible`, which holds the result of the same
    /// frustum before they moved: one by one or in a full pass (with `coherence` where given), as
    /// [`RetestCost::choose_alone`] chooses, recording what it cost. Both give the same bits.
    pub fn retest_frustum(
        &mut self,
        store: &BoundsStore,
        frustum: &Frustum,
        moved: &[u32],
        coherence: Option<&mut PlaneCoherence>,
        visible: &mut VisibleSet,
    ) {
        let start = Instant::now();
        if self.choose_alone(moved.len(), store.len()) {
            retest_frustum(store, frustum, moved, visible);
            self.record_alone(start.elapsed(), moved.len());
        } else {
            cull_frustum_with_coherence(store, frustum, coherence, visible);
            self.record_full(start.elapsed(), store.len());
        }
    }
}

/// What the gating remembers between frames.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct AdaptiveState {
    /// The view of the last frame: camera, store layout generation and settings.
    last_view: Option<(Camera, u64, FrustumSettings, OcclusionSettings, LightOcclusionSettings)>,
    /// The light views of the last frame.
    last_lights: LightViews,
    /// The store generation of the last frame.
    last_generation: u64,
    /// The slots the frustum stage re-tested alone this frame, for the occlusion stage to re-test too.
    retest: Option<Vec<u32>>,
    /// When the occlusion stage is skipped for removing too little.
    occlusion: BenefitGate,
    /// Whether the frustum stage re-tests moved objects one by one or in a full pass.
    retest_cost: RetestCost,
    /// The same for each light view's occlusion, in [`LightViewsVisible`]'s order.
    light_occlusion: Vec<BenefitGate>,
}

/// Settings of the frustum stage.
#[derive(Resource, Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrustumSettings {
    /// Whether the stage culls; when off, every object stays visible (for comparison and debugging).
    pub enabled: bool,
}

impl Default for FrustumSettings {
    fn default() -> Self {
        Self { enabled: true }
    }
}

/// Settings of the software occlusion stage.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct OcclusionSettings {
    /// Whether the stage runs at all; when off, every frustum survivor stays visible.
    pub enabled: bool,
    /// Depth-buffer width in texels.
    pub width: u32,
    /// Depth-buffer height in texels.
    pub height: u32,
    /// How texels are sampled ([`RasterMode`]): conservative (default), pixel centres or masked blocks at the
    /// viewport's size (or below it, for [`OcclusionSettings::frame`]), or fast.
    pub mode: RasterMode,
    /// Most occluder triangles rasterized per frame. The default, 4096, sits on the measured run-time-against-
    /// error Pareto front (see the README): on the city, 16 384 culls 1.5 points more for 60% more time.
    pub triangle_budget: usize,
    /// The resolution (width, height) of the frame the kept objects are drawn at, where known (`None` by
    /// default). With it, a [`RasterMode::PixelCentres`] or [`RasterMode::Masked`] buffer smaller than the frame
    /// is conservative for it: each buffer pixel stands for the frame's pixel centres in its square
    /// ([`ScreenView::for_frame`]). Without it, those modes are conservative at their own resolution only.
    pub frame: Option<(u32, u32)>,
}

impl OcclusionSettings {
    /// Whether these settings never hide an object a rendering of `viewport` (width, height) pixels shows: the
    /// stage is off, its mode is conservative at that size ([`RasterMode::is_conservative_for`]), or it samples
    /// pixel centres for that very frame ([`OcclusionSettings::frame`]) at a buffer no larger.
    pub fn is_conservative_for(&self, viewport: (u32, u32)) -> bool {
        let buffer = (self.width, self.height);
        let sampled_for_it = self.mode.samples_pixel_centres()
            && self.frame == Some(viewport)
            && buffer.0 <= viewport.0
            && buffer.1 <= viewport.1;
        !self.enabled || self.mode.is_conservative_for(buffer, viewport) || sampled_for_it
    }

    /// The settings to use where the frame's size (width, height, pixels) is known: a masked buffer standing
    /// for its pixels ([`OcclusionSettings::frame`]), the frame divided by the smallest whole number that
    /// leaves at most 960x540 samples (rounded up: the frame's own size up to there, half of 1920x1080, a
    /// quarter of 3840x2160), with 5120 occluder triangles. On the city's fly-through at 1920x1080 (the
    /// README's run-time-against-error table) it culls 97.2% of what is hidden in the CPU time of
    /// [`OcclusionSettings::default`] (256x144, 94.6%; 0.998x on one thread, timed pass for pass), with no
    /// object wrongly hidden; a whole divisor keeps the buffer's samples from reaching as far
    /// ([`ScreenView::for_frame`]). The default cannot be this, as it does not know the frame.
    ///
    /// ```
    /// use cullet::pipeline::OcclusionSettings;
    /// let settings = OcclusionSettings::for_frame(1920, 1080);
    /// assert_eq!((settings.width, settings.height), (960, 540));
    /// assert!(settings.is_conservative_for((1920, 1080)));
    /// assert_eq!(OcclusionSettings::for_frame(640, 360).width, 640);
    /// ```
    pub fn for_frame(width: u32, height: u32) -> Self {
        let samples = |divisor: u32| u64::from(width.div_ceil(divisor)) * u64::from(height.div_ceil(divisor));
        let estimate = (samples(1) as f64 / FRAME_BUFFER_SAMPLES as f64).sqrt() as u32;
        let divisor = (estimate.max(1)..).find(|&divisor| samples(divisor) <= FRAME_BUFFER_SAMPLES).unwrap_or(1);
        Self {
            width: width.div_ceil(divisor),
            height: height.div_ceil(divisor),
            mode: RasterMode::Masked,
            triangle_budget: 5120,
            frame: Some((width, height)),
            ..Self::default()
        }
    }

    /// These settings for a frame of `width` x `height` pixels, as when a window or viewport is resized, so that
    /// they stay conservative for the frame drawn. Settings whose buffer [`OcclusionSettings::for_frame`] chose
    /// for the old frame get its choice for the new one (their switch and triangle budget kept). Any other
    /// pixel-centre or masked buffer ([`RasterMode::samples_pixel_centres`]) keeps its relation to the frame:
    /// one that is the old [`OcclusionSettings::frame`] divided by a whole number and rounded up becomes the
    /// new frame divided by that number, any other its share of the new frame (rounded up), and one with no
    /// frame becomes the new frame's size. A conservative or fast buffer keeps its size (the first is
    /// conservative at any frame size, the second at none). `frame` becomes the new size. A frame with no
    /// pixels draws nothing: the settings are returned as they are.
    ///
    /// ```
    /// use cullet::pipeline::OcclusionSettings;
    /// use cullet::raster::RasterMode;
    /// let resized = OcclusionSettings::for_frame(1920, 1080).resized_to(3840, 2160);
    /// assert_eq!((resized.width, resized.height, resized.frame), (960, 540, Some((3840, 2160))));
    /// assert!(resized.is_conservative_for((3840, 2160)));
    /// let sixth = OcclusionSettings { width: 640, height: 360, mode: RasterMode::Masked, ..resized };
    /// assert_eq!(sixth.resized_to(1920, 1080).width, 320);
    /// ```
    pub fn resized_to(self, width: u32, height: u32) -> Self {
        if width == 0 || height == 0 {
            return self;
        }
        let old = self.frame.unwrap_or((self.width, self.height));
        let chosen = Self::for_frame(old.0, old.1);
        if self.frame.is_some() && (self.width, self.height, self.mode) == (chosen.width, chosen.height, chosen.mode) {
            let (enabled, triangle_budget) = (self.enabled, self.triangle_budget);
            return Self { enabled, triangle_budget, ..Self::for_frame(width, height) };
        }
        let mut resized = Self { frame: Some((width, height)), ..self };
        if self.mode.samples_pixel_centres() {
            (resized.width, resized.height) =
                (resized_axis(self.width, old.0, width), resized_axis(self.height, old.1, height));
        }
        resized
    }

    /// The view the stage rasterizes and tests through for `camera`: the buffer's size, standing for
    /// [`OcclusionSettings::frame`]'s pixels where that is given.
    pub fn view(&self, camera: &Camera) -> ScreenView {
        let view = ScreenView::new(camera, self.width, self.height);
        self.frame.map_or(view, |frame| view.for_frame(frame))
    }
}

/// The most samples [`OcclusionSettings::for_frame`] gives its buffer: 960x540, the half of 1920x1080 measured
/// on the fly-through.
const FRAME_BUFFER_SAMPLES: u64 = 960 * 540;

/// A buffer's size along one axis for a frame resized from `old` to `new` pixels (see
/// [`OcclusionSettings::resized_to`]): `new / k` rounded up where `buffer` is `old / k` rounded up for a whole
/// `k` (so half stays half, as whole-number ratios sample better), otherwise `buffer`'s share of `new`.
fn resized_axis(buffer: u32, old: u32, new: u32) -> u32 {
    if buffer == 0 || old == 0 {
        return new;
    }
    let divisor = (f64::from(old) / f64::from(buffer)).round().max(1.0) as u32;
    if old.div_ceil(divisor) == buffer {
        new.div_ceil(divisor)
    } else {
        let share = (u64::from(new) * u64::from(buffer)).div_ceil(u64::from(old));
        u32::try_from(share).unwrap_or(u32::MAX).max(1)
    }
}

impl Default for OcclusionSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            width: 256,
            height: 144,
            mode: RasterMode::Conservative,
            triangle_budget: 4096,
            frame: None,
        }
    }
}

/// Output and working memory of the occlusion stage.
#[derive(Resource, Default, Debug, Clone)]
pub struct OcclusionState {
    /// The farthest-depth pyramid of this frame's occluder depth buffer, which is its level 0
    /// ([`OcclusionState::depth`]); empty where nothing was rasterized.
    pub pyramid: DepthPyramid,
    /// Store slots still visible after occlusion culling: the input of the next stage.
    pub visible: VisibleSet,
    /// Store slots of the occluders rasterized this frame, best first.
    pub occluder_slots: Vec<u32>,
    /// Store slots the frustum kept and occlusion hid. It stays until the next frame's occlusion stage runs,
    /// so earlier stages of the next frame can use it (for instance to test last frame's occluded first).
    pub occluded: VisibleSet,
}

impl OcclusionState {
    /// This frame's occluder depth buffer (`1/w` of the farthest occluder covering each texel, 0 for none): the
    /// pyramid's level 0, or an empty (0x0) buffer where nothing was rasterized.
    pub fn depth(&self) -> &DepthBuffer {
        self.pyramid.base()
    }
}

/// Settings of the light views' occlusion: each light view of [`LightViews`] (a sun's cascade, a lamp's face)
/// gets a conservative depth buffer of its own, seen from its light, of the occluders among its casters that
/// face the light, and its casters hidden behind them are dropped.
///
/// A caster hidden from the light at every point of its box changes no texel of the shadow map: wherever it
/// would be drawn, a nearer occluder, inside geometry that is drawn (or whose own shadow cannot reach the
/// camera's view), already is. Each view has its own benefit gate
/// ([`AdaptiveSettings::min_light_occlusion_benefit`]),
/// so a view whose occlusion hides too little soon costs only its occluder selection.
#[derive(Resource, Clone, Copy, Debug, PartialEq, Eq)]
pub struct LightOcclusionSettings {
    /// Whether light views are occlusion culled; when off, each keeps every caster its frustum kept.
    pub enabled: bool,
    /// Width and height of each light view's depth buffer, in texels (the buffer is always
    /// [`RasterMode::Conservative`]: it never hides what a shadow map of any resolution shows).
    pub size: u32,
    /// Most occluder triangles rasterized per light view and frame.
    pub triangle_budget: usize,
    /// A light view with fewer casters than this is not occlusion culled: too little to gain for a raster.
    pub min_casters: usize,
}

impl Default for LightOcclusionSettings {
    /// On, 128x128 texels, 2048 triangles a view, views of 64 casters or more.
    fn default() -> Self {
        Self { enabled: true, size: 128, triangle_budget: 2048, min_casters: 64 }
    }
}

/// Output and working memory of the light views' occlusion, in [`LightViewsVisible`]'s order.
#[derive(Resource, Default, Debug, Clone)]
pub struct LightOcclusionState {
    /// Each light view's farthest-depth pyramid this frame; empty where it rasterized nothing.
    pub pyramids: Vec<DepthPyramid>,
    /// Each light view's casters that its frustum kept and its occlusion hid this frame (empty where its
    /// occlusion did not run).
    pub occluded: Vec<VisibleSet>,
    /// Reused for each view's survivors.
    survivors: Vec<VisibleSet>,
}

/// The settings of every CPU stage, installed together by [`install`]; each is a resource of the world
/// afterwards, to change between frames.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PipelineSettings {
    /// The frustum stage.
    pub frustum: FrustumSettings,
    /// The occlusion stage (buffer resolution, mode, triangle budget).
    pub occlusion: OcclusionSettings,
    /// The light views' occlusion.
    pub light_occlusion: LightOcclusionSettings,
    /// What the pipeline may skip or reuse when it cannot pay off.
    pub adaptive: AdaptiveSettings,
}

/// Installs the CPU culling pipeline: the [`BoundsStore`] and its observers, the stage outputs and `settings`
/// as resources of `world`, and the stages, in order ([`CullStage`]), in `schedule`. Each
/// `schedule.run(&mut world)` then culls one frame: entities with [`crate::bounds::LocalBounds`] and
/// [`ObjectTransform`] (and optionally an [`Occluder`]) are culled against the [`Camera`] resource, which
/// the caller inserts before the first run; [`OcclusionState::visible`] holds the result, [`CullStats`] the
/// counts and times.
///
/// Call `world.clear_trackers()` after each run, as `bevy_ecs` apps do between frames, so that the next run's
/// change detection sees only that frame's changes.
///
/// # Example
/// ```
/// use bevy_ecs::prelude::*;
/// use cullet::prelude::*;
/// use glam::{Affine3A, Vec3};
///
/// let (mut world, mut schedule) = (World::new(), Schedule::default());
/// cullet::install(&mut world, &mut schedule, PipelineSettings::default());
/// world.insert_resource(Camera::looking_at(Vec3::new(0.0, 2.0, 10.0), Vec3::ZERO));
/// let unit = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) };
/// let in_view = world.spawn((unit, ObjectTransform(Affine3A::IDENTITY))).id();
/// let behind = world.spawn((unit, ObjectTransform(Affine3A::from_translation(Vec3::new(0.0, 0.0, 50.0))))).id();
///
/// schedule.run(&mut world);
/// world.clear_trackers();
///
/// let store = world.resource::<BoundsStore>();
/// let visible = &world.resource::<OcclusionState>().visible;
/// assert!(visible.contains(store.slot_of(in_view).unwrap()));
/// assert!(!visible.contains(store.slot_of(behind).unwrap()));
/// ```
pub fn install(world: &mut World, schedule: &mut Schedule, settings: PipelineSettings) {
    init_world(world);
    world.insert_resource(settings.frustum);
    world.insert_resource(settings.occlusion);
    world.insert_resource(settings.light_occlusion);
    world.insert_resource(settings.adaptive);
    add_systems(schedule);
}

/// Sets up a world for culling: the [`BoundsStore`], its insertion and removal observers, and the stage
/// outputs ([`install`] inserts the settings).
fn init_world(world: &mut World) {
    world.init_resource::<BoundsStore>();
    world.init_resource::<FrustumVisible>();
    world.init_resource::<LightViews>();
    world.init_resource::<LightViewsVisible>();
    world.init_resource::<CullStats>();
    world.init_resource::<AdaptiveState>();
    world.init_resource::<PlaneCoherence>();
    world.init_resource::<OcclusionState>();
    world.init_resource::<LightOcclusionState>();
    world.add_observer(on_bounds_inserted);
    world.add_observer(on_bounds_removed);
    world.add_observer(on_occluder_inserted);
    world.add_observer(on_occluder_removed);
}

/// Adds the culling stages to `schedule`, in order.
fn add_systems(schedule: &mut Schedule) {
    schedule.configure_sets((CullStage::Bounds, CullStage::Frustum, CullStage::Occlusion).chain());
    schedule.add_systems((
        sync_bounds.in_set(CullStage::Bounds),
        frustum_stage.in_set(CullStage::Frustum),
        (occlusion_stage, light_occlusion_stage).chain().in_set(CullStage::Occlusion),
    ));
}

/// Culls the store against the [`Camera`]'s frustum into [`FrustumVisible`], and for the [`LightViews`] into
/// [`LightViewsVisible`], all views in one pass over the bounds. A camera that gives no valid frustum culls
/// nothing (everything stays visible) and reports the error in [`CullStats`]; so does a stage turned off in
/// [`FrustumSettings`]. With [`AdaptiveSettings::reuse_unchanged`] it keeps last frame's result when nothing
/// changed, and, without light views, re-tests only the moved objects when nothing else did
/// ([`CullStats::retested`]).
#[allow(clippy::too_many_arguments)]
pub fn frustum_stage(
    mut store: ResMut<BoundsStore>,
    camera: Res<Camera>,
    lights: Res<LightViews>,
    mut light_views: ResMut<LightViewsVisible>,
    settings: Res<FrustumSettings>,
    occlusion: Res<OcclusionSettings>,
    light_occlusion: Res<LightOcclusionSettings>,
    adaptive: Res<AdaptiveSettings>,
    mut gate: ResMut<AdaptiveState>,
    mut visible: ResMut<FrustumVisible>,
    mut stats: ResMut<CullStats>,
    mut coherence: ResMut<PlaneCoherence>,
    changed_occluders: Query<(), Changed<Occluder>>,
) {
    let start = Instant::now();
    stats.bounds_recomputed = store.recomputed_last_sync();
    stats.bounds_time = store.last_sync_time();
    let moved = store.take_moved_slots();
    let view = (*camera, store.layout_generation(), *settings, *occlusion, *light_occlusion);
    let same_view = adaptive.reuse_unchanged
        && gate.last_view == Some(view)
        && gate.last_lights == *lights
        && changed_occluders.is_empty();
    stats.reused = same_view && gate.last_generation == store.generation();
    (gate.last_view, gate.last_generation, gate.retest, stats.retested) = (Some(view), store.generation(), None, 0);
    if gate.last_lights != *lights {
        gate.last_lights.clone_from(&lights);
    }
    if stats.reused {
        // Last frame's counts stand; only the times are this frame's.
        (stats.frustum_time, stats.raster_time, stats.occlusion_time) =
            (start.elapsed(), Duration::ZERO, Duration::ZERO);
        return;
    }
    // Only objects without occluders moved: the planes and the occluder buffer stand, re-test just those (the
    // light views have no single-object test: with them, the frame runs in full).
    if let (true, true, true, Some(moved), Ok(frustum)) =
        (same_view, settings.enabled, lights.0.is_empty(), moved, camera.frustum())
        && moved.iter().all(|&slot| !store.occluders().contains(slot as usize))
    {
        let coherence = adaptive.plane_coherence.then_some(&mut *coherence);
        gate.retest_cost.retest_frustum(&store, &frustum, &moved, coherence, &mut visible.0);
        stats.after_frustum = visible.0.count();
        stats.retested = moved.len();
        gate.retest = Some(moved);
        stats.frustum_time = start.elapsed();
        return;
    }
    stats.objects = store.len();
    // This frame's light views, until culled with the camera below.
    let mut unculled = Some(light_views_of(&lights, &camera, &mut stats.light_view_error));
    match camera.frustum() {
        Ok(_) if !settings.enabled => {
            visible.0 = VisibleSet::all(store.len());
            stats.after_frustum = store.len();
            stats.frustum_error = None;
        }
        Ok(frustum) if unculled.as_ref().is_some_and(|lit| !lit.is_empty()) => {
            let lit = unculled.take().unwrap_or_default();
            // The camera and the light views in one pass over the bounds.
            let views: Vec<View> =
                std::iter::once(View::new(frustum)).chain(lit.iter().map(|(_, light)| light.view.clone())).collect();
            let mut sets: Vec<VisibleSet> = std::iter::once(std::mem::take(&mut visible.0))
                .chain(light_views.0.iter_mut().map(|view| std::mem::take(&mut view.visible)))
                .collect();
            let counts = cull_views(&store, &views, &mut sets);
            let mut sets = sets.into_iter();
            visible.0 = sets.next().unwrap_or_default();
            stats.after_frustum = counts[0];
            light_views.0 = lit
                .into_iter()
                .zip(sets.zip(&counts[1..]))
                .map(|((light, view), (visible, &kept))| LightViewVisible { light, view, visible, kept, occluded: 0 })
                .collect();
            stats.frustum_error = None;
        }
        Ok(frustum) => {
            let pass = Instant::now();
            let coherence = adaptive.plane_coherence.then_some(&mut *coherence);
            stats.after_frustum = cull_frustum_with_coherence(&store, &frustum, coherence, &mut visible.0);
            gate.retest_cost.record_full(pass.elapsed(), store.len());
            stats.frustum_error = None;
        }
        Err(error) => {
            tracing::warn!("frustum stage skipped: {error}");
            visible.0 = VisibleSet::all(store.len());
            stats.after_frustum = store.len();
            stats.frustum_error = Some(error);
        }
    }
    if let Some(lit) = unculled {
        // Not culled this frame (the stage is off): every light view keeps everything.
        let all = |(light, view)| LightViewVisible {
            light,
            view,
            visible: VisibleSet::all(store.len()),
            kept: store.len(),
            occluded: 0,
        };
        light_views.0 = lit.into_iter().map(all).collect();
    }
    stats.light_views = light_views.0.len();
    stats.light_view_casters = light_views.0.iter().map(|view| view.kept).sum();
    stats.frustum_time = start.elapsed();
}

/// The light views of every light in `lights` for `camera`, each with its light's index; a light whose views
/// cannot be built is left out and its error kept in `error` (cleared where none fails).
fn light_views_of(lights: &LightViews, camera: &Camera, error: &mut Option<ViewError>) -> Vec<(usize, LightView)> {
    *error = None;
    let mut views = Vec::new();
    for (index, light) in lights.0.iter().enumerate() {
        match light.light_views(camera) {
            Ok(built) => views.extend(built.into_iter().map(|view| (index, view))),
            Err(why) => {
                tracing::warn!("light {index} has no views this frame: {why}");
                *error = Some(why);
            }
        }
    }
    views
}

/// Selects occluders among the frustum survivors, rasterizes them into the depth buffer, builds its pyramid and
/// tests every frustum survivor against it, into [`OcclusionState`]. With no occluder in view it rasterizes
/// and tests nothing; where the frustum stage re-tested only moved objects, so does this stage, against last
/// frame's pyramid; after frames of too little benefit it is skipped for a while
/// ([`AdaptiveSettings::min_occlusion_benefit`]).
#[allow(clippy::too_many_arguments)]
pub fn occlusion_stage(
    store: Res<BoundsStore>,
    camera: Res<Camera>,
    frustum_visible: Res<FrustumVisible>,
    settings: Res<OcclusionSettings>,
    mut state: ResMut<OcclusionState>,
    mut stats: ResMut<CullStats>,
    adaptive: Res<AdaptiveSettings>,
    mut gate: ResMut<AdaptiveState>,
    occluders: Query<(&Occluder, &ObjectTransform)>,
) {
    if stats.reused {
        return;
    }
    let start = Instant::now();
    let state = &mut *state;
    if let Some(moved) = gate.retest.take() {
        // Same view and occluders as last frame: its pyramid stands (or its absence, where the stage was off,
        // gated or had no occluder); the benefit count waits for a full frame.
        let view = settings.view(&camera);
        retest_occlusion(
            &store,
            &frustum_visible.0,
            &view,
            &state.pyramid,
            &moved,
            &mut state.visible,
            &mut state.occluded,
        );
        stats.after_occlusion = state.visible.count();
        (stats.raster_time, stats.occlusion_time) = (Duration::ZERO, start.elapsed());
        return;
    }
    stats.occlusion_gated = settings.enabled && gate.occlusion.skip_this_frame();
    // Occluders hidden last frame are left out: `state.occluded` still holds last frame's hidden objects.
    let candidates = if adaptive.skip_hidden_occluders && state.occluded.len() == frustum_visible.0.len() {
        let mut candidates = frustum_visible.0.clone();
        candidates.and_not(&state.occluded);
        std::borrow::Cow::Owned(candidates)
    } else {
        std::borrow::Cow::Borrowed(&frustum_visible.0)
    };
    let (slots, chosen): (Vec<u32>, Vec<OccluderInstance>) = if settings.enabled && !stats.occlusion_gated {
        select_occluders(&store, &candidates, camera.position, settings.triangle_budget, |slot| {
            let (occluder, transform) = occluders.get(store.entities()[slot]).ok()?;
            Some(OccluderInstance { occluder, transform: transform.0 })
        })
        .into_iter()
        .unzip()
    } else {
        Default::default()
    };
    state.occluder_slots = slots;
    stats.occluders = chosen.len();
    let selection_time = start.elapsed();
    let view = settings.view(&camera);
    let run = occlude(
        &store,
        &frustum_visible.0,
        Some(&view),
        &chosen,
        settings.mode,
        &mut state.pyramid,
        &mut state.visible,
        &mut state.occluded,
    );
    (stats.occluder_triangles, stats.occluders_hidden) = (run.raster.triangles_rasterized, run.raster.occluders_hidden);
    stats.after_occlusion = run.test.visible;
    (stats.raster_time, stats.occlusion_time) = (selection_time + run.raster_time, run.test_time);
    if chosen.is_empty() {
        return; // Nothing was rasterized: no benefit to record.
    }
    gate.occlusion.record(
        stats.occlusion_removed(),
        stats.after_frustum,
        adaptive.min_occlusion_benefit,
        adaptive.low_benefit_frames,
        adaptive.reprobe_every,
    );
}

/// Occlusion culls each light view of [`LightViewsVisible`] (see [`LightOcclusionSettings`]): selects the
/// occluders among its casters, best first within the budget, rasterizes them as its light sees them
/// ([`ScreenView::of_light_view`]) and drops its casters hidden behind them, updating the view's `visible`,
/// `kept` and `occluded`, [`LightOcclusionState`] and [`CullStats`]. Runs only on frames whose frustum stage
/// culled the light views afresh. A view with fewer casters than [`LightOcclusionSettings::min_casters`] or no
/// occluder among them rasterizes nothing, and one whose occlusion keeps hiding too little is skipped for a
/// while, each view with its own gate. The views are rasterized and tested in parallel.
#[allow(clippy::too_many_arguments)]
pub fn light_occlusion_stage(
    store: Res<BoundsStore>,
    settings: Res<LightOcclusionSettings>,
    adaptive: Res<AdaptiveSettings>,
    mut light_views: ResMut<LightViewsVisible>,
    mut state: ResMut<LightOcclusionState>,
    mut gate: ResMut<AdaptiveState>,
    mut stats: ResMut<CullStats>,
    occluders: Query<(&Occluder, &ObjectTransform)>,
) {
    if stats.reused {
        return; // Last frame's light views, occlusion included, stand.
    }
    let start = Instant::now();
    let views = light_views.0.len();
    let state = &mut *state;
    state.pyramids.resize_with(views, DepthPyramid::default);
    state.occluded.resize_with(views, VisibleSet::default);
    state.survivors.resize_with(views, VisibleSet::default);
    if gate.light_occlusion.len() != views {
        gate.light_occlusion = vec![BenefitGate::default(); views];
    }
    // Each view's screen and occluders (those among its casters), where its occlusion runs this frame.
    let mut gated = 0;
    let chosen: Vec<Option<(ScreenView, Vec<OccluderInstance>)>> = light_views
        .0
        .iter()
        .zip(&mut gate.light_occlusion)
        .map(|(view, gate)| {
            if !settings.enabled || view.kept < settings.min_casters {
                return None;
            }
            if gate.skip_this_frame() {
                gated += 1;
                return None;
            }
            // A light view not made by `light_views` may have no screen; it keeps its casters.
            let screen = ScreenView::of_light_view(&view.view, settings.size)?;
            let instances: Vec<OccluderInstance> =
                select_occluders_for_view(&store, &view.visible, &screen, settings.triangle_budget, |slot| {
                    let (occluder, transform) = occluders.get(store.entities()[slot]).ok()?;
                    Some(OccluderInstance { occluder, transform: transform.0 })
                })
                .into_iter()
                .map(|(_, instance)| instance)
                .collect();
            (!instances.is_empty()).then_some((screen, instances))
        })
        .collect();
    stats.light_occlusion_gated = gated;
    light_views
        .0
        .par_iter_mut()
        .zip(&mut state.pyramids)
        .zip(&mut state.occluded)
        .zip(&mut state.survivors)
        .zip(&chosen)
        .for_each(|((((view, pyramid), occluded), survivors), chosen)| {
            view.occluded = 0;
            let Some((screen, chosen)) = chosen else {
                *pyramid = DepthPyramid::default();
                occluded.reset(0);
                return;
            };
            let tested = view.kept;
            let mode = RasterMode::Conservative;
            view.kept =
                occlude(&store, &view.visible, Some(screen), chosen, mode, pyramid, survivors, occluded).test.visible;
            std::mem::swap(&mut view.visible, survivors);
            view.occluded = tested - view.kept;
        });
    for ((view, gate), chosen) in light_views.0.iter().zip(&mut gate.light_occlusion).zip(&chosen) {
        if chosen.is_some() {
            let (min_benefit, low_frames, reprobe) =
                (adaptive.min_light_occlusion_benefit, adaptive.low_benefit_frames, adaptive.reprobe_every);
            gate.record(view.occluded, view.kept + view.occluded, min_benefit, low_frames, reprobe);
        }
    }
    stats.light_view_occluded = light_views.0.iter().map(|view| view.occluded).sum();
    stats.light_view_casters = light_views.0.iter().map(|view| view.kept).sum();
    stats.light_occlusion_time = start.elapsed();
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pixel-centre or masked buffer below the frame is conservative for the frame it stands for, and only
    /// for it; no larger than it; and its view moves each test inward by what the frame's pixel centres reach.
    #[test]
    fn sample_centre_buffers_below_the_frame_are_conservative_for_that_frame() {
        let frame = (1920, 1080);
        let masked = OcclusionSettings {
            width: 960,
            height: 540,
            mode: RasterMode::Masked,
            frame: Some(frame),
            ..OcclusionSettings::default()
        };
        assert!(masked.is_conservative_for(frame));
        assert!(!masked.is_conservative_for((2560, 1440)));
        assert!(!OcclusionSettings { frame: None, ..masked }.is_conservative_for(frame));
        assert!(!OcclusionSettings { width: 2560, height: 1440, ..masked }.is_conservative_for(frame));
        let fast = OcclusionSettings { mode: RasterMode::Fast, ..masked };
        assert!(!fast.is_conservative_for(frame));
        let camera = Camera::looking_at(glam::Vec3::ZERO, glam::Vec3::NEG_Z);
        assert_eq!(masked.view(&camera).sample_reach, [0.25, 0.25]);
        // At two thirds, a frame pixel centre can lie on a buffer pixel's edge.
        let two_thirds = OcclusionSettings { width: 1280, height: 720, ..masked };
        assert_eq!(two_thirds.view(&camera).sample_reach, [0.5, 0.5]);
        let third = OcclusionSettings { width: 640, height: 360, ..masked };
        assert!(third.view(&camera).sample_reach.iter().all(|r| (r - 1.0 / 3.0).abs() < 1e-12));
        let own_size = OcclusionSettings { width: 1920, height: 1080, ..masked };
        assert_eq!(own_size.view(&camera).sample_reach, [0.0, 0.0]);
        assert_eq!(OcclusionSettings::default().view(&camera).sample_reach, [0.0, 0.0]);
    }

    /// The frame's settings take the frame's own size up to 960x540 samples, a whole divisor of it beyond.
    #[test]
    fn settings_for_a_frame_divide_it_by_the_smallest_whole_number_that_fits() {
        let size = |(width, height)| {
            let settings = OcclusionSettings::for_frame(width, height);
            assert!(settings.is_conservative_for((width, height)), "{width}x{height}");
            (settings.width, settings.height)
        };
        assert_eq!(size((640, 360)), (640, 360));
        assert_eq!(size((960, 540)), (960, 540));
        assert_eq!(size((961, 540)), (481, 270));
        assert_eq!(size((1920, 1080)), (960, 540));
        assert_eq!(size((2560, 1440)), (854, 480));
        assert_eq!(size((3840, 2160)), (960, 540));
        assert_eq!(size((1, 1)), (1, 1));
        let (width, height) = size((u32::MAX, u32::MAX));
        assert!(u64::from(width) * u64::from(height) <= FRAME_BUFFER_SAMPLES);
    }

    /// A resized frame gets the buffer the frame's settings would choose where they chose it; keeps any other
    /// pixel-centre or masked buffer in the same relation to it (and conservative for it); leaves a
    /// conservative buffer's size alone; and ignores a frame with no pixels.
    #[test]
    fn resized_settings_follow_the_frame() {
        let chosen =
            OcclusionSettings { enabled: false, triangle_budget: 77, ..OcclusionSettings::for_frame(1281, 721) };
        for (width, height) in [(1920, 1080), (1281, 721), (640, 360), (7, 3), (u32::MAX, 100)] {
            let resized = chosen.resized_to(width, height);
            let expected = OcclusionSettings {
                enabled: false,
                triangle_budget: 77,
                ..OcclusionSettings::for_frame(width, height)
            };
            assert_eq!(resized, expected);
            assert_eq!(resized.resized_to(1281, 721), chosen);
        }
        // A quarter of the frame stays a quarter; two thirds, no whole divisor, keeps its share.
        let quarter = OcclusionSettings { width: 480, height: 270, ..OcclusionSettings::for_frame(1920, 1080) };
        let resized = quarter.resized_to(1281, 721);
        assert_eq!((resized.width, resized.height, resized.frame), (321, 181, Some((1281, 721))));
        assert!(resized.is_conservative_for((1281, 721)));
        let two_thirds = OcclusionSettings { width: 1280, height: 720, ..quarter };
        let resized = two_thirds.resized_to(960, 540);
        assert_eq!((resized.width, resized.height), (640, 360));
        assert!(resized.is_conservative_for((960, 540)));
        // With no frame, the buffer was the frame's own size.
        let own_size = OcclusionSettings { mode: RasterMode::PixelCentres, ..OcclusionSettings::default() };
        let resized = own_size.resized_to(1920, 1080);
        assert_eq!((resized.width, resized.height, resized.frame), (1920, 1080, Some((1920, 1080))));
        assert_eq!(resized.view(&Camera::looking_at(glam::Vec3::ZERO, glam::Vec3::NEG_Z)).sample_reach, [0.0; 2]);
        let conservative = OcclusionSettings::default().resized_to(640, 360);
        assert_eq!((conservative.width, conservative.height, conservative.frame), (256, 144, Some((640, 360))));
        assert_eq!(chosen.resized_to(0, 720), chosen);
    }

    /// Each way is measured (its first, cold measurement dropped) before they are compared; then the one that
    /// costs less for this many moved objects, a disturbed measurement moving the estimate halfway, and every
    /// 32nd choice the other way.
    #[test]
    fn moved_objects_are_re_tested_the_way_that_last_cost_less() {
        let mut cost = RetestCost::default();
        // Asks `cost` for `moved` of 1000 objects, past any probe, and says whether one by one was chosen.
        let choose = |cost: &mut RetestCost, moved: usize| {
            if (cost.choices + 1).is_multiple_of(RETEST_PROBE_EVERY) {
                cost.choose_alone(moved, 1000);
            }
            cost.choose_alone(moved, 1000)
        };
        cost.record_full(Duration::from_millis(1), 1000); // cold: dropped
        cost.record_full(Duration::from_micros(1), 1000); // 1 ns an object
        assert!(choose(&mut cost, 1_000_000), "one by one is not measured yet");
        cost.record_alone(Duration::from_micros(50), 50); // cold: dropped
        assert!(choose(&mut cost, 1_000_000), "nor yet");
        cost.record_alone(Duration::from_nanos(400), 50); // 8 ns a moved object
        assert!(choose(&mut cost, 100) && !choose(&mut cost, 150));
        cost.record_full(Duration::from_micros(5), 1000); // 5 ns once: 3 ns smoothed
        assert!(choose(&mut cost, 350) && !choose(&mut cost, 400));
        cost.record_alone(Duration::ZERO, 0); // nothing moved: nothing learnt
        assert!(choose(&mut cost, 350) && !choose(&mut cost, 400));
        // The probes: every 32nd choice goes the other way.
        let picks: Vec<bool> = (0..64).map(|_| cost.choose_alone(100, 1000)).collect();
        assert_eq!(picks.iter().filter(|&&alone| !alone).count(), 2);
        // The full pass is measured first where one by one already is.
        let mut fresh = RetestCost::default();
        fresh.record_alone(Duration::from_nanos(400), 50);
        fresh.record_alone(Duration::from_nanos(400), 50);
        assert!(!fresh.choose_alone(1, 1000));
    }
}
