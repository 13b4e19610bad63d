//! Two-phase occlusion (Haar and Aaltonen; seed 000 §19.7), from the frame's own depth merged with the CPU
//! occluder buffer, for the camera's view:
//!
//! 1. **Early phase**: the camera's cluster pass tests only the clusters visible last frame, against the
//!    pyramids as the last frame left them (this frame's view of last frame's depth: a guess, as whatever it
//!    wrongly culls the late phase draws), and marks what it keeps; the triangle pass and the draw follow.
//! 2. **Merge** (`hzb_merge.wgsl`): a pyramid whose level 0 has a texel per pixel of the depth the early
//!    phase drew, each the nearer of two farthest depths, that pixel's and the CPU pyramid's at the pixel's
//!    centre (each bounds what lies behind it there), reduced level by level.
//! 3. **Late phase**: every candidate cluster tested against the merged pyramid and the CPU's (copied after it
//!    in its buffer); the ones kept are marked visible for the next frame, and those the early phase did not
//!    draw go through the triangle pass and are drawn over the early image. Where much comes into view at once,
//!    an occluder step goes first ([`super::interface::VIEW_PHASE_LATE_OCCLUDERS`]): of the clusters the late
//!    phase keeps, the large ones are drawn and the depth merged again, so that what they hide of the rest is
//!    culled rather than drawn through the early depth's holes ([`super::GpuGating::min_late_occluder_share`]
//!    skips it where it draws too little).
//! 4. **Final marks**: the frame's final depth is merged again, and the clusters the late phase kept that it
//!    hides lose their marks, so that the next frame does not draw them early.
//!
//! Conservative whatever last frame saw: every candidate the early phase did not draw is tested by the late
//! phase against depth drawn this frame, from this frame's camera, and against the CPU's conservative buffer.
//! Last frame's visibility only decides what is drawn early, so a camera cut, a teleport or a new object costs
//! time (drawn late) and never hides anything.

use super::GpuContext;
use super::hzb::{Hzb, HzbLevel};
use super::interface::{GpuView, VIEW_HZB, VIEW_SECOND_HZB};
use super::scene::GpuScene;
use super::view_cull::{Against, ViewCull, view_buffer};
use crate::camera::{Camera, DepthConvention};
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// The merge pass's uniform (`Merge` in `hzb_merge.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuMerge {
    level: HzbLevel,
    cpu_level: HzbLevel,
    cpu_screen_size: [f32; 2],
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
    /// The same for the late phase's occluder step ([`super::interface::VIEW_PHASE_LATE_OCCLUDERS`]).
    pub late_occluders: ViewCull,
    /// This frame's late phase runs the occluder step first.
    pub split: bool,
    /// The view of the pass that takes the marks of clusters the frame's final depth hides.
    pub final_view: wgpu::Buffer,
    /// The merged pyramid, a level-0 texel per pixel of the render target; the CPU's is copied after it in its
    /// buffer, for the late phase to test against both.
    pub hzb: Hzb,
    merge: wgpu::ComputePipeline,
    merge_uniform: wgpu::Buffer,
    /// Per instance the index of its first cluster's entry, then per cluster of every instance its last mark:
    /// `2f` visible to frame `f`'s late phase, `2f + 1` drawn by its early phase (`cluster_cull.wgsl`).
    visibility: wgpu::Buffer,
    /// The scene's mesh generation the visibility is laid out for.
    layout: Option<u64>,
    /// The mesh of each instance when the visibility was laid out, and its first cluster's entry.
    laid_out: Vec<(u32, u32)>,
    /// This frame's number: 2 on the first, so that a zeroed entry never reads as visible last frame. Before
    /// the marks (`2f + 1`) would wrap, every mark is cleared and the count starts again: a stale mark read as
    /// this frame's would keep a cluster from being drawn.
    pub frame: u32,
}

impl TwoPhase {
    /// The state for `target` (width, height) render targets and the CPU pyramid `cpu`.
    pub fn new(context: &GpuContext, target: (u32, u32), cpu: &Hzb) -> Self {
        let merge_uniform = context.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hzb merge"),
            size: std::mem::size_of::<GpuMerge>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Self {
            late: ViewCull::new(context, "late view"),
            late_occluders: ViewCull::new(context, "late occluders view"),
            split: false,
            final_view: view_buffer(context, "final view"),
            hzb: Hzb::with_room(context, target.0, target.1, cpu.texels()),
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

    /// Starts a frame over `scene` drawn into `target` (width, height) render targets: the merged pyramid
    /// follows the targets' size, the visibility the scene's instances (laid out anew when an instance's mesh
    /// or their count changed). Returns `false`, and the frame should run in one phase, when the visibility
    /// would not fit a storage binding of `binding_limit` bytes.
    pub fn begin_frame(
        &mut self,
        context: &GpuContext,
        scene: &GpuScene,
        (target, cpu): ((u32, u32), &Hzb),
        binding_limit: u64,
    ) -> bool {
        let room = self.hzb.buffer.size() / 4 - u64::from(self.hzb.texels());
        if !self.hzb.fits(target.0, target.1) || room < u64::from(cpu.texels()) {
            self.hzb = Hzb::with_room(context, target.0, target.1, cpu.texels());
        }
        if self.frame >= u32::MAX / 2 - 1 {
            (self.layout, self.frame) = (None, 1);
            self.laid_out.clear();
        }
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

    /// `view` made to test against the merged pyramid and the CPU pyramid `cpu` copied after it: the early
    /// phase finds them as the last frame left them (a guess at what this frame hides: what it wrongly
    /// skips, the late phase draws), the late phase as this frame's merge made them.
    pub fn against_merged(&self, mut view: GpuView, cpu: &Hzb) -> GpuView {
        view.flags |= VIEW_HZB | VIEW_SECOND_HZB;
        (view.second_hzb_size, view.second_hzb_level_count) = (view.hzb_size, view.hzb_level_count);
        view.second_hzb_levels = cpu.view_levels(self.hzb.texels());
        let merged = &self.hzb;
        (view.hzb_size, view.hzb_levels) = (merged.screen_size, merged.view_levels(0));
        view.hzb_level_count = merged.levels.len() as u32;
        view
    }

    /// What both phases test against: the merged pyramid (with the CPU's after it) and the visibility.
    pub fn against(&self) -> Against<'_> {
        Against { hzb: &self.hzb.buffer, visibility: &self.visibility }
    }

    /// Records the merge of `depth` (the early phase's, drawn from `camera`, of the merged pyramid's level-0
    /// size) with the CPU pyramid `cpu` (only where `with_cpu`) into the merged pyramid's level 0, timed by
    /// `timestamps` if given, then the passes that build its other levels; and the CPU pyramid copied after it
    /// ([`TwoPhase::against_merged`] says where).
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
            cpu_level: cpu.levels[0],
            cpu_screen_size: cpu.screen_size,
            inv_w_scale: scale as f32,
            inv_w_offset: offset as f32,
            empty_depth: if camera.depth == DepthConvention::Reversed { 0.0 } else { 1.0 },
            with_cpu: u32::from(with_cpu),
            _pad: [0; 2],
        };
        context.queue.write_buffer(&self.merge_uniform, 0, bytemuck::bytes_of(&uniform));
        let cpu_bytes = u64::from(cpu.texels()) * 4;
        encoder.copy_buffer_to_buffer(&cpu.buffer, 0, &self.hzb.buffer, u64::from(self.hzb.texels()) * 4, cpu_bytes);
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

/// Whether the CPU occluder stage pays for itself beside two-phase occlusion, whose late phase culls behind the
/// frame's own depth: adjacent frames with and without the stage compared by the share of the frustum's
/// triangles each drew. The stage pays where it saves at least `min_benefit` of the triangles drawn without
/// it. The way the last comparison chose holds for `reprobe_every` frames, then one frame the other way
/// probes it again.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct OccluderStageGate {
    /// Share of the frustum's triangles drawn on the last frame with the CPU stage.
    with: Option<f32>,
    /// The same on the last frame without it.
    without: Option<f32>,
    /// The CPU stage is skipped: the last comparison found it does not pay.
    skipping: bool,
    /// Frames before the next probe of the other way.
    frames_left: u32,
}

impl OccluderStageGate {
    /// Records a frame of two phases that drew `drawn` of the `frustum` triangles of the objects in the frustum,
    /// with the CPU stage or without it (`ran`), and returns whether the next frame skips the stage. A frame run
    /// the other way than the gate holds is a probe: it decides again.
    pub fn record(&mut self, ran: bool, (drawn, frustum): (u32, u32), min_benefit: f32, reprobe_every: u32) -> bool {
        if frustum > 0 {
            let share = Some(drawn as f32 / frustum as f32);
            *(if ran { &mut self.with } else { &mut self.without }) = share;
            if let (Some(with), Some(without), true) = (self.with, self.without, ran == self.skipping) {
                self.skipping = with > without * (1.0 - min_benefit);
                self.frames_left = reprobe_every;
            }
        }
        if self.frames_left == 0 {
            self.frames_left = reprobe_every;
            return !self.skipping;
        }
        self.frames_left -= 1;
        self.skipping
    }
}

/// The merge pass of `hzb_merge.wgsl` on the CPU: level 0 of the merged pyramid from `depth` (a `width` x
/// `height` depth image, rows from the top, in `camera`'s convention) and, where given, the CPU pyramid's
/// level 0 (`cpu_level0`, laid out as `cpu_level`, the view `cpu_screen_size` of its texels). For the tests
/// that compare the GPU with it.
#[doc(hidden)]
pub fn merge_level0(
    (depth, width, height): (&[f32], u32, u32),
    cpu: Option<(&[f32], HzbLevel, [f32; 2])>,
    camera: &Camera,
) -> Vec<f32> {
    use super::interface::{DEPTH_ULPS, RECT_MARGIN};
    let (scale, offset) = camera.inv_w_from_depth();
    let (scale, offset) = (scale as f32, offset as f32);
    let empty = if camera.depth == DepthConvention::Reversed { 0.0 } else { 1.0 };
    let inv_w_of = |value: f32| {
        if value == empty {
            return 0.0;
        }
        let farther = value + (empty - value).signum() * value.abs() * DEPTH_ULPS;
        (farther * scale + offset).max(0.0)
    };
    let mut merged = Vec::with_capacity(depth.len());
    for y in 0..height {
        for x in 0..width {
            let mut farthest = inv_w_of(depth[(y * width + x) as usize]);
            if let Some((texels, level, screen)) = cpu {
                let centre = (glam::Vec2::new(x as f32, y as f32) + 0.5) / glam::Vec2::new(width as f32, height as f32)
                    * glam::Vec2::from(screen);
                let lo = (centre - RECT_MARGIN).floor().max(glam::Vec2::ZERO).as_uvec2();
                let hi = (centre + RECT_MARGIN).floor().max(glam::Vec2::ZERO).as_uvec2();
                let texel =
                    |x: u32, y: u32| texels[(y.min(level.height - 1) * level.width + x.min(level.width - 1)) as usize];
                let cpu = texel(lo.x, lo.y).min(texel(hi.x, lo.y)).min(texel(lo.x, hi.y).min(texel(hi.x, hi.y)));
                farthest = farthest.max(cpu);
            }
            merged.push(farthest);
        }
    }
    merged
}

#[cfg(test)]
mod tests {
    use super::OccluderStageGate;

    /// The gate probes the other way every `reprobe_every` frames and follows what the probe shows: the stage
    /// skipped while it saves less than its share, run again once it saves more.
    #[test]
    fn the_occluder_gate_probes_and_follows_the_comparison() {
        let mut gate = OccluderStageGate::default();
        let (min_benefit, reprobe_every) = (0.05, 2);
        // Frames with the stage draw 50 of 100 triangles; the probe without draws 51: it does not pay.
        assert!(gate.record(true, (50, 100), min_benefit, reprobe_every), "the first frame asks for a probe");
        assert!(gate.record(false, (51, 100), min_benefit, reprobe_every), "2% saved: skipped");
        assert!(gate.record(false, (51, 100), min_benefit, reprobe_every));
        assert!(!gate.record(false, (51, 100), min_benefit, reprobe_every), "after two frames, a probe with it");
        // The probe with the stage draws 40 where the frames without drew 51: it pays again.
        assert!(!gate.record(true, (40, 100), min_benefit, reprobe_every), "22% saved: run");
        assert!(!gate.record(true, (40, 100), min_benefit, reprobe_every));
        assert!(gate.record(true, (40, 100), min_benefit, reprobe_every), "after two frames, a probe without it");
        // A frame with nothing in the frustum decides nothing.
        assert!(!gate.record(false, (0, 0), min_benefit, reprobe_every));
    }
}
