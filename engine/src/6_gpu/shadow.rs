//! Shadow maps (`shadow.wgsl`): the casters each sun cascade kept (the light views of
//! [`crate::pipeline::LightViewsVisible`]) drawn as depth into that cascade's layer, which the draw
//! (`draw.wgsl`) samples to shade what they hide from the sun. The light views are the consumer the CPU's
//! shadow-caster culling feeds: only the casters that can shadow what the camera sees are drawn.

use super::GpuContext;
use super::draw::{cluster_draws, indirect_buffer, position_vertex_state};
use super::interface::{GpuShadows, GpuView, MAX_CASCADES};
use super::scene::GpuScene;
use bytemuck::Zeroable;
use glam::{DMat4, Vec3};
use wgpu::util::DeviceExt;

/// Width and height of each cascade's shadow map, in texels.
pub const SHADOW_MAP_SIZE: u32 = 1024;

const SHADOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// One sun cascade to draw: its light view's matrix and the casters it kept.
#[derive(Clone, Copy, Debug)]
pub struct Cascade<'a> {
    /// Clip (standard depth, orthographic) from `origin`-relative world space, as
    /// [`crate::frustum::LightView::clip_from_relative`].
    pub clip_from_relative: DMat4,
    /// The world point `clip_from_relative` is relative to.
    pub origin: Vec3,
    /// Store slots (instances) of the casters.
    pub casters: &'a [u32],
}

/// The shadow maps of up to [`MAX_CASCADES`] cascades, the pipeline that draws them, and the uniform and
/// bindings the draw samples them through.
pub struct ShadowMaps {
    texture: wgpu::Texture,
    layers: Vec<wgpu::TextureView>,
    array: wgpu::TextureView,
    sampler: wgpu::Sampler,
    pipeline: wgpu::RenderPipeline,
    /// The [`GpuShadows`] uniform of the draw.
    uniform: wgpu::Buffer,
    /// One light [`GpuView`] per cascade.
    light_views: Vec<wgpu::Buffer>,
    /// Cascades drawn by the last [`ShadowMaps::draw`].
    count: usize,
}

impl ShadowMaps {
    /// Empty shadow maps: the draw shades without shadows until [`ShadowMaps::draw`] draws some.
    pub fn new(context: &GpuContext) -> Self {
        let device = &context.device;
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow maps"),
            size: wgpu::Extent3d {
                width: SHADOW_MAP_SIZE,
                height: SHADOW_MAP_SIZE,
                depth_or_array_layers: MAX_CASCADES as u32,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: SHADOW_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let layer = |layer: u32| {
            texture.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: layer,
                array_layer_count: Some(1),
                ..Default::default()
            })
        };
        let layers = (0..MAX_CASCADES as u32).map(layer).collect();
        let array = texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("shadows"),
            contents: bytemuck::bytes_of(&GpuShadows::zeroed()),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        });
        let light_views = (0..MAX_CASCADES)
            .map(|_| {
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("light view"),
                    size: std::mem::size_of::<GpuView>() as u64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                })
            })
            .collect();
        Self { texture, layers, array, sampler, pipeline: shadow_pipeline(context), uniform, light_views, count: 0 }
    }

    /// Draws the casters of `cascades` (nearest first; those past [`MAX_CASCADES`] are left out) into their
    /// maps, and sets the draw to shade with them from `draw_origin`, the position of the camera it draws
    /// from. No cascade: the draw shades without shadows.
    pub fn draw(&mut self, context: &GpuContext, scene: &GpuScene, cascades: &[Cascade<'_>], draw_origin: Vec3) {
        let cascades = &cascades[..cascades.len().min(MAX_CASCADES)];
        let mut shadows = GpuShadows { count: cascades.len() as u32, ..GpuShadows::zeroed() };
        let mut encoder = context.device.create_command_encoder(&Default::default());
        let bind_group = |buffer: &wgpu::Buffer| {
            let layout = self.pipeline.get_bind_group_layout(0);
            context.bind_buffers("shadow", &layout, &[(0, buffer), (1, &scene.instances)])
        };
        for (index, cascade) in cascades.iter().enumerate() {
            // The draw's points are relative to its camera: move the cascade's matrix there, in f64.
            let shift = DMat4::from_translation(draw_origin.as_dvec3() - cascade.origin.as_dvec3());
            shadows.cascade_from_relative[index] = (cascade.clip_from_relative * shift).as_mat4().to_cols_array_2d();
            let light = GpuView {
                clip_from_relative: cascade.clip_from_relative.as_mat4().to_cols_array_2d(),
                camera: cascade.origin.extend(0.0).to_array(),
                ..GpuView::zeroed()
            };
            context.queue.write_buffer(&self.light_views[index], 0, bytemuck::bytes_of(&light));
            let args = cluster_draws(&scene.library, scene.instances(), cascade.casters.iter().copied());
            let draws =
                (!args.is_empty()).then(|| (indirect_buffer(context, "caster draws", &args), args.len() as u32));
            let bind_group = bind_group(&self.light_views[index]);
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow map"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.layers[index],
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
                    stencil_ops: None,
                }),
                ..Default::default()
            });
            if let Some((buffer, count)) = &draws {
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind_group, &[]);
                pass.set_vertex_buffer(0, scene.positions.slice(..));
                pass.set_index_buffer(scene.cluster_indices.slice(..), wgpu::IndexFormat::Uint32);
                pass.multi_draw_indexed_indirect(buffer, 0, *count);
            }
        }
        context.queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&shadows));
        context.queue.submit([encoder.finish()]);
        self.count = cascades.len();
    }

    /// Cascades the draw shades with.
    pub fn cascades(&self) -> usize {
        self.count
    }

    /// The draw's bindings 2 to 4: the [`GpuShadows`] uniform, the maps and their comparison sampler.
    pub(crate) fn bind_entries(&self) -> [wgpu::BindGroupEntry<'_>; 3] {
        [
            wgpu::BindGroupEntry { binding: 2, resource: self.uniform.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(&self.array) },
            wgpu::BindGroupEntry { binding: 4, resource: wgpu::BindingResource::Sampler(&self.sampler) },
        ]
    }

    /// The maps' texture: [`MAX_CASCADES`] layers of [`SHADOW_MAP_SIZE`] squared depths.
    pub fn texture(&self) -> &wgpu::Texture {
        &self.texture
    }
}

/// The depth-only pipeline of `shadow.wgsl`: both faces drawn (open meshes cast too), with a slope-scaled depth
/// bias against self-shadowing.
fn shadow_pipeline(context: &GpuContext) -> wgpu::RenderPipeline {
    let module = context.shader("shadow", include_str!("../../shaders/shadow.wgsl"));
    context.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("shadow map"),
        layout: None,
        vertex: position_vertex_state(&module),
        primitive: Default::default(),
        depth_stencil: Some(wgpu::DepthStencilState {
            format: SHADOW_FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: wgpu::DepthBiasState { constant: 4, slope_scale: 2.5, clamp: 0.0 },
        }),
        multisample: Default::default(),
        fragment: None,
        multiview_mask: None,
        cache: None,
    })
}
