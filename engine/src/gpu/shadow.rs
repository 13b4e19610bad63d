//! Shadow maps (`shadow.wgsl`): the casters each sun cascade kept (the light views of
//! [`crate::pipeline::LightViewsVisible`]) drawn as depth into that cascade's layer, which the draw
//! (`draw.wgsl`) samples to shade what they hide from the sun. The light views are the consumer the CPU's
//! shadow-caster culling feeds: only the casters that can shadow what the camera sees are drawn.
//!
//! Each cascade is a view of its own on the GPU (`view_cull`): its casters' clusters go through the
//! cluster pass (the cascade's side and far planes; casters between the sun and the near plane still cast, so
//! that plane is not tested) and the triangle pass (off-map and small triangles; both faces cast, so no
//! back-face test), and the map is drawn from the survivors with one indirect multi-draw, all recorded into
//! the camera's submission.

use super::indirect::{DrawBuffers, cluster_draws, indirect_buffer, position_vertex_state};
use super::interface::{
    GpuShadows, GpuView, MAX_CASCADES, VIEW_DRAW_CLUSTERS, VIEW_SMALL_TRIANGLE, VIEW_TRIANGLE_FRUSTUM,
};
use super::output::{COUNTER_BYTES, GpuCounters};
use super::scene::GpuScene;
use super::view_cull::{CullPasses, PassGate, ViewCull, candidates, fits_binding, storage_buffer};
use super::{GpuContext, GpuError, GpuGating};
use bytemuck::Zeroable;
use glam::{DMat4, DVec4, Vec3};
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

/// What the cascades' culling shares with the camera's: the passes, the HZB binding (which the light views
/// do not test), the gating and the largest storage binding.
pub(crate) struct CascadeCulling<'a> {
    pub passes: &'a CullPasses,
    pub hzb: &'a wgpu::Buffer,
    pub gating: &'a GpuGating,
    pub binding_limit: u64,
}

/// How a cascade of the last [`ShadowMaps::record`] was drawn.
#[derive(Clone, Copy, Debug)]
enum CascadeRun {
    /// Culled on the GPU, from `instances` casters.
    Culled { instances: u32, gate: PassGate },
    /// Too many candidates for one storage binding: every cluster drawn, as these counters say.
    Whole(GpuCounters),
}

/// The shadow maps of up to [`MAX_CASCADES`] cascades, their culling, the pipeline that draws them, and the
/// uniform and bindings the draw samples them through.
pub struct ShadowMaps {
    texture: wgpu::Texture,
    layers: Vec<wgpu::TextureView>,
    array: wgpu::TextureView,
    sampler: wgpu::Sampler,
    pipeline: wgpu::RenderPipeline,
    /// The [`GpuShadows`] uniform of the draw.
    uniform: wgpu::Buffer,
    /// One light view per cascade: its [`GpuView`], counters and buffers.
    views: Vec<ViewCull>,
    /// Every cascade's counters, copied together for one read-back.
    counters: wgpu::Buffer,
    /// How each cascade of the last [`ShadowMaps::record`] was drawn.
    runs: Vec<CascadeRun>,
    /// Cascades the draw shades with.
    count: usize,
}

impl ShadowMaps {
    /// Empty shadow maps: the draw shades without shadows until cascades are drawn.
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
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
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
        Self {
            texture,
            layers,
            array,
            sampler,
            pipeline: shadow_pipeline(context),
            uniform,
            views: (0..MAX_CASCADES).map(|_| ViewCull::new(context, "light view")).collect(),
            counters: storage_buffer(
                context,
                "cascade counters",
                MAX_CASCADES as u64 * COUNTER_BYTES,
                wgpu::BufferUsages::empty(),
            ),
            runs: Vec::new(),
            count: 0,
        }
    }

    /// Records into `encoder` the drawing of `cascades` (nearest first; those past [`MAX_CASCADES`] are left
    /// out) into their maps, each culled on the GPU with `culling` (every cluster of every caster drawn for
    /// `None`), and sets the draw to shade with them from `draw_origin`, the position of the camera it draws
    /// from. No cascade: the draw shades without shadows. Once the encoder has run,
    /// [`ShadowMaps::read_counters`] reads what each cascade's culling did.
    pub(crate) fn record(
        &mut self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        scene: &GpuScene,
        culling: Option<&CascadeCulling<'_>>,
        cascades: &[Cascade<'_>],
        draw_origin: Vec3,
    ) {
        let cascades = &cascades[..cascades.len().min(MAX_CASCADES)];
        let mut shadows = GpuShadows { count: cascades.len() as u32, ..GpuShadows::zeroed() };
        self.runs.clear();
        for (index, cascade) in cascades.iter().enumerate() {
            // The draw's points are relative to its camera: move the cascade's matrix there, in f64.
            let shift = DMat4::from_translation(draw_origin.as_dvec3() - cascade.origin.as_dvec3());
            shadows.cascade_from_relative[index] = (cascade.clip_from_relative * shift).as_mat4().to_cols_array_2d();
            let (clusters, triangles) = candidates(scene, cascade.casters);
            let instances = cascade.casters.len() as u32;
            let culling = culling.filter(|c| fits_binding(u64::from(clusters), u64::from(triangles), c.binding_limit));
            let mut light = light_view(cascade);
            let draws = if let Some(culling) = culling {
                let view = &mut self.views[index];
                let gate = view.gate(culling.gating, clusters as usize);
                if gate.skip_triangles {
                    light.flags |= VIEW_DRAW_CLUSTERS;
                }
                view.fit(context, cascade.casters.len(), (clusters, triangles));
                let against = culling.passes.one_phase(culling.hzb);
                view.record(context, encoder, scene, culling.passes, against, cascade.casters, gate, (None, 0));
                let offset = index as u64 * COUNTER_BYTES;
                encoder.copy_buffer_to_buffer(&view.counters, 0, &self.counters, offset, COUNTER_BYTES);
                self.runs.push(CascadeRun::Culled { instances, gate });
                CasterDraws::Culled(self.views[index].draws(scene, gate.skip_triangles).expect("fit above"))
            } else {
                self.runs.push(CascadeRun::Whole(GpuCounters {
                    instances,
                    clusters_in: clusters,
                    clusters_out: clusters,
                    triangles_in: triangles,
                    triangles_out: triangles,
                    draws: clusters,
                    ..Default::default()
                }));
                let args = cluster_draws(&scene.library, scene.instances(), cascade.casters.iter().copied());
                match args.len() as u32 {
                    0 => CasterDraws::None,
                    count => CasterDraws::Whole(indirect_buffer(context, "caster draws", &args), count),
                }
            };
            // Written before the submission runs, whichever way the layer is drawn.
            context.queue.write_buffer(&self.views[index].view, 0, bytemuck::bytes_of(&light));
            self.draw_layer(context, encoder, scene, index, &draws);
        }
        context.queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&shadows));
        self.count = cascades.len();
    }

    /// Records the draw of one cascade's layer from `draws`, cleared first.
    fn draw_layer(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        scene: &GpuScene,
        index: usize,
        draws: &CasterDraws<'_>,
    ) {
        let layout = self.pipeline.get_bind_group_layout(0);
        let bind_group =
            context.bind_buffers("shadow", &layout, &[(0, &self.views[index].view), (1, &scene.instances)]);
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
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        match draws {
            CasterDraws::Culled(buffers) => buffers.record(context, &mut pass),
            CasterDraws::Whole(args, count) => {
                pass.set_vertex_buffer(0, scene.positions.slice(..));
                pass.set_index_buffer(scene.cluster_indices.slice(..), wgpu::IndexFormat::Uint32);
                pass.multi_draw_indexed_indirect(args, 0, *count);
            }
            CasterDraws::None => {}
        }
    }

    /// Draws `cascades` as [`ShadowMaps::record`] does with no culling on the GPU, in a submission of its own:
    /// the reference the culled maps are compared against.
    pub(crate) fn draw_unculled(
        &mut self,
        context: &GpuContext,
        scene: &GpuScene,
        cascades: &[Cascade<'_>],
        draw_origin: Vec3,
    ) {
        let mut encoder = context.device.create_command_encoder(&Default::default());
        self.record(context, &mut encoder, scene, None, cascades, draw_origin);
        context.queue.submit([encoder.finish()]);
    }

    /// What each cascade of the last [`ShadowMaps::record`] culled, nearest first, once its commands have run;
    /// `gating` judges whether each cascade's triangle pass paid. A cascade drawn whole reports every cluster
    /// and triangle of its casters as kept.
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    pub(crate) fn read_counters(
        &mut self,
        context: &GpuContext,
        gating: &GpuGating,
    ) -> Result<Vec<GpuCounters>, GpuError> {
        let bytes = if self.runs.iter().any(|run| matches!(run, CascadeRun::Culled { .. })) {
            context.read_buffer(&self.counters, self.runs.len() as u64 * COUNTER_BYTES)?
        } else {
            Vec::new()
        };
        let slots: &[u32] = bytemuck::cast_slice(&bytes);
        let per_view = COUNTER_BYTES as usize / 4;
        let mut counters = Vec::with_capacity(self.runs.len());
        for (index, run) in self.runs.iter().enumerate() {
            counters.push(match *run {
                CascadeRun::Culled { instances, gate } => {
                    let c = GpuCounters::from_slots(instances, &slots[index * per_view..(index + 1) * per_view]);
                    self.views[index].record_benefit(gating, gate, &c);
                    c
                }
                CascadeRun::Whole(c) => c,
            });
        }
        Ok(counters)
    }

    /// Starts every cascade's triangle-pass benefit count afresh (new gating settings).
    pub(crate) fn reset_gates(&mut self) {
        self.views.iter_mut().for_each(ViewCull::reset_gate);
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

    /// Reads the depths of cascade `index`'s map back (0 nearest, 1 where nothing was drawn), rows from the
    /// top.
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    ///
    /// # Panics
    /// If `index` is not below [`MAX_CASCADES`].
    pub fn read_layer(&self, context: &GpuContext, index: usize) -> Result<Vec<f32>, GpuError> {
        assert!(index < MAX_CASCADES, "cascade {index} of {MAX_CASCADES}");
        let bytes = context.read_texture_layer(&self.texture, index as u32, wgpu::TextureAspect::DepthOnly, 4)?;
        Ok(bytemuck::cast_slice(&bytes).to_vec())
    }
}

/// What a cascade's layer is drawn from.
enum CasterDraws<'a> {
    /// The culling passes' survivors.
    Culled(DrawBuffers<'a>),
    /// Every cluster of every caster: `args` holding `count` draws over the clusters' own indices.
    Whole(wgpu::Buffer, u32),
    /// No caster.
    None,
}

/// The light [`GpuView`] the culling passes and the shadow map's draw read for `cascade`: its matrix and
/// origin, the side and far planes of its box (a small margin out, for the rounding of the f32 test), the
/// map's size as viewport, and the tests that fit a shadow map: off-map and small triangles.
fn light_view(cascade: &Cascade<'_>) -> GpuView {
    let m = cascade.clip_from_relative;
    let (row_x, row_y, row_z, row_w) = (m.row(0), m.row(1), m.row(2), m.row(3));
    // x and y in -w..w, z at most w (standard depth); z >= 0 is not a bound, casters nearer the sun cast.
    let bounds = [row_w + row_x, row_w - row_x, row_w + row_y, row_w - row_y, row_w - row_z];
    let unit = |plane: DVec4| plane / plane.truncate().length();
    let planes: Vec<DVec4> = bounds.into_iter().map(unit).collect();
    // The f32 test's error grows with the distances involved: the box's own extents bound them.
    let margin = 1e-5 * planes.iter().map(|p| p.w.abs()).sum::<f64>();
    let mut gpu_planes = [[0.0, 0.0, 0.0, 1.0]; 6];
    for (slot, plane) in gpu_planes.iter_mut().zip(&planes) {
        *slot = (*plane + DVec4::new(0.0, 0.0, 0.0, margin)).as_vec4().to_array();
    }
    let size = SHADOW_MAP_SIZE as f32;
    GpuView {
        clip_from_relative: m.as_mat4().to_cols_array_2d(),
        planes: gpu_planes,
        camera: cascade.origin.extend(0.0).to_array(),
        viewport: [size, size],
        visible_count: cascade.casters.len() as u32,
        flags: VIEW_TRIANGLE_FRUSTUM | VIEW_SMALL_TRIANGLE,
        ..GpuView::zeroed()
    }
}

/// The depth-only pipeline of `shadow.wgsl`: both faces drawn (open meshes cast too), with a slope-scaled depth
/// bias against self-shadowing.
fn shadow_pipeline(context: &GpuContext) -> wgpu::RenderPipeline {
    let module = context.shader("shadow", cullet_shaders::SHADOW);
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
