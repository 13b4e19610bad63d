//! `--validate`: every frame judged against the exact ground truth, headless or live in the window's HUD.

use bevy_ecs::world::World;
use cullet::Camera;
use cullet::culler::{Culled, OcclusionSettings};
use cullet::detail::DetailSettings;
use cullet::mesh::Mesh;
use cullet::pipeline::CameraCuller;
use cullet_truth::judge::judge_culled;
use cullet_truth::shadows::light_view_false_negatives;
use cullet_truth::{FrameMetrics, JudgeSettings, PathMetrics, ReferenceSettings};

/// The judge of a run, and what it found so far.
pub struct Validation {
    judge: JudgeSettings,
    /// Every judged frame added up.
    pub total: PathMetrics,
    /// The last judged frame.
    pub last: Option<FrameMetrics>,
    /// False negatives in frames whose settings promise none (conservative occlusion, or none).
    pub conservative_false_negatives: usize,
    /// Shadow casters the light views culled though they needed them, over all judged frames (the light views
    /// are always conservative).
    pub light_view_false_negatives: usize,
}

impl Validation {
    /// A judge rendering the exact visibility at `width` x `height` pixels (the viewport's resolution).
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            judge: JudgeSettings {
                reference: ReferenceSettings { width, height, ..ReferenceSettings::default() },
                occlusion_ideal: false,
            },
            total: PathMetrics::default(),
            last: None,
            conservative_false_negatives: 0,
            light_view_false_negatives: 0,
        }
    }

    /// Judges later frames at `width` x `height` pixels (the window was resized).
    pub fn set_resolution(&mut self, width: u32, height: u32) {
        (self.judge.reference.width, self.judge.reference.height) = (width, height);
    }

    /// Judges the frame the pipeline just culled in `world` (its camera and each stage's survivors, through
    /// [`Validation::judge_culled`]) and returns the metrics.
    pub fn judge(&mut self, world: &World, meshes: &[Mesh]) -> &FrameMetrics {
        let culled = world.resource::<CameraCuller>().culled();
        let reference = &self.judge.reference;
        // Detail culling (lossy) drops what may be visible.
        let detail = world.get_resource::<DetailSettings>().is_some_and(DetailSettings::enabled);
        let conservative =
            world.resource::<OcclusionSettings>().is_conservative_for((reference.width, reference.height)) && !detail;
        self.judge_culled(world, world.resource::<Camera>(), &culled, conservative, meshes)
    }

    /// Judges what a culler kept (`culled`, any [`cullet::culler::Culler`]'s result) in the frame of `world`
    /// seen through `camera`, and the light views `world`'s pipeline culled; `conservative` where the culler
    /// promises no false negative at the judged resolution. Returns the metrics.
    pub fn judge_culled(
        &mut self,
        world: &World,
        camera: &Camera,
        culled: &Culled<'_>,
        conservative: bool,
        meshes: &[Mesh],
    ) -> &FrameMetrics {
        let metrics = judge_culled(world, camera, culled, meshes, &self.judge).metrics;
        self.total.add(&metrics);
        if conservative {
            self.conservative_false_negatives += metrics.false_negatives.len();
        }
        // Light views are judged at the shadow maps' resolution (the lamps' faces too, which draw none).
        let light_views = light_view_false_negatives(world, meshes, cullet::gpu::shadow::SHADOW_MAP_SIZE);
        self.light_view_false_negatives += light_views.iter().sum::<usize>();
        self.last.insert(metrics)
    }

    /// The run's summary line.
    pub fn summary(&self) -> String {
        let total = &self.total;
        format!(
            "validation over {} frames: {} false negatives ({} frames), culling efficiency frustum {:.1}%, \
             + occlusion {:.1}%, image error {} pixels in all; light views: {} shadow casters culled that were needed",
            total.frames,
            total.false_negatives,
            total.frames_with_false_negatives,
            100.0 * total.efficiency(0),
            100.0 * total.efficiency(1),
            total.image_error_pixels,
            self.light_view_false_negatives
        )
    }

    /// Fails when a frame whose settings promise no false negatives had one.
    pub fn verdict(&self) -> Result<(), String> {
        if self.conservative_false_negatives > 0 {
            return Err("validation failed: a conservative configuration culled visible objects".into());
        }
        if self.light_view_false_negatives > 0 {
            return Err("validation failed: a light view culled shadow casters it needed".into());
        }
        Ok(())
    }
}

/// Culling efficiency of stage `index` (0 frustum, 1 occlusion, cumulative) in one frame's metrics.
pub fn frame_efficiency(metrics: &FrameMetrics, index: usize) -> f64 {
    let mut one = PathMetrics::default();
    one.add(metrics);
    one.efficiency(index)
}
