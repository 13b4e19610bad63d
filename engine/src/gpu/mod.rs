//! The GPU half of the pipeline, on `wgpu`: after the CPU stages, the surviving objects' clusters and then
//! their triangles are culled in compute passes, and the survivors drawn with one multi-draw-indirect.
//!
//! 1. [`clusters`]: meshes split into meshlets with bounds and normal cones (meshoptimizer), once at load;
//! 2. [`scene`]: one set of large buffers for all meshes, and per-instance data written only where it changed;
//! 3. [`hzb`]: the CPU occluder depth buffer uploaded and reduced to a farthest-depth pyramid;
//! 4. [`cluster_cull`]: frustum, normal-cone and HZB tests per cluster, survivors appended compactly;
//! 5. [`triangle_cull`]: degenerate, back-facing, off-screen and small triangles removed, survivors compacted
//!    into an index buffer with one indirect draw per cluster;
//! 6. [`draw`]: `multi_draw_indexed_indirect_count` into colour, object-ID and depth targets, read back.
//! 7. [`two_phase`] (opt-in, [`GpuCullSettings::two_phase`]): the passes above draw only what was visible last
//!    frame; that depth, merged with the CPU's HZB, culls the rest in a second round of steps 4 to 6.
//!
//! Beside the pipeline, [`query_grid`] is a culler of its own behind [`crate::culler::Culler`]: seed 001's
//! hardware occlusion queries over a uniform grid of cells ([`cell_queries`]), their results a frame late.
//!
//! Every view of a frame is culled by the same passes into buffers of its own (`view_cull`): the camera, and
//! each sun cascade whose [`shadow`] map the draw samples, all in one submission.
//!
//! Each pass's module owns its pipeline, bind groups, dispatch and CPU twin (which the tests compare the GPU
//! against); [`frame`] only orchestrates them, and [`output`] is what a frame reads back. [`interface`] holds
//! what Rust and WGSL share, once.
//! [`GpuContext`] opens a device; [`GpuCuller::for_world`] builds the passes for a scene and
//! [`GpuCuller::run_world`] runs one frame after the CPU stages.
//!
//! # Example: culling and drawing a frame
//! ```no_run
//! use bevy_ecs::prelude::*;
//! use cullet::prelude::*;
//! use cullet::scene::city::{CityParams, CityScene};
//!
//! let city = CityScene::generate(CityParams::with_objects(1_000));
//! let (mut world, mut schedule) = (World::new(), Schedule::default());
//! cullet::install(&mut world, &mut schedule, PipelineSettings::default());
//! city.spawn(&mut world);
//! world.insert_resource(city.benchmark_cameras()[0].1);
//!
//! let context = GpuContext::new()?;
//! let mut culler = GpuCuller::for_world(&context, &world, &city.scene.meshes, (1280, 720));
//! schedule.run(&mut world);
//! world.clear_trackers();
//! let frame = culler.run_world(&context, &mut world, &GpuCullSettings::default())?;
//! println!("{} triangles drawn in {} draws", frame.counters.triangles_out, frame.counters.draws);
//! # Ok::<(), GpuError>(())
//! ```

pub mod cell_queries;
pub mod cluster_cull;
pub mod clusters;
pub mod debug_draw;
pub mod draw;
pub mod frame;
pub mod hzb;
pub mod indirect;
pub mod interface;
mod late_read;
pub mod output;
pub mod own_renderer;
pub mod query_grid;
pub mod scene;
pub mod shadow;
pub mod triangle_cull;
pub mod two_phase;
mod view_cull;

pub use debug_draw::DebugDraw;
pub use frame::{GpuCullSettings, GpuCuller, GpuGating, ReadBack, Survivors};
pub use indirect::DrawBuffers;
pub use output::{GpuCounters, GpuFrameOutput, GpuPassTimes, PhaseCounters};
pub use own_renderer::OwnRenderer;
pub use query_grid::{QueryGridCuller, QueryGridSettings, QueryGridStats};

use thiserror::Error;

/// The WGSL every stage shares (structs, bindings of the view and the HZB, the HZB test); it follows the
/// generated [`interface::wgsl_prelude`] in every shader.
const COMMON_WGSL: &str = cullet_shaders::COMMON;

/// Why no GPU pipeline could be made, or a frame could not run.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum GpuError {
    /// No adapter at all (no driver, or none that wgpu supports).
    #[error("no GPU adapter found: {0}")]
    NoAdapter(String),
    /// The adapter lacks something the pipeline needs.
    #[error("GPU adapter '{adapter}' lacks {missing}")]
    Unsupported {
        /// The adapter's name.
        adapter: String,
        /// What is missing.
        missing: String,
    },
    /// The device could not be opened.
    #[error("could not open the GPU device: {0}")]
    Device(String),
    /// The device was lost, or a read-back from it failed, mid-frame: make a new [`GpuContext`] and culler.
    #[error("the GPU device was lost or a read-back failed: {0}")]
    Lost(String),
    /// A visible slot given to [`GpuCuller::run`] is not an instance of the culler's scene.
    #[error("visible slot {slot} is out of range: the scene has {instances} instances")]
    SlotOutOfRange {
        /// The slot given.
        slot: u32,
        /// Instances in the scene.
        instances: usize,
    },
    /// Two-phase occlusion cannot read the depth of an [`OwnRenderer`] ([`OwnRenderer::depth`] says what it
    /// must be): nothing is run.
    #[error("two-phase occlusion cannot read the renderer's depth texture: {0}")]
    RendererDepth(String),
}

/// Most storage buffers one pass binds in one shader stage: the cluster pass binds ten (the view, the HZB and
/// two-phase occlusion's visibility included), the triangle pass nine. [`GpuContext::new`] refuses an adapter
/// that allows fewer.
pub const STORAGE_BUFFERS_PER_STAGE: u32 = 10;

/// A device and queue opened without a window, with the features the pipeline uses. Clones share the device.
#[derive(Clone)]
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter the device was opened on.
    pub adapter: wgpu::Adapter,
    /// The adapter's name, backend and type.
    pub adapter_info: wgpu::AdapterInfo,
    /// Whether `multi_draw_indexed_indirect_count` is available; without it the draw falls back to
    /// `multi_draw_indexed_indirect` with a CPU-known maximum count.
    pub has_draw_count: bool,
    /// Whether GPU timestamps can be taken.
    pub has_timestamps: bool,
}

impl GpuContext {
    /// Opens the default adapter of the primary backends (Vulkan, Metal, DX12; `WGPU_BACKEND` and the other
    /// wgpu environment variables override). Requires indirect draws with a first instance: each indirect draw
    /// names its instance there, and [`STORAGE_BUFFERS_PER_STAGE`] storage buffers in a shader stage. The
    /// device gets every limit the adapter has.
    ///
    /// # Errors
    /// [`GpuError::NoAdapter`] without a usable driver (install Mesa's `mesa-vulkan-drivers` on a machine
    /// without a GPU), [`GpuError::Unsupported`] for an adapter without `INDIRECT_FIRST_INSTANCE` or with
    /// fewer storage buffers, [`GpuError::Device`] when the device cannot be opened.
    pub fn new() -> Result<Self, GpuError> {
        Self::new_with_limits(|limits| limits)
    }

    /// [`GpuContext::new`] with the device's limits chosen by `limits` from the adapter's: to leave the rest of
    /// the adapter to other users, or to check that the engine works within less.
    ///
    /// # Errors
    /// As [`GpuContext::new`], the storage buffers counted in the limits chosen.
    pub fn new_with_limits(limits: impl FnOnce(wgpu::Limits) -> wgpu::Limits) -> Result<Self, GpuError> {
        let instance = Self::instance(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        futures_lite::future::block_on(Self::open(&instance, None, limits))
    }

    /// An instance of `descriptor` limited to the primary backends unless `WGPU_BACKEND` says otherwise.
    pub fn instance(mut descriptor: wgpu::InstanceDescriptor) -> wgpu::Instance {
        if std::env::var_os("WGPU_BACKEND").is_none() {
            // Vulkan, Metal or DX12 (lavapipe is Vulkan); the GL backend would probe for a display.
            descriptor.backends = wgpu::Backends::PRIMARY;
        }
        wgpu::Instance::new(descriptor)
    }

    /// Opens the default adapter of `instance` that can present to `surface` (for a window; see
    /// [`GpuContext::instance`]), with the same requirements as [`GpuContext::new`].
    ///
    /// # Errors
    /// As [`GpuContext::new`].
    pub fn for_surface(instance: &wgpu::Instance, surface: &wgpu::Surface<'_>) -> Result<Self, GpuError> {
        futures_lite::future::block_on(Self::open(instance, Some(surface), |limits| limits))
    }

    async fn open(
        instance: &wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
        limits: impl FnOnce(wgpu::Limits) -> wgpu::Limits,
    ) -> Result<Self, GpuError> {
        let options = wgpu::RequestAdapterOptions { compatible_surface: surface, ..Default::default() };
        let adapter = instance.request_adapter(&options).await.map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let adapter_info = adapter.get_info();
        let available = adapter.features();
        let required = wgpu::Features::INDIRECT_FIRST_INSTANCE;
        if !available.contains(required) {
            return Err(GpuError::Unsupported {
                adapter: adapter_info.name.clone(),
                missing: "INDIRECT_FIRST_INSTANCE".into(),
            });
        }
        let required_limits = limits(adapter.limits());
        let storage_buffers = required_limits.max_storage_buffers_per_shader_stage;
        if storage_buffers < STORAGE_BUFFERS_PER_STAGE {
            return Err(GpuError::Unsupported {
                adapter: adapter_info.name.clone(),
                missing: format!(
                    "{STORAGE_BUFFERS_PER_STAGE} storage buffers in a shader stage (its limit is {storage_buffers})"
                ),
            });
        }
        let optional = wgpu::Features::MULTI_DRAW_INDIRECT_COUNT | wgpu::Features::TIMESTAMP_QUERY;
        let features = required | (available & optional);
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("cullet"),
                required_features: features,
                required_limits,
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::Device(e.to_string()))?;
        Ok(Self {
            device,
            queue,
            adapter,
            adapter_info,
            has_draw_count: features.contains(wgpu::Features::MULTI_DRAW_INDIRECT_COUNT),
            has_timestamps: features.contains(wgpu::Features::TIMESTAMP_QUERY),
        })
    }

    /// A compute pipeline from a stage's WGSL, with the shared declarations prepended.
    pub(crate) fn compute_pipeline(&self, label: &str, stage_source: &str) -> wgpu::ComputePipeline {
        let module = self.shader(label, stage_source);
        self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: None,
            module: &module,
            entry_point: None,
            compilation_options: Default::default(),
            cache: None,
        })
    }

    /// A shader module from a stage's WGSL, assembled by [`shader_source`].
    pub(crate) fn shader(&self, label: &str, stage_source: &str) -> wgpu::ShaderModule {
        self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(shader_source(stage_source).into()),
        })
    }

    /// A bind group of `layout` (a pipeline's `get_bind_group_layout`) with `buffers` as `(binding, buffer)`
    /// pairs, each bound whole.
    pub(crate) fn bind_buffers(
        &self,
        label: &str,
        layout: &wgpu::BindGroupLayout,
        buffers: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let entries: Vec<_> = buffers
            .iter()
            .map(|&(binding, buffer)| wgpu::BindGroupEntry { binding, resource: buffer.as_entire_binding() })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(label), layout, entries: &entries })
    }

    /// Reads a buffer back (it must have `COPY_SRC`), waiting for the GPU.
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost or the buffer cannot be mapped.
    pub fn read_buffer(&self, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<u8>, GpuError> {
        self.read_back(size, |encoder, staging| encoder.copy_buffer_to_buffer(buffer, 0, staging, 0, size))
    }

    /// Reads mip level 0 of a 2D texture back (it must have `COPY_SRC`), waiting for the GPU: the `aspect`'s
    /// texels of `bytes_per_texel` bytes each (4 for RGBA8, BGRA8, R32 and 32-bit depth), rows packed top to
    /// bottom with no padding.
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost or the staging buffer cannot be mapped.
    pub fn read_texture(
        &self,
        texture: &wgpu::Texture,
        aspect: wgpu::TextureAspect,
        bytes_per_texel: u32,
    ) -> Result<Vec<u8>, GpuError> {
        self.read_texture_layer(texture, 0, aspect, bytes_per_texel)
    }

    /// [`GpuContext::read_texture`] of array layer `layer`.
    ///
    /// # Errors
    /// As [`GpuContext::read_texture`].
    pub fn read_texture_layer(
        &self,
        texture: &wgpu::Texture,
        layer: u32,
        aspect: wgpu::TextureAspect,
        bytes_per_texel: u32,
    ) -> Result<Vec<u8>, GpuError> {
        let (width, height) = (texture.width(), texture.height());
        let packed_row = (width * bytes_per_texel) as usize;
        // Copies to buffers need rows aligned to 256 bytes; the padding is dropped below.
        let row_bytes = (width * bytes_per_texel).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let bytes = self.read_back(u64::from(row_bytes * height), |encoder, staging| {
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: 0, z: layer },
                    aspect,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: staging,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(row_bytes),
                        rows_per_image: None,
                    },
                },
                wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
            )
        })?;
        let mut packed = Vec::with_capacity(packed_row * height as usize);
        for row in bytes.chunks_exact(row_bytes as usize) {
            packed.extend_from_slice(&row[..packed_row]);
        }
        Ok(packed)
    }

    /// Reads back `size` bytes that `copy` records into a staging buffer, waiting for the GPU.
    pub(crate) fn read_back(
        &self,
        size: u64,
        copy: impl FnOnce(&mut wgpu::CommandEncoder, &wgpu::Buffer),
    ) -> Result<Vec<u8>, GpuError> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        copy(&mut encoder, &staging);
        self.queue.submit([encoder.finish()]);
        self.map_and_read(&staging)
    }

    /// Maps a `MAP_READ` buffer after the queue's work is done and copies it out.
    fn map_and_read(&self, staging: &wgpu::Buffer) -> Result<Vec<u8>, GpuError> {
        let lost = |what: &str, error: &dyn std::fmt::Display| GpuError::Lost(format!("{what}: {error}"));
        let slice = staging.slice(..);
        let (sender, receiver) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |result| {
            let _ = sender.send(result);
        });
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| lost("waiting for the GPU", &e))?;
        receiver
            .recv()
            .map_err(|e| lost("buffer map callback dropped", &e))?
            .map_err(|e| lost("buffer map failed", &e))?;
        let bytes = slice.get_mapped_range().map_err(|e| lost("mapped range", &e))?.to_vec();
        staging.unmap();
        Ok(bytes)
    }
}

/// The full WGSL of a stage: the generated constants ([`interface::wgsl_prelude`]), `common.wgsl`, then the
/// stage's own source.
pub fn shader_source(stage_source: &str) -> String {
    format!("{}\n{}\n{}", interface::wgsl_prelude(), COMMON_WGSL, stage_source)
}
