//! Shared helpers of Cullet's integration tests: exact (f64) references that the fast paths are judged against.

use cullet::{Camera, WorldBounds};
use glam::{DMat4, DVec3, DVec4};

/// The camera's clip-from-relative matrix in f64, from its parameters: the true frustum, free of the f32
/// rounding the engine's culling arithmetic works with. (The depth conventions themselves are checked by the
/// explicit near- and far-plane cases of the frustum tests.)
pub fn reference_clip_from_relative(camera: &Camera) -> DMat4 {
    camera.clip_from_relative_f64()
}

/// The frustum's half-spaces `(n, d)` (inside where `n · p + d >= 0`, p camera-relative), in f64, with planes at
/// infinity left out. Not normalized: the box test below does not need it.
pub fn reference_planes(camera: &Camera) -> Vec<DVec4> {
    cullet_truth::stress::exact_half_spaces(camera)
}

/// Exact box-versus-planes test in f64: kept unless the box lies entirely outside one plane.
pub fn reference_keeps(planes: &[DVec4], camera_position: DVec3, bounds: &WorldBounds) -> bool {
    let center = bounds.center.as_dvec3() - camera_position;
    let extent = bounds.half_extent.as_dvec3();
    planes.iter().all(|p| p.truncate().dot(center) + p.w + p.truncate().abs().dot(extent) >= 0.0)
}

/// Flies `scene` along `path` (spread over `frame_count` frames) with the default pipeline, running the frames
/// listed in `frames` in that order, and judges each against the exact rendering at 640x360. Panics on the
/// first false negative; returns the metrics over all judged frames.
pub fn fly_and_judge(
    scene: &cullet::scene::Scene,
    path: cullet::CameraPath,
    frame_count: u32,
    frames: impl IntoIterator<Item = u32>,
) -> cullet_truth::PathMetrics {
    use cullet_truth::{JudgeSettings, ReferenceSettings, judge_frame};
    let occlusion = cullet::pipeline::OcclusionSettings::default();
    let mut flight = cullet::scene::flight::Flight::new(path, 16.0 / 9.0, frame_count, occlusion, |world| {
        scene.spawn(world);
    });
    let settings = JudgeSettings {
        reference: ReferenceSettings { width: 640, height: 360, ..ReferenceSettings::default() },
        occlusion_ideal: false,
    };
    let mut metrics = cullet_truth::PathMetrics::default();
    for frame in frames {
        flight.run_frame(frame);
        let judged = judge_frame(&flight.world, &scene.meshes, &settings).metrics;
        if let Some(missed) = judged.false_negatives.first() {
            panic!("frame {frame}: object {} is visible but {} culled it", missed.object, missed.stage);
        }
        metrics.add(&judged);
    }
    metrics
}
