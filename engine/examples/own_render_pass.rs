//! A renderer's use of the GPU culler: frames of the built-in city culled in two phases (two-phase occlusion:
//! what the frame before saw is drawn first, and the rest culled against that depth), each phase drawn by a
//! render pass of your own into your own colour and depth textures, with one
//! `multi_draw_indexed_indirect_count` over the culler's outputs (compacted indices, indirect arguments, draw
//! count). The culler reads your depth between the phases: the late phase culls against what you drew. The
//! pixels covered are compared with an unculled image.
//!
//! Your shader starts with the engine's declarations (`cullet::gpu::shader_source`): the `Instance` struct,
//! the `view` (a read-only storage buffer) at group 0 binding 0 and `relative_point`. Each indirect draw's
//! `first_instance` is the object's store slot, so `instance_index` picks its transform.
//!
//! `cargo run --release -p cullet --example own_render_pass` (needs a GPU adapter; Mesa's lavapipe will do).

use bevy_ecs::prelude::*;
use cullet::gpu::draw::NO_OBJECT;
use cullet::gpu::{DrawBuffers, GpuContext, GpuCullSettings, GpuCuller, GpuError, OwnRenderer};
use cullet::prelude::*;
use cullet::scene::city::{CityParams, CityScene};

/// Flat orange, depth-tested: just enough to show where the survivors cover the screen.
const SHADER: &str = "
@group(0) @binding(1) var<storage, read> instances: array<Instance>;

@vertex
fn vs(@location(0) position: vec3<f32>, @builtin(instance_index) instance: u32) -> @builtin(position) vec4<f32> {
    let relative = relative_point(instances[instance], position, view.camera.xyz);
    return view.clip_from_relative * vec4<f32>(relative, 1.0);
}

@fragment
fn fs() -> @location(0) vec4<f32> {
    return vec4<f32>(1.0, 0.5, 0.1, 1.0);
}
";

const SIZE: (u32, u32) = (640, 360);
const COLOR: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Your renderer: a pipeline over the culler's buffers, and colour and depth textures of your own.
struct MyRenderer {
    pipeline: wgpu::RenderPipeline,
    color: wgpu::Texture,
    depth: wgpu::Texture,
}

impl MyRenderer {
    fn new(device: &wgpu::Device) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("my draw"),
            source: wgpu::ShaderSource::Wgsl(cullet::gpu::shader_source(SHADER).into()),
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("my draw"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                // `positions`: three f32 a vertex, at location 0.
                buffers: &[Some(cullet::gpu::indirect::POSITION_LAYOUT)],
            },
            primitive: wgpu::PrimitiveState { cull_mode: Some(wgpu::Face::Back), ..Default::default() },
            // The camera's default depth is reversed: nearer is greater, cleared to 0.
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Greater),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[Some(COLOR.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let texture = |format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: None,
                size: wgpu::Extent3d { width: SIZE.0, height: SIZE.1, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let color = texture(COLOR, wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC);
        // The culler reads this depth between the phases: it needs the texture binding.
        let depth = texture(DEPTH, wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING);
        Self { pipeline, color, depth }
    }
}

impl OwnRenderer for MyRenderer {
    fn depth(&self) -> &wgpu::Texture {
        &self.depth
    }

    fn draw(
        &mut self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        buffers: DrawBuffers<'_>,
        clear: bool,
    ) {
        let bind_group = buffers.bind_group(context, &self.pipeline.get_bind_group_layout(0));
        let (color_view, depth_view) =
            (self.color.create_view(&Default::default()), self.depth.create_view(&Default::default()));
        let (color_load, depth_load) = match clear {
            true => (wgpu::LoadOp::Clear(wgpu::Color::BLACK), wgpu::LoadOp::Clear(0.0)),
            false => (wgpu::LoadOp::Load, wgpu::LoadOp::Load),
        };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("my draw"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: color_load, store: wgpu::StoreOp::Store },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &depth_view,
                depth_ops: Some(wgpu::Operations { load: depth_load, store: wgpu::StoreOp::Store }),
                stencil_ops: None,
            }),
            ..Default::default()
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        // The positions as vertex buffer, the compacted indices, and one multi-draw-indirect-count over the
        // culler's arguments and draw count.
        buffers.record(context, &mut pass);
    }
}

fn main() -> Result<(), GpuError> {
    // The CPU stages, then the GPU passes, for frames of a 10 000-object city.
    let city = CityScene::generate(CityParams::with_objects(10_000));
    let (mut world, mut schedule) = (World::new(), Schedule::default());
    cullet::install(&mut world, &mut schedule, PipelineSettings::default());
    city.spawn(&mut world);
    let camera = Camera { aspect: SIZE.0 as f32 / SIZE.1 as f32, ..city.benchmark_cameras()[0].1 };
    let context = GpuContext::new()?;
    let mut culler = GpuCuller::for_world(&context, &world, &city.scene.meshes, SIZE);
    let mut renderer = MyRenderer::new(&context.device);
    let settings = GpuCullSettings { two_phase: true, ..GpuCullSettings::default() };
    let mut frame = None;
    for turn in [0.0, 0.3] {
        // The second frame turned a little: most of it was visible in the first, and is drawn early; what
        // comes into view is culled against that depth and drawn late.
        let forward = glam::Quat::from_rotation_y(turn) * camera.forward;
        world.insert_resource(Camera { forward, ..camera });
        schedule.run(&mut world);
        world.clear_trackers();
        frame = Some(culler.run_world_into(&context, &mut world, &settings, &mut renderer)?);
    }
    let frame = frame.expect("two frames ran");

    // Read your image back and count the pixels the survivors cover.
    let covered = covered_pixels(&context, &renderer.color)?;
    let c = frame.counters;
    let phases = frame.phases.expect("two phases");
    println!("two phases: {} triangles drawn early, {} late", phases.early.triangles_out, phases.late.triangles_out);
    println!(
        "{} objects; the CPU kept {}, the GPU kept {} of {} clusters and {} of {} triangles in {} draws",
        world.resource::<BoundsStore>().len(),
        c.instances,
        c.clusters_out,
        c.clusters_in,
        c.triangles_out,
        c.triangles_in,
        c.draws
    );
    // Every object drawn with no culling at all covers the same pixels.
    let last_camera = *world.resource::<Camera>();
    let unculled = culler.debug().unculled(&context, &last_camera, false)?;
    let unculled_covered = unculled.object.iter().filter(|&&object| object != NO_OBJECT).count();
    println!("my render pass covered {covered} of {} pixels, the unculled draw {unculled_covered}", SIZE.0 * SIZE.1);
    assert!(covered > 0, "the survivors cover part of the screen");
    assert_eq!(covered, unculled_covered, "the culled draws cover what every object does");
    Ok(())
}

/// Pixels of `color` that are not the black it was cleared to.
fn covered_pixels(context: &GpuContext, color: &wgpu::Texture) -> Result<usize, GpuError> {
    let row_bytes = (SIZE.0 * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let staging = context.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: u64::from(row_bytes * SIZE.1),
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let mut encoder = context.device.create_command_encoder(&Default::default());
    encoder.copy_texture_to_buffer(
        color.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &staging,
            layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(row_bytes), rows_per_image: None },
        },
        wgpu::Extent3d { width: SIZE.0, height: SIZE.1, depth_or_array_layers: 1 },
    );
    context.queue.submit([encoder.finish()]);
    let bytes = context.read_buffer(&staging, staging.size())?;
    Ok(bytes
        .chunks_exact(row_bytes as usize)
        .flat_map(|row| row[..SIZE.0 as usize * 4].chunks_exact(4))
        .filter(|pixel| pixel[..3] != [0, 0, 0])
        .count())
}
