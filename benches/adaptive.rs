//! The adaptive pipeline against fixed configurations on scenes that need a stage and scenes that do not:
//! the city (dense, occluded), the open field (nothing to occlude), the CAD assembly (everything on screen)
//! and the city (with its moving cars) and the CAD assembly (nothing moves) seen from a static camera. Each configuration flies the scene's path and reports its CPU time
//! per frame (best of five passes, interleaved) and the work it leaves the GPU: the triangles of the objects it kept. The
//! best fixed configuration of a scene is the fastest among those leaving no more than 1% more triangles than
//! everything on (a configuration that culls less is not cheaper, it moves the cost to the GPU). Writes
//! `target/adaptive/adaptive.csv`.
//!
//! `cargo bench -p cullet-benches --bench adaptive`

use cullet::flight::Flight;
use cullet::pipeline::{AdaptiveSettings, OcclusionSettings, OcclusionState};
use cullet::scene::Scene;
use cullet::{BoundsStore, MeshRef};
use cullet::{CameraPath, scene};
use std::fmt::Write as _;
use std::time::{Duration, Instant};

/// Frames along each 20-second path: 30 frames a second, so that frame-to-frame coherence is realistic.
const FRAMES: u32 = 600;
const PASSES: usize = 5;

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

/// Mean CPU time per frame of one pass of `config` over `path`, and the mean triangles of the objects kept.
fn fly(scene: &Scene, path: &CameraPath, config: &Config) -> (Duration, f64) {
    let occlusion = OcclusionSettings { enabled: config.occlusion, ..OcclusionSettings::default() };
    let mut flight = Flight::new(path.clone(), 16.0 / 9.0, FRAMES, occlusion, |world| {
        scene.spawn(world);
    });
    flight.world.insert_resource(config.adaptive);
    // Triangles per store slot, from each object's mesh.
    let triangles_of = |world: &bevy_ecs::world::World, slot: usize| {
        let entity = world.resource::<BoundsStore>().entities()[slot];
        world.get::<MeshRef>(entity).map_or(0, |m| scene.meshes[m.0 as usize].triangle_count())
    };
    let (mut cpu, mut triangles) = (Duration::ZERO, 0usize);
    for frame in 0..FRAMES {
        let start = Instant::now();
        flight.run_frame(frame);
        cpu += start.elapsed();
        let world = &flight.world;
        triangles +=
            world.resource::<OcclusionState>().visible.iter().map(|slot| triangles_of(world, slot)).sum::<usize>();
    }
    (cpu / FRAMES, triangles as f64 / f64::from(FRAMES))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let city = scene::city::CityScene::generate(scene::city::CityParams::with_objects(100_000));
    let mut static_path = city.flythrough();
    static_path.keys.truncate(1);
    let (field, field_path) = scene::field::field(100_000);
    let (cad, cad_path) = scene::cad::cad(20_000);
    let mut cad_static = cad_path.clone();
    cad_static.keys.truncate(1);
    let scenes = [
        ("city 1e5", &city.scene, city.flythrough()),
        ("field 1e5", &field, field_path),
        ("cad 2e4", &cad, cad_path),
        ("city 1e5, static camera", &city.scene, static_path),
        ("cad 2e4, static camera", &cad, cad_static),
    ];
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/adaptive");
    std::fs::create_dir_all(&out)?;
    let mut csv = String::from("scene,config,cpu_us,gpu_triangles\n");
    println!("{:<26} {:<24} {:>10} {:>14}", "scene", "configuration", "CPU us", "GPU triangles");
    for (name, scene, path) in scenes {
        // Passes interleave the configurations, so that the machine's drifting speed touches them alike.
        let configs = configs();
        let mut results = vec![(f64::INFINITY, 0.0); configs.len()];
        for _ in 0..PASSES {
            for (result, config) in results.iter_mut().zip(&configs) {
                let (cpu, triangles) = fly(scene, &path, config);
                *result = (result.0.min(cpu.as_secs_f64() * 1e6), triangles);
            }
        }
        for (config, &(micros, triangles)) in configs.iter().zip(&results) {
            println!("{name:<26} {:<24} {micros:>10.1} {triangles:>14.0}", config.name);
            writeln!(csv, "{name},{},{micros:.1},{triangles:.0}", config.name)?;
        }
        let all_on = results[0];
        let best_fixed =
            results[..2].iter().filter(|r| r.1 <= all_on.1 * 1.01).map(|r| r.0).fold(f64::INFINITY, f64::min);
        let adaptive = results[2];
        println!(
            "{name:<26} adaptive: CPU {:+.1}% against the best fixed, {:+.1}% against everything on; GPU triangles {:+.2}%",
            100.0 * (adaptive.0 / best_fixed - 1.0),
            100.0 * (adaptive.0 / all_on.0 - 1.0),
            100.0 * (adaptive.1 / all_on.1 - 1.0)
        );
    }
    std::fs::write(out.join("adaptive.csv"), csv)?;
    Ok(())
}
