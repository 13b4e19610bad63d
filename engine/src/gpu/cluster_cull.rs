//! Cluster culling (`cluster_cull.wgsl`): for every cluster of every instance the CPU stages kept, the
//! frustum test on its bounding sphere, the normal-cone back-face test (meshoptimizer's cone, tested in mesh
//! space with the camera brought there, for any transform that does not mirror), the HZB test (the sphere's box against the pyramid at the eq.
//! 19.5 level, 2x2 texels) and, opt-in and lossy, a small-cluster test. Survivors are appended to a compact
//! `(instance, cluster)` list with an atomic counter.
//!
//! `ClusterCullPass` records the pass, and `write_all_candidates` stands in for it on a tiny frame; [`cull_cluster`] is the same test on the CPU, operation for operation,
//! for the tests to compare against.

use super::GpuContext;
use super::clusters::GpuCluster;
use super::indirect::cluster_draws;
use super::interface::{
    CONE_SLACK, DEPTH_MARGIN, GpuView, INSTANCE_CONE_SAFE, RECT_MARGIN, SMALL_CLUSTER_PIXELS, VIEW_CONE, VIEW_HZB,
    VIEW_SECOND_HZB, VIEW_SMALL_CLUSTER, counter, workgroup_grid,
};
use super::scene::{GpuInstance, GpuScene};
use glam::{Mat3, Vec2, Vec3, Vec4};

/// The buffers the cluster pass reads and writes.
pub(crate) struct ClusterCullBuffers<'a> {
    /// The [`GpuView`] buffer.
    pub view: &'a wgpu::Buffer,
    /// [`GpuInstance`] per store slot.
    pub instances: &'a wgpu::Buffer,
    /// [`super::clusters::GpuMesh`] table.
    pub meshes: &'a wgpu::Buffer,
    /// [`GpuCluster`] table.
    pub clusters: &'a wgpu::Buffer,
    /// The store slots the CPU stages kept.
    pub visible: &'a wgpu::Buffer,
    /// The HZB levels.
    pub hzb: &'a wgpu::Buffer,
    /// The counter slots.
    pub counters: &'a wgpu::Buffer,
    /// `(instance, cluster)` survivors, appended.
    pub survivors: &'a wgpu::Buffer,
    /// Whole-cluster draws, where the triangle pass is skipped.
    pub draws: &'a wgpu::Buffer,
    /// Two-phase occlusion's per-cluster visibility ([`super::two_phase`]), or a placeholder with one phase.
    pub visibility: &'a wgpu::Buffer,
}

/// The cluster pass's pipeline.
pub(crate) struct ClusterCullPass {
    pipeline: wgpu::ComputePipeline,
}

impl ClusterCullPass {
    /// Compiles the pass.
    pub fn new(context: &GpuContext) -> Self {
        Self { pipeline: context.compute_pipeline("cluster cull", cullet_shaders::CLUSTER_CULL) }
    }

    /// Records the pass over `instance_count` visible instances (one workgroup each) into its own compute pass,
    /// with `timestamps` at its start and end if given. With no instance, or `skip`, the pass is empty (it
    /// still writes its timestamps).
    pub fn record(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        buffers: &ClusterCullBuffers<'_>,
        instance_count: u32,
        skip: bool,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("cluster cull"),
            timestamp_writes: timestamps,
        });
        if instance_count == 0 || skip {
            return;
        }
        let b = buffers;
        let frame_group = context.bind_buffers(
            "cluster cull",
            &self.pipeline.get_bind_group_layout(0),
            &[
                (0, b.view),
                (1, b.instances),
                (2, b.meshes),
                (3, b.clusters),
                (4, b.visible),
                (5, b.counters),
                (6, b.survivors),
                (7, b.draws),
                (8, b.visibility),
            ],
        );
        let hzb_group =
            context.bind_buffers("cluster cull hzb", &self.pipeline.get_bind_group_layout(1), &[(0, b.hzb)]);
        let (x, y) = workgroup_grid(instance_count);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &frame_group, &[]);
        pass.set_bind_group(1, &hzb_group, &[]);
        pass.dispatch_workgroups(x, y, 1);
    }
}

/// The buffers [`write_all_candidates`] fills in place of the cluster pass.
pub(crate) struct CandidateBuffers<'a> {
    /// `(instance, cluster)` survivors.
    pub survivors: &'a wgpu::Buffer,
    /// The counter slots.
    pub counters: &'a wgpu::Buffer,
    /// Whole-cluster draws, where the triangle pass is skipped too.
    pub draws: &'a wgpu::Buffer,
    /// Bytes of `draws`: without a draw count every slot is drawn, so the unused ones are zeroed.
    pub draw_capacity: u64,
}

/// Stands in for the cluster pass of a tiny frame ([`super::GpuGating::tiny_scene_clusters`]): every cluster of
/// the `visible` instances survives, and with `draw_clusters` each is also drawn whole (no triangle pass).
/// Written before the frame's commands run, so these buffers are not cleared on the GPU.
pub(crate) fn write_all_candidates(
    context: &GpuContext,
    scene: &GpuScene,
    visible: &[u32],
    buffers: &CandidateBuffers<'_>,
    draw_clusters: bool,
) {
    let (library, instances) = (&scene.library, scene.instances());
    let survivors: Vec<[u32; 2]> = visible
        .iter()
        .flat_map(|&slot| library.cluster_range(instances[slot as usize].mesh).map(move |c| [slot, c]))
        .collect();
    let mut counters = [0u32; counter::COUNTER_COUNT as usize];
    counters[counter::CLUSTERS_IN as usize] = survivors.len() as u32;
    counters[counter::CLUSTERS_OUT as usize] = survivors.len() as u32;
    let draws = if draw_clusters { cluster_draws(library, instances, visible.iter().copied()) } else { Vec::new() };
    if draw_clusters {
        counters[counter::TRIANGLES_OUT as usize] = draws.iter().map(|d| d.index_count / 3).sum();
        counters[counter::DRAWS as usize] = draws.len() as u32;
    }
    if !survivors.is_empty() {
        context.queue.write_buffer(buffers.survivors, 0, bytemuck::cast_slice(&survivors));
    }
    context.queue.write_buffer(buffers.counters, 0, bytemuck::cast_slice(&counters));
    // Without a draw count every slot is drawn: the unused ones must be empty draws.
    let mut args: Vec<u8> = draws.iter().flat_map(|d| d.as_bytes().to_vec()).collect();
    if !context.has_draw_count {
        args.resize(buffers.draw_capacity as usize, 0);
    }
    if !args.is_empty() {
        context.queue.write_buffer(buffers.draws, 0, &args);
    }
}

/// What the cluster test decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ClusterVerdict {
    /// May be visible: its triangles go on to the triangle pass.
    Keep,
    /// Its bounding sphere is outside a frustum plane.
    Frustum,
    /// All its triangles face away from the camera.
    Cone,
    /// Its bounds are behind the HZB.
    Hzb,
    /// Smaller than a pixel (opt-in, lossy).
    Small,
}

/// The GPU's cluster test on the CPU. `hzb` holds the pyramids' texels, levels as in `view.hzb_levels` (and
/// `view.second_hzb_levels`).
/// For the tests that compare the GPU with it.
#[doc(hidden)]
pub fn cull_cluster(view: &GpuView, hzb: &[f32], instance: &GpuInstance, cluster: &GpuCluster) -> ClusterVerdict {
    let camera = Vec3::from_slice(&view.camera[..3]);
    let center = instance.relative_point(Vec3::from(cluster.center), camera);
    let radius = cluster.radius * instance.max_scale;
    for plane in &view.planes {
        let plane = Vec4::from(*plane);
        if plane.truncate().dot(center) + plane.w < -radius {
            return ClusterVerdict::Frustum;
        }
    }
    if view.flags & VIEW_CONE != 0 && instance.flags & INSTANCE_CONE_SAFE != 0 && cluster.cone_cutoff < 1.0 {
        let camera = instance.camera_in_mesh_space(camera);
        if (Vec3::from(cluster.cone_apex) - camera).normalize().dot(Vec3::from(cluster.cone_axis))
            >= cluster.cone_cutoff + CONE_SLACK
        {
            return ClusterVerdict::Cone;
        }
    }
    if view.flags & VIEW_HZB != 0
        && let Some(footprint) = box_footprint(view, center, instance.box_axes(Vec3::from(cluster.extent)))
        && (hidden_behind(view, hzb, &footprint, false)
            || (view.flags & VIEW_SECOND_HZB != 0 && hidden_behind(view, hzb, &footprint, true)))
    {
        return ClusterVerdict::Hzb;
    }
    if view.flags & VIEW_SMALL_CLUSTER != 0 {
        let clip = view.clip_from_relative() * center.extend(1.0);
        let pixels = 2.0 * radius * view.focal_pixels / clip.w;
        if clip.w - radius > view.near && pixels < SMALL_CLUSTER_PIXELS {
            return ClusterVerdict::Small;
        }
    }
    ClusterVerdict::Keep
}

/// `common.wgsl`'s `Footprint`: a box's extent on screen in fractions of the view, y down, and its nearest
/// `1/w`.
struct Footprint {
    lo: Vec2,
    hi: Vec2,
    nearest: f32,
}

/// `common.wgsl`'s `box_footprint` on the CPU: `None` where the box reaches the near plane.
fn box_footprint(view: &GpuView, center: Vec3, axes: Mat3) -> Option<Footprint> {
    let matrix = view.clip_from_relative();
    let mut box_ = Footprint { lo: Vec2::splat(3.4e38), hi: Vec2::splat(-3.4e38), nearest: 0.0 };
    for corner in 0..8 {
        let sign = Vec3::new(
            if corner & 1 != 0 { 1.0 } else { -1.0 },
            if corner & 2 != 0 { 1.0 } else { -1.0 },
            if corner & 4 != 0 { 1.0 } else { -1.0 },
        );
        let clip = matrix * (center + axes * sign).extend(1.0);
        if clip.w <= view.near {
            return None;
        }
        let inv_w = 1.0 / clip.w;
        let screen = Vec2::new(clip.x * inv_w * 0.5 + 0.5, -(clip.y * inv_w) * 0.5 + 0.5);
        box_.lo = box_.lo.min(screen);
        box_.hi = box_.hi.max(screen);
        box_.nearest = box_.nearest.max(inv_w);
    }
    Some(box_)
}

/// `common.wgsl`'s `hidden_behind` on the CPU: whether `footprint` lies behind the view's first pyramid (or
/// `second`), whose texels are in `hzb`.
fn hidden_behind(view: &GpuView, hzb: &[f32], footprint: &Footprint, second: bool) -> bool {
    let (size, level_count, levels) = match second {
        false => (view.hzb_size, view.hzb_level_count, &view.hzb_levels),
        true => (view.second_hzb_size, view.second_hzb_level_count, &view.second_hzb_levels),
    };
    let size = Vec2::from(size);
    // The last texel, which may reach past the view (`size` is then a fraction less than the level's size).
    let top = Vec2::new(levels[0].width as f32, levels[0].height as f32) - Vec2::ONE;
    let lo_texel = (footprint.lo * size - RECT_MARGIN).floor().clamp(Vec2::ZERO, top).as_uvec2();
    let hi_texel = (footprint.hi * size + RECT_MARGIN).floor().clamp(Vec2::ZERO, top).as_uvec2();
    let span = (hi_texel.x - lo_texel.x).max(hi_texel.y - lo_texel.y) + 1;
    // One level finer than eq. 19.5's: at most 4x4 texels.
    let level_index = (31 - (span.max(1) * 2 - 1).leading_zeros()).min(level_count - 1);
    let finer = level_index.saturating_sub(1);
    let level = levels[finer as usize];
    let texel =
        |x: u32, y: u32| hzb[(level.offset + y.min(level.height - 1) * level.width + x.min(level.width - 1)) as usize];
    let (a, b) = (lo_texel >> finer, hi_texel >> finer);
    let texels = (a.y..=b.y).flat_map(|y| (a.x..=b.x).map(move |x| (x, y)));
    let farthest = texels.fold(f32::MAX, |farthest, (x, y)| farthest.min(texel(x, y)));
    footprint.nearest * (1.0 + DEPTH_MARGIN) < farthest
}
