//! Triangle culling (`triangle_cull.wgsl`, after `prepare_triangles.wgsl` sizes its dispatch): one workgroup per surviving cluster, one thread per
//! triangle. In order: degenerate (two corners at one position, so no area in any view; three distinct
//! collinear corners are kept, as rounding in the transform can open them into a sliver); any vertex at `w <= 0` keeps the
//! triangle (screen tests need all three in front of the eye); back-facing (clearly clockwise on screen, by
//! more than the rasterizer's vertex snapping could change); outside the viewport; and small (eq. 19.4: its
//! pixel bounding box holds no pixel centre, with the snapping margin). Each test only removes triangles that
//! cover no sample, so culling stays conservative. Survivors are compacted into the draw index buffer and each
//! cluster with survivors becomes one `DrawIndexedIndirectArgs` whose first instance names its instance.
//!
//! `TriangleCullPass` records the pass; [`cull_triangle`] is the same test on the CPU.

use super::GpuContext;
use super::interface::{GpuView, SNAP, VIEW_BACKFACE, VIEW_SMALL_TRIANGLE, VIEW_TRIANGLE_FRUSTUM};
use super::scene::GpuInstance;
use glam::{Vec2, Vec3, Vec4};

/// The buffers the triangle pass reads and writes.
pub(crate) struct TriangleCullBuffers<'a> {
    /// The [`GpuView`] uniform.
    pub view: &'a wgpu::Buffer,
    /// [`GpuInstance`] per store slot.
    pub instances: &'a wgpu::Buffer,
    /// [`super::clusters::GpuCluster`] table.
    pub clusters: &'a wgpu::Buffer,
    /// Vertex positions.
    pub positions: &'a wgpu::Buffer,
    /// The clusters' triangles as global vertex indices.
    pub cluster_indices: &'a wgpu::Buffer,
    /// The cluster pass's `(instance, cluster)` survivors.
    pub survivors: &'a wgpu::Buffer,
    /// The counter slots.
    pub counters: &'a wgpu::Buffer,
    /// The pass's own indirect dispatch arguments (three `u32`).
    pub dispatch: &'a wgpu::Buffer,
    /// The compacted index buffer written.
    pub draw_indices: &'a wgpu::Buffer,
    /// One indexed indirect draw per cluster with survivors.
    pub draws: &'a wgpu::Buffer,
}

/// The triangle pass's pipelines: the dispatch sizing and the culling.
pub(crate) struct TriangleCullPass {
    prepare: wgpu::ComputePipeline,
    cull: wgpu::ComputePipeline,
}

impl TriangleCullPass {
    /// Compiles the pass.
    pub fn new(context: &GpuContext) -> Self {
        Self {
            prepare: context.compute_pipeline("prepare triangles", cullet_shaders::PREPARE_TRIANGLES),
            cull: context.compute_pipeline("triangle cull", cullet_shaders::TRIANGLE_CULL),
        }
    }

    /// Records the pass into its own compute pass, with `timestamps` at its start and end if given: the
    /// surviving-cluster count turned into the indirect dispatch, then one workgroup per surviving cluster.
    /// With `skip` the pass is empty (it still writes its timestamps).
    pub fn record(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        buffers: &TriangleCullBuffers<'_>,
        skip: bool,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("triangle cull"),
            timestamp_writes: timestamps,
        });
        if skip {
            return;
        }
        let b = buffers;
        let prepare_group = context.bind_buffers(
            "prepare triangles",
            &self.prepare.get_bind_group_layout(0),
            &[(1, b.counters), (2, b.dispatch)],
        );
        let cull_group = context.bind_buffers(
            "triangle cull",
            &self.cull.get_bind_group_layout(0),
            &[
                (0, b.view),
                (1, b.instances),
                (2, b.clusters),
                (3, b.positions),
                (4, b.cluster_indices),
                (5, b.survivors),
                (6, b.counters),
                (7, b.draw_indices),
                (8, b.draws),
            ],
        );
        pass.set_pipeline(&self.prepare);
        pass.set_bind_group(0, &prepare_group, &[]);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&self.cull);
        pass.set_bind_group(0, &cull_group, &[]);
        pass.dispatch_workgroups_indirect(b.dispatch, 0);
    }
}

/// What the triangle test decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TriangleVerdict {
    /// May cover a sample: drawn.
    Keep,
    /// Two corners at one position: no area in any view.
    Degenerate,
    /// Faces away from the camera.
    Backface,
    /// Wholly outside the viewport.
    Frustum,
    /// Covers no pixel centre.
    Small,
}

/// The GPU's triangle test on the CPU, for mesh-space corners `p` of a triangle of `instance`. For the tests
/// that compare the GPU with it.
#[doc(hidden)]
pub fn cull_triangle(view: &GpuView, instance: &GpuInstance, p: [Vec3; 3]) -> TriangleVerdict {
    if p[0] == p[1] || p[1] == p[2] || p[2] == p[0] {
        return TriangleVerdict::Degenerate;
    }
    let camera = Vec3::from_slice(&view.camera[..3]);
    let matrix = view.clip_from_relative();
    let clip: [Vec4; 3] = p.map(|p| matrix * instance.relative_point(p, camera).extend(1.0));
    if clip.iter().any(|c| c.w <= 0.0) {
        return TriangleVerdict::Keep;
    }
    let viewport = Vec2::from(view.viewport);
    let [s0, s1, s2] = clip.map(|c| (Vec2::new(c.x, c.y) / c.w * 0.5 + 0.5) * viewport);
    if view.flags & VIEW_BACKFACE != 0 {
        let (e0, e1) = (s1 - s0, s2 - s0);
        let area = e0.x * e1.y - e0.y * e1.x;
        let perimeter = e0.length() + e1.length() + (s2 - s1).length();
        if area < -2.0 * SNAP * perimeter {
            return TriangleVerdict::Backface;
        }
    }
    let lo = s0.min(s1.min(s2));
    let hi = s0.max(s1.max(s2));
    if view.flags & VIEW_TRIANGLE_FRUSTUM != 0
        && (hi.cmplt(Vec2::splat(-SNAP)).any() || lo.cmpgt(viewport + Vec2::splat(SNAP)).any())
    {
        return TriangleVerdict::Frustum;
    }
    let no_sample_between = |lo: f32, hi: f32| (lo - SNAP - 0.5).ceil() > (hi + SNAP - 0.5).floor();
    if view.flags & VIEW_SMALL_TRIANGLE != 0 && (no_sample_between(lo.x, hi.x) || no_sample_between(lo.y, hi.y)) {
        return TriangleVerdict::Small;
    }
    TriangleVerdict::Keep
}
