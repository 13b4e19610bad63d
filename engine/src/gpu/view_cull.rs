//! One view's GPU culling: its [`GpuView`] uniform, counters and the buffers sized for its candidates, and the
//! cluster and triangle passes recorded for it. The camera is one such view ([`super::GpuCuller`]); each sun
//! cascade's shadow map is another ([`super::shadow`]), recorded into the same submission, so every view of a
//! frame has its own survivors and indirect draw arguments.

use super::cluster_cull::{CandidateBuffers, ClusterCullBuffers, ClusterCullPass, write_all_candidates};
use super::indirect::DrawBuffers;
use super::interface::{GpuView, counter};
use super::output::{COUNTER_BYTES, GpuCounters, PassTimer};
use super::scene::GpuScene;
use super::triangle_cull::{TriangleCullBuffers, TriangleCullPass};
use super::{GpuContext, GpuGating};
use crate::culler::BenefitGate;

/// The culling passes' pipelines, shared by every view.
pub(crate) struct CullPasses {
    cluster: ClusterCullPass,
    triangle: TriangleCullPass,
    /// The visibility binding of a view culled in one phase, never read.
    no_visibility: wgpu::Buffer,
}

impl CullPasses {
    /// Compiles both passes.
    pub fn new(context: &GpuContext) -> Self {
        Self {
            cluster: ClusterCullPass::new(context),
            triangle: TriangleCullPass::new(context),
            no_visibility: storage_buffer(context, "no visibility", 16, wgpu::BufferUsages::empty()),
        }
    }

    /// What a view culled in one phase tests against: `hzb`.
    pub fn one_phase<'a>(&'a self, hzb: &'a wgpu::Buffer) -> Against<'a> {
        Against { hzb, visibility: &self.no_visibility }
    }
}

/// What a view's cluster pass tests against: an HZB, and two-phase occlusion's visibility
/// ([`super::two_phase`]) where the view's flags name a phase.
#[derive(Clone, Copy)]
pub(crate) struct Against<'a> {
    /// The HZB levels.
    pub hzb: &'a wgpu::Buffer,
    /// The per-cluster visibility.
    pub visibility: &'a wgpu::Buffer,
}

/// Which passes one view skips this frame.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct PassGate {
    /// No cluster pass: the CPU lists every candidate cluster.
    pub skip_clusters: bool,
    /// No triangle pass: surviving clusters are drawn whole.
    pub skip_triangles: bool,
}

/// Buffers sized for a view's candidates.
pub(crate) struct FrameBuffers {
    pub visible: wgpu::Buffer,
    pub survivors: wgpu::Buffer,
    pub draw_indices: wgpu::Buffer,
    pub draw_args: wgpu::Buffer,
    pub max_clusters: u32,
    pub max_indices: u32,
}

/// A storage buffer of `size` bytes (at least 16).
pub(crate) fn storage_buffer(context: &GpuContext, label: &str, size: u64, extra: wgpu::BufferUsages) -> wgpu::Buffer {
    context.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16).next_multiple_of(4),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC | extra,
        mapped_at_creation: false,
    })
}

/// A read-only storage buffer for one [`GpuView`] (`view` in `common.wgsl` says why not a uniform).
pub(crate) fn view_buffer(context: &GpuContext, label: &str) -> wgpu::Buffer {
    context.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: std::mem::size_of::<GpuView>() as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Candidate clusters and triangles of the instances at `visible`.
pub(crate) fn candidates(scene: &GpuScene, visible: &[u32]) -> (u32, u32) {
    let instances = scene.instances();
    visible
        .iter()
        .flat_map(|&slot| scene.library.clusters_of(instances[slot as usize].mesh))
        .fold((0, 0), |(clusters, triangles), cluster| (clusters + 1, triangles + cluster.triangle_count))
}

/// Whether the buffers for `clusters` candidate clusters and `triangles` candidate triangles (grown as
/// [`ViewCull::fit`] grows them) fit a storage binding of `limit` bytes: 12 bytes a triangle, 20 a cluster.
pub(crate) fn fits_binding(clusters: u64, triangles: u64, limit: u64) -> bool {
    let max_triangles = (limit / 12).saturating_sub(64) * 2 / 3;
    let max_clusters = (limit / 20).saturating_sub(64) * 2 / 3;
    triangles <= max_triangles && clusters <= max_clusters
}

/// One view's uniform, counters and per-frame buffers, and when its triangle pass pays.
pub(crate) struct ViewCull {
    /// The [`GpuView`] uniform its passes read.
    pub view: wgpu::Buffer,
    /// Its counter slots ([`counter`]).
    pub counters: wgpu::Buffer,
    /// The triangle pass's indirect dispatch.
    dispatch: wgpu::Buffer,
    /// Buffers sized for its candidates, once it has had any.
    pub frame: Option<FrameBuffers>,
    /// When its cluster pass is skipped for removing too little.
    cluster_gate: BenefitGate,
    /// When its triangle pass is skipped for removing too little.
    triangle_gate: BenefitGate,
}

impl ViewCull {
    /// A view with no frame yet.
    pub fn new(context: &GpuContext, label: &str) -> Self {
        Self {
            view: view_buffer(context, label),
            counters: storage_buffer(context, "counters", COUNTER_BYTES, wgpu::BufferUsages::INDIRECT),
            dispatch: storage_buffer(context, "triangle dispatch", 12, wgpu::BufferUsages::INDIRECT),
            frame: None,
            cluster_gate: BenefitGate::default(),
            triangle_gate: BenefitGate::default(),
        }
    }

    /// The passes this view skips this frame, with `clusters` candidate clusters: the cluster pass for a tiny
    /// frame, and each pass while its benefit gate says so. Call once a frame.
    pub fn gate(&mut self, gating: &GpuGating, clusters: usize) -> PassGate {
        let clusters_gated = self.cluster_gate.skip_this_frame();
        PassGate {
            skip_clusters: clusters <= gating.tiny_scene_clusters as usize || clusters_gated,
            skip_triangles: self.triangle_gate.skip_this_frame(),
        }
    }

    /// Records what the passes that ran this frame (not skipped in `gate`) removed, for their benefit gates.
    pub fn record_benefit(&mut self, gating: &GpuGating, gate: PassGate, counters: &GpuCounters) {
        if !gate.skip_clusters {
            self.cluster_gate.record(
                counters.clusters_in.saturating_sub(counters.clusters_out) as usize,
                counters.clusters_in as usize,
                gating.min_cluster_benefit,
                gating.low_benefit_frames,
                gating.reprobe_every,
            );
        }
        if !gate.skip_triangles {
            let removed = counters.triangles_in - counters.triangles_out;
            self.triangle_gate.record(
                removed as usize,
                counters.triangles_in as usize,
                gating.min_triangle_benefit,
                gating.low_benefit_frames,
                gating.reprobe_every,
            );
        }
    }

    /// Starts the benefit gates afresh (new gating settings).
    pub fn reset_gate(&mut self) {
        self.cluster_gate = BenefitGate::default();
        self.triangle_gate = BenefitGate::default();
    }

    /// Grows the per-frame buffers to hold `visible` instances whose `(clusters, triangles)` are their
    /// [`candidates`], by half again so that a slowly growing view does not reallocate every frame.
    pub fn fit(&mut self, context: &GpuContext, visible: usize, (clusters, triangles): (u32, u32)) -> &FrameBuffers {
        let fits = self.frame.as_ref().is_some_and(|f| {
            f.max_clusters >= clusters && f.max_indices >= 3 * triangles && f.visible.size() >= 4 * visible as u64
        });
        if !fits {
            let (clusters, indices) = (clusters + clusters / 2 + 64, 3 * (triangles + triangles / 2 + 64));
            let none = wgpu::BufferUsages::empty();
            self.frame = Some(FrameBuffers {
                visible: storage_buffer(context, "visible instances", 4 * (visible as u64 * 3 / 2 + 64), none),
                survivors: storage_buffer(context, "cluster survivors", 8 * u64::from(clusters), none),
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

    /// Records the view's culling of the instances at `visible` into `encoder`: their upload, the counters
    /// cleared (or, with `gate.skip_clusters`, every candidate cluster written in place of the cluster pass),
    /// the cluster pass `against` an HZB and the triangle pass, each timed by `timer`'s passes `timed` and
    /// `timed + 1` if given. The view's uniform must be written, and its buffers [`ViewCull::fit`] to `visible`.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        scene: &GpuScene,
        passes: &CullPasses,
        against: Against<'_>,
        visible: &[u32],
        gate: PassGate,
        (timer, timed): (Option<&PassTimer>, u32),
    ) {
        let frame = self.frame.as_ref().expect("ViewCull::fit before ViewCull::record");
        if !visible.is_empty() {
            context.queue.write_buffer(&frame.visible, 0, bytemuck::cast_slice(visible));
        }
        if gate.skip_clusters {
            let buffers = CandidateBuffers {
                survivors: &frame.survivors,
                counters: &self.counters,
                draws: &frame.draw_args,
                draw_capacity: frame.draw_args.size(),
            };
            write_all_candidates(context, scene, visible, &buffers, gate.skip_triangles);
        } else {
            encoder.clear_buffer(&self.counters, 0, None);
            if !context.has_draw_count {
                encoder.clear_buffer(&frame.draw_args, 0, None);
            }
        }
        let cluster_buffers = self.cluster_buffers(scene, frame, against, &self.view);
        let instance_count = visible.len() as u32;
        let skip_clusters = gate.skip_clusters;
        passes.cluster.record(
            context,
            encoder,
            &cluster_buffers,
            instance_count,
            skip_clusters,
            timer.map(|t| t.compute(timed)),
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
        let timestamps = timer.map(|t| t.compute(timed + 1));
        passes.triangle.record(context, encoder, &triangle_buffers, gate.skip_triangles, timestamps);
    }

    /// Records the cluster pass alone over the instances the last [`ViewCull::record`] uploaded, reading the
    /// view in `view` (flagged [`super::interface::VIEW_PHASE_FINAL`]: it only changes `against`'s visibility),
    /// with `timestamps` at its start and end if given.
    #[allow(clippy::too_many_arguments)]
    pub fn record_marks(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        scene: &GpuScene,
        (passes, against): (&CullPasses, Against<'_>),
        view: &wgpu::Buffer,
        instance_count: u32,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let frame = self.frame.as_ref().expect("ViewCull::record before ViewCull::record_marks");
        let buffers = self.cluster_buffers(scene, frame, against, view);
        passes.cluster.record(context, encoder, &buffers, instance_count, false, timestamps);
    }

    /// The cluster pass's buffers for this view's `frame`, reading the view in `view`.
    fn cluster_buffers<'a>(
        &'a self,
        scene: &'a GpuScene,
        frame: &'a FrameBuffers,
        against: Against<'a>,
        view: &'a wgpu::Buffer,
    ) -> ClusterCullBuffers<'a> {
        ClusterCullBuffers {
            view,
            instances: &scene.instances,
            meshes: &scene.meshes,
            clusters: &scene.clusters,
            visible: &frame.visible,
            hzb: against.hzb,
            counters: &self.counters,
            survivors: &frame.survivors,
            draws: &frame.draw_args,
            visibility: against.visibility,
        }
    }

    /// The draws the view's last culled frame wrote, over `scene`'s buffers; `None` before its first frame.
    pub fn draws<'a>(&'a self, scene: &'a GpuScene, skip_triangles: bool) -> Option<DrawBuffers<'a>> {
        let frame = self.frame.as_ref()?;
        Some(DrawBuffers {
            positions: &scene.positions,
            // Without the triangle pass, the draws index the clusters' own triangles.
            indices: if skip_triangles { &scene.cluster_indices } else { &frame.draw_indices },
            args: &frame.draw_args,
            count: &self.counters,
            count_offset: u64::from(counter::DRAWS) * 4,
            max_draws: frame.max_clusters,
            instances: &scene.instances,
            view: &self.view,
        })
    }
}
