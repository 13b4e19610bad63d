//! Levels of detail, run time and triangles against image error: each scene flown with levels chosen under
//! pixel thresholds and under triangle budgets, every frame judged exactly against full detail
//! (`cullet_truth::lod`). Writes `target/lod/lod.csv` and `target/lod/lod.png`.
//!
//! Scenes: the city (`CULLET_LOD_OBJECTS`, default 10 000 objects, its fly-through) and the shared scenes
//! truck_town and zdm2 around their orbits (with automatic occluders, as the tradeoff bench has them).
//! `CULLET_LOD_FRAMES` (default 30) frames each, judged at 1920x1080. A budget is a share of the mean triangles
//! a frame that 1 px of error draws (over the objects the camera keeps), so that it binds.
//!
//! Where a GPU adapter is found, each frame also goes through the GPU passes at 1920x1080 (cluster and triangle
//! culling, the draw of the chosen levels): the triangles they draw, and their GPU time where the adapter has
//! timestamp queries (on lavapipe, the CPU's: ratios only).
//!
//! Run: `cargo bench -p cullet-benches --bench lod`.

use cullet::CameraPath;
use cullet::culler::OcclusionSettings;
use cullet::gpu::{GpuContext, GpuCullSettings, GpuCuller};
use cullet::lod::{self, ChainSettings, LodLibrary, LodSelection, LodSettings};
use cullet::pipeline::CullStats;
use cullet::scene::Scene;
use cullet::scene::auto_occluders::{AutoOccluderSettings, add_auto_occluders};
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use cullet::scene::gltf_import::load_gltf;
use cullet_truth::ReferenceSettings;
use cullet_truth::lod::{ImageError, judge_lod};
use plotters::prelude::*;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// One scene flown under one setting.
struct Row {
    scene: &'static str,
    setting: String,
    triangles_full: f64,
    triangles: f64,
    most_triangles: u64,
    /// The most triangles a frame at full detail.
    most_full: u64,
    budget: Option<u64>,
    error: ImageError,
    switches: f64,
    dropped: f64,
    selection_us: f64,
    frame_us: f64,
    /// Triangles the GPU passes drew a frame, and their GPU time a frame in ms (mean), where measured.
    gpu_triangles: Option<f64>,
    gpu_ms: Option<f64>,
}

fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(0.0)
}

fn micros(duration: Duration) -> f64 {
    duration.as_secs_f64() * 1e6
}

/// A scene flown along a path, with its levels.
struct Flown<'a> {
    name: &'static str,
    scene: &'a Scene,
    path: CameraPath,
    frames: u32,
    library: LodLibrary,
    gpu: Option<&'a GpuContext>,
}

/// Flies `flown` with its levels installed under `settings`, judging every frame (and drawing it on the GPU,
/// where there is one).
fn fly(flown: &Flown<'_>, setting: String, settings: LodSettings, reference: &ReferenceSettings) -> Row {
    let Flown { name, scene, ref path, frames, ref library, gpu } = *flown;
    let aspect = reference.width as f32 / reference.height as f32;
    let occlusion = OcclusionSettings::for_frame(reference.width, reference.height);
    let mut flight = Flight::new(path.clone(), aspect, frames, occlusion, |world| {
        scene.spawn(world);
    });
    lod::install(&mut flight.world, &mut flight.schedule, library.clone(), settings);
    let size = (reference.width, reference.height);
    let mut gpu = gpu.map(|context| (context, GpuCuller::for_world(context, &flight.world, &scene.meshes, size)));
    let (mut gpu_triangles, mut gpu_times) = (0.0, Vec::new());
    let (mut full, mut drawn, mut most, mut most_full, mut switches, mut dropped) = (0.0, 0.0, 0, 0, 0.0, 0.0);
    let (mut selection, mut frame_times, mut error) = (Vec::new(), Vec::new(), ImageError::default());
    for frame in 0..frames {
        let stats: CullStats = flight.run_frame(frame);
        let lod = flight.world.resource::<LodSelection>().stats();
        (full, drawn) = (full + lod.triangles_full as f64, drawn + lod.triangles as f64);
        (most, most_full) = (most.max(lod.triangles), most_full.max(lod.triangles_full));
        (switches, dropped) = (switches + lod.switches as f64, dropped + lod.dropped as f64);
        selection.push(micros(lod.time));
        let stages = stats.bounds_time + stats.frustum_time + stats.raster_time + stats.occlusion_time;
        frame_times.push(micros(stages + lod.time));
        error.add(&judge_lod(&flight.world, flight.world.resource::<LodLibrary>(), reference));
        if let Some((context, culler)) = &mut gpu {
            let output = culler.run_world(context, &mut flight.world, &GpuCullSettings::default()).expect("GPU frame");
            gpu_triangles += output.counters.triangles_out as f64;
            if let Some(t) = output.pass_times {
                gpu_times.push((t.hzb + t.clusters + t.triangles + t.draw).as_secs_f64() * 1e3);
            }
        }
    }
    let n = frames as f64;
    let gpu_ms = (gpu_times.len() == frames as usize).then(|| gpu_times.iter().sum::<f64>() / n);
    Row {
        scene: name,
        setting,
        triangles_full: full / n,
        triangles: drawn / n,
        most_triangles: most,
        most_full,
        budget: settings.triangle_budget,
        error,
        switches: switches / n,
        dropped: dropped / n,
        selection_us: median(selection),
        frame_us: median(frame_times),
        gpu_triangles: gpu.is_some().then_some(gpu_triangles / n),
        gpu_ms,
    }
}

/// Every setting for one scene: off, pixel thresholds, then budgets as shares of what 1 px draws.
fn sweep(
    name: &'static str,
    scene: &Scene,
    path: CameraPath,
    frames: u32,
    gpu: Option<&GpuContext>,
    reference: &ReferenceSettings,
) -> Vec<Row> {
    let start = Instant::now();
    let library = LodLibrary::for_scene(scene, &ChainSettings::default());
    let levels: usize = (0..library.chain_count() as u32).map(|c| library.levels(c)).sum();
    println!(
        "{name}: {} meshes, {levels} levels in all, generated in {:.0} ms",
        scene.meshes.len(),
        start.elapsed().as_secs_f64() * 1e3
    );
    let height = reference.height;
    let flown = Flown { name, scene, path, frames, library, gpu };
    let run = |setting: String, settings: LodSettings| fly(&flown, setting, settings, reference);
    let mut rows = vec![run("full detail".into(), LodSettings::default())];
    for pixels in [0.25, 0.5, 1.0, 2.0, 4.0, 8.0] {
        rows.push(run(format!("{pixels} px"), LodSettings::pixels(pixels, height)));
    }
    // Off, the selection counts nothing: the kept objects' full-detail triangles are any other row's (culling
    // is the same).
    let full = rows[1].triangles_full;
    (rows[0].triangles_full, rows[0].triangles) = (full, full);
    (rows[0].most_full, rows[0].most_triangles) = (rows[1].most_full, rows[1].most_full);
    // Budgets below what 1 px of error draws, so that they bind.
    let one_pixel = rows[3].triangles;
    for share in [0.75, 0.5, 0.25, 0.1] {
        let budget = ((one_pixel * share) as u64).max(1);
        let settings = LodSettings { triangle_budget: Some(budget), ..LodSettings::pixels(1.0, height) };
        rows.push(run(format!("1 px under a budget of {:.0}% of that", share * 100.0), settings));
    }
    rows.iter().for_each(print_row);
    rows
}

fn print_row(row: &Row) {
    println!(
        "  {:<36} triangles {:>10.0} of {:>10.0} ({:>5.1}% fewer, most {:>9}), pixels changed {:>7.4}%, colour \
         {:.5}, depth {:.5}, switches {:>7.1}/frame, dropped {:>7.1}/frame, selection {:>7.1} us of a {:>8.1} us \
         CPU frame (medians); GPU: {}",
        row.setting,
        row.triangles,
        row.triangles_full,
        100.0 * (1.0 - row.triangles / row.triangles_full.max(1.0)),
        row.most_triangles,
        100.0 * row.error.changed_fraction(),
        row.error.colour_error,
        row.error.depth_error,
        row.switches,
        row.dropped,
        row.selection_us,
        row.frame_us,
        match (row.gpu_triangles, row.gpu_ms) {
            (Some(triangles), Some(ms)) => format!("{triangles:.0} triangles drawn in {ms:.2} ms a frame"),
            (Some(triangles), None) => format!("{triangles:.0} triangles drawn (no timestamps)"),
            _ => "no adapter".into(),
        }
    );
}

fn csv(rows: &[Row]) -> String {
    let mut out = String::from(
        "scene,setting,budget,triangles_full,triangles,most_triangles,pixels_changed_percent,colour_error,\
         depth_error,switches_per_frame,dropped_per_frame,selection_us_median,cpu_frame_us_median,gpu_triangles,\
         gpu_ms_mean\n",
    );
    let optional = |value: Option<f64>, digits: usize| value.map_or(String::new(), |v| format!("{v:.digits$}"));
    for r in rows {
        out.push_str(&format!(
            "{},{},{},{:.0},{:.0},{},{:.5},{:.6},{:.6},{:.2},{:.2},{:.1},{:.1},{},{}\n",
            r.scene,
            r.setting,
            r.budget.map_or(String::new(), |b| b.to_string()),
            r.triangles_full,
            r.triangles,
            r.most_triangles,
            100.0 * r.error.changed_fraction(),
            r.error.colour_error,
            r.error.depth_error,
            r.switches,
            r.dropped,
            r.selection_us,
            r.frame_us,
            optional(r.gpu_triangles, 0),
            optional(r.gpu_ms, 3)
        ));
    }
    out
}

/// Where the plot's log axis draws a frame with no pixel changed, in percent.
const PIXELS_FLOOR: f64 = 1e-4;

/// Against pixels changed, one colour per scene, each as a share of the scene's full detail: the triangles of
/// kept objects drawn, the CPU frame (culling and selection), and where measured the GPU passes' time.
fn plot(rows: &[Row], path: &std::path::Path) -> Result<(), Box<dyn std::error::Error>> {
    let timed = rows.iter().any(|r| r.gpu_ms.is_some());
    let panels = if timed { 3 } else { 2 };
    let root = BitMapBackend::new(path, (1000 * panels as u32, 760)).into_drawing_area();
    root.fill(&WHITE)?;
    let titled = root.titled("Cullet levels of detail against image error (1920x1080)", ("sans-serif", 24))?;
    let areas = titled.split_evenly((1, panels));
    // Each scene's full-detail row comes first.
    let full = |scene: &str| rows.iter().find(|r| r.scene == scene);
    panel(&areas[0], rows, "triangles of kept objects drawn (% of full detail)", |r| {
        Some(100.0 * r.triangles / r.triangles_full.max(1.0))
    })?;
    panel(&areas[1], rows, "CPU frame, culling and selection (% of full detail's, medians)", |r| {
        Some(100.0 * r.frame_us / full(r.scene)?.frame_us)
    })?;
    if timed {
        panel(&areas[2], rows, "GPU passes' time (% of full detail's; lavapipe: ratios only)", |r| {
            Some(100.0 * r.gpu_ms? / full(r.scene)?.gpu_ms?)
        })?;
    }
    root.present()?;
    Ok(())
}

/// One panel of [`plot`]: `y` of each row (a share in percent) against its pixels changed.
fn panel(
    area: &DrawingArea<BitMapBackend, plotters::coord::Shift>,
    rows: &[Row],
    y_desc: &str,
    y: impl Fn(&Row) -> Option<f64>,
) -> Result<(), Box<dyn std::error::Error>> {
    let max_x = rows.iter().map(|r| 100.0 * r.error.changed_fraction()).fold(0.0, f64::max).max(0.1) * 2.0;
    let max_y = rows.iter().filter_map(&y).fold(100.0, f64::max) * 1.05;
    let mut chart = ChartBuilder::on(area)
        .margin(20)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d((PIXELS_FLOOR..max_x).log_scale(), 0.0..max_y)?;
    chart
        .configure_mesh()
        .x_desc("pixels changed against full detail (%, log scale; none is drawn at 0.0001)")
        .y_desc(y_desc)
        .draw()?;
    let colours = [BLUE, RGBColor(230, 120, 0), RGBColor(0, 150, 60)];
    let mut scenes: Vec<&str> = rows.iter().map(|r| r.scene).collect();
    scenes.dedup();
    for (scene, colour) in scenes.into_iter().zip(colours) {
        let points: Vec<(f64, f64, bool)> = rows
            .iter()
            .filter(|r| r.scene == scene)
            .filter_map(|r| Some((100.0 * r.error.changed_fraction(), y(r)?, r.budget.is_some())))
            .collect();
        chart
            .draw_series(points.iter().filter(|p| !p.2).map(|&(x, y, _)| Circle::new((x, y), 5, colour.filled())))?
            .label(format!("{scene}: pixel thresholds"))
            .legend(move |(x, y)| Circle::new((x + 10, y), 5, colour.filled()));
        chart
            .draw_series(
                points.iter().filter(|p| p.2).map(|&(x, y, _)| TriangleMarker::new((x, y), 7, colour.filled())),
            )?
            .label(format!("{scene}: 1 px under budgets"))
            .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 7, colour.filled()));
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    Ok(())
}

fn main() {
    let reference = ReferenceSettings::default();
    let frames = env_or("CULLET_LOD_FRAMES", 30) as u32;
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/lod");
    std::fs::create_dir_all(&dir).unwrap();
    let gpu = match GpuContext::new() {
        Ok(context) => {
            let info = &context.adapter_info;
            println!("adapter: {} ({:?}), timestamps: {}", info.name, info.backend, context.has_timestamps);
            Some(context)
        }
        Err(error) => {
            println!("no GPU adapter ({error}): GPU columns left empty");
            None
        }
    };
    let mut rows = Vec::new();
    let city = CityScene::generate(CityParams::with_objects(env_or("CULLET_LOD_OBJECTS", 10_000)));
    rows.extend(sweep("city", &city.scene, city.flythrough(), frames, gpu.as_ref(), &reference));
    for (name, file) in [("truck_town", "truck_town/town_model.gltf"), ("zdm2", "zdm2/zdm2.glb")] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes").join(file);
        match load_gltf(&path) {
            Ok(mut loaded) => {
                add_auto_occluders(&mut loaded.scene, &AutoOccluderSettings::default());
                let orbit = loaded.scene.orbit_path();
                rows.extend(sweep(name, &loaded.scene, orbit, frames, gpu.as_ref(), &reference));
            }
            Err(error) => println!("SKIPPED {name}: {error}"),
        }
    }
    std::fs::write(dir.join("lod.csv"), csv(&rows)).unwrap();
    if let Err(error) = plot(&rows, &dir.join("lod.png")) {
        println!("no plot: {error}");
    }
    println!("wrote {}", dir.canonicalize().unwrap().display());
}
