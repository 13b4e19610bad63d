//! Draw (`draw.wgsl`): the culled survivors with one `multi_draw_indexed_indirect_count` (or
//! `multi_draw_indexed_indirect` where the count feature is missing), or every cluster of every instance with
//! culling off, through the same shader, into colour, object-ID and depth targets that are read back as an
//! image. Back faces are culled by the rasterizer; depth follows the camera's convention.

use super::GpuContext;
use super::indirect::{DrawBuffers, position_vertex_state};
use crate::camera::DepthConvention;

/// Colour target format.
const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
/// Object-ID target format: the instance (store slot) per pixel.
const OBJECT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Colour of pixels nothing covers.
const SKY: wgpu::Color = wgpu::Color { r: 0.55, g: 0.7, b: 0.9, a: 1.0 };
/// Object ID of pixels nothing covers.
pub const NO_OBJECT: u32 = u32::MAX;

/// A rendered frame read back to the CPU, rows from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderedImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// RGBA8 per pixel.
    pub color: Vec<[u8; 4]>,
    /// Instance index per pixel, [`NO_OBJECT`] where none.
    pub object: Vec<u32>,
    /// Depth per pixel, in the camera's convention.
    pub depth: Vec<f32>,
}

/// The render targets of one size.
pub struct RenderTargets {
    width: u32,
    height: u32,
    color: wgpu::Texture,
    object: wgpu::Texture,
    depth: wgpu::Texture,
}

impl RenderTargets {
    /// Targets of `width` x `height`.
    pub fn new(context: &GpuContext, width: u32, height: u32) -> Self {
        let texture = |label, format| {
            context.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::COPY_SRC
                    | wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            })
        };
        Self {
            width,
            height,
            color: texture("color", COLOR_FORMAT),
            object: texture("object id", OBJECT_FORMAT),
            depth: texture("depth", DEPTH_FORMAT),
        }
    }

    /// Width and height.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The depth target (`Depth32Float`), which two-phase occlusion reads after its early draw.
    pub(crate) fn depth_texture(&self) -> &wgpu::Texture {
        &self.depth
    }

    /// A view of the colour target (RGBA8), for showing it in a window.
    pub fn color_view(&self) -> wgpu::TextureView {
        self.color.create_view(&wgpu::TextureViewDescriptor::default())
    }

    /// Reads all three targets back.
    ///
    /// # Errors
    /// [`super::GpuError::Lost`] when the device is lost.
    pub fn read(&self, context: &GpuContext) -> Result<RenderedImage, super::GpuError> {
        let read = |texture: &wgpu::Texture, aspect| context.read_texture(texture, aspect, 4);
        let color = read(&self.color, wgpu::TextureAspect::All)?;
        let object = read(&self.object, wgpu::TextureAspect::All)?;
        let depth = read(&self.depth, wgpu::TextureAspect::DepthOnly)?;
        Ok(RenderedImage {
            width: self.width,
            height: self.height,
            color: bytemuck::cast_slice(&color).to_vec(),
            object: bytemuck::cast_slice(&object).to_vec(),
            depth: bytemuck::cast_slice(&depth).to_vec(),
        })
    }
}

/// Which draws a [`DrawPass`] records.
pub enum DrawSource<'a> {
    /// The culling passes' output.
    Culled(DrawBuffers<'a>),
    /// Every cluster drawn with no culling: `args` holds `draws` draws into the cluster index buffer.
    Unculled {
        /// The scene's cluster index buffer.
        indices: &'a wgpu::Buffer,
        /// `DrawIndexedIndirectArgs` per cluster of each instance.
        args: &'a wgpu::Buffer,
        /// Number of draws.
        draws: u32,
    },
}

/// The draw pipeline.
pub struct DrawPass {
    pipelines: [wgpu::RenderPipeline; 2],
}

impl DrawPass {
    /// Builds the pipelines (one per depth direction).
    pub fn new(context: &GpuContext) -> Self {
        let module = context.shader("draw", cullet_shaders::DRAW);
        let pipeline = |compare| {
            context.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("draw"),
                layout: None,
                vertex: position_vertex_state(&module),
                primitive: wgpu::PrimitiveState { cull_mode: Some(wgpu::Face::Back), ..Default::default() },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(compare),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs"),
                    compilation_options: Default::default(),
                    targets: &[Some(COLOR_FORMAT.into()), Some(OBJECT_FORMAT.into())],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        Self { pipelines: [pipeline(wgpu::CompareFunction::Greater), pipeline(wgpu::CompareFunction::Less)] }
    }

    /// Records the draw of `source` into `targets`, clearing them first if `clear` (else drawing over them),
    /// shaded with `shadows`, with `timestamps` at the pass's start and end if given.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        targets: &RenderTargets,
        depth: DepthConvention,
        view: &wgpu::Buffer,
        instances: &wgpu::Buffer,
        positions: &wgpu::Buffer,
        shadows: &super::shadow::ShadowMaps,
        source: DrawSource<'_>,
        clear: bool,
        timestamps: Option<wgpu::RenderPassTimestampWrites<'_>>,
    ) {
        let reversed = depth == DepthConvention::Reversed;
        let load = |value| if clear { wgpu::LoadOp::Clear(value) } else { wgpu::LoadOp::Load };
        let pipeline = &self.pipelines[usize::from(!reversed)];
        let [uniform, maps, sampler] = shadows.bind_entries();
        let bind_group = context.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("draw"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: view.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: instances.as_entire_binding() },
                uniform,
                maps,
                sampler,
            ],
        });
        let color_view = targets.color.create_view(&Default::default());
        let object_view = targets.object.create_view(&Default::default());
        let depth_view = targets.depth.create_view(&Default::default());
        let clear_object = wgpu::Color { r: f64::from(NO_OBJECT), g: 0.0, b: 0.0, a: 0.0 };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("draw"),
            color_attachments: &[
                Some(wgpu::RenderPassColorAttachment {
                    view: &color_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: load(SKY), store: wgpu::StoreOp::Store },
                }),
                Some(wgpu::RenderPassColorAttachment {
                    view: &object_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: load(clear_object), store: wgpu::StoreOp::Store },
                }),
            ],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: if clear {
                        wgpu::LoadOp::Clear(if reversed { 0.0 } else { 1.0 })
                    } else {
                        wgpu::LoadOp::Load
                    },
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: timestamps,
            ..Default::default()
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        match source {
            DrawSource::Culled(draws) => draws.record(context, &mut pass),
            DrawSource::Unculled { indices, args, draws } => {
                pass.set_vertex_buffer(0, positions.slice(..));
                pass.set_index_buffer(indices.slice(..), wgpu::IndexFormat::Uint32);
                pass.multi_draw_indexed_indirect(args, 0, draws);
            }
        }
    }
}
