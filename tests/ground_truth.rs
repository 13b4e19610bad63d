//! The whole CPU pipeline against the exact ground truth over the city's camera path: no conservative stage
//! ever culls an object that owns a pixel of the full-resolution (1920x1080) reference rendering.

use cullet::culler::OcclusionSettings;
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use cullet_truth::{JudgeSettings, PathMetrics, judge_frame};

/// Flies `frames` frames through a city of `objects` objects with `occlusion`, judging every frame.
fn fly_and_judge(objects: usize, frames: u32, occlusion: OcclusionSettings) -> PathMetrics {
    let city = CityScene::generate(CityParams::with_objects(objects));
    let mut flight = Flight::new(city.flythrough(), 16.0 / 9.0, frames, occlusion, |world| {
        city.spawn(world);
    });
    let settings = JudgeSettings::default();
    let mut path = PathMetrics::default();
    for frame in 0..frames {
        flight.run_frame(frame);
        let judgement = judge_frame(&flight.world, &city.scene.meshes, &settings);
        if let Some(missed) = judgement.metrics.false_negatives.first() {
            let entity = flight.world.resource::<cullet::BoundsStore>().entities()[missed.object];
            panic!(
                "frame {frame}: {entity:?} (slot {}) is visible but {} culled it; {} false negatives in all",
                missed.object,
                missed.stage,
                judgement.metrics.false_negatives.len()
            );
        }
        path.add(&judgement.metrics);
    }
    path
}

/// The default pipeline (frustum, then conservative 256x144 occlusion) over 200 frames of the fly-through.
#[test]
fn default_pipeline_has_no_false_negatives_over_200_frames() {
    let path = fly_and_judge(10_000, 200, OcclusionSettings::default());
    println!("{path:#?}");
    assert_eq!(path.false_negatives, 0);
    assert_eq!(path.image_error_pixels, 0);
    // Not vacuous: both stages cull, and occlusion culls a good share of what the frustum leaves.
    assert!(path.efficiency(0) > 0.3, "frustum efficiency {}", path.efficiency(0));
    assert!(path.efficiency(1) > path.efficiency(0) + 0.1, "occlusion adds {}", path.efficiency(1));
}

/// The coarsest buffer of the run-time-against-error sweep, with a small occluder budget: still conservative.
#[test]
fn coarse_occlusion_buffer_has_no_false_negatives_over_200_frames() {
    let occlusion = OcclusionSettings { width: 64, height: 36, triangle_budget: 2048, ..OcclusionSettings::default() };
    let path = fly_and_judge(10_000, 200, occlusion);
    assert_eq!(path.false_negatives, 0);
    assert_eq!(path.image_error_pixels, 0);
}
