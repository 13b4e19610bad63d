//! The GPU hierarchical z-buffer: each frame the CPU occluder depth buffer ([`crate::depth::DepthBuffer`],
//! `1/w`, 0 where no occluder) is uploaded as level 0, and one compute pass per level (`hzb_build.wgsl`)
//! reduces it to the farthest-depth pyramid, ceil-halving so that odd sizes drop no row or column: the same
//! pyramid as the CPU's [`crate::depth::DepthPyramid`], value for value.
//!
//! Only what the CPU buffer proves hidden is culled: the HZB is as conservative as the mode it was rasterized
//! in (conservative by default). Two-phase occlusion ([`super::two_phase`]) builds a second pyramid, a level-0
//! texel per pixel of the depth the frame's early phase drew merged with this one, with this one copied after
//! it in its buffer.

use super::GpuContext;
use crate::depth::DepthBuffer;

use wgpu::util::DeviceExt;

pub use super::interface::{HzbLevel, MAX_HZB_LEVELS};

/// The levels of a `width` x `height` pyramid, level 0 first, down to 1x1.
pub fn hzb_levels(width: u32, height: u32) -> Vec<HzbLevel> {
    let mut levels = vec![HzbLevel { width: width.max(1), height: height.max(1), offset: 0, _pad: 0 }];
    while let Some(&last) = levels.last().filter(|l| (l.width > 1 || l.height > 1) && levels.len() < MAX_HZB_LEVELS) {
        levels.push(HzbLevel {
            width: last.width.div_ceil(2),
            height: last.height.div_ceil(2),
            offset: last.offset + last.width * last.height,
            _pad: 0,
        });
    }
    levels
}

/// Texels in all of `levels`.
fn texels_of(levels: &[HzbLevel]) -> u32 {
    levels.iter().map(|l| l.width * l.height).sum()
}

/// The pyramid on the GPU, rebuilt from a CPU depth buffer each frame.
pub struct Hzb {
    /// All levels, one after another (`f32` texels).
    pub buffer: wgpu::Buffer,
    /// Level sizes and offsets.
    pub levels: Vec<HzbLevel>,
    /// The view's size in level-0 texels ([`DepthBuffer::screen_size`] of the last buffer built from): maps
    /// normalized device coordinates to texels.
    pub screen_size: [f32; 2],
    pipeline: wgpu::ComputePipeline,
    /// One bind group per level above 0, with its (fine, coarse) pair.
    level_bind_groups: Vec<wgpu::BindGroup>,
}

impl Hzb {
    /// A pyramid for buffers of `width` x `height` (an empty buffer gives a 1x1 pyramid holding 0: nothing
    /// hidden).
    pub fn new(context: &GpuContext, width: u32, height: u32) -> Self {
        Self::with_room(context, width, height, 0)
    }

    /// [`Hzb::new`] with room for `extra` more texels after the levels in its buffer (another pyramid copied
    /// there, which the HZB test reads through the same binding).
    pub fn with_room(context: &GpuContext, width: u32, height: u32, extra: u32) -> Self {
        let device = &context.device;
        let levels = hzb_levels(width, height);
        let texels = texels_of(&levels);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hzb"),
            size: u64::from(texels + extra) * 4,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let pipeline = context.compute_pipeline("hzb build", cullet_shaders::HZB_BUILD);
        let layout = pipeline.get_bind_group_layout(0);
        let level_bind_groups = levels
            .windows(2)
            .map(|pair| {
                let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("hzb level pair"),
                    contents: bytemuck::cast_slice(pair),
                    usage: wgpu::BufferUsages::UNIFORM,
                });
                context.bind_buffers("hzb level", &layout, &[(1, &buffer), (2, &uniform)])
            })
            .collect();
        let screen_size = [levels[0].width as f32, levels[0].height as f32];
        Self { buffer, levels, screen_size, pipeline, level_bind_groups }
    }

    /// Texels in all levels.
    pub fn texels(&self) -> u32 {
        texels_of(&self.levels)
    }

    /// The levels as a [`super::interface::GpuView`] holds them, each offset moved `shift` texels on (for a
    /// copy of the pyramid placed after another in one buffer).
    pub fn view_levels(&self, shift: u32) -> [HzbLevel; MAX_HZB_LEVELS] {
        let mut levels = [HzbLevel::default(); MAX_HZB_LEVELS];
        for (slot, level) in levels.iter_mut().zip(&self.levels) {
            *slot = HzbLevel { offset: level.offset + shift, ..*level };
        }
        levels
    }

    /// Whether this pyramid fits buffers of `width` x `height`.
    pub fn fits(&self, width: u32, height: u32) -> bool {
        self.levels[0].width == width.max(1) && self.levels[0].height == height.max(1)
    }

    /// Whether [`Hzb::build`] uploads `depth` as level 0: it has level 0's size (otherwise level 0 is cleared).
    fn uploads(&self, depth: &DepthBuffer) -> bool {
        depth.width() == self.levels[0].width && depth.height() == self.levels[0].height
    }

    /// Sets [`Hzb::screen_size`] for building from `depth`.
    pub fn set_screen(&mut self, depth: &DepthBuffer) {
        let base = self.levels[0];
        self.screen_size =
            if self.uploads(depth) { depth.screen_size() } else { [base.width as f32, base.height as f32] };
    }

    /// Uploads `depth` as level 0 (all zero when it is empty) and records the passes that build the rest,
    /// with `timestamps` written at the pass's start and end if given.
    pub fn build(
        &self,
        context: &GpuContext,
        depth: &DepthBuffer,
        encoder: &mut wgpu::CommandEncoder,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let base = self.levels[0];
        if self.uploads(depth) {
            context.queue.write_buffer(&self.buffer, 0, bytemuck::cast_slice(depth.texels()));
        } else {
            encoder.clear_buffer(&self.buffer, 0, Some(u64::from(base.width * base.height) * 4));
        }
        self.build_levels(encoder, timestamps);
    }

    /// Records the passes that build every level above 0 from level 0 as it will be when they run, with
    /// `timestamps` written at the pass's start and end if given.
    pub fn build_levels(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("hzb build"),
            timestamp_writes: timestamps,
        });
        pass.set_pipeline(&self.pipeline);
        for (level, bind_group) in self.levels[1..].iter().zip(&self.level_bind_groups) {
            pass.set_bind_group(0, bind_group, &[]);
            pass.dispatch_workgroups(level.width.div_ceil(8), level.height.div_ceil(8), 1);
        }
    }

    /// Reads the whole pyramid back, level by level.
    ///
    /// # Errors
    /// [`super::GpuError::Lost`] when the device is lost.
    pub fn read(&self, context: &GpuContext) -> Result<Vec<Vec<f32>>, super::GpuError> {
        let bytes = context.read_buffer(&self.buffer, u64::from(self.texels()) * 4)?;
        let texels: &[f32] = bytemuck::cast_slice(&bytes);
        Ok(self
            .levels
            .iter()
            .map(|l| texels[l.offset as usize..(l.offset + l.width * l.height) as usize].to_vec())
            .collect())
    }
}
