//! Occlusion per light view: what each light view's own buffer ([`LightOcclusionSettings`]) costs on the CPU
//! and what it saves the shadow maps, over the built-in city's fly-through with the sample game's lights (a
//! sun's four cascades to 400 m and a lamp's six faces). For each buffer size and triangle budget, and with
//! the light views' occlusion off: the stage's CPU time a frame, the casters the light views keep, and the
//! triangles of those casters (what the shadow maps would draw), for the game's high sun and a low one. The
//! sweep runs every view's occlusion every frame; the last row is the default settings with their benefit
//! gates ([`AdaptiveSettings::min_light_occlusion_benefit`]), which skip a view's occlusion that hides too
//! little.
//!
//! `cargo bench -p cullet-benches --bench light_occlusion [objects]` (1e5 by default; 2 threads as on the CI
//! machine unless `RAYON_NUM_THREADS` says otherwise).

use cullet::culler::LightOcclusionSettings;
use cullet::draw_cost::SlotTriangles;
use cullet::frustum::LightSource;
use cullet::pipeline::{CullStats, LightViews, LightViewsVisible};

use cullet::culler::{AdaptiveSettings, OcclusionSettings};
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use glam::Vec3;
use std::time::Duration;

/// Frames along the 20-second path.
const FRAMES: u32 = 100;
/// Passes over the path per configuration; each frame's fastest counts.
const PASSES: usize = 3;

fn main() {
    let objects = std::env::args().skip(1).find_map(|arg| arg.parse::<f64>().ok()).map_or(100_000, |n| n as usize);
    let city = CityScene::generate(CityParams::with_objects(objects));
    println!("city of {objects} objects, {FRAMES} frames of its fly-through, fastest of {PASSES} passes a frame");
    let sweep: Vec<LightOcclusionSettings> =
        std::iter::once(LightOcclusionSettings { enabled: false, ..Default::default() })
            .chain([64, 128, 256].into_iter().flat_map(|size| {
                [512, 2048, 8192].map(|triangle_budget| LightOcclusionSettings {
                    size,
                    triangle_budget,
                    ..LightOcclusionSettings::default()
                })
            }))
            .collect();
    let ungated = AdaptiveSettings { min_light_occlusion_benefit: 0.0, ..AdaptiveSettings::default() };
    let configs: Vec<(LightOcclusionSettings, AdaptiveSettings)> = sweep
        .into_iter()
        .map(|config| (config, ungated))
        .chain([(LightOcclusionSettings::default(), AdaptiveSettings::default())])
        .collect();
    for (sun_name, sun) in [("high sun (game)", Vec3::new(0.35, -1.0, 0.25)), ("low sun", Vec3::new(1.0, -0.45, 0.6))] {
        println!("\n{sun_name}, travelling along {sun}");
        println!(
            "{:<22} {:>12} {:>10} {:>10} {:>14} {:>10} {:>16}",
            "light occlusion", "ms a frame", "casters", "hidden", "caster tris", "saved", "saved tris / us"
        );
        let mut off_triangles = None;
        for (config, adaptive) in &configs {
            let mut flight =
                Flight::new(city.flythrough(), 16.0 / 9.0, FRAMES, OcclusionSettings::default(), |world| {
                    city.spawn(world);
                });
            let lamp = flight.path.keys[0].position + Vec3::new(0.0, 6.0, 0.0);
            flight.world.insert_resource(LightViews(vec![
                LightSource::Sun { direction: sun, splits: vec![0.1, 12.0, 40.0, 120.0, 400.0] },
                LightSource::Lamp { position: lamp, near: 0.05, range: Some(60.0) },
            ]));
            flight.world.insert_resource(*config);
            flight.world.insert_resource(*adaptive);
            let slot_triangles = SlotTriangles::of_world(&flight.world, &city.scene.meshes);
            let mut fastest = vec![Duration::MAX; FRAMES as usize];
            let (mut casters, mut hidden, mut triangles) = (0, 0, 0);
            for pass in 0..PASSES {
                for frame in 0..FRAMES {
                    let stats: CullStats = flight.run_frame(frame);
                    fastest[frame as usize] = fastest[frame as usize].min(stats.light_occlusion_time);
                    if pass == 0 {
                        casters += stats.light_view_casters;
                        hidden += stats.light_view_occluded;
                        let views = flight.world.resource::<LightViewsVisible>();
                        triangles += views.0.iter().map(|view| slot_triangles.sum(&view.visible)).sum::<u64>();
                    }
                }
            }
            let n = FRAMES as f64;
            let ms = fastest.iter().map(Duration::as_secs_f64).sum::<f64>() / n * 1e3;
            let triangles = triangles as f64 / n;
            let off = *off_triangles.get_or_insert(triangles);
            let name = match (config.enabled, adaptive.min_light_occlusion_benefit > 0.0) {
                (false, _) => "off".to_string(),
                (true, false) => format!("{0}x{0}, {1} tris", config.size, config.triangle_budget),
                (true, true) => "default, gated".to_string(),
            };
            let saved = off - triangles;
            println!(
                "{name:<22} {ms:>12.3} {:>10.0} {:>9.1}% {triangles:>14.0} {:>9.1}% {:>16}",
                casters as f64 / n,
                100.0 * hidden as f64 / (casters + hidden).max(1) as f64,
                100.0 * saved / off.max(1.0),
                if config.enabled { format!("{:.0}", saved / (ms * 1e3).max(1e-9)) } else { "-".into() }
            );
        }
    }
}
