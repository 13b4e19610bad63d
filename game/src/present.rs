//! Showing a frame in the window (`present.wgsl`): the GPU draw's colour target, or a depth texture
//! uploaded from the CPU (the software occlusion buffer, or a level of its pyramid), stretched over the
//! window with nearest texels.

use bytemuck::{Pod, Zeroable};
use cullet::depth::DepthBuffer;
use cullet::gpu::GpuContext;

/// What the present pass shows.
pub enum Source<'a> {
    /// A colour texture view (the draw's colour target).
    Color(&'a wgpu::TextureView),
    /// A CPU depth buffer, uploaded for this frame.
    Depth(&'a DepthBuffer),
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    target_size: [f32; 2],
    mode: u32,
    depth_scale: f32,
}

/// The present pipeline for one surface format, and the depth texture it uploads into.
pub struct PresentPass {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    depth: Option<(wgpu::Texture, u32, u32)>,
}

impl PresentPass {
    /// The pass writing to surfaces of `format`.
    pub fn new(context: &GpuContext, format: wgpu::TextureFormat) -> Self {
        let device = &context.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("present"),
            source: wgpu::ShaderSource::Wgsl(include_str!("present.wgsl").into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("present"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    // Unfilterable, so both RGBA8 and R32Float textures bind; the shader loads texels.
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("present"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("present"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[Some(format.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("present params"),
            size: std::mem::size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Self { pipeline, layout, params, depth: None }
    }

    /// Records drawing `source` over all of `target` (`size` pixels).
    pub fn record(
        &mut self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        source: Source<'_>,
        target: &wgpu::TextureView,
        size: (u32, u32),
    ) {
        let mut params = Params { target_size: [size.0 as f32, size.1 as f32], mode: 0, depth_scale: 1.0 };
        let depth_view;
        let view = match source {
            Source::Color(view) => view,
            Source::Depth(buffer) => {
                params.mode = 1;
                let nearest = buffer.texels().iter().copied().fold(0.0f32, f32::max);
                params.depth_scale = if nearest > 0.0 { 1.0 / nearest } else { 1.0 };
                depth_view = self.upload_depth(context, buffer);
                &depth_view
            }
        };
        context.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        let bind_group = context.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("present"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(view) },
                wgpu::BindGroupEntry { binding: 1, resource: self.params.as_entire_binding() },
            ],
        });
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("present"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::BLACK), store: wgpu::StoreOp::Store },
            })],
            ..Default::default()
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.draw(0..3, 0..1);
    }

    /// Uploads `buffer` into the depth texture (regrown when its size changes) and returns a view of it.
    fn upload_depth(&mut self, context: &GpuContext, buffer: &DepthBuffer) -> wgpu::TextureView {
        let (width, height) = (buffer.width().max(1), buffer.height().max(1));
        if !matches!(self.depth, Some((_, w, h)) if (w, h) == (width, height)) {
            let texture = context.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("debug depth"),
                size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::R32Float,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            });
            self.depth = Some((texture, width, height));
        }
        let (texture, _, _) = self.depth.as_ref().expect("made above");
        let empty = [0.0f32];
        let texels = if buffer.width() == 0 { &empty[..] } else { buffer.texels() };
        context.queue.write_texture(
            texture.as_image_copy(),
            bytemuck::cast_slice(texels),
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(width * 4), rows_per_image: None },
            wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
        );
        texture.create_view(&wgpu::TextureViewDescriptor::default())
    }
}
