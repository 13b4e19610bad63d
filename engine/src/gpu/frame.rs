//! One frame of the GPU pipeline: the view uniform, the HZB build, cluster culling, the dispatch of the
//! triangle pass, triangle culling and the draw, then the counters read back.

use super::GpuContext;
use super::cluster_cull::ClusterVerdict;
use super::draw::{DrawPass, DrawSource, RenderTargets, RenderedImage, cluster_draws};
use super::hzb::{Hzb, HzbLevel, MAX_HZB_LEVELS};
use super::scene::GpuScene;
use super::triangle_cull::TriangleVerdict;
use crate::camera::Camera;
use crate::frustum::DepthConvention;
use crate::pipeline::{AdaptiveSettings, BenefitGate};
use crate::raster::DepthBuffer;
use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec4};
use std::time::{Duration, Instant};
use wgpu::util::DeviceExt;

/// View flag: normal-cone test of clusters.
pub const VIEW_CONE: u32 = 1;
/// View flag: HZB test of clusters.
pub const VIEW_HZB: u32 = 2;
/// View flag: small-cluster test (lossy).
pub const VIEW_SMALL_CLUSTER: u32 = 4;
/// View flag: back-face test of triangles.
pub const VIEW_BACKFACE: u32 = 8;
/// View flag: small-triangle test (eq. 19.4).
pub const VIEW_SMALL_TRIANGLE: u32 = 16;
/// View flag: viewport test of triangles.
pub const VIEW_TRIANGLE_FRUSTUM: u32 = 32;
/// View flag: the triangle pass is skipped; the cluster pass writes each surviving cluster's draw.
pub const VIEW_DRAW_CLUSTERS: u32 = 64;

/// The per-frame uniform every pass reads (`View` in `shaders/common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuView {
    /// Clip from camera-relative world space, columns.
    pub clip_from_relative: [[f32; 4]; 4],
    /// Camera-relative frustum planes, unit inward normals; unused ones `(0, 0, 0, 1)`.
    pub planes: [[f32; 4]; 6],
    /// Camera position in xyz.
    pub camera: [f32; 4],
    /// Render-target size in pixels.
    pub viewport: [f32; 2],
    /// HZB level-0 size in texels.
    pub hzb_size: [f32; 2],
    /// HZB level sizes and offsets.
    pub hzb_levels: [HzbLevel; MAX_HZB_LEVELS],
    /// Number of HZB levels.
    pub hzb_level_count: u32,
    /// Instances in the visible list.
    pub visible_count: u32,
    /// `VIEW_*` flags.
    pub flags: u32,
    /// Near-plane distance.
    pub near: f32,
    /// 1 when clip z must be mapped from -1..1 to 0..1.
    pub depth_from_negative_one: u32,
    /// Pixels per unit at unit distance, vertically.
    pub focal_pixels: f32,
    /// Padding.
    pub _pad: [u32; 2],
}

impl GpuView {
    /// `clip_from_relative` as a matrix.
    pub fn clip_from_relative(&self) -> Mat4 {
        Mat4::from_cols_array_2d(&self.clip_from_relative)
    }
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

/// Counters of one frame, read back from the GPU.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GpuCounters {
    /// Instances submitted (the CPU stages' survivors).
    pub instances: u32,
    /// Clusters tested.
    pub clusters_in: u32,
    /// Clusters culled by the frustum, cone, HZB and small tests.
    pub clusters_frustum: u32,
    /// See `clusters_frustum`.
    pub clusters_cone: u32,
    /// See `clusters_frustum`.
    pub clusters_hzb: u32,
    /// See `clusters_frustum`.
    pub clusters_small: u32,
    /// Clusters kept.
    pub clusters_out: u32,
    /// Triangles tested.
    pub triangles_in: u32,
    /// Triangles culled as degenerate, back-facing, off-screen and small.
    pub triangles_degenerate: u32,
    /// See `triangles_degenerate`.
    pub triangles_backface: u32,
    /// See `triangles_degenerate`.
    pub triangles_frustum: u32,
    /// See `triangles_degenerate`.
    pub triangles_small: u32,
    /// Triangles kept.
    pub triangles_out: u32,
    /// Indirect draws issued (clusters with surviving triangles), all in one multi-draw.
    pub draws: u32,
}

/// Counter slots, as in `shaders/common.wgsl`.
const COUNTER_COUNT: usize = 16;
const CLUSTERS_IN_SLOT: usize = 0;
const CLUSTERS_OUT_SLOT: usize = 5;
const TRIANGLES_OUT_SLOT: usize = 11;
const DRAWS_SLOT: u64 = 12;

impl GpuCounters {
    fn from_slots(instances: u32, c: &[u32]) -> Self {
        Self {
            instances,
            clusters_in: c[0],
            clusters_frustum: c[1],
            clusters_cone: c[2],
            clusters_hzb: c[3],
            clusters_small: c[4],
            clusters_out: c[5],
            triangles_in: c[6],
            triangles_degenerate: c[7],
            triangles_backface: c[8],
            triangles_frustum: c[9],
            triangles_small: c[10],
            triangles_out: c[11],
            draws: c[12],
        }
    }

    /// Every counter, `instances` first, then in the order of the counter slots.
    fn to_array(self) -> [u32; 14] {
        [
            self.instances,
            self.clusters_in,
            self.clusters_frustum,
            self.clusters_cone,
            self.clusters_hzb,
            self.clusters_small,
            self.clusters_out,
            self.triangles_in,
            self.triangles_degenerate,
            self.triangles_backface,
            self.triangles_frustum,
            self.triangles_small,
            self.triangles_out,
            self.draws,
        ]
    }

    /// The inverse of [`GpuCounters::to_array`].
    fn from_array(c: [u32; 14]) -> Self {
        Self::from_slots(c[0], &c[1..])
    }

    /// How many clusters `verdict` accounts for.
    pub fn clusters(&self, verdict: ClusterVerdict) -> u32 {
        match verdict {
            ClusterVerdict::Keep => self.clusters_out,
            ClusterVerdict::Frustum => self.clusters_frustum,
            ClusterVerdict::Cone => self.clusters_cone,
            ClusterVerdict::Hzb => self.clusters_hzb,
            ClusterVerdict::Small => self.clusters_small,
        }
    }

    /// How many triangles `verdict` accounts for.
    pub fn triangles(&self, verdict: TriangleVerdict) -> u32 {
        match verdict {
            TriangleVerdict::Keep => self.triangles_out,
            TriangleVerdict::Degenerate => self.triangles_degenerate,
            TriangleVerdict::Backface => self.triangles_backface,
            TriangleVerdict::Frustum => self.triangles_frustum,
            TriangleVerdict::Small => self.triangles_small,
        }
    }
}

/// GPU time of each pass of a frame, from timestamp queries.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuPassTimes {
    /// HZB upload reduction.
    pub hzb: Duration,
    /// Cluster culling.
    pub clusters: Duration,
    /// Triangle-pass dispatch and triangle culling.
    pub triangles: Duration,
    /// The draw.
    pub draw: Duration,
}

impl GpuPassTimes {
    /// The mean over `frames`, or `None` unless every frame was timed.
    pub fn mean(frames: &[GpuFrameOutput]) -> Option<Self> {
        let times: Option<Vec<&Self>> = frames.iter().map(|f| f.pass_times.as_ref()).collect();
        let times = times.filter(|t| !t.is_empty())?;
        let n = times.len() as u32;
        let sum = |f: fn(&Self) -> Duration| times.iter().map(|t| f(t)).sum::<Duration>() / n;
        Some(Self {
            hzb: sum(|t| t.hzb),
            clusters: sum(|t| t.clusters),
            triangles: sum(|t| t.triangles),
            draw: sum(|t| t.draw),
        })
    }
}

impl std::fmt::Display for GpuPassTimes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let us = |d: Duration| d.as_secs_f64() * 1e6;
        write!(
            f,
            "HZB {:.1} us, clusters {:.1} us, triangles {:.1} us, draw {:.1} us",
            us(self.hzb),
            us(self.clusters),
            us(self.triangles),
            us(self.draw)
        )
    }
}

/// Timestamp queries around each pass, where the adapter has them.
struct PassTimer {
    queries: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    /// Nanoseconds per tick.
    period: f64,
}

/// Passes timed, two timestamps each.
const TIMED_PASSES: u32 = 4;

impl PassTimer {
    fn new(context: &GpuContext) -> Option<Self> {
        if !context.has_timestamps {
            return None;
        }
        Some(Self {
            queries: context.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2 * TIMED_PASSES,
            }),
            resolve: context.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: 8 * u64::from(2 * TIMED_PASSES),
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            period: f64::from(context.queue.get_timestamp_period()),
        })
    }

    fn compute(&self, pass: u32) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: Some(2 * pass),
            end_of_pass_write_index: Some(2 * pass + 1),
        }
    }

    fn render(&self, pass: u32) -> wgpu::RenderPassTimestampWrites<'_> {
        wgpu::RenderPassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: Some(2 * pass),
            end_of_pass_write_index: Some(2 * pass + 1),
        }
    }

    fn read(&self, context: &GpuContext) -> GpuPassTimes {
        let bytes = context.read_buffer(&self.resolve, self.resolve.size());
        let ticks: &[u64] = bytemuck::cast_slice(&bytes);
        let span = |pass: usize| {
            Duration::from_nanos((ticks[2 * pass + 1].saturating_sub(ticks[2 * pass]) as f64 * self.period) as u64)
        };
        GpuPassTimes { hzb: span(0), clusters: span(1), triangles: span(2), draw: span(3) }
    }
}

/// What one frame produced, read back.
#[derive(Clone, Debug, Default)]
pub struct GpuFrameOutput {
    /// The counters.
    pub counters: GpuCounters,
    /// GPU time per pass, where the adapter has timestamp queries.
    pub pass_times: Option<GpuPassTimes>,
    /// Wall time from submitting the frame until its counters were back on the CPU.
    pub wall_time: Duration,
    /// The frame had too few clusters for the cluster pass to pay ([`AdaptiveSettings::tiny_scene_clusters`]):
    /// every candidate cluster went on to the next pass.
    pub cluster_pass_skipped: bool,
    /// The triangle pass was skipped for removing too little lately
    /// ([`AdaptiveSettings::min_triangle_benefit`]): the surviving clusters were drawn whole.
    pub triangle_pass_skipped: bool,
}

impl GpuFrameOutput {
    /// Both outputs added up: counters, pass times and wall time (the batches of one frame).
    pub fn plus(&self, other: &GpuFrameOutput) -> GpuFrameOutput {
        let (a, b) = (self.counters.to_array(), other.counters.to_array());
        let counters = GpuCounters::from_array(std::array::from_fn(|i| a[i] + b[i]));
        let pass_times = self.pass_times.zip(other.pass_times).map(|(a, b)| GpuPassTimes {
            hzb: a.hzb + b.hzb,
            clusters: a.clusters + b.clusters,
            triangles: a.triangles + b.triangles,
            draw: a.draw + b.draw,
        });
        GpuFrameOutput {
            counters,
            pass_times,
            wall_time: self.wall_time + other.wall_time,
            cluster_pass_skipped: self.cluster_pass_skipped || other.cluster_pass_skipped,
            triangle_pass_skipped: self.triangle_pass_skipped || other.triangle_pass_skipped,
        }
    }
}

/// The GPU pipeline for one scene: passes, per-frame buffers and render targets.
pub struct GpuCuller {
    /// The scene buffers.
    pub scene: GpuScene,
    /// The HZB.
    pub hzb: Hzb,
    cluster_pipeline: wgpu::ComputePipeline,
    prepare_pipeline: wgpu::ComputePipeline,
    triangle_pipeline: wgpu::ComputePipeline,
    draw: DrawPass,
    /// The render targets.
    pub targets: RenderTargets,
    view: wgpu::Buffer,
    /// The view the draw pass renders from: the culling view, or another camera's (see [`GpuCuller::run_from`]).
    draw_view: wgpu::Buffer,
    counters: wgpu::Buffer,
    dispatch: wgpu::Buffer,
    /// The last frame's view uniform (for the CPU twins in tests).
    pub last_view: GpuView,
    frame: Option<FrameBuffers>,
    timer: Option<PassTimer>,
    last_counters: GpuCounters,
    /// Which passes the last frame skipped.
    last_gate: PassGate,
    /// A smaller storage-binding budget than the device's, to split frames into batches (see
    /// [`GpuCuller::limit_batches`]).
    batch_bytes: Option<u64>,
    /// Which GPU passes a frame may skip (see [`GpuCuller::set_adaptive`]).
    adaptive: AdaptiveSettings,
    /// When the triangle pass is skipped for removing too little.
    triangle_gate: BenefitGate,
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
    /// The pipeline for `scene`, drawing into `width` x `height` targets, with an HZB for occlusion buffers of
    /// `hzb_width` x `hzb_height`.
    pub fn new(
        context: &GpuContext,
        scene: GpuScene,
        width: u32,
        height: u32,
        hzb_width: u32,
        hzb_height: u32,
    ) -> Self {
        let compute = |label, source| context.compute_pipeline(label, source);
        Self {
            scene,
            hzb: Hzb::new(context, hzb_width, hzb_height),
            cluster_pipeline: compute("cluster cull", include_str!("../../../shaders/cluster_cull.wgsl")),
            prepare_pipeline: compute("prepare triangles", include_str!("../../../shaders/prepare_triangles.wgsl")),
            triangle_pipeline: compute("triangle cull", include_str!("../../../shaders/triangle_cull.wgsl")),
            draw: DrawPass::new(context),
            targets: RenderTargets::new(context, width, height),
            view: view_buffer(context, "view"),
            draw_view: view_buffer(context, "draw view"),
            counters: storage_buffer(context, "counters", (COUNTER_COUNT * 4) as u64, wgpu::BufferUsages::INDIRECT),
            dispatch: storage_buffer(context, "triangle dispatch", 12, wgpu::BufferUsages::INDIRECT),
            last_view: GpuView::zeroed(),
            frame: None,
            timer: PassTimer::new(context),
            last_counters: GpuCounters::default(),
            last_gate: PassGate::default(),
            batch_bytes: None,
            adaptive: AdaptiveSettings::default(),
            triangle_gate: BenefitGate::default(),
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
    /// GPU ([`GpuCuller::read_survivors`]).
    pub fn run(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
    ) -> GpuFrameOutput {
        self.run_from(context, camera, camera, visible, depth, settings)
    }

    /// [`GpuCuller::run`] culling for `camera` but drawing the survivors as `draw_camera` sees them: with
    /// culling frozen at one camera, flying another shows what was culled.
    pub fn run_from(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        draw_camera: &Camera,
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
    ) -> GpuFrameOutput {
        if depth.width() > 0 && !self.hzb.fits(depth.width(), depth.height()) {
            self.hzb = Hzb::new(context, depth.width(), depth.height());
        }
        let library = &self.scene.library;
        let instances = self.scene.instances();
        let candidate_clusters: usize =
            visible.iter().map(|&slot| library.cluster_range(instances[slot as usize].mesh).len()).sum();
        let gate = PassGate {
            skip_clusters: candidate_clusters <= self.adaptive.tiny_scene_clusters as usize,
            skip_triangles: self.triangle_gate.skip_this_frame(),
        };
        let mut total: Option<GpuFrameOutput> = None;
        for (i, batch) in self.batches(context, visible).into_iter().enumerate() {
            let output = self.run_batch(context, camera, draw_camera, &visible[batch], depth, settings, gate, i == 0);
            total = Some(match total {
                None => output,
                Some(sum) => sum.plus(&output),
            });
        }
        let total = total.unwrap_or_default();
        if !gate.skip_triangles {
            let c = total.counters;
            let removed = c.triangles_in - c.triangles_out;
            self.triangle_gate.record(
                removed as usize,
                c.triangles_in as usize,
                self.adaptive.min_triangle_benefit,
                &self.adaptive,
            );
        }
        total
    }

    /// Sets which GPU passes a frame may skip: [`AdaptiveSettings::tiny_scene_clusters`] and
    /// [`AdaptiveSettings::min_triangle_benefit`] (the default settings until set). New settings start the
    /// triangle pass's benefit count afresh. [`GpuCuller::run_world`] sets the world's.
    pub fn set_adaptive(&mut self, adaptive: AdaptiveSettings) {
        if adaptive != self.adaptive {
            self.adaptive = adaptive;
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
    ) -> GpuFrameOutput {
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
            self.write_candidate_clusters(context, frame, visible, gate.skip_triangles);
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
        let bind = |pipeline: &wgpu::ComputePipeline, buffers: &[&wgpu::Buffer]| {
            let entries: Vec<_> = buffers
                .iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() })
                .collect();
            context.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &pipeline.get_bind_group_layout(0),
                entries: &entries,
            })
        };
        let scene = &self.scene;
        let cluster_group = bind(
            &self.cluster_pipeline,
            &[
                &self.view,
                &scene.instances,
                &scene.meshes,
                &scene.clusters,
                &frame.visible,
                &self.hzb.buffer,
                &self.counters,
                &frame.survivors,
                &frame.draw_args,
            ],
        );
        let prepare_group = bind(&self.prepare_pipeline, &[&self.counters, &self.dispatch]);
        let triangle_group = bind(
            &self.triangle_pipeline,
            &[
                &self.view,
                &scene.instances,
                &scene.clusters,
                &scene.positions,
                &scene.cluster_indices,
                &frame.survivors,
                &self.counters,
                &frame.draw_indices,
                &frame.draw_args,
            ],
        );
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("cluster cull"),
                timestamp_writes: timer.map(|t| t.compute(1)),
            });
            if !visible.is_empty() && !gate.skip_clusters {
                let n = visible.len() as u32;
                pass.set_pipeline(&self.cluster_pipeline);
                pass.set_bind_group(0, &cluster_group, &[]);
                pass.dispatch_workgroups(n.min(65535), n.div_ceil(65535), 1);
            }
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("triangle cull"),
                timestamp_writes: timer.map(|t| t.compute(2)),
            });
            if !gate.skip_triangles {
                pass.set_pipeline(&self.prepare_pipeline);
                pass.set_bind_group(0, &prepare_group, &[]);
                pass.dispatch_workgroups(1, 1, 1);
                pass.set_pipeline(&self.triangle_pipeline);
                pass.set_bind_group(0, &triangle_group, &[]);
                pass.dispatch_workgroups_indirect(&self.dispatch, 0);
            }
        }
        let source = DrawSource::Culled {
            // Without the triangle pass, the draws index the clusters' own triangles.
            indices: if gate.skip_triangles { &scene.cluster_indices } else { &frame.draw_indices },
            args: &frame.draw_args,
            count: &self.counters,
            count_offset: DRAWS_SLOT * 4,
            max_draws: frame.max_clusters,
        };
        self.record_draw(context, &mut encoder, camera.depth, source, first, timer.map(|t| t.render(3)));
        if let Some(timer) = timer {
            encoder.resolve_query_set(&timer.queries, 0..2 * TIMED_PASSES, &timer.resolve, 0);
        }
        let start = Instant::now();
        context.queue.submit([encoder.finish()]);
        let counter_bytes = context.read_buffer(&self.counters, (COUNTER_COUNT * 4) as u64);
        let wall_time = start.elapsed();
        let counters = GpuCounters::from_slots(visible.len() as u32, bytemuck::cast_slice(&counter_bytes));
        self.last_counters = counters;
        self.last_gate = gate;
        let pass_times = timer.map(|t| t.read(context));
        GpuFrameOutput {
            counters,
            pass_times,
            wall_time,
            cluster_pass_skipped: gate.skip_clusters,
            triangle_pass_skipped: gate.skip_triangles,
        }
    }

    /// Stands in for the cluster pass of a tiny frame: every cluster of the `visible` instances survives, and
    /// with `draw_clusters` each is also drawn whole (no triangle pass). Written before the frame's commands
    /// run, so these buffers are not cleared on the GPU.
    fn write_candidate_clusters(
        &self,
        context: &GpuContext,
        frame: &FrameBuffers,
        visible: &[u32],
        draw_clusters: bool,
    ) {
        let library = &self.scene.library;
        let instances = self.scene.instances();
        let survivors: Vec<[u32; 2]> = visible
            .iter()
            .flat_map(|&slot| library.cluster_range(instances[slot as usize].mesh).map(move |c| [slot, c]))
            .collect();
        let mut counters = [0u32; COUNTER_COUNT];
        counters[CLUSTERS_IN_SLOT] = survivors.len() as u32;
        counters[CLUSTERS_OUT_SLOT] = survivors.len() as u32;
        let draws = if draw_clusters { cluster_draws(library, instances, visible.iter().copied()) } else { Vec::new() };
        if draw_clusters {
            counters[TRIANGLES_OUT_SLOT] = draws.iter().map(|d| d.index_count / 3).sum();
            counters[DRAWS_SLOT as usize] = draws.len() as u32;
        }
        if !survivors.is_empty() {
            context.queue.write_buffer(&frame.survivors, 0, bytemuck::cast_slice(&survivors));
        }
        context.queue.write_buffer(&self.counters, 0, bytemuck::cast_slice(&counters));
        // Without a draw count every slot is drawn: the unused ones must be empty draws.
        let mut args: Vec<u8> = draws.iter().flat_map(|d| d.as_bytes().to_vec()).collect();
        if !context.has_draw_count {
            args.resize(frame.draw_args.size() as usize, 0);
        }
        if !args.is_empty() {
            context.queue.write_buffer(&frame.draw_args, 0, &args);
        }
    }

    /// The last frame's surviving `(instance, cluster)` pairs, in the GPU's (unordered) append order, and the
    /// global vertex indices of the triangles it drew: its compacted index buffer, or where the triangle pass
    /// was skipped, the surviving clusters' own triangles.
    pub fn read_survivors(&self, context: &GpuContext) -> (Vec<(u32, u32)>, Vec<u32>) {
        let (Some(frame), counters) = (self.frame.as_ref(), self.last_counters) else { return Default::default() };
        let clusters = if counters.clusters_out > 0 {
            let bytes = context.read_buffer(&frame.survivors, 8 * u64::from(counters.clusters_out));
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
            bytemuck::cast_slice(&context.read_buffer(&frame.draw_indices, 12 * u64::from(counters.triangles_out)))
                .to_vec()
        } else {
            Vec::new()
        };
        (clusters, indices)
    }

    /// Runs the GPU passes after the CPU stages of `world`'s frame: instances brought up to date (only the
    /// store slots written since the last call are copied), the occlusion stage's survivors culled and drawn
    /// against its depth buffer, from the world's [`Camera`].
    pub fn run_world(
        &mut self,
        context: &GpuContext,
        world: &mut bevy_ecs::world::World,
        settings: &GpuCullSettings,
    ) -> GpuFrameOutput {
        let camera = *world.resource::<Camera>();
        self.run_world_from(context, world, &camera, settings)
    }

    /// [`GpuCuller::run_world`] drawing from `draw_camera` (see [`GpuCuller::run_from`]).
    pub fn run_world_from(
        &mut self,
        context: &GpuContext,
        world: &mut bevy_ecs::world::World,
        draw_camera: &Camera,
        settings: &GpuCullSettings,
    ) -> GpuFrameOutput {
        if let Some(&adaptive) = world.get_resource::<AdaptiveSettings>() {
            self.set_adaptive(adaptive);
        }
        let written = world.resource_mut::<crate::bounds::BoundsStore>().take_written_slots();
        let count = world.resource::<crate::bounds::BoundsStore>().len();
        self.scene.write_instances(context, count, &written, |slot| super::scene::instance_of(world, slot));
        let state = world.resource::<crate::pipeline::OcclusionState>();
        let visible: Vec<u32> = state.visible.iter().map(|slot| slot as u32).collect();
        let camera = *world.resource::<Camera>();
        self.run_from(context, &camera, draw_camera, &visible, &state.depth, settings)
    }

    /// Draws every cluster of every instance with no culling at all, for comparison; `reversed` draws them in
    /// the opposite order, which shows where the image depends on draw order (coplanar surfaces of different
    /// objects at exactly the same depth).
    pub fn draw_unculled(&self, context: &GpuContext, camera: &Camera, reversed: bool) -> RenderedImage {
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
            let bytes: Vec<u8> = args.iter().flat_map(|a| a.as_bytes().to_vec()).collect();
            let buffer = context.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("unculled draws"),
                contents: &bytes,
                usage: wgpu::BufferUsages::INDIRECT,
            });
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
            source,
            clear,
            timestamps,
        );
    }

    /// Reads the render targets of the last frame.
    pub fn read_image(&self, context: &GpuContext) -> RenderedImage {
        self.targets.read(context)
    }
}
