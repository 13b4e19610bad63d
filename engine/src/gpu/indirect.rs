//! The multi-draw-indirect's inputs: the scene's vertex layout, the buffers the culling passes fill for one
//! `multi_draw_indexed_indirect_count`, and the uncompacted draws of whole clusters. Every pass that draws the
//! scene's clusters (the frame's draw, the shadow maps, a renderer's own pass) reads them.

use super::GpuContext;
use wgpu::util::DrawIndexedIndirectArgs;

/// The layout of the vertex buffer every draw of the scene reads ([`super::scene::GpuScene::positions`],
/// [`DrawBuffers::positions`]): three `f32` a vertex, at location 0.
pub const POSITION_LAYOUT: wgpu::VertexBufferLayout<'static> = wgpu::VertexBufferLayout {
    array_stride: 12,
    step_mode: wgpu::VertexStepMode::Vertex,
    attributes: &[wgpu::VertexAttribute { format: wgpu::VertexFormat::Float32x3, offset: 0, shader_location: 0 }],
};

/// The vertex stage `vs` of `module`, reading [`POSITION_LAYOUT`]: every pipeline that draws the scene's
/// clusters starts here.
pub(crate) fn position_vertex_state(module: &wgpu::ShaderModule) -> wgpu::VertexState<'_> {
    wgpu::VertexState {
        module,
        entry_point: Some("vs"),
        compilation_options: Default::default(),
        buffers: &[Some(POSITION_LAYOUT)],
    }
}

/// What a renderer needs to draw the last frame's survivors itself, with one
/// `multi_draw_indexed_indirect_count`: vertex positions pulled by the compacted indices, one
/// `DrawIndexedIndirectArgs` per drawn cluster whose `first_instance` names the instance (store slot) in
/// `instances`, and the draw count in `count` at byte offset `count_offset` ([`super::GpuCuller::draw_buffers`]).
#[derive(Clone, Copy, Debug)]
pub struct DrawBuffers<'a> {
    /// Vertex positions, three `f32` per vertex (vertex buffer).
    pub positions: &'a wgpu::Buffer,
    /// Triangle indices into `positions` (index buffer, `u32`).
    pub indices: &'a wgpu::Buffer,
    /// `DrawIndexedIndirectArgs` per draw (indirect buffer).
    pub args: &'a wgpu::Buffer,
    /// Holds the draw count (indirect buffer).
    pub count: &'a wgpu::Buffer,
    /// Byte offset of the draw count in `count`.
    pub count_offset: u64,
    /// Most draws `args` holds: the `max_count` of the multi-draw.
    pub max_draws: u32,
    /// [`super::scene::GpuInstance`] per store slot (storage buffer, 64 bytes each): each object's transform and colour.
    pub instances: &'a wgpu::Buffer,
    /// The [`super::interface::GpuView`] buffer the frame was culled with (`view` in `common.wgsl`).
    pub view: &'a wgpu::Buffer,
}

impl DrawBuffers<'_> {
    /// The bind group a shader written on the engine's declarations ([`super::shader_source`]) takes at group
    /// 0 with `layout`: the view at binding 0 and the instances at binding 1.
    pub fn bind_group(&self, context: &GpuContext, layout: &wgpu::BindGroupLayout) -> wgpu::BindGroup {
        context.bind_buffers("draw buffers", layout, &[(0, self.view), (1, self.instances)])
    }

    /// Records the draws into `pass`, whose pipeline and bind groups are set: `positions` as vertex buffer 0,
    /// `indices` as the index buffer, then one `multi_draw_indexed_indirect_count`, or without that feature
    /// `multi_draw_indexed_indirect` of all `max_draws` slots (the culler zeroes the unused ones).
    pub fn record(&self, context: &GpuContext, pass: &mut wgpu::RenderPass<'_>) {
        pass.set_vertex_buffer(0, self.positions.slice(..));
        pass.set_index_buffer(self.indices.slice(..), wgpu::IndexFormat::Uint32);
        if context.has_draw_count {
            pass.multi_draw_indexed_indirect_count(self.args, 0, self.count, self.count_offset, self.max_draws);
        } else {
            pass.multi_draw_indexed_indirect(self.args, 0, self.max_draws);
        }
    }
}

/// An indirect buffer holding `args` (not empty), for a `multi_draw_indexed_indirect` of `args.len()` draws.
pub(crate) fn indirect_buffer(context: &GpuContext, label: &str, args: &[DrawIndexedIndirectArgs]) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    let bytes: Vec<u8> = args.iter().flat_map(|a| a.as_bytes().to_vec()).collect();
    context.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: &bytes,
        usage: wgpu::BufferUsages::INDIRECT,
    })
}

/// The draws of every cluster of the instances at `slots`, uncompacted (each over its cluster's own indices):
/// for drawing with culling off, or without the triangle pass.
pub fn cluster_draws(
    library: &super::clusters::ClusterLibrary,
    instances: &[super::scene::GpuInstance],
    slots: impl IntoIterator<Item = u32>,
) -> Vec<DrawIndexedIndirectArgs> {
    slots
        .into_iter()
        .flat_map(|slot| {
            library.clusters_of(instances[slot as usize].mesh).iter().map(move |cluster| DrawIndexedIndirectArgs {
                index_count: 3 * cluster.triangle_count,
                instance_count: 1,
                first_index: cluster.first_index,
                base_vertex: 0,
                first_instance: slot,
            })
        })
        .collect()
}

/// The draws of the whole meshes of the instances at `slots` (ascending), uncompacted: a mesh's clusters are
/// one range of the index buffer, so each run of consecutive slots of one mesh is one instanced draw. For a
/// depth pass that needs no culling below the object.
pub fn object_draws(
    library: &super::clusters::ClusterLibrary,
    instances: &[super::scene::GpuInstance],
    slots: impl IntoIterator<Item = u32>,
) -> Vec<DrawIndexedIndirectArgs> {
    let mut draws: Vec<DrawIndexedIndirectArgs> = Vec::new();
    let mut last: Option<(u32, u32)> = None;
    for slot in slots {
        let mesh = instances[slot as usize].mesh;
        let clusters = library.clusters_of(mesh);
        let (Some(first), Some(end)) = (clusters.first(), clusters.last()) else { continue };
        if let (Some((last_slot, last_mesh)), Some(draw)) = (last, draws.last_mut())
            && last_slot + 1 == slot
            && last_mesh == mesh
        {
            draw.instance_count += 1;
        } else {
            draws.push(DrawIndexedIndirectArgs {
                index_count: end.first_index + 3 * end.triangle_count - first.first_index,
                instance_count: 1,
                first_index: first.first_index,
                base_vertex: 0,
                first_instance: slot,
            });
        }
        last = Some((slot, mesh));
    }
    draws
}
