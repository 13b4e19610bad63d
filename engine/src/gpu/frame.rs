//! One frame of the GPU pipeline, orchestrated: the view buffer, then the passes in order (HZB build, cluster
//! culling, triangle culling, draw), each recorded by its own module, then the counters read back. Frames whose
//! candidates exceed the device's largest storage binding run in batches.

use super::clusters::ClusterLibrary;
use super::draw::{DrawPass, DrawSource, RenderTargets, RenderedImage};
use super::hzb::Hzb;
use super::indirect::{DrawBuffers, cluster_draws, indirect_buffer};
use super::interface::{
    GpuView, VIEW_BACKFACE, VIEW_CONE, VIEW_DRAW_CLUSTERS, VIEW_HZB, VIEW_PHASE_EARLY, VIEW_PHASE_FINAL,
    VIEW_PHASE_LATE, VIEW_PHASE_LATE_OCCLUDERS, VIEW_SECOND_HZB, VIEW_SMALL_CLUSTER, VIEW_SMALL_TRIANGLE,
    VIEW_TRIANGLE_FRUSTUM,
};
use super::late_read::LateRead;
use super::output::{
    COUNTER_BYTES, GpuCounters, GpuFrameOutput, ONE_PHASE_PASSES, PassTimer, PhaseCounters, TIMED_PASSES,
    TWO_PHASE_PASSES,
};
use super::own_renderer::{OwnRenderer, check_depth};
use super::scene::{GpuInstance, GpuScene, drawn_meshes, instance_of, instances_from_world};
use super::shadow::{Cascade, CascadeCulling, ShadowMaps};
use super::two_phase::{OccluderStageGate, TwoPhase};
use super::view_cull::{CullPasses, PassGate, ViewCull, candidates, fits_binding, view_buffer};
use super::{GpuContext, GpuError};
use crate::bounds::BoundsStore;
use crate::camera::Camera;
use crate::camera::DepthConvention;
use crate::culler::LightViewVisible;
use crate::depth::DepthBuffer;
use crate::frustum::LightSource;
use crate::mesh::Mesh;
use crate::pipeline::{CameraCuller, LightViews, LightViewsVisible};

use crate::culler::{BenefitGate, OcclusionSettings};
use bevy_ecs::prelude::*;
use bytemuck::Zeroable;
use std::time::{Duration, Instant};

/// `renderer` lent for a shorter while: the trait object's lifetime shrinks with the borrow's.
fn reborrow<'a>(renderer: &'a mut Option<&mut dyn OwnRenderer>) -> Option<&'a mut dyn OwnRenderer> {
    renderer.as_mut().map(|renderer| &mut **renderer as &mut dyn OwnRenderer)
}

/// Which GPU tests run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GpuCullSettings {
    /// Normal-cone back-face test of clusters (conservative).
    pub cluster_cone: bool,
    /// HZB test of clusters against the CPU occluder buffer (conservative when that buffer is).
    pub cluster_hzb: bool,
    /// Cull clusters under a pixel across (lossy, off by default).
    pub small_clusters: bool,
    /// Back-face test of triangles (conservative).
    pub triangle_backface: bool,
    /// Viewport test of triangles (conservative).
    pub triangle_frustum: bool,
    /// Small-triangle test, eq. 19.4 (conservative: only triangles that cover no pixel centre).
    pub small_triangles: bool,
    /// Two-phase occlusion ([`super::two_phase`], conservative): the camera's clusters visible last frame are
    /// drawn first, and the rest tested against the depth they drew merged with the CPU occluder buffer (the
    /// CPU buffer only where `cluster_hzb`). A frame split into batches, or drawn from another camera than it
    /// culls for, runs in one phase, as do frames while it hides too little
    /// ([`GpuGating::min_two_phase_benefit`]).
    pub two_phase: bool,
}

impl Default for GpuCullSettings {
    /// Every conservative test on; small-cluster culling off.
    fn default() -> Self {
        Self {
            cluster_cone: true,
            cluster_hzb: true,
            small_clusters: false,
            triangle_backface: true,
            triangle_frustum: true,
            small_triangles: true,
            two_phase: false,
        }
    }
}

/// When a frame's counters come back to the CPU ([`GpuCuller::set_read_back`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ReadBack {
    /// Each frame waits for its own GPU work and returns its own counters: what tests and the judge need.
    #[default]
    Wait,
    /// Each frame returns the previous frame's counters, copied in that frame's own submission, and waits at
    /// most for that earlier work: the CPU prepares frame N while the GPU works on frame N-1. The first such
    /// frame returns zero counters; pass times and light views' counters are not read.
    /// ([`GpuFrameOutput::counters_late`] says which a frame returned.) A frame split into batches waits.
    Late,
}

/// What [`GpuCuller::run_batch`] needs to know of its frame.
#[derive(Clone, Copy)]
struct BatchFrame {
    /// The passes the frame skips.
    gate: PassGate,
    /// The frame's first batch (it builds the HZB and clears the targets).
    first: bool,
    /// Its counters come back a frame late ([`ReadBack::Late`]).
    late: bool,
    /// It runs in two phases ([`GpuCullSettings::two_phase`], and [`TwoPhase::begin_frame`] done).
    two_phase: bool,
}

/// Which GPU passes a frame may skip where they cannot pay off. Insert it as a resource of the world to have
/// [`GpuCuller::run_world`] use it (the default otherwise), or give it with [`GpuCuller::set_gating`]. Skipping
/// a pass keeps everything it would have tested, so gating adds no false negative.
///
/// Each pass is skipped once it has removed less than its share of what it tested for `low_benefit_frames`
/// frames in a row, and re-probed every `reprobe_every` frames. The shares a pass must remove to pay for
/// itself depend on the GPU: `CULLET_GPU_GATES=1 cargo bench -p cullet-benches --bench gpu` measures them.
/// The defaults are an NVIDIA H200's (1920x1080): the triangle pass paid above 34-40% removed on the city
/// and the CAD scene (81% on the open field), the cluster pass above about 40% on the city.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct GpuGating {
    /// A frame whose candidates (the CPU stages' survivors) have at most this many clusters skips the cluster
    /// pass: the CPU lists every candidate cluster for the triangle pass (or the draw) instead. With so few
    /// clusters the pass cannot save more than its own dispatch costs. 0 never skips.
    pub tiny_scene_clusters: u32,
    /// The least fraction of its clusters the cluster pass must remove; below it (see the type's docs) the
    /// CPU lists every candidate cluster instead. The pass tests each cluster's normal cone and box, which
    /// saves the triangle pass and the draw only the clusters it removes. 0 never skips.
    pub min_cluster_benefit: f32,
    /// The least fraction of its triangles the triangle pass must remove; below it (see the type's docs) the
    /// surviving clusters are drawn whole and the hardware culls their triangles. The pass reads and
    /// transforms every triangle, about the work the hardware's vertex stage and culling do on it, so it pays
    /// only when it removes a good share. 0 never skips.
    pub min_triangle_benefit: f32,
    /// The least fraction of the clusters two-phase occlusion's late phase tests that its merged HZB must
    /// hide ([`GpuCullSettings::two_phase`]); below it (see the type's docs) frames run in one phase. The late
    /// phase and the merge cost about a second cluster pass and a pass over the depth, and they pay only where
    /// the frame's own depth hides what the CPU buffer does not. 0 never skips.
    pub min_two_phase_benefit: f32,
    /// The least fraction of the triangles two phases draw without the CPU occluder stage that the stage must
    /// save; below it, the world's camera culler skips the stage ([`crate::culler::ViewCuller::skip_occlusion_once`]),
    /// and the frame's own depth culls alone. Judged by [`GpuCuller::run_world`] on frames of two phases whose
    /// counters it reads at once: one frame without the stage next to one with it, every `reprobe_every`
    /// frames, each by the share of the frustum's triangles drawn. 0 never skips.
    pub min_occluder_benefit: f32,
    /// The least fraction of a frame's triangles that two phases' late occluder step must draw
    /// ([`super::interface::VIEW_PHASE_LATE_OCCLUDERS`]); below it (see the type's docs) the late phase runs
    /// in one step. The step draws the large clusters the late phase keeps before it tests the rest, and costs
    /// a cluster pass and another merge of the depth: it can pay only where it draws something, which is where
    /// much comes into view at once. 0 never skips.
    pub min_late_occluder_share: f32,
    /// Frames in a row under its share before a pass is skipped.
    pub low_benefit_frames: u32,
    /// Frames a pass stays skipped before it runs again to re-probe.
    pub reprobe_every: u32,
}

impl Default for GpuGating {
    /// No cluster pass for 64 clusters or fewer; each pass skipped after 8 frames under 40% removed, two
    /// phases after 8 frames under 5% of the late phase's clusters hidden, the late occluder step after 8 frames
    /// drawing under 1% of the triangles; re-probed every 30 frames. Beside two phases, the CPU occluder stage
    /// skipped where it saves less than 5% of the triangles drawn.
    fn default() -> Self {
        Self {
            tiny_scene_clusters: 64,
            min_cluster_benefit: 0.4,
            min_triangle_benefit: 0.4,
            min_two_phase_benefit: 0.05,
            min_occluder_benefit: 0.05,
            min_late_occluder_share: 0.01,
            low_benefit_frames: 8,
            reprobe_every: 30,
        }
    }
}

impl GpuGating {
    /// No gating: every pass runs every frame (the fixed pipeline, for comparison).
    pub fn fixed() -> Self {
        Self {
            tiny_scene_clusters: 0,
            min_cluster_benefit: 0.0,
            min_triangle_benefit: 0.0,
            min_two_phase_benefit: 0.0,
            min_occluder_benefit: 0.0,
            min_late_occluder_share: 0.0,
            low_benefit_frames: u32::MAX,
            reprobe_every: 0,
        }
    }
}

/// One sun cascade of a world's [`LightViewsVisible`]: its light view's matrix and origin, and its casters' store
/// slots.
pub(super) struct SunCasters(glam::DMat4, glam::Vec3, Vec<u32>);

impl SunCasters {
    pub(super) fn cascade(&self) -> Cascade<'_> {
        Cascade { clip_from_relative: self.0, origin: self.1, casters: &self.2 }
    }
}

/// The sun cascades of `world`'s [`LightViewsVisible`] (of its [`LightViews`] suns, nearest first), each with
/// the casters its light view kept; `None` without light views.
pub(super) fn sun_casters(world: &World) -> Option<Vec<SunCasters>> {
    let results = world.get_resource::<LightViewsVisible>()?;
    let lights = world.get_resource::<LightViews>()?;
    let suns = results.0.iter().filter(|result| matches!(lights.0.get(result.light), Some(LightSource::Sun { .. })));
    Some(
        suns.map(|result: &LightViewVisible| {
            let casters = result.visible.iter().map(|slot| slot as u32).collect();
            SunCasters(result.view.clip_from_relative, result.view.origin, casters)
        })
        .collect(),
    )
}

/// A frame's surviving `(instance, cluster)` pairs and the global vertex indices of the triangles it drew (see
/// [`GpuCuller::read_survivors`]).
pub type Survivors = (Vec<(u32, u32)>, Vec<u32>);

/// The GPU pipeline for one scene: the scene's buffers, the passes, per-frame buffers and render targets.
///
/// Build it with [`GpuCuller::for_world`]; each frame, after the CPU stages ran,
/// [`GpuCuller::run_world`] brings the instances up to date, culls and draws. A renderer of its own draws
/// from [`GpuCuller::draw_buffers`] after the culler's draw, or every frame in place of it through
/// [`GpuCuller::run_world_into`] (which two-phase occlusion needs to cull against the renderer's depth).
pub struct GpuCuller {
    pub(super) scene: GpuScene,
    hzb: Hzb,
    passes: CullPasses,
    /// The camera's culling: its uniform, counters and per-frame buffers.
    camera: ViewCull,
    draw: DrawPass,
    /// The sun cascades' shadow maps the draw shades with (none until a world with light views runs).
    pub(super) shadows: ShadowMaps,
    targets: RenderTargets,
    /// The view the draw pass renders from: the culling view, or another camera's (see [`DebugDraw::run_from`](super::DebugDraw::run_from)).
    draw_view: wgpu::Buffer,
    last_view: GpuView,
    timer: Option<PassTimer>,
    last_counters: GpuCounters,
    /// Which passes the last frame skipped.
    last_gate: PassGate,
    /// A smaller storage-binding budget than the device's, to split frames into batches (see
    /// [`GpuCuller::limit_batches`]).
    batch_bytes: Option<u64>,
    /// Which GPU passes a frame may skip (see [`GpuCuller::set_gating`]).
    gating: GpuGating,
    /// The instance buffer holds colours other than the objects' own ([`DebugDraw::recolored`](super::DebugDraw::recolored)):
    /// the next [`GpuCuller::run_world`] rewrites every instance.
    pub(super) recolored: bool,
    /// When the counters come back (see [`GpuCuller::set_read_back`]).
    read_back: ReadBack,
    /// The copies of the counters read a frame late, each with its frame's instance count and pass gate.
    late: Option<LateRead<(u32, PassGate)>>,
    /// The last frame's counters are still on the GPU (it read the frame before's): `last_counters` is stale.
    counters_pending: bool,
    /// The instances the last frame culled.
    last_instances: u32,
    /// Two-phase occlusion's state, once a frame has asked for it.
    two_phase: Option<TwoPhase>,
    /// The last frame ran in two phases.
    last_two_phase: bool,
    /// Its phases' counters, where it did.
    last_phases: Option<PhaseCounters>,
    /// The late phase's view of the last frame of two phases.
    last_late_view: Option<GpuView>,
    /// When frames run in one phase for two-phase occlusion's hiding too little lately.
    two_phase_gate: BenefitGate,
    /// Frames of two phases in a row: the first after frames of one has nothing marked to draw early, and
    /// says nothing of what two phases remove.
    two_phase_run: u32,
    /// Whether the world's CPU occluder stage pays beside two phases ([`GpuGating::min_occluder_benefit`]).
    occluder_gate: OccluderStageGate,
    /// When the late phase runs in one step for its occluder step's drawing too little lately
    /// ([`GpuGating::min_late_occluder_share`]).
    late_occluder_gate: BenefitGate,
}

impl GpuCuller {
    /// The GPU pipeline for the objects of `world` (set up by [`crate::install`], its objects spawned), which
    /// draw `meshes` through their [`crate::mesh::MeshRef`], rendering into `target_size` (width, height in
    /// pixels) targets. The HZB is sized for the world's [`OcclusionSettings`] (it follows their changes
    /// frame by frame). Builds the clusters of every mesh (meshoptimizer) and uploads them with the
    /// instances.
    ///
    /// # Panics
    /// If `world` was not set up by [`crate::install`] (it has no [`BoundsStore`]).
    pub fn for_world(context: &GpuContext, world: &World, meshes: &[Mesh], target_size: (u32, u32)) -> Self {
        let occlusion = world.get_resource::<OcclusionSettings>().copied().unwrap_or_default();
        let scene =
            GpuScene::new(context, ClusterLibrary::build(drawn_meshes(world, meshes)), instances_from_world(world));
        Self::new(context, scene, target_size.0, target_size.1, occlusion.width, occlusion.height)
    }

    /// The pipeline for `scene` (its buffers already uploaded), drawing into `width` x `height` targets, with
    /// an HZB for occlusion buffers of `hzb_width` x `hzb_height`. [`GpuCuller::for_world`] is the usual way in.
    pub fn new(
        context: &GpuContext,
        scene: GpuScene,
        width: u32,
        height: u32,
        hzb_width: u32,
        hzb_height: u32,
    ) -> Self {
        Self {
            scene,
            hzb: Hzb::new(context, hzb_width, hzb_height),
            passes: CullPasses::new(context),
            camera: ViewCull::new(context, "view"),
            draw: DrawPass::new(context),
            shadows: ShadowMaps::new(context),
            targets: RenderTargets::new(context, width, height),
            draw_view: view_buffer(context, "draw view"),
            last_view: GpuView::zeroed(),
            timer: PassTimer::new(context),
            last_counters: GpuCounters::default(),
            last_gate: PassGate::default(),
            batch_bytes: None,
            gating: GpuGating::default(),
            recolored: false,
            read_back: ReadBack::Wait,
            late: None,
            counters_pending: false,
            last_instances: 0,
            two_phase: None,
            last_two_phase: false,
            last_phases: None,
            last_late_view: None,
            two_phase_gate: BenefitGate::default(),
            two_phase_run: 0,
            occluder_gate: OccluderStageGate::default(),
            late_occluder_gate: BenefitGate::default(),
        }
    }

    /// Sets when frames' counters come back to the CPU: [`ReadBack::Wait`] (the default) or a frame late.
    pub fn set_read_back(&mut self, read_back: ReadBack) {
        self.read_back = read_back;
    }

    /// The scene's buffers and cluster library.
    pub fn scene(&self) -> &GpuScene {
        &self.scene
    }

    /// The HZB of the last frame.
    pub fn hzb(&self) -> &Hzb {
        &self.hzb
    }

    /// Sets two-phase occlusion's frame count (see `two_phase.rs`): for the test of its wrapping around.
    #[doc(hidden)]
    pub fn set_two_phase_frame(&mut self, frame: u32) {
        if let Some(state) = self.two_phase.as_mut() {
            state.frame = frame;
        }
    }

    /// The late phase's view of the last frame of two phases (for the CPU twins in tests).
    pub fn last_late_view(&self) -> Option<&GpuView> {
        self.last_late_view.as_ref()
    }

    /// The merged HZB of the last frame of two phases ([`GpuCullSettings::two_phase`]; `None` before one).
    pub fn merged_hzb(&self) -> Option<&Hzb> {
        self.two_phase.as_ref().map(|state| &state.hzb)
    }

    /// The render targets the culler draws into.
    pub fn targets(&self) -> &RenderTargets {
        &self.targets
    }

    /// The last frame's view (for the CPU twins in tests).
    pub fn last_view(&self) -> &GpuView {
        &self.last_view
    }

    /// Makes new `width` x `height` render targets (a resized window); the next frame draws into them.
    pub fn resize(&mut self, context: &GpuContext, width: u32, height: u32) {
        if self.targets.size() != (width, height) {
            self.targets = RenderTargets::new(context, width, height);
        }
    }

    /// The buffers of the last frame's draw, to draw the survivors from a render pass of your own; `None`
    /// before the first frame. Valid until the next frame (which may grow and so replace them).
    pub fn draw_buffers(&self) -> Option<DrawBuffers<'_>> {
        self.camera.draws(&self.scene, self.last_gate.skip_triangles)
    }

    /// The buffers of the last frame's late phase, where it ran in two ([`GpuCullSettings::two_phase`]), in the
    /// order drawn: its occluder step's, where it ran, then the rest's. A renderer of its own draws them after
    /// [`GpuCuller::draw_buffers`] (the early phase), into the same depth. Empty after a frame of one phase.
    pub fn late_draw_buffers(&self) -> Vec<DrawBuffers<'_>> {
        let Some(state) = self.two_phase.as_ref().filter(|_| self.last_two_phase) else {
            return Vec::new();
        };
        let steps = [state.split.then_some(&state.late_occluders), Some(&state.late)];
        steps.into_iter().flatten().filter_map(|view| view.draws(&self.scene, self.last_gate.skip_triangles)).collect()
    }

    /// The view for `camera` with `settings`, the HZB as it is sized now and `visible_count` instances.
    pub fn view_for(&self, camera: &Camera, settings: &GpuCullSettings, visible_count: u32) -> GpuView {
        let flags = [
            (settings.cluster_cone, VIEW_CONE),
            (settings.cluster_hzb, VIEW_HZB),
            (settings.small_clusters, VIEW_SMALL_CLUSTER),
            (settings.triangle_backface, VIEW_BACKFACE),
            (settings.small_triangles, VIEW_SMALL_TRIANGLE),
            (settings.triangle_frustum, VIEW_TRIANGLE_FRUSTUM),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .fold(0, |flags, (_, bit)| flags | bit);
        GpuView {
            hzb_size: self.hzb.screen_size,
            hzb_levels: self.hzb.view_levels(0),
            hzb_level_count: self.hzb.levels.len() as u32,
            visible_count,
            flags,
            ..GpuView::of_camera(camera, self.targets.size())
        }
    }

    /// Culls and draws one frame: `visible` lists the instances (store slots) the CPU stages kept, `depth` is
    /// the CPU occluder buffer (empty for none). Returns the counters and timings; the survivors stay on the
    /// GPU ([`GpuCuller::read_survivors`], [`GpuCuller::draw_buffers`]).
    ///
    /// # Errors
    /// [`GpuError::SlotOutOfRange`] for a slot of `visible` that is not an instance of the scene (nothing is
    /// run), [`GpuError::Lost`] when the device is lost.
    pub fn run(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
    ) -> Result<GpuFrameOutput, GpuError> {
        self.run_views(context, camera, camera, visible, depth, settings, None, None)
    }

    /// [`GpuCuller::run`] with `renderer` drawing the survivors into its own targets instead of the culler
    /// into its own ([`GpuCuller::read_image`] then keeps an earlier frame's image). With
    /// [`GpuCullSettings::two_phase`], the late phase culls against the depth `renderer` drew in the early
    /// phase, merged with the CPU pyramid.
    ///
    /// # Errors
    /// As [`GpuCuller::run`], and [`GpuError::RendererDepth`] (nothing is run) where the settings ask for two
    /// phases and the renderer's depth texture is not one the merge can read.
    pub fn run_into(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
        renderer: &mut dyn OwnRenderer,
    ) -> Result<GpuFrameOutput, GpuError> {
        self.run_views(context, camera, camera, visible, depth, settings, None, Some(renderer))
    }

    /// [`GpuCuller::run`] drawing the survivors as `draw_camera` sees them (by `renderer` where given, from
    /// `camera`), and with `cascades` the shadow maps culled and drawn first, in the same submission; with
    /// `None` the shadow maps stay as they are.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn run_views(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        draw_camera: &Camera,
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
        mut cascades: Option<&[Cascade<'_>]>,
        mut renderer: Option<&mut dyn OwnRenderer>,
    ) -> Result<GpuFrameOutput, GpuError> {
        if let Some(renderer) = renderer.as_deref().filter(|_| settings.two_phase) {
            check_depth(renderer.depth(), self.targets.size())?;
        }
        let draw_camera = if renderer.is_some() { camera } else { draw_camera };
        if depth.width() > 0 && !self.hzb.fits(depth.width(), depth.height()) {
            self.hzb = Hzb::new(context, depth.width(), depth.height());
        }
        self.hzb.set_screen(depth);
        let instances = self.scene.instances();
        let out_of_range = |slots: &[u32]| slots.iter().copied().find(|&slot| slot as usize >= instances.len());
        let casters = cascades.into_iter().flatten().map(|cascade| cascade.casters);
        if let Some(slot) = std::iter::once(visible).chain(casters).find_map(out_of_range) {
            return Err(GpuError::SlotOutOfRange { slot, instances: instances.len() });
        }
        let (candidate_clusters, _) = candidates(&self.scene, visible);
        let mut gate = self.camera.gate(&self.gating, candidate_clusters as usize);
        let batches = self.batches(context, visible);
        let gated = settings.two_phase && self.two_phase_gate.skip_this_frame();
        let two_phase = settings.two_phase
            && !gated
            && batches.len() == 1
            && draw_camera == camera
            && self.begin_two_phase(context);
        self.two_phase_run = if two_phase { self.two_phase_run + 1 } else { 0 };
        if let Some(state) = self.two_phase.as_mut().filter(|_| two_phase) {
            state.split = !self.late_occluder_gate.skip_this_frame();
        }
        // The cluster pass splits the phases: it always runs.
        gate.skip_clusters &= !two_phase;
        let late = self.read_back == ReadBack::Late && batches.len() == 1 && !two_phase;
        if !late && let Some(pending) = self.late.as_mut() {
            pending.forget(context)?;
        }
        let mut total: Option<GpuFrameOutput> = None;
        for (i, batch) in batches.into_iter().enumerate() {
            let (first, cascades) = (i == 0, cascades.take());
            let frame = BatchFrame { gate, first, late, two_phase };
            let renderer = reborrow(&mut renderer);
            let draw = (draw_camera, renderer);
            let output = self.run_batch(context, camera, draw, &visible[batch], depth, settings, frame, cascades)?;
            total = Some(match total {
                None => output,
                Some(sum) => sum.plus(&output),
            });
        }
        let total = total.unwrap_or_default();
        if !late {
            self.camera.record_benefit(&self.gating, gate, &total.counters);
        }
        if let Some(phases) = total.phases.filter(|_| self.two_phase_run >= 2) {
            let g = &self.gating;
            let (hidden, tested) = (phases.late.clusters_hzb as usize, phases.late.clusters_in as usize);
            self.two_phase_gate.record(hidden, tested, g.min_two_phase_benefit, g.low_benefit_frames, g.reprobe_every);
            if let Some(step) = phases.late_occluders {
                let (drawn, all) = (step.triangles_out as usize, total.counters.triangles_out as usize);
                let (share, low, reprobe) = (g.min_late_occluder_share, g.low_benefit_frames, g.reprobe_every);
                self.late_occluder_gate.record(drawn, all, share, low, reprobe);
            }
        }
        Ok(total)
    }

    /// Starts a frame of two phases: the state made or brought up to date with the scene and the CPU pyramid.
    /// `false` where the visibility does not fit a storage binding: the frame runs in one phase.
    fn begin_two_phase(&mut self, context: &GpuContext) -> bool {
        let (limit, target) = (self.binding_limit(context), self.targets.size());
        let state = self.two_phase.get_or_insert_with(|| TwoPhase::new(context, target, &self.hzb));
        state.begin_frame(context, &self.scene, (target, &self.hzb), limit)
    }

    /// Sets which GPU passes a frame may skip (the default [`GpuGating`] until set). New settings start the
    /// triangle pass's benefit count afresh. [`GpuCuller::run_world`] sets the world's, where it has one.
    pub fn set_gating(&mut self, gating: GpuGating) {
        if gating != self.gating {
            self.gating = gating;
            self.camera.reset_gate();
            self.shadows.reset_gates();
            self.two_phase_gate = BenefitGate::default();
            self.occluder_gate = OccluderStageGate::default();
            self.late_occluder_gate = BenefitGate::default();
        }
    }

    /// Splits frames into batches as if the device's largest storage binding were `bytes` (never more than
    /// it is): the path a frame with too many candidate triangles for one batch takes, made testable on a
    /// small scene.
    #[doc(hidden)]
    pub fn limit_batches(&mut self, bytes: u64) {
        self.batch_bytes = Some(bytes);
    }

    /// Splits `visible` into runs whose candidate triangles fit the device's largest storage binding (the
    /// compacted index buffer is sized for every candidate surviving): almost always one run; several when
    /// the CPU stages leave millions of triangles (a large scene with occlusion off), instead of failing.
    fn batches(&self, context: &GpuContext, visible: &[u32]) -> Vec<std::ops::Range<usize>> {
        let limit = self.binding_limit(context);
        let library = &self.scene.library;
        let instances = self.scene.instances();
        let mut batches = Vec::new();
        let (mut start, mut triangles, mut clusters) = (0, 0u64, 0u64);
        for (i, &slot) in visible.iter().enumerate() {
            let own = library.clusters_of(instances[slot as usize].mesh);
            let own_triangles: u64 = own.iter().map(|c| u64::from(c.triangle_count)).sum();
            if i > start && !fits_binding(clusters + own.len() as u64, triangles + own_triangles, limit) {
                batches.push(start..i);
                (start, triangles, clusters) = (i, 0, 0);
            }
            triangles += own_triangles;
            clusters += own.len() as u64;
        }
        batches.push(start..visible.len());
        batches
    }

    /// The largest storage binding a frame's buffers may take: the device's, or less after
    /// [`GpuCuller::limit_batches`].
    fn binding_limit(&self, context: &GpuContext) -> u64 {
        let device_limit = context.device.limits().max_storage_buffer_binding_size;
        self.batch_bytes.map_or(device_limit, |bytes| bytes.min(device_limit))
    }

    /// One batch of [`GpuCuller::run_views`]: the first builds the HZB and clears the targets, later ones draw
    /// over what the earlier ones drew.
    #[allow(clippy::too_many_arguments)]
    fn run_batch(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        (draw_camera, mut renderer): (&Camera, Option<&mut dyn OwnRenderer>),
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
        BatchFrame { gate, first, late, two_phase }: BatchFrame,
        cascades: Option<&[Cascade<'_>]>,
    ) -> Result<GpuFrameOutput, GpuError> {
        let mut view = self.view_for(camera, settings, visible.len() as u32);
        if gate.skip_triangles {
            view.flags |= VIEW_DRAW_CLUSTERS;
        }
        let frame_candidates = candidates(&self.scene, visible);
        if let Some(state) = self.two_phase.as_mut().filter(|_| two_phase) {
            view.flags |= VIEW_PHASE_EARLY;
            view.frame = state.frame;
            state.late.fit(context, visible.len(), frame_candidates);
            state.late_occluders.fit(context, visible.len(), frame_candidates);
            view = state.against_merged(view, &self.hzb);
        }
        self.last_view = view;
        context.queue.write_buffer(&self.camera.view, 0, bytemuck::bytes_of(&view));
        let draw_view = if draw_camera == camera { view } else { self.view_for(draw_camera, settings, 0) };
        context.queue.write_buffer(&self.draw_view, 0, bytemuck::bytes_of(&draw_view));
        self.camera.fit(context, visible.len(), frame_candidates);
        let mut encoder = context.device.create_command_encoder(&Default::default());
        let timer = self.timer.as_ref();
        if first {
            self.hzb.build(context, depth, &mut encoder, timer.map(|t| t.compute(0)));
        }
        if let Some(cascades) = cascades {
            let culling = CascadeCulling {
                passes: &self.passes,
                hzb: &self.hzb.buffer,
                gating: &self.gating,
                binding_limit: self.binding_limit(context),
            };
            let origin = draw_camera.position;
            self.shadows.record(context, &mut encoder, &self.scene, Some(&culling), cascades, origin);
        }
        let state = self.two_phase.as_ref().filter(|_| two_phase);
        let against = match state {
            Some(state) => state.against(),
            None => self.passes.one_phase(&self.hzb.buffer),
        };
        let scene = &self.scene;
        self.camera.record(context, &mut encoder, scene, &self.passes, against, visible, gate, (timer, 1));
        let draws = self.camera.draws(scene, gate.skip_triangles).expect("fit above");
        match reborrow(&mut renderer) {
            Some(renderer) => renderer.draw(context, &mut encoder, draws, first),
            None => self.record_draw(
                context,
                &mut encoder,
                camera.depth,
                DrawSource::Culled(draws),
                first,
                timer.map(|t| t.render(3)),
            ),
        }
        if let Some(state) = state {
            let late_view = Self::late_view(view, settings);
            let late = (camera, &late_view, settings.cluster_hzb);
            self.record_late_phase(context, &mut encoder, state, late, visible, gate, reborrow(&mut renderer));
            self.last_late_view = Some(late_view);
        }
        let timed = match state {
            Some(state) if state.split => TIMED_PASSES,
            Some(_) => TWO_PHASE_PASSES,
            None => ONE_PHASE_PASSES,
        };
        if let Some(timer) = timer {
            timer.resolve(&mut encoder, timed);
        }
        self.last_gate = gate;
        self.last_instances = visible.len() as u32;
        self.last_two_phase = two_phase;
        if late {
            return self.submit_late(context, encoder, gate);
        }
        let start = Instant::now();
        context.queue.submit([encoder.finish()]);
        let (counters, phases) = self.read_counters(context)?;
        let wall_time = start.elapsed();
        (self.last_counters, self.last_phases, self.counters_pending) = (counters, phases, false);
        let mut pass_times = timer.map(|t| t.read(context, timed)).transpose()?;
        if let Some(times) = pass_times.as_mut().filter(|_| renderer.is_some()) {
            // The renderer's draws are its own passes, which the culler does not time.
            (times.draw, times.late_draw) = (Duration::ZERO, Duration::ZERO);
        }
        let light_views = match cascades {
            Some(_) => self.shadows.read_counters(context, &self.gating)?,
            None => Vec::new(),
        };
        Ok(GpuFrameOutput {
            counters,
            pass_times,
            wall_time,
            cluster_pass_skipped: gate.skip_clusters,
            triangle_pass_skipped: gate.skip_triangles,
            light_views,
            counters_late: false,
            phases,
        })
    }

    /// The late phase's view from the early phase's `view` (which tested against the merged pyramid), with
    /// `settings`: the second pyramid, the CPU's, only where the frame tests against it.
    fn late_view(mut view: GpuView, settings: &GpuCullSettings) -> GpuView {
        view.flags = (view.flags & !VIEW_PHASE_EARLY) | VIEW_PHASE_LATE;
        if !settings.cluster_hzb {
            view.flags &= !VIEW_SECOND_HZB;
        }
        view
    }

    /// Records two-phase occlusion after the early phase's draw from `camera` (by `renderer`, into its depth,
    /// where given): the merge of its depth with the CPU pyramid, the late phase's culling of `visible` with
    /// `late_view` and its draw over the early image, then the final depth merged again and the marks it hides
    /// taken (timed as passes 4 to 9); where [`TwoPhase::split`], the occluder step before the late phase's
    /// culling (passes 10 to 13).
    #[allow(clippy::too_many_arguments)]
    fn record_late_phase(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        state: &TwoPhase,
        (camera, late_view, with_cpu): (&Camera, &GpuView, bool),
        visible: &[u32],
        gate: PassGate,
        renderer: Option<&mut dyn OwnRenderer>,
    ) {
        let timer = self.timer.as_ref();
        // Every draw of the frame goes to one depth, which each merge reads.
        let depth = renderer.as_deref().map_or(self.targets.depth_texture(), |renderer| renderer.depth()).clone();
        let depth = &depth;
        state.record_merge(context, encoder, depth, (&self.hzb, with_cpu), camera, timer.map(|t| t.compute(4)));
        let mut renderer = renderer;
        if state.split {
            // The large clusters first, so that what they hide of the rest is culled (passes 10 to 13).
            let view =
                GpuView { flags: (late_view.flags & !VIEW_PHASE_LATE) | VIEW_PHASE_LATE_OCCLUDERS, ..*late_view };
            let step = &state.late_occluders;
            context.queue.write_buffer(&step.view, 0, bytemuck::bytes_of(&view));
            step.record(context, encoder, &self.scene, &self.passes, state.against(), visible, gate, (timer, 10));
            let draws = step.draws(&self.scene, gate.skip_triangles).expect("fit in run_batch");
            self.record_phase_draw(context, encoder, camera, draws, reborrow(&mut renderer), 12);
            state.record_merge(context, encoder, depth, (&self.hzb, with_cpu), camera, timer.map(|t| t.compute(13)));
        }
        context.queue.write_buffer(&state.late.view, 0, bytemuck::bytes_of(late_view));
        let against = state.against();
        state.late.record(context, encoder, &self.scene, &self.passes, against, visible, gate, (timer, 5));
        let draws = state.late.draws(&self.scene, gate.skip_triangles).expect("fit in run_batch");
        self.record_phase_draw(context, encoder, camera, draws, renderer, 7);
        // The frame's final depth, merged again, takes the marks of what it hides (next frame's early phase
        // tests against this pyramid too).
        state.record_merge(context, encoder, depth, (&self.hzb, with_cpu), camera, timer.map(|t| t.compute(8)));
        let final_view = GpuView { flags: (late_view.flags & !VIEW_PHASE_LATE) | VIEW_PHASE_FINAL, ..*late_view };
        context.queue.write_buffer(&state.final_view, 0, bytemuck::bytes_of(&final_view));
        let marking = (&self.passes, state.against());
        let (instances, timestamps) = (visible.len() as u32, timer.map(|t| t.compute(9)));
        state.late.record_marks(context, encoder, &self.scene, marking, &state.final_view, instances, timestamps);
    }

    /// Records the draw of a late phase's `draws` over the early image from `camera`, by `renderer` where
    /// given or into the culler's targets timed as pass `timed`.
    fn record_phase_draw(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        camera: &Camera,
        draws: DrawBuffers<'_>,
        renderer: Option<&mut dyn OwnRenderer>,
        timed: u32,
    ) {
        match renderer {
            Some(renderer) => renderer.draw(context, encoder, draws, false),
            None => {
                let timestamps = self.timer.as_ref().map(|t| t.render(timed));
                self.record_draw(context, encoder, camera.depth, DrawSource::Culled(draws), false, timestamps);
            }
        }
    }

    /// The last submitted frame's counters, waiting for the GPU: the camera's, and where the frame ran in two
    /// phases, both phases' added up and each on its own.
    fn read_counters(&self, context: &GpuContext) -> Result<(GpuCounters, Option<PhaseCounters>), GpuError> {
        let read = |view: &ViewCull| self.read_view_counters(context, view);
        let early = read(&self.camera)?;
        match self.two_phase.as_ref().filter(|_| self.last_two_phase) {
            None => Ok((early, None)),
            Some(state) => {
                let late_occluders = if state.split { Some(read(&state.late_occluders)?) } else { None };
                let rest = read(&state.late)?;
                // Both steps cull the same instances.
                let late =
                    late_occluders.map_or(rest, |step| GpuCounters { instances: rest.instances, ..step.plus(&rest) });
                let total = GpuCounters { instances: self.last_instances, ..early.plus(&late) };
                Ok((total, Some(PhaseCounters { early, late, late_occluders })))
            }
        }
    }

    /// Submits a frame's work with a copy of its counters, and returns the previous frame's ([`ReadBack::Late`]),
    /// waiting at most for the previous frame's work. The gates learn from the previous frame's counters.
    fn submit_late(
        &mut self,
        context: &GpuContext,
        mut encoder: wgpu::CommandEncoder,
        gate: PassGate,
    ) -> Result<GpuFrameOutput, GpuError> {
        let late = self.late.get_or_insert_with(|| LateRead::new(context, COUNTER_BYTES));
        let slot = late.record(&mut encoder, &self.camera.counters);
        let start = Instant::now();
        let submission = context.queue.submit([encoder.finish()]);
        late.submitted(slot, submission, (self.last_instances, gate));
        let previous = late.take_previous(context)?;
        let wall_time = start.elapsed();
        self.counters_pending = true;
        let counters = match previous {
            Some((bytes, (instances, previous_gate))) => {
                let counters = GpuCounters::from_slots(instances, bytemuck::cast_slice(&bytes));
                self.camera.record_benefit(&self.gating, previous_gate, &counters);
                counters
            }
            None => GpuCounters::default(),
        };
        Ok(GpuFrameOutput {
            counters,
            pass_times: None,
            wall_time,
            cluster_pass_skipped: gate.skip_clusters,
            triangle_pass_skipped: gate.skip_triangles,
            light_views: Vec::new(),
            counters_late: true,
            phases: None,
        })
    }

    /// The last frame's surviving `(instance, cluster)` pairs, in the GPU's (unordered) append order, and the
    /// global vertex indices of the triangles it drew: its compacted index buffer, or where the triangle pass
    /// was skipped, the surviving clusters' own triangles.
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    pub fn read_survivors(&self, context: &GpuContext) -> Result<Survivors, GpuError> {
        let (mut counters, mut phases) = (self.last_counters, self.last_phases);
        if self.counters_pending {
            // Read a frame late: this frame's counters, which say how much of the buffers to read, are read now.
            (counters, phases) = self.read_counters(context)?;
        }
        match (phases, self.two_phase.as_ref()) {
            (Some(phases), Some(state)) => {
                let early = self.survivors_of(context, &self.camera, phases.early)?;
                // The late phase's own counters: `phases.late` includes the occluder step's.
                let rest = phases.late_occluders.map_or(phases.late, |step| phases.late.less(&step));
                let rest = GpuCounters { instances: phases.late.instances, ..rest };
                let mut late = self.survivors_of(context, &state.late, rest)?;
                if let Some(counters) = phases.late_occluders {
                    let step = self.survivors_of(context, &state.late_occluders, counters)?;
                    late = ([step.0, late.0].concat(), [step.1, late.1].concat());
                }
                Ok(([early.0, late.0].concat(), [early.1, late.1].concat()))
            }
            _ => self.survivors_of(context, &self.camera, counters),
        }
    }

    /// The counters of `view`'s last frame, waiting for the GPU.
    fn read_view_counters(&self, context: &GpuContext, view: &ViewCull) -> Result<GpuCounters, GpuError> {
        let bytes = context.read_buffer(&view.counters, COUNTER_BYTES)?;
        Ok(GpuCounters::from_slots(self.last_instances, bytemuck::cast_slice(&bytes)))
    }

    /// [`GpuCuller::read_survivors`] of one view whose last frame counted `counters`.
    fn survivors_of(
        &self,
        context: &GpuContext,
        view: &ViewCull,
        counters: GpuCounters,
    ) -> Result<Survivors, GpuError> {
        let Some(frame) = view.frame.as_ref() else {
            return Ok(Default::default());
        };
        let clusters: Vec<(u32, u32)> = if counters.clusters_out > 0 {
            let bytes = context.read_buffer(&frame.survivors, 8 * u64::from(counters.clusters_out))?;
            bytemuck::cast_slice::<u8, [u32; 2]>(&bytes).iter().map(|&[i, c]| (i, c)).collect()
        } else {
            Vec::new()
        };
        let indices = if self.last_gate.skip_triangles {
            // Drawn whole: each surviving cluster's own triangles.
            let library = &self.scene.library;
            clusters
                .iter()
                .flat_map(|&(_, c)| {
                    let cluster = &library.clusters[c as usize];
                    let first = cluster.first_index as usize;
                    library.indices[first..first + 3 * cluster.triangle_count as usize].to_vec()
                })
                .collect()
        } else if counters.triangles_out > 0 {
            bytemuck::cast_slice(&context.read_buffer(&frame.draw_indices, 12 * u64::from(counters.triangles_out))?)
                .to_vec()
        } else {
            Vec::new()
        };
        Ok((clusters, indices))
    }

    /// Runs the GPU passes after the CPU stages of `world`'s frame: instances brought up to date (only the
    /// store slots written since the last call are copied, from each object's [`crate::mesh::MeshRef`],
    /// [`crate::ObjectTransform`] and [`crate::mesh::ObjectColor`]), the occlusion stage's survivors culled and
    /// drawn against its depth buffer, from the world's [`Camera`], with the world's [`GpuGating`] if it has
    /// one.
    ///
    /// The culler drains [`BoundsStore::take_written_slots`]: nothing else should.
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    ///
    /// # Panics
    /// If `world` was not set up by [`crate::install`] or has no [`Camera`].
    pub fn run_world(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        settings: &GpuCullSettings,
    ) -> Result<GpuFrameOutput, GpuError> {
        let camera = *world.resource::<Camera>();
        self.run_world_from(context, world, &camera, settings, None)
    }

    /// [`GpuCuller::run_world`] with `renderer` drawing the survivors into its own targets, as
    /// [`GpuCuller::run_into`] does.
    ///
    /// # Errors
    /// As [`GpuCuller::run_into`].
    ///
    /// # Panics
    /// As [`GpuCuller::run_world`].
    pub fn run_world_into(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        settings: &GpuCullSettings,
        renderer: &mut dyn OwnRenderer,
    ) -> Result<GpuFrameOutput, GpuError> {
        let camera = *world.resource::<Camera>();
        self.run_world_from(context, world, &camera, settings, Some(renderer))
    }

    /// [`GpuCuller::run_world`] drawing from `draw_camera`, or by `renderer` where given.
    pub(super) fn run_world_from(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        draw_camera: &Camera,
        settings: &GpuCullSettings,
        renderer: Option<&mut dyn OwnRenderer>,
    ) -> Result<GpuFrameOutput, GpuError> {
        self.sync_world(context, world);
        let state = world.resource::<CameraCuller>();
        let visible: Vec<u32> = state.visible().iter().map(|slot| slot as u32).collect();
        let output = self.run_synced(context, world, (draw_camera, renderer), &visible, state.depth(), settings)?;
        self.judge_occluder_stage(world, &output);
        Ok(output)
    }

    /// Feeds [`GpuGating::min_occluder_benefit`]'s gate a frame of two phases (its counters read at once, and
    /// two frames of two phases before it: the first draws everything late, and the second early what the first
    /// kept with no depth of its own), and has the world's camera culler skip its occluder stage next frame
    /// where the gate says so.
    fn judge_occluder_stage(&mut self, world: &mut World, output: &GpuFrameOutput) {
        let min_benefit = self.gating.min_occluder_benefit;
        if min_benefit <= 0.0 || output.phases.is_none() || output.counters_late || self.two_phase_run < 3 {
            return;
        }
        let state = world.resource::<CameraCuller>();
        let ran = state.stats().occluders > 0;
        let in_frustum: Vec<u32> = state.frustum_visible().iter().map(|slot| slot as u32).collect();
        let (_, frustum_triangles) = candidates(&self.scene, &in_frustum);
        let drawn = (output.counters.triangles_out, frustum_triangles);
        if self.occluder_gate.record(ran, drawn, min_benefit, self.gating.reprobe_every) {
            world.resource_mut::<CameraCuller>().skip_occlusion_once();
        }
    }

    /// [`GpuCuller::run_world`] for what a culler of your own kept ([`crate::culler::Culler`]): the store slots
    /// `visible`, against `depth`, its occluder depth buffer (empty for none: the HZB then hides nothing),
    /// from the world's [`Camera`]. The world's light views, where it has any, are drawn as the pipeline
    /// culled them.
    ///
    /// # Errors
    /// [`GpuError::SlotOutOfRange`] for a slot of `visible` that is not an object of the world (nothing is
    /// run), [`GpuError::Lost`] when the device is lost.
    ///
    /// # Panics
    /// As [`GpuCuller::run_world`].
    pub fn run_world_culled(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
    ) -> Result<GpuFrameOutput, GpuError> {
        self.sync_world(context, world);
        let camera = *world.resource::<Camera>();
        self.run_synced(context, world, (&camera, None), visible, depth, settings)
    }

    /// Brings the instances up to date with `world` and takes its [`GpuGating`], where it has one.
    fn sync_world(&mut self, context: &GpuContext, world: &mut World) {
        if let Some(&gating) = world.get_resource::<GpuGating>() {
            self.set_gating(gating);
        }
        self.sync_instances(context, world, |_, instance| instance);
        self.recolored = false;
    }

    /// Culls and draws `visible` against `depth` from `world`'s [`Camera`], drawn from `draw_camera` (or by
    /// `renderer`), with the world's sun cascades.
    fn run_synced(
        &mut self,
        context: &GpuContext,
        world: &World,
        (draw_camera, renderer): (&Camera, Option<&mut dyn OwnRenderer>),
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
    ) -> Result<GpuFrameOutput, GpuError> {
        let suns = sun_casters(world).filter(|suns| !suns.is_empty() || self.shadows.cascades() > 0);
        let cascades: Option<Vec<Cascade<'_>>> =
            suns.as_ref().map(|suns| suns.iter().map(SunCasters::cascade).collect());
        let camera = *world.resource::<Camera>();
        self.run_views(context, &camera, draw_camera, visible, depth, settings, cascades.as_deref(), renderer)
    }

    /// The shadow maps the draw shades with.
    pub fn shadow_maps(&self) -> &ShadowMaps {
        &self.shadows
    }

    /// Copies to the GPU the instances of the store slots written since the last call (every slot after a
    /// recolouring), each as `recolor` makes it from its slot and the object's own instance.
    pub(super) fn sync_instances(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        recolor: impl Fn(usize, GpuInstance) -> GpuInstance,
    ) {
        let mut written = world.resource_mut::<BoundsStore>().take_written_slots();
        // Objects whose level of detail changed draw another mesh.
        if let Some(selection) = world.get_resource::<crate::lod::LodSelection>()
            && !selection.changed().is_empty()
        {
            written.extend_from_slice(selection.changed());
            written.sort_unstable();
            written.dedup();
        }
        let count = world.resource::<BoundsStore>().len();
        let slots = if self.recolored { (0..count as u32).collect() } else { written };
        self.scene.write_instances(context, count, &slots, |slot| recolor(slot as usize, instance_of(world, slot)));
    }

    /// Draws every cluster of every instance into the targets with no culling, in store order or `reversed`.
    pub(super) fn draw_all(&self, context: &GpuContext, camera: &Camera, reversed: bool) {
        let view = self.view_for(camera, &GpuCullSettings::default(), 0);
        context.queue.write_buffer(&self.draw_view, 0, bytemuck::bytes_of(&view));
        let instances = self.scene.instances();
        let mut args = cluster_draws(&self.scene.library, instances, 0..instances.len() as u32);
        if reversed {
            args.reverse();
        }
        let mut encoder = context.device.create_command_encoder(&Default::default());
        if !args.is_empty() {
            let buffer = indirect_buffer(context, "unculled draws", &args);
            let source =
                DrawSource::Unculled { indices: &self.scene.cluster_indices, args: &buffer, draws: args.len() as u32 };
            self.record_draw(context, &mut encoder, camera.depth, source, true, None);
            context.queue.submit([encoder.finish()]);
        }
    }

    /// Records the draw of `source` into this culler's targets, clearing them first if `clear`.
    fn record_draw(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        depth: DepthConvention,
        source: DrawSource<'_>,
        clear: bool,
        timestamps: Option<wgpu::RenderPassTimestampWrites<'_>>,
    ) {
        let scene = &self.scene;
        self.draw.record(
            context,
            encoder,
            &self.targets,
            depth,
            &self.draw_view,
            &scene.instances,
            &scene.positions,
            &self.shadows,
            source,
            clear,
            timestamps,
        );
    }

    /// Reads the render targets of the last frame.
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    pub fn read_image(&self, context: &GpuContext) -> Result<RenderedImage, GpuError> {
        self.targets.read(context)
    }
}
