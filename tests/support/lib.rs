//! Shared helpers of Cullet's integration tests: exact (f64) references that the fast paths are judged against.

#![forbid(unsafe_code)]

use bevy_ecs::entity::Entity;
use cullet::bounds::LocalBounds;
use cullet::{BoundsStore, Camera, WorldBounds};
use glam::{Affine3A, DMat4, DVec3, DVec4, Vec3};

/// A path inside the repository.
pub fn repo_file(relative: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(relative)
}

/// A third-party scene of `../shared/scenes`, or `None` (with a visible message) where that folder is absent.
///
/// # Panics
/// If the scene is there but does not load.
pub fn shared_scene(relative: &str) -> Option<cullet::scene::gltf_import::GltfScene> {
    let path = repo_file("../shared/scenes").join(relative);
    if !path.exists() {
        eprintln!("SKIPPED: {} not found (the shared scenes sit beside the repository)", path.display());
        return None;
    }
    Some(cullet::scene::gltf_import::load_gltf(&path).unwrap_or_else(|e| panic!("{e}")))
}

/// A store of boxes `(centre, half extent)`, the world bounds each gets from its translation, entity `i + 1`
/// for box `i`.
pub fn store_of(boxes: &[(Vec3, Vec3)]) -> BoundsStore {
    let mut store = BoundsStore::default();
    for (i, &(center, half_extent)) in boxes.iter().enumerate() {
        let entity = Entity::from_raw_u32(i as u32 + 1).unwrap();
        let local = LocalBounds { center: Vec3::ZERO, half_extent };
        let bounds = WorldBounds::from_local(entity, &local, &Affine3A::from_translation(center)).unwrap();
        store.insert(entity, &bounds).unwrap();
    }
    store
}

/// The camera's clip-from-relative matrix in f64, from its parameters: the true frustum, free of the f32
/// rounding the engine's culling arithmetic works with. (The depth conventions themselves are checked by the
/// explicit near- and far-plane cases of the frustum tests.)
pub fn reference_clip_from_relative(camera: &Camera) -> DMat4 {
    camera.clip_from_relative_f64()
}

/// The frustum's half-spaces `(n, d)` (inside where `n · p + d >= 0`, p camera-relative), in f64, with planes at
/// infinity left out. Not normalized: the box test below does not need it.
pub fn reference_planes(camera: &Camera) -> Vec<DVec4> {
    cullet_truth::half_spaces::exact_half_spaces(camera)
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
    fly_and_judge_with(scene, path, frame_count, frames, cullet::culler::AdaptiveSettings::default()).0
}

/// [`fly_and_judge`] with `adaptive` gating; also returns each frame's stats, in the order run.
pub fn fly_and_judge_with(
    scene: &cullet::scene::Scene,
    path: cullet::CameraPath,
    frame_count: u32,
    frames: impl IntoIterator<Item = u32>,
    adaptive: cullet::culler::AdaptiveSettings,
) -> (cullet_truth::PathMetrics, Vec<cullet::pipeline::CullStats>) {
    use cullet_truth::{JudgeSettings, ReferenceSettings, judge_frame};
    let occlusion = cullet::culler::OcclusionSettings::default();
    let mut flight = cullet::scene::flight::Flight::new(path, 16.0 / 9.0, frame_count, occlusion, |world| {
        scene.spawn(world);
    });
    flight.world.insert_resource(adaptive);
    let mut stats = Vec::new();
    let settings = JudgeSettings {
        reference: ReferenceSettings { width: 640, height: 360, ..ReferenceSettings::default() },
        occlusion_ideal: false,
    };
    let mut metrics = cullet_truth::PathMetrics::default();
    for frame in frames {
        stats.push(flight.run_frame(frame));
        let judged = judge_frame(&flight.world, &scene.meshes, &settings).metrics;
        if let Some(missed) = judged.false_negatives.first() {
            panic!("frame {frame}: object {} is visible but {} culled it", missed.object, missed.stage);
        }
        metrics.add(&judged);
    }
    (metrics, stats)
}

/// Opens a [`cullet::gpu::GpuContext`] for a test, or says why it cannot: with `CULLET_REQUIRE_GPU` set (as CI sets it)
/// a missing GPU fails the test; otherwise the test is skipped with a visible message.
pub fn context_for_tests() -> Option<cullet::gpu::GpuContext> {
    match cullet::gpu::GpuContext::new() {
        Ok(context) => Some(context),
        Err(error) if std::env::var_os("CULLET_REQUIRE_GPU").is_some() => {
            panic!("CULLET_REQUIRE_GPU is set but no usable GPU: {error}")
        }
        Err(error) => {
            eprintln!("SKIPPED: GPU test needs a GPU adapter ({error}); install Mesa's lavapipe to run it");
            None
        }
    }
}
