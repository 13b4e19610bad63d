//! Cullet's occlusion stage side by side with Intel's Masked Occlusion Culling (MOC), in the same run, on the
//! same occluders and the same occludee boxes:
//!
//! 1. **Street view:** the 400k-object city from its street camera, 10k occluder triangles, every frustum
//!    survivor tested; raster, test and total time on 1 and 2 threads at 256x144, 512x288, 1024x576 and
//!    1920x1080 (Cullet's conservative buffer at each, its masked buffer at 256x144, its pixel-centre and
//!    masked buffers at 1920x1080, and its masked buffer at 960x540 standing for 1920x1080 against MOC at
//!    1920x1080), and the boxes each keeps. Fastest of `CULLET_MOC_RUNS` (default 15) runs.
//! 2. **Judged paths:** the city's fly-through and truck_town's orbit (automatic occluders), every frame
//!    judged against the exact rendering: false negatives, culling efficiency and image error of both, each
//!    given the occluders Cullet's pipeline selected that frame.
//!
//! Writes `target/moc/street.csv` and `target/moc/paths.csv`.
//!
//! `cargo bench -p cullet-benches --bench moc`; `CULLET_MOC_OBJECTS` (default 100000) and `CULLET_MOC_FRAMES`
//! (default 100) size the city's path. MOC is built from `../shared/peers/moc` (see `build.rs`); without it
//! this bench says so and measures nothing.

#[path = "moc/mod.rs"]
mod moc;
#[path = "street/mod.rs"]
mod street;

use cullet::VisibleSet;
use cullet::camera::CameraPath;
use cullet::depth::DepthPyramid;
use cullet::pipeline::CullStats;

use cullet::culler::OcclusionSettings;
use cullet::raster::{RasterMode, rasterize};
use cullet::scene::Scene;
use cullet::scene::auto_occluders::{AutoOccluderSettings, add_auto_occluders};
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use cullet::scene::gltf_import::load_gltf;
use cullet_truth::judge::{render_world, stage_metrics};
use cullet_truth::{ExactVisibility, PathMetrics, ReferenceSettings};
use moc::{Moc, Occludees};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use street::StreetView;

/// Cullet's configurations compared, each against MOC at the size of the frame it stands for (its own where it
/// names none): the default conservative buffer at 256x144, two steps up and the viewport's resolution; the
/// masked buffer at 256x144 (sampling the same pixel centres as MOC there); the pixel-centre and masked buffers at
/// the viewport's; and the masked buffer at half the viewport standing for its pixels (the game's default).
fn configs() -> [OcclusionSettings; 8] {
    let at = |width, height, mode| OcclusionSettings { width, height, mode, ..OcclusionSettings::default() };
    [
        at(256, 144, RasterMode::Conservative),
        at(256, 144, RasterMode::Masked),
        at(512, 288, RasterMode::Conservative),
        at(1024, 576, RasterMode::Conservative),
        at(1920, 1080, RasterMode::Conservative),
        at(1920, 1080, RasterMode::PixelCentres),
        at(1920, 1080, RasterMode::Masked),
        OcclusionSettings::for_frame(1920, 1080),
    ]
}

/// The size MOC runs at beside `settings`: the frame Cullet's buffer stands for, or its own.
fn peer_size(settings: &OcclusionSettings) -> (u32, u32) {
    settings.frame.unwrap_or((settings.width, settings.height))
}

/// A configuration's name in tables: `960x540 masked for 1920x1080`.
fn config_name(settings: &OcclusionSettings) -> String {
    let name = format!("{}x{} {}", settings.width, settings.height, settings.mode.name());
    match settings.frame {
        Some((width, height)) => format!("{name} for {width}x{height}"),
        None => name,
    }
}

/// A configuration's CSV cells: `width,height,cullet_mode,frame` (the frame `WxH`, empty where none).
fn config_cells(settings: &OcclusionSettings) -> String {
    let frame = settings.frame.map(|(width, height)| format!("{width}x{height}")).unwrap_or_default();
    format!("{},{},{},{frame}", settings.width, settings.height, settings.mode.name())
}

fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn main() {
    if std::env::args().skip(1).any(|a| !a.starts_with('-') && !"moc".contains(a.as_str())) {
        return;
    }
    match Moc::new(64, 64, 0.1, 1) {
        Ok(mut probe) => println!("Intel MOC, {} back end", probe.implementation()),
        Err(why) => {
            println!("SKIPPED: Intel MOC is not built, so there is nothing to compare with: {why}");
            return;
        }
    }
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/moc");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("street.csv"), street_view(env_or("CULLET_MOC_RUNS", 15))).unwrap();
    std::fs::write(dir.join("paths.csv"), judged_paths()).unwrap();
    println!("wrote {}", dir.canonicalize().unwrap().display());
}

/// Fastest of `runs` calls of `work`, which returns its own timings (raster, test) and the boxes kept.
fn fastest(runs: usize, mut work: impl FnMut() -> (Duration, Duration, usize)) -> (Duration, Duration, usize) {
    (0..runs.max(1)).map(|_| work()).min_by_key(|&(raster, test, _)| raster + test).unwrap()
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Part 1: the street view at each resolution and thread count; returns the CSV.
fn street_view(runs: usize) -> String {
    let street = StreetView::new(400_000);
    let (store, camera, survivors) = (&street.store, street.camera, &street.frustum_visible);
    let selected = street.select(10_000);
    let triangles: usize = selected.iter().map(|o| o.occluder.triangle_count()).sum();
    println!(
        "\nstreet view of the 400k-object city: {triangles} occluder triangles, {} frustum survivors; fastest of \
         {runs} runs, ms",
        survivors.count()
    );
    println!(
        "{:<32} {:>7} | {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "buffer",
        "threads",
        "C raster",
        "C test",
        "C total",
        "C kept",
        "M raster",
        "M TestR",
        "M total",
        "M kept",
        "M proj"
    );
    let mut csv = String::from(
        "width,height,cullet_mode,frame,threads,cullet_raster_ms,cullet_test_ms,cullet_total_ms,cullet_kept,moc_raster_ms,\
         moc_testrect_ms,moc_total_ms,moc_kept,moc_project_ms,survivors,occluder_triangles\n",
    );
    for settings in configs() {
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let view = settings.view(&camera);
            let mut pyramid = DepthPyramid::default();
            let (mut visible, mut occluded) = (VisibleSet::default(), VisibleSet::default());
            let cullet = pool.install(|| {
                fastest(runs, || {
                    let start = Instant::now();
                    rasterize(&view, &selected, settings.mode, &mut pyramid);
                    let raster = start.elapsed();
                    let start = Instant::now();
                    street.test(&view, &pyramid, &mut visible, &mut occluded);
                    (raster, start.elapsed(), visible.count())
                })
            });
            let (width, height) = peer_size(&settings);
            let mut peer = Moc::new(width, height, camera.near, threads).unwrap();
            let mut scratch = Occludees::default();
            let mut project = Duration::MAX;
            let peer_times = pool.install(|| {
                fastest(runs, || {
                    let frame = moc::cull(&mut peer, &camera, store, survivors, &selected, threads, &mut scratch);
                    project = project.min(frame.project);
                    (frame.raster, frame.test, frame.visible.count())
                })
            });
            // The table's columns after buffer and threads, which are also the CSV's.
            let figures = [
                format!("{:.3}", ms(cullet.0)),
                format!("{:.3}", ms(cullet.1)),
                format!("{:.3}", ms(cullet.0 + cullet.1)),
                cullet.2.to_string(),
                format!("{:.3}", ms(peer_times.0)),
                format!("{:.3}", ms(peer_times.1)),
                format!("{:.3}", ms(peer_times.0 + peer_times.1)),
                peer_times.2.to_string(),
                format!("{:.3}", ms(project)),
            ];
            let cells: Vec<String> = figures.iter().map(|f| format!("{f:>8}")).collect();
            println!("{:<32} {threads:>7} | {}", config_name(&settings), cells.join(" "));
            let config = config_cells(&settings);
            writeln!(csv, "{config},{threads},{},{},{triangles}", figures.join(","), survivors.count()).unwrap();
        }
    }
    csv
}

/// A scene to judge along a camera path.
struct JudgedPath<'a> {
    name: &'static str,
    scene: &'a Scene,
    path: CameraPath,
    frames: u32,
}

/// Part 2: both stages judged over the city's fly-through and truck_town's orbit; returns the CSV.
fn judged_paths() -> String {
    let objects = env_or("CULLET_MOC_OBJECTS", 100_000);
    let frames = env_or("CULLET_MOC_FRAMES", 100) as u32;
    let city = CityScene::generate(CityParams::with_objects(objects));
    let mut paths = vec![JudgedPath { name: "city", scene: &city.scene, path: city.flythrough(), frames }];
    let truck_town = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes/truck_town/town_model.gltf");
    let town = match load_gltf(&truck_town) {
        Ok(mut loaded) => {
            add_auto_occluders(&mut loaded.scene, &AutoOccluderSettings::default());
            Some(loaded.scene)
        }
        Err(e) => {
            println!("SKIPPED truck_town: {e}");
            None
        }
    };
    if let Some(town) = &town {
        paths.push(JudgedPath { name: "truck_town", scene: town, path: town.orbit_path(), frames: 60 });
    }
    let mut csv = String::from(
        "scene,frames,width,height,cullet_mode,frame,peer,mean_stage_ms,culling_efficiency,false_negatives,\
         frames_with_false_negatives,image_error_pixels_per_frame\n",
    );
    let reference = ReferenceSettings::default();
    for path in paths {
        let flight = |settings| {
            Flight::new(path.path.clone(), 16.0 / 9.0, path.frames, settings, |world| {
                path.scene.spawn(world);
            })
        };
        let start = Instant::now();
        let mut truth_flight = flight(OcclusionSettings::default());
        let truth: Vec<ExactVisibility> = (0..path.frames)
            .map(|frame| {
                truth_flight.run_frame(frame);
                render_world(&truth_flight.world, &path.scene.meshes, &reference).visibility()
            })
            .collect();
        println!(
            "\n{}: {} frames judged at {}x{} (exact visibility in {:.1} s); occlusion stage ms a frame on 2 \
             threads (Cullet's includes choosing the occluders and projecting the boxes; MOC's is raster and \
             TestRect only)",
            path.name,
            path.frames,
            reference.width,
            reference.height,
            start.elapsed().as_secs_f64()
        );
        for settings in configs() {
            let mut run = flight(settings);
            let (width, height) = peer_size(&settings);
            let mut peer = Moc::new(width, height, run.path.camera_at(0.0, 16.0 / 9.0).near, 2).unwrap();
            let mut scratch = Occludees::default();
            let (mut ours, mut theirs) = (PathMetrics::default(), PathMetrics::default());
            let (mut our_time, mut their_time) = (Duration::ZERO, Duration::ZERO);
            for frame in 0..path.frames {
                let stats: CullStats = run.run_frame(frame);
                our_time += stats.raster_time + stats.occlusion_time;
                let exact = &truth[frame as usize];
                ours.add(&stage_metrics(&run.world, exact));
                let peer_frame = moc::cull_world(&mut peer, &run.world, 2, &mut scratch);
                their_time += peer_frame.raster + peer_frame.test;
                theirs.add(&peer_frame.judge(&run.world, exact));
            }
            for (peer, metrics, time) in [("cullet", &ours, our_time), ("moc", &theirs, their_time)] {
                let mean = ms(time) / path.frames as f64;
                println!(
                    "{:<10} {:>32} {:<6} {:>7.3} ms  efficiency {:5.1}%  false negatives {:5} in {:3} frames  \
                     image error {:7.1} px/frame",
                    path.name,
                    config_name(&settings),
                    peer,
                    mean,
                    100.0 * metrics.efficiency(1),
                    metrics.false_negatives,
                    metrics.frames_with_false_negatives,
                    metrics.image_error_pixels as f64 / path.frames as f64,
                );
                writeln!(
                    csv,
                    "{},{},{},{peer},{mean:.4},{:.4},{},{},{:.1}",
                    path.name,
                    path.frames,
                    config_cells(&settings),
                    metrics.efficiency(1),
                    metrics.false_negatives,
                    metrics.frames_with_false_negatives,
                    metrics.image_error_pixels as f64 / path.frames as f64,
                )
                .unwrap();
            }
        }
    }
    csv
}
