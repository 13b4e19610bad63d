//! One frame of the GPU pipeline, orchestrated: the view uniform, then the passes in order (HZB build, cluster
//! culling, triangle culling, draw), each recorded by its own module, then the counters read back. Frames whose
//! candidates exceed the device's largest storage binding run in batches.

use super::cluster_cull::{CandidateBuffers, ClusterCullBuffers, ClusterCullPass, write_all_candidates};
use super::clusters::ClusterLibrary;
use super::draw::{DrawBuffers, DrawPass, DrawSource, RenderTargets, RenderedImage, cluster_draws, indirect_buffer};
use super::hzb::{Hzb, HzbLevel};
use super::interface::{
    GpuView, MAX_HZB_LEVELS, VIEW_BACKFACE, VIEW_CONE, VIEW_DRAW_CLUSTERS, VIEW_HZB, VIEW_SMALL_CLUSTER,
    VIEW_SMALL_TRIANGLE, VIEW_TRIANGLE_FRUSTUM, counter,
};
use super::output::{COUNTER_BYTES, GpuCounters, GpuFrameOutput, PassTimer, TIMED_PASSES};
use super::scene::{GpuInstance, GpuScene, instance_of, instances_from_world};
use super::shadow::{Cascade, ShadowMaps};
use super::triangle_cull::{TriangleCullBuffers, TriangleCullPass};
use super::{GpuContext, GpuError};
use crate::bounds::BoundsStore;
use crate::camera::Camera;
use crate::depth::DepthBuffer;
use crate::frustum::{DepthConvention, LightSource};
use crate::mesh::Mesh;
use crate::pipeline::{
    BenefitGate, LightViewVisible, LightViews, LightViewsVisible, OcclusionSettings, OcclusionState,
};
use bevy_ecs::prelude::*;
use bytemuck::Zeroable;
use glam::Vec4;
use std::time::Instant;

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
        }
    }
}

/// Which GPU passes a frame may skip where they cannot pay off. Insert it as a resource of the world to have
/// [`GpuCuller::run_world`] use it (the default otherwise), or give it with [`GpuCuller::set_gating`]. Skipping
/// a pass keeps everything it would have tested, so gating adds no false negative.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct GpuGating {
    /// A frame whose candidates (the CPU stages' survivors) have at most this many clusters skips the cluster
    /// pass: the CPU lists every candidate cluster for the triangle pass (or the draw) instead. With so few
    /// clusters the pass cannot save more than its own dispatch costs. 0 never skips.
    pub tiny_scene_clusters: u32,
    /// The triangle pass is skipped once it has removed less than this fraction of the triangles it tested
    /// for `low_benefit_frames` frames in a row, and re-probed every `reprobe_every` frames: the surviving
    /// clusters are then drawn whole and the hardware culls their triangles. The pass reads and transforms
    /// every triangle, about the work the hardware's vertex stage and culling do on it, so it pays only when it
    /// removes a good share. 0 never skips.
    pub min_triangle_benefit: f32,
    /// See `min_triangle_benefit`.
    pub low_benefit_frames: u32,
    /// See `min_triangle_benefit`.
    pub reprobe_every: u32,
}

impl Default for GpuGating {
    /// No cluster pass for 64 clusters or fewer; the triangle pass skipped after 8 frames under 10% removed,
    /// re-probed every 30 frames.
    fn default() -> Self {
        Self { tiny_scene_clusters: 64, min_triangle_benefit: 0.1, low_benefit_frames: 8, reprobe_every: 30 }
    }
}

impl GpuGating {
    /// No gating: every pass runs every frame (the fixed pipeline, for comparison).
    pub fn fixed() -> Self {
        Self { tiny_scene_clusters: 0, min_triangle_benefit: 0.0, low_benefit_frames: u32::MAX, reprobe_every: 0 }
    }
}

/// A frame's surviving `(instance, cluster)` pairs and the global vertex indices of the triangles it drew (see
/// [`GpuCuller::read_survivors`]).
pub type Survivors = (Vec<(u32, u32)>, Vec<u32>);

/// The GPU pipeline for one scene: the scene's buffers, the passes, per-frame buffers and render targets.
///
/// Build it with [`GpuCuller::for_world`]; each frame, after the CPU stages ran,
/// [`GpuCuller::run_world`] brings the instances up to date, culls and draws. A renderer of its own draws
/// from [`GpuCuller::draw_buffers`] instead of (or after) the culler's draw.
pub struct GpuCuller {
    scene: GpuScene,
    hzb: Hzb,
    cluster_pass: ClusterCullPass,
    triangle_pass: TriangleCullPass,
    draw: DrawPass,
    /// The sun cascades' shadow maps the draw shades with (none until a world with light views runs).
    shadows: ShadowMaps,
    targets: RenderTargets,
    view: wgpu::Buffer,
    /// The view the draw pass renders from: the culling view, or another camera's (see [`GpuCuller::run_from`]).
    draw_view: wgpu::Buffer,
    counters: wgpu::Buffer,
    dispatch: wgpu::Buffer,
    last_view: GpuView,
    frame: Option<FrameBuffers>,
    timer: Option<PassTimer>,
    last_counters: GpuCounters,
    /// Which passes the last frame skipped.
    last_gate: PassGate,
    /// A smaller storage-binding budget than the device's, to split frames into batches (see
    /// [`GpuCuller::limit_batches`]).
    batch_bytes: Option<u64>,
    /// Which GPU passes a frame may skip (see [`GpuCuller::set_gating`]).
    gating: GpuGating,
    /// When the triangle pass is skipped for removing too little.
    triangle_gate: BenefitGate,
    /// The instance buffer holds colours other than the objects' own ([`GpuCuller::draw_all_recolored`]):
    /// the next [`GpuCuller::run_world`] rewrites every instance.
    recolored: bool,
}

/// Which passes one frame skips.
#[derive(Clone, Copy, Debug, Default)]
struct PassGate {
    /// No cluster pass: the CPU lists every candidate cluster.
    skip_clusters: bool,
    /// No triangle pass: surviving clusters are drawn whole.
    skip_triangles: bool,
}

/// Buffers sized for a frame's candidates.
struct FrameBuffers {
    visible: wgpu::Buffer,
    survivors: wgpu::Buffer,
    draw_indices: wgpu::Buffer,
    draw_args: wgpu::Buffer,
    max_clusters: u32,
    max_indices: u32,
}

/// A storage buffer of `size` bytes (at least 16).
fn storage_buffer(context: &GpuContext, label: &str, size: u64, extra: wgpu::BufferUsages) -> wgpu::Buffer {
    context.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16).next_multiple_of(4),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC | extra,
        mapped_at_creation: false,
    })
}

/// A uniform buffer for one [`GpuView`].
fn view_buffer(context: &GpuContext, label: &str) -> wgpu::Buffer {
    context.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: std::mem::size_of::<GpuView>() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
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
        let scene = GpuScene::new(context, ClusterLibrary::build(meshes), instances_from_world(world));
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
            cluster_pass: ClusterCullPass::new(context),
            triangle_pass: TriangleCullPass::new(context),
            draw: DrawPass::new(context),
            shadows: ShadowMaps::new(context),
            targets: RenderTargets::new(context, width, height),
            view: view_buffer(context, "view"),
            draw_view: view_buffer(context, "draw view"),
            counters: storage_buffer(context, "counters", COUNTER_BYTES, wgpu::BufferUsages::INDIRECT),
            dispatch: storage_buffer(context, "triangle dispatch", 12, wgpu::BufferUsages::INDIRECT),
            last_view: GpuView::zeroed(),
            frame: None,
            timer: PassTimer::new(context),
            last_counters: GpuCounters::default(),
            last_gate: PassGate::default(),
            batch_bytes: None,
            gating: GpuGating::default(),
            triangle_gate: BenefitGate::default(),
            recolored: false,
        }
    }

    /// The scene's buffers and cluster library.
    pub fn scene(&self) -> &GpuScene {
        &self.scene
    }

    /// The HZB of the last frame.
    pub fn hzb(&self) -> &Hzb {
        &self.hzb
    }

    /// The render targets the culler draws into.
    pub fn targets(&self) -> &RenderTargets {
        &self.targets
    }

    /// The last frame's view uniform (for the CPU twins in tests).
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
        Some(self.culled_draws(self.frame.as_ref()?, self.last_gate.skip_triangles))
    }

    /// The draws a culled frame with `frame`'s buffers wrote.
    fn culled_draws<'a>(&'a self, frame: &'a FrameBuffers, skip_triangles: bool) -> DrawBuffers<'a> {
        DrawBuffers {
            positions: &self.scene.positions,
            // Without the triangle pass, the draws index the clusters' own triangles.
            indices: if skip_triangles { &self.scene.cluster_indices } else { &frame.draw_indices },
            args: &frame.draw_args,
            count: &self.counters,
            count_offset: u64::from(counter::DRAWS) * 4,
            max_draws: frame.max_clusters,
            instances: &self.scene.instances,
            view: &self.view,
        }
    }

    /// The view uniform for `camera` with `settings`, the HZB as it is sized now and `visible_count` instances.
    pub fn view_for(&self, camera: &Camera, settings: &GpuCullSettings, visible_count: u32) -> GpuView {
        let (width, height) = self.targets.size();
        let matrix = camera.clip_from_relative_f64().as_mat4();
        let mut planes = [[0.0, 0.0, 0.0, 1.0]; 6];
        if let Ok(frustum) = camera.frustum() {
            for (slot, plane) in planes.iter_mut().zip(frustum.planes()) {
                *slot = Vec4::from((plane.normal, plane.d)).to_array();
            }
        }
        let mut hzb_levels = [HzbLevel::default(); MAX_HZB_LEVELS];
        hzb_levels[..self.hzb.levels.len()].copy_from_slice(&self.hzb.levels);
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
            clip_from_relative: matrix.to_cols_array_2d(),
            planes,
            camera: camera.position.extend(0.0).to_array(),
            viewport: [width as f32, height as f32],
            hzb_size: [self.hzb.levels[0].width as f32, self.hzb.levels[0].height as f32],
            hzb_levels,
            hzb_level_count: self.hzb.levels.len() as u32,
            visible_count,
            flags,
            near: camera.near,
            depth_from_negative_one: u32::from(camera.depth == DepthConvention::NegativeOneToOne),
            focal_pixels: 0.5 * height as f32 / (0.5 * camera.fov_y).tan(),
            _pad: [0; 2],
        }
    }

    /// Grows the per-frame buffers to hold the candidates of `visible`.
    fn frame_buffers(&mut self, context: &GpuContext, visible: &[u32]) -> &FrameBuffers {
        let library = &self.scene.library;
        let instances = self.scene.instances();
        let (mut clusters, mut triangles) = (0u32, 0u32);
        for &slot in visible {
            for cluster in library.clusters_of(instances[slot as usize].mesh) {
                clusters += 1;
                triangles += cluster.triangle_count;
            }
        }
        let fits = self.frame.as_ref().is_some_and(|f| {
            f.max_clusters >= clusters && f.max_indices >= 3 * triangles && f.visible.size() >= 4 * visible.len() as u64
        });
        if !fits {
            // Grow by half again, so a slowly growing view does not reallocate every frame.
            let (clusters, indices) = (clusters + clusters / 2 + 64, 3 * (triangles + triangles / 2 + 64));
            self.frame = Some(FrameBuffers {
                visible: storage_buffer(
                    context,
                    "visible instances",
                    4 * (visible.len() as u64 * 3 / 2 + 64),
                    wgpu::BufferUsages::empty(),
                ),
                survivors: storage_buffer(
                    context,
                    "cluster survivors",
                    8 * u64::from(clusters),
                    wgpu::BufferUsages::empty(),
                ),
                draw_indices: storage_buffer(
                    context,
                    "draw indices",
                    4 * u64::from(indices),
                    wgpu::BufferUsages::INDEX,
                ),
                draw_args: storage_buffer(context, "draw args", 20 * u64::from(clusters), wgpu::BufferUsages::INDIRECT),
                max_clusters: clusters,
                max_indices: indices,
            });
        }
        self.frame.as_ref().expect("just made")
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
        self.run_from(context, camera, camera, visible, depth, settings)
    }

    /// [`GpuCuller::run`] culling for `camera` but drawing the survivors as `draw_camera` sees them: with
    /// culling frozen at one camera, flying another shows what was culled.
    ///
    /// # Errors
    /// As [`GpuCuller::run`].
    pub fn run_from(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        draw_camera: &Camera,
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
    ) -> Result<GpuFrameOutput, GpuError> {
        if depth.width() > 0 && !self.hzb.fits(depth.width(), depth.height()) {
            self.hzb = Hzb::new(context, depth.width(), depth.height());
        }
        let library = &self.scene.library;
        let instances = self.scene.instances();
        if let Some(&slot) = visible.iter().find(|&&slot| slot as usize >= instances.len()) {
            return Err(GpuError::SlotOutOfRange { slot, instances: instances.len() });
        }
        let candidate_clusters: usize =
            visible.iter().map(|&slot| library.cluster_range(instances[slot as usize].mesh).len()).sum();
        let gate = PassGate {
            skip_clusters: candidate_clusters <= self.gating.tiny_scene_clusters as usize,
            skip_triangles: self.triangle_gate.skip_this_frame(),
        };
        let mut total: Option<GpuFrameOutput> = None;
        for (i, batch) in self.batches(context, visible).into_iter().enumerate() {
            let output =
                self.run_batch(context, camera, draw_camera, &visible[batch], depth, settings, gate, i == 0)?;
            total = Some(match total {
                None => output,
                Some(sum) => sum.plus(&output),
            });
        }
        let total = total.unwrap_or_default();
        if !gate.skip_triangles {
            let c = total.counters;
            let removed = c.triangles_in - c.triangles_out;
            let g = self.gating;
            self.triangle_gate.record(
                removed as usize,
                c.triangles_in as usize,
                g.min_triangle_benefit,
                g.low_benefit_frames,
                g.reprobe_every,
            );
        }
        Ok(total)
    }

    /// Sets which GPU passes a frame may skip (the default [`GpuGating`] until set). New settings start the
    /// triangle pass's benefit count afresh. [`GpuCuller::run_world`] sets the world's, where it has one.
    pub fn set_gating(&mut self, gating: GpuGating) {
        if gating != self.gating {
            self.gating = gating;
            self.triangle_gate = BenefitGate::default();
        }
    }

    /// Splits frames into batches as if the device's largest storage binding were `bytes` (never more than
    /// it is): the path a frame with too many candidate triangles for one batch takes, made testable on a
    /// small scene.
    pub fn limit_batches(&mut self, bytes: u64) {
        self.batch_bytes = Some(bytes);
    }

    /// Splits `visible` into runs whose candidate triangles fit the device's largest storage binding (the
    /// compacted index buffer is sized for every candidate surviving): almost always one run; several when
    /// the CPU stages leave millions of triangles (a large scene with occlusion off), instead of failing.
    fn batches(&self, context: &GpuContext, visible: &[u32]) -> Vec<std::ops::Range<usize>> {
        let device_limit = context.device.limits().max_storage_buffer_binding_size;
        let limit = self.batch_bytes.map_or(device_limit, |bytes| bytes.min(device_limit));
        // Buffers grow to 1.5x the candidates plus 64 (see `frame_buffers`): 12 bytes a triangle, 20 a cluster.
        let max_triangles = (limit / 12).saturating_sub(64) * 2 / 3;
        let max_clusters = (limit / 20).saturating_sub(64) * 2 / 3;
        let library = &self.scene.library;
        let instances = self.scene.instances();
        let mut batches = Vec::new();
        let (mut start, mut triangles, mut clusters) = (0, 0u64, 0u64);
        for (i, &slot) in visible.iter().enumerate() {
            let own = library.clusters_of(instances[slot as usize].mesh);
            let own_triangles: u64 = own.iter().map(|c| u64::from(c.triangle_count)).sum();
            if i > start && (triangles + own_triangles > max_triangles || clusters + own.len() as u64 > max_clusters) {
                batches.push(start..i);
                (start, triangles, clusters) = (i, 0, 0);
            }
            triangles += own_triangles;
            clusters += own.len() as u64;
        }
        batches.push(start..visible.len());
        batches
    }

    /// One batch of [`GpuCuller::run_from`]: the first builds the HZB and clears the targets, later ones draw
    /// over what the earlier ones drew.
    #[allow(clippy::too_many_arguments)]
    fn run_batch(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        draw_camera: &Camera,
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
        gate: PassGate,
        first: bool,
    ) -> Result<GpuFrameOutput, GpuError> {
        let mut view = self.view_for(camera, settings, visible.len() as u32);
        if gate.skip_triangles {
            view.flags |= VIEW_DRAW_CLUSTERS;
        }
        self.last_view = view;
        context.queue.write_buffer(&self.view, 0, bytemuck::bytes_of(&view));
        let draw_view = if draw_camera == camera { view } else { self.view_for(draw_camera, settings, 0) };
        context.queue.write_buffer(&self.draw_view, 0, bytemuck::bytes_of(&draw_view));
        self.frame_buffers(context, visible);
        let frame = self.frame.as_ref().expect("sized above");
        if !visible.is_empty() {
            context.queue.write_buffer(&frame.visible, 0, bytemuck::cast_slice(visible));
        }
        let mut encoder = context.device.create_command_encoder(&Default::default());
        if gate.skip_clusters {
            let buffers = CandidateBuffers {
                survivors: &frame.survivors,
                counters: &self.counters,
                draws: &frame.draw_args,
                draw_capacity: frame.draw_args.size(),
            };
            write_all_candidates(context, &self.scene, visible, &buffers, gate.skip_triangles);
        } else {
            encoder.clear_buffer(&self.counters, 0, None);
            if !context.has_draw_count {
                encoder.clear_buffer(&frame.draw_args, 0, None);
            }
        }
        let timer = self.timer.as_ref();
        if first {
            self.hzb.build(context, depth, &mut encoder, timer.map(|t| t.compute(0)));
        }
        let scene = &self.scene;
        let cluster_buffers = ClusterCullBuffers {
            view: &self.view,
            instances: &scene.instances,
            meshes: &scene.meshes,
            clusters: &scene.clusters,
            visible: &frame.visible,
            hzb: &self.hzb.buffer,
            counters: &self.counters,
            survivors: &frame.survivors,
            draws: &frame.draw_args,
        };
        let instance_count = visible.len() as u32;
        self.cluster_pass.record(
            context,
            &mut encoder,
            &cluster_buffers,
            instance_count,
            gate.skip_clusters,
            timer.map(|t| t.compute(1)),
        );
        let triangle_buffers = TriangleCullBuffers {
            view: &self.view,
            instances: &scene.instances,
            clusters: &scene.clusters,
            positions: &scene.positions,
            cluster_indices: &scene.cluster_indices,
            survivors: &frame.survivors,
            counters: &self.counters,
            dispatch: &self.dispatch,
            draw_indices: &frame.draw_indices,
            draws: &frame.draw_args,
        };
        self.triangle_pass.record(
            context,
            &mut encoder,
            &triangle_buffers,
            gate.skip_triangles,
            timer.map(|t| t.compute(2)),
        );
        let source = DrawSource::Culled(self.culled_draws(frame, gate.skip_triangles));
        self.record_draw(context, &mut encoder, camera.depth, source, first, timer.map(|t| t.render(3)));
        if let Some(timer) = timer {
            encoder.resolve_query_set(&timer.queries, 0..2 * TIMED_PASSES, &timer.resolve, 0);
        }
        let start = Instant::now();
        context.queue.submit([encoder.finish()]);
        let counter_bytes = context.read_buffer(&self.counters, COUNTER_BYTES)?;
        let wall_time = start.elapsed();
        let counters = GpuCounters::from_slots(visible.len() as u32, bytemuck::cast_slice(&counter_bytes));
        self.last_counters = counters;
        self.last_gate = gate;
        let pass_times = timer.map(|t| t.read(context)).transpose()?;
        Ok(GpuFrameOutput {
            counters,
            pass_times,
            wall_time,
            cluster_pass_skipped: gate.skip_clusters,
            triangle_pass_skipped: gate.skip_triangles,
        })
    }

    /// The last frame's surviving `(instance, cluster)` pairs, in the GPU's (unordered) append order, and the
    /// global vertex indices of the triangles it drew: its compacted index buffer, or where the triangle pass
    /// was skipped, the surviving clusters' own triangles.
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    pub fn read_survivors(&self, context: &GpuContext) -> Result<Survivors, GpuError> {
        let (Some(frame), counters) = (self.frame.as_ref(), self.last_counters) else { return Ok(Default::default()) };
        let clusters = if counters.clusters_out > 0 {
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
        self.run_world_from(context, world, &camera, settings)
    }

    /// [`GpuCuller::run_world`] drawing from `draw_camera` (see [`GpuCuller::run_from`]).
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    pub fn run_world_from(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        draw_camera: &Camera,
        settings: &GpuCullSettings,
    ) -> Result<GpuFrameOutput, GpuError> {
        if let Some(&gating) = world.get_resource::<GpuGating>() {
            self.set_gating(gating);
        }
        self.sync_instances(context, world, |_, instance| instance);
        self.recolored = false;
        self.draw_shadow_maps(context, world, draw_camera.position);
        let state = world.resource::<OcclusionState>();
        let visible: Vec<u32> = state.visible.iter().map(|slot| slot as u32).collect();
        let camera = *world.resource::<Camera>();
        self.run_from(context, &camera, draw_camera, &visible, state.depth(), settings)
    }

    /// Draws the shadow maps of the world's sun cascades ([`LightViewsVisible`] of its [`LightViews`] suns,
    /// nearest first), each from the casters its light view kept, for a draw from `draw_origin`; without sun
    /// cascades the draw shades without shadows.
    fn draw_shadow_maps(&mut self, context: &GpuContext, world: &World, draw_origin: glam::Vec3) {
        let (Some(results), Some(lights)) =
            (world.get_resource::<LightViewsVisible>(), world.get_resource::<LightViews>())
        else {
            return;
        };
        let suns: Vec<(&LightViewVisible, Vec<u32>)> = results
            .0
            .iter()
            .filter(|result| matches!(lights.0.get(result.light), Some(LightSource::Sun { .. })))
            .map(|result| (result, result.visible.iter().map(|slot| slot as u32).collect()))
            .collect();
        if suns.is_empty() && self.shadows.cascades() == 0 {
            return;
        }
        let cascades: Vec<Cascade<'_>> = suns
            .iter()
            .map(|(result, casters)| Cascade {
                clip_from_relative: result.view.clip_from_relative,
                origin: result.view.origin,
                casters,
            })
            .collect();
        self.shadows.draw(context, &self.scene, &cascades, draw_origin);
    }

    /// Copies to the GPU the instances of the store slots written since the last call (every slot after a
    /// recolouring), each as `recolor` makes it from its slot and the object's own instance.
    fn sync_instances(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        recolor: impl Fn(usize, GpuInstance) -> GpuInstance,
    ) {
        let written = world.resource_mut::<BoundsStore>().take_written_slots();
        let count = world.resource::<BoundsStore>().len();
        let slots = if self.recolored { (0..count as u32).collect() } else { written };
        self.scene.write_instances(context, count, &slots, |slot| recolor(slot as usize, instance_of(world, slot)));
    }

    /// Draws every object of `world` with no culling, each in the colour `color_of(slot)` gives it (its own
    /// for `None`), as `camera` sees it: for debug views, such as tinting each object by the stage that culled
    /// it. The next [`GpuCuller::run_world`] restores every object's own colour.
    pub fn draw_all_recolored(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        camera: &Camera,
        color_of: impl Fn(usize) -> Option<[u8; 4]>,
    ) {
        self.recolored = true;
        self.sync_instances(context, world, |slot, instance| match color_of(slot) {
            Some(color) => instance.with_color(Some(color)),
            None => instance,
        });
        self.draw_all(context, camera, false);
    }

    /// Draws every cluster of every instance with no culling at all, for comparison; `reversed` draws them in
    /// the opposite order, which shows where the image depends on draw order (coplanar surfaces of different
    /// objects at exactly the same depth).
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    pub fn draw_unculled(
        &self,
        context: &GpuContext,
        camera: &Camera,
        reversed: bool,
    ) -> Result<RenderedImage, GpuError> {
        self.draw_all(context, camera, reversed);
        self.targets.read(context)
    }

    /// Draws every cluster of every instance into the targets with no culling, in store order or `reversed`.
    pub fn draw_all(&self, context: &GpuContext, camera: &Camera, reversed: bool) {
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
