//! The adaptive pipeline against fixed configurations on scenes that need a stage and scenes that do not:
//! the city (dense, occluded), the open field (nothing to occlude), the CAD assembly (everything on screen)
//! and the city seen from a static camera. Each configuration flies the scene's path; a frame costs the CPU
//! stages plus, where a GPU adapter exists, the GPU passes (cluster and triangle culling and the draw, whose
//! work the CPU stages' culling decides). Best of three passes. Writes `target/adaptive/adaptive.csv`.
//!
//! `cargo bench -p cullet-benches --bench adaptive`

use cullet::flight::Flight;
use cullet::gpu::GpuContext;
use cullet::gpu::clusters::ClusterLibrary;
use cullet::gpu::frame::{GpuCullSettings, GpuCuller};
use cullet::gpu::scene::{GpuScene, instances_from_world};
use cullet::pipeline::{AdaptiveSettings, OcclusionSettings};
use cullet::scene::Scene;
use cullet::{CameraPath, scene};
use std::fmt::Write as _;
use std::time::{Duration, Instant};

const FRAMES: u32 = 60;
const PASSES: usize = 3;
const RESOLUTION: (u32, u32) = (640, 360);

/// A fixed or adaptive pipeline.
struct Config {
    name: &'static str,
    occlusion: bool,
    adaptive: AdaptiveSettings,
}

fn configs() -> [Config; 3] {
    [
        Config { name: "everything on (fixed)", occlusion: true, adaptive: AdaptiveSettings::fixed() },
        Config { name: "frustum only (fixed)", occlusion: false, adaptive: AdaptiveSettings::fixed() },
        Config { name: "adaptive", occlusion: true, adaptive: AdaptiveSettings::default() },
    ]
}

/// Mean CPU and GPU time per frame of one pass of `config` over `path`.
fn fly(scene: &Scene, path: &CameraPath, config: &Config, gpu: Option<&GpuContext>) -> (Duration, Duration) {
    let occlusion = OcclusionSettings { enabled: config.occlusion, ..OcclusionSettings::default() };
    let aspect = RESOLUTION.0 as f32 / RESOLUTION.1 as f32;
    let mut flight = Flight::new(path.clone(), aspect, FRAMES, occlusion, |world| {
        scene.spawn(world);
    });
    flight.world.insert_resource(config.adaptive);
    let mut culler = gpu.map(|context| {
        let gpu_scene =
            GpuScene::new(context, ClusterLibrary::build(&scene.meshes), instances_from_world(&flight.world));
        GpuCuller::new(context, gpu_scene, RESOLUTION.0, RESOLUTION.1, occlusion.width, occlusion.height)
    });
    let (mut cpu, mut gpu_time) = (Duration::ZERO, Duration::ZERO);
    for frame in 0..FRAMES {
        let start = Instant::now();
        flight.run_frame(frame);
        cpu += start.elapsed();
        if let (Some(context), Some(culler)) = (gpu, culler.as_mut()) {
            let start = Instant::now();
            culler.run_world(context, &mut flight.world, &GpuCullSettings::default());
            gpu_time += start.elapsed();
        }
    }
    (cpu / FRAMES, gpu_time / FRAMES)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let gpu = GpuContext::new().map_err(|e| println!("no GPU ({e}): CPU stages only")).ok();
    let city = scene::city::CityScene::generate(scene::city::CityParams::with_objects(100_000));
    let mut static_path = city.flythrough();
    static_path.keys.truncate(1);
    let (field, field_path) = scene::field::field(100_000);
    let (cad, cad_path) = scene::cad::cad(20_000);
    let scenes = [
        ("city 1e5", &city.scene, city.flythrough()),
        ("field 1e5", &field, field_path),
        ("cad 2e4", &cad, cad_path),
        ("city 1e5, static camera", &city.scene, static_path),
    ];
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/adaptive");
    std::fs::create_dir_all(&out)?;
    let mut csv = String::from("scene,config,cpu_us,gpu_us,total_us\n");
    println!("{:<26} {:<24} {:>10} {:>10} {:>10}", "scene", "configuration", "CPU us", "GPU us", "total us");
    for (name, scene, path) in scenes {
        let mut totals = Vec::new();
        for config in configs() {
            let best = (0..PASSES)
                .map(|_| fly(scene, &path, &config, gpu.as_ref()))
                .min_by_key(|(cpu, gpu)| *cpu + *gpu)
                .expect("at least one pass");
            let micros = |d: Duration| d.as_secs_f64() * 1e6;
            let total = micros(best.0 + best.1);
            println!(
                "{name:<26} {:<24} {:>10.1} {:>10.1} {:>10.1}",
                config.name,
                micros(best.0),
                micros(best.1),
                total
            );
            writeln!(csv, "{name},{},{:.1},{:.1},{total:.1}", config.name, micros(best.0), micros(best.1))?;
            totals.push(total);
        }
        let best_fixed = totals[0].min(totals[1]);
        println!(
            "{name:<26} adaptive vs best fixed: {:+.1}%, vs everything on: {:+.1}%",
            100.0 * (totals[2] / best_fixed - 1.0),
            100.0 * (totals[2] / totals[0] - 1.0)
        );
    }
    std::fs::write(out.join("adaptive.csv"), csv)?;
    Ok(())
}
