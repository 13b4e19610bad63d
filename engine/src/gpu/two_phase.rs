//! Two-phase occlusion (Haar and Aaltonen; seed 000 §19.7), from the frame's own depth merged with the CPU
//! occluder buffer, for the camera's view:
//!
//! 1. **Early phase**: the camera's cluster pass tests only the clusters visible last frame (against the CPU's
//!    HZB, as a frame of one phase does); the triangle pass and the draw follow.
//! 2. **Merge** (`hzb_merge.wgsl`): the depth the early phase drew, reduced to the CPU pyramid's level 0 (each
//!    texel the farthest depth of the pixels whose centres it covers), merged texel by texel with the CPU's
//!    (the nearer of the two farthest depths: each bounds what lies behind it), then reduced level by level.
//! 3. **Late phase**: every candidate cluster tested against the merged pyramid; the ones kept are marked
//!    visible for the next frame, and those the early phase did not draw go through the triangle pass and are
//!    drawn over the early image.
//!
//! Conservative whatever last frame saw: every candidate the early phase did not draw is tested by the late
//! phase against depth drawn this frame, from this frame's camera, and against the CPU's conservative buffer.
//! Last frame's visibility only decides what is drawn early, so a camera cut, a teleport or a new object costs
//! time (drawn late) and never hides anything.

use super::GpuContext;
use super::hzb::{Hzb, HzbLevel};
use super::scene::GpuScene;
use super::view_cull::{Against, ViewCull};
use crate::camera::{Camera, DepthConvention};
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// The merge pass's uniform (`Merge` in `hzb_merge.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuMerge {
    level: HzbLevel,
    screen_size: [f32; 2],
    inv_w_scale: f32,
    inv_w_offset: f32,
    empty_depth: f32,
    with_cpu: u32,
    _pad: [u32; 2],
}

/// What the camera's second phase needs from frame to frame: the merged pyramid, the late phase's buffers
/// and every cluster's visibility.
pub(crate) struct TwoPhase {
    /// The late phase's view, counters and per-frame buffers.
    pub late: ViewCull,
    /// The merged pyramid, laid out as the CPU's.
    pub hzb: Hzb,
    merge: wgpu::ComputePipeline,
    merge_uniform: wgpu::Buffer,
    /// Per instance the index of its first cluster's entry, then per cluster of every instance the last
    /// frame it was visible (`cluster_cull.wgsl`).
    visibility: wgpu::Buffer,
    /// The scene's mesh generation the visibility is laid out for.
    layout: Option<u64>,
    /// The mesh of each instance when the visibility was laid out, and its first cluster's entry.
    laid_out: Vec<(u32, u32)>,
    /// This frame's number: 2 on the first, so that a zeroed entry never reads as visible last frame.
    pub frame: u32,
}

impl TwoPhase {
    /// The state for a CPU pyramid laid out as `cpu`.
    pub fn new(context: &GpuContext, cpu: &Hzb) -> Self {
        let merge_uniform = context.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hzb merge"),
            size: std::mem::size_of::<GpuMerge>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Self {
            late: ViewCull::new(context, "late view"),
            hzb: Hzb::new(context, cpu.levels[0].width, cpu.levels[0].height),
            merge: context.compute_pipeline("hzb merge", cullet_shaders::HZB_MERGE),
            merge_uniform,
            visibility: context.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("cluster visibility"),
                size: 16,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            layout: None,
            laid_out: Vec::new(),
            frame: 1,
        }
    }

    /// Starts a frame over `scene` with the CPU pyramid `cpu`: the merged pyramid follows the CPU's layout,
    /// the visibility the scene's (laid out anew, every cluster unseen, when an instance's mesh or their count
    /// changed). Returns `false`, and the frame should run in one phase, when the visibility would not fit a
    /// storage binding of `binding_limit` bytes.
    pub fn begin_frame(&mut self, context: &GpuContext, scene: &GpuScene, cpu: &Hzb, binding_limit: u64) -> bool {
        let base = cpu.levels[0];
        if !self.hzb.fits(base.width, base.height) {
            self.hzb = Hzb::new(context, base.width, base.height);
        }
        self.hzb.screen_size = cpu.screen_size;
        let generation = scene.mesh_generation();
        if self.layout != Some(generation) {
            if !self.lay_out(context, scene, binding_limit) {
                return false;
            }
            self.layout = Some(generation);
        }
        self.frame += 1;
        true
    }

    /// Lays the visibility out anew for `scene`'s instances, keeping the entries of every instance whose mesh
    /// is unchanged (a slot refilled by another object of the same mesh keeps the previous one's: that only
    /// decides what is drawn early). `false` where it would not fit a binding of `binding_limit` bytes.
    fn lay_out(&mut self, context: &GpuContext, scene: &GpuScene, binding_limit: u64) -> bool {
        let instances = scene.instances();
        let mut laid_out = Vec::with_capacity(instances.len());
        let mut next = instances.len() as u64;
        for instance in instances {
            laid_out.push((instance.mesh, u32::try_from(next).unwrap_or(u32::MAX)));
            next += u64::from(scene.library.cluster_range(instance.mesh).len() as u32);
        }
        if 4 * next > binding_limit || next > u64::from(u32::MAX) {
            return false;
        }
        let mut entries: Vec<u32> = laid_out.iter().map(|&(_, first)| first).collect();
        entries.resize(next.max(4) as usize, 0);
        let visibility = context.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("cluster visibility"),
            contents: bytemuck::cast_slice(&entries),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        });
        // Runs of instances whose mesh is unchanged, copied in one piece each.
        let mut encoder = context.device.create_command_encoder(&Default::default());
        let mut run: Option<(u32, u32, u32)> = None;
        let mut copy = |(from, to, len): (u32, u32, u32)| {
            encoder.copy_buffer_to_buffer(
                &self.visibility,
                4 * u64::from(from),
                &visibility,
                4 * u64::from(to),
                4 * u64::from(len),
            );
        };
        for (slot, &(mesh, first)) in laid_out.iter().enumerate() {
            let clusters = scene.library.cluster_range(mesh).len() as u32;
            match self.laid_out.get(slot).filter(|&&(old_mesh, _)| old_mesh == mesh && clusters > 0) {
                Some(&(_, old_first)) => match run.as_mut() {
                    Some((from, to, len)) if *from + *len == old_first && *to + *len == first => *len += clusters,
                    _ => {
                        if let Some(finished) = run.replace((old_first, first, clusters)) {
                            copy(finished);
                        }
                    }
                },
                None => {
                    if let Some(finished) = run.take() {
                        copy(finished);
                    }
                }
            }
        }
        if let Some(finished) = run {
            copy(finished);
        }
        context.queue.submit([encoder.finish()]);
        (self.visibility, self.laid_out) = (visibility, laid_out);
        true
    }

    /// What the late phase tests against: the merged pyramid and the visibility.
    pub fn late_against(&self) -> Against<'_> {
        Against { hzb: &self.hzb.buffer, visibility: &self.visibility }
    }

    /// What the early phase tests against: the CPU pyramid `cpu` and the visibility.
    pub fn early_against<'a>(&'a self, cpu: &'a Hzb) -> Against<'a> {
        Against { hzb: &cpu.buffer, visibility: &self.visibility }
    }

    /// Records the merge of `depth` (the early phase's, drawn from `camera`) with the CPU pyramid `cpu` (only
    /// where `with_cpu`) into the merged pyramid's level 0, timed by `timestamps` if given, then the passes that
    /// build its other levels.
    pub fn record_merge(
        &self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        depth: &wgpu::Texture,
        (cpu, with_cpu): (&Hzb, bool),
        camera: &Camera,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let (scale, offset) = camera.inv_w_from_depth();
        let level = self.hzb.levels[0];
        let uniform = GpuMerge {
            level,
            screen_size: self.hzb.screen_size,
            inv_w_scale: scale as f32,
            inv_w_offset: offset as f32,
            empty_depth: if camera.depth == DepthConvention::Reversed { 0.0 } else { 1.0 },
            with_cpu: u32::from(with_cpu),
            _pad: [0; 2],
        };
        context.queue.write_buffer(&self.merge_uniform, 0, bytemuck::bytes_of(&uniform));
        let depth_view = depth
            .create_view(&wgpu::TextureViewDescriptor { aspect: wgpu::TextureAspect::DepthOnly, ..Default::default() });
        let frame_group = context.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("hzb merge"),
            layout: &self.merge.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 1, resource: self.hzb.buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: self.merge_uniform.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(&depth_view) },
            ],
        });
        let cpu_group =
            context.bind_buffers("hzb merge cpu", &self.merge.get_bind_group_layout(1), &[(0, &cpu.buffer)]);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("hzb merge"),
                timestamp_writes: timestamps,
            });
            pass.set_pipeline(&self.merge);
            pass.set_bind_group(0, &frame_group, &[]);
            pass.set_bind_group(1, &cpu_group, &[]);
            pass.dispatch_workgroups(level.width.div_ceil(8), level.height.div_ceil(8), 1);
        }
        self.hzb.build_levels(encoder, None);
    }
}

/// The merge pass of `hzb_merge.wgsl` on the CPU: level 0 of the merged pyramid, laid out as `level`, from
/// `depth` (a `width` x `height` depth image, rows from the top, in `camera`'s convention) and, where
/// `cpu_level0` is given, the CPU pyramid's level 0; `screen_size` is the view's size in level-0 texels. For
/// the tests that compare the GPU with it.
#[doc(hidden)]
pub fn merge_level0(
    (depth, width, height): (&[f32], u32, u32),
    cpu_level0: Option<&[f32]>,
    (level, screen_size): (HzbLevel, [f32; 2]),
    camera: &Camera,
) -> Vec<f32> {
    let (scale, offset) = camera.inv_w_from_depth();
    let (scale, offset) = (scale as f32, offset as f32);
    let empty = if camera.depth == DepthConvention::Reversed { 0.0 } else { 1.0 };
    let inv_w_of = |value: f32| {
        if value == empty {
            return 0.0;
        }
        let farther = value + (empty - value).signum() * value.abs() * super::interface::DEPTH_ULPS;
        (farther * scale + offset).max(0.0)
    };
    let per_texel = [width as f32 / screen_size[0], height as f32 / screen_size[1]];
    let last = [width as i32 - 1, height as i32 - 1];
    let range = |texel: u32, axis: usize| {
        let lo = ((texel as f32 * per_texel[axis] - 0.5).floor() as i32).clamp(0, last[axis]);
        let hi = (((texel + 1) as f32 * per_texel[axis] - 0.5).ceil() as i32).clamp(lo, last[axis]);
        lo..=hi
    };
    let mut merged = Vec::with_capacity((level.width * level.height) as usize);
    for y in 0..level.height {
        for x in 0..level.width {
            let mut farthest = f32::MAX;
            for py in range(y, 1) {
                for px in range(x, 0) {
                    farthest = farthest.min(inv_w_of(depth[(py as u32 * width + px as u32) as usize]));
                }
            }
            if let Some(cpu) = cpu_level0 {
                farthest = farthest.max(cpu[(y * level.width + x) as usize]);
            }
            merged.push(farthest);
        }
    }
    merged
}
