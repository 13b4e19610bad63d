//! The cullers other than the pipeline's stages, each run through the culler interface and judged against the
//! exact rendering on the same scenes, paths and frames as the pipeline.

use cullet::culler::{CullScene, Culler, ShadowFrustaCuller};
use cullet::scene::Scene;
use cullet::scene::auto_occluders::{AutoOccluderSettings, add_auto_occluders};
use cullet::scene::flight::Flight;
use cullet_truth::{JudgeSettings, PathMetrics, ReferenceSettings, judge_culled};

/// Flies `scene` along `path` over `frames` frames with `culler` on a flight of its own, judging every frame
/// at 640x360; panics on the first false negative. Returns the metrics and the objects the culler's last
/// stage removed after the frustum, over all frames.
fn fly_and_judge(
    scene: &Scene,
    path: cullet::CameraPath,
    frames: u32,
    culler: &mut dyn Culler,
) -> (PathMetrics, usize) {
    let mut flight = Flight::for_cullers(path, 16.0 / 9.0, frames, |world| {
        scene.spawn(world);
    });
    let judge = JudgeSettings {
        reference: ReferenceSettings { width: 640, height: 360, ..ReferenceSettings::default() },
        occlusion_ideal: false,
    };
    let (mut metrics, mut occluded) = (PathMetrics::default(), 0);
    for frame in 0..frames {
        let (_, culled) = flight.cull_frame(frame, culler);
        occluded += culled.stats.after_frustum - culled.stats.after_occlusion;
        let camera = *flight.world.resource::<cullet::Camera>();
        let judged = judge_culled(&flight.world, &camera, &culled, &scene.meshes, &judge).metrics;
        if let Some(missed) = judged.false_negatives.first() {
            panic!("frame {frame}: object {} is visible but {} culled it", missed.object, missed.stage);
        }
        metrics.add(&judged);
    }
    (metrics, occluded)
}

/// On the city's fly-through (box buildings, some moving), the shadow frusta cull behind the buildings and
/// never what is visible.
#[test]
fn shadow_frusta_keep_everything_visible_on_the_city_path() {
    let city = cullet::scene::city::CityScene::generate(cullet::scene::city::CityParams::with_objects(5000));
    let mut culler = ShadowFrustaCuller::default();
    let (metrics, occluded) = fly_and_judge(&city.scene, city.flythrough(), 40, &mut culler);
    assert!(occluded > 0, "the shadow frusta culled nothing: {metrics:?}");
    assert!(culler.is_conservative((640, 360)));
    println!("city: {occluded} objects culled by shadow frusta over 40 frames; {metrics:?}");
}

/// Every stress case (far from the origin, tiny near planes, reversed and infinite depth, degenerate input):
/// no false negative.
#[test]
fn shadow_frusta_lose_nothing_on_the_stress_cases() {
    for case in cullet_truth::stress::cases() {
        let path = cullet::CameraPath { fov_y_deg: 60.0, near: 0.1, far: None, keys: Vec::new() };
        let mut flight = Flight::for_cullers(path, case.camera.aspect, 1, |world| {
            case.scene.spawn(world);
        });
        flight.schedule.run(&mut flight.world);
        let judge = JudgeSettings {
            reference: ReferenceSettings { width: case.width, height: case.height, ..ReferenceSettings::default() },
            occlusion_ideal: false,
        };
        let mut culler = ShadowFrustaCuller::default();
        let culled = culler.cull(&CullScene::new(&flight.world), &case.camera);
        let judged = judge_culled(&flight.world, &case.camera, &culled, &case.scene.meshes, &judge).metrics;
        assert!(judged.false_negatives.is_empty(), "{} {}: {:?}", case.sweep, case.value, judged.false_negatives);
    }
}

/// truck_town, nobody here's scene, with automatic occluders, around its orbit: no false negative.
#[test]
fn shadow_frusta_lose_nothing_on_truck_town() {
    let Some(mut town) = cullet_test_support::shared_scene("truck_town/town_model.gltf") else { return };
    add_auto_occluders(&mut town.scene, &AutoOccluderSettings::default());
    let path = town.scene.orbit_path();
    let (metrics, occluded) = fly_and_judge(&town.scene, path, 24, &mut ShadowFrustaCuller::default());
    println!("truck_town: {occluded} objects culled by shadow frusta over 24 frames; {metrics:?}");
}
