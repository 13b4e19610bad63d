//! `cullet-game`: flies a camera through a scene and culls it every frame, printing per-frame and summary
//! statistics of each stage.

use clap::Parser;
use cullet::flight::Flight;
use cullet::gpu::GpuContext;
use cullet::gpu::clusters::ClusterLibrary;
use cullet::gpu::frame::{GpuCounters, GpuCullSettings, GpuCuller, GpuFrameOutput, GpuPassTimes};
use cullet::gpu::scene::{GpuScene, instances_from_world};
use cullet::pipeline::{CullStats, OcclusionSettings};
use cullet::raster::RasterMode;
use cullet::scene::Scene;
use cullet::scene::auto_occluders::{AutoOccluderSettings, add_auto_occluders};
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::gltf_import::load_gltf;
use cullet::{BoundsStore, Camera, CameraPath};
use cullet_truth::{JudgeSettings, PathMetrics, ReferenceSettings, judge_frame};
use std::process::ExitCode;
use std::time::{Duration, Instant};

/// Fly through a scene and cull it every frame.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Scene to load: `city` or `city:N` for the built-in procedural city of N objects, or a glTF file
    /// (`.gltf` or `.glb`).
    #[arg(long, default_value = "city:100000")]
    scene: String,
    /// Give large meshes without an artist occluder one made of their own largest triangles (conservative:
    /// those triangles are the drawn surface).
    #[arg(long)]
    auto_occluders: bool,
    /// Number of frames along the camera path.
    #[arg(long, default_value_t = 300)]
    frames: u32,
    /// Viewport size, `WIDTHxHEIGHT` (sets the aspect ratio of the camera).
    #[arg(long, default_value = "1920x1080")]
    resolution: String,
    /// Print only the summary, not one line per frame.
    #[arg(long)]
    quiet: bool,
    /// Size of the software occlusion depth buffer, `WIDTHxHEIGHT`.
    #[arg(long, default_value = "256x144")]
    occlusion_resolution: String,
    /// Sample the occlusion buffer at texel centres (not conservative) instead of whole-texel coverage.
    #[arg(long)]
    fast_occlusion: bool,
    /// Turn the software occlusion stage off.
    #[arg(long)]
    no_occlusion: bool,
    /// Most occluder triangles rasterized per frame.
    #[arg(long, default_value_t = OcclusionSettings::default().triangle_budget)]
    occluder_budget: usize,
    /// Judge every frame against the exact ground truth (every object's triangles rasterized at the viewport
    /// resolution): report false negatives, false positives and image error, and fail if a conservative
    /// configuration culled anything visible.
    #[arg(long)]
    validate: bool,
    /// Run only the CPU stages (bounds, frustum, occlusion), without a GPU adapter: cluster and triangle
    /// culling and the draw are skipped.
    #[arg(long)]
    cpu_only: bool,
    /// Camera path to fly instead of the scene's built-in one (JSON, see the README).
    #[arg(long, value_name = "FILE.json")]
    camera_path: Option<std::path::PathBuf>,
    /// Write one CSV row per frame: counts and each stage's time in microseconds (plus accuracy with
    /// --validate).
    #[arg(long, value_name = "FILE.csv")]
    stats: Option<std::path::PathBuf>,
    /// Save the drawn frame as PNG into this folder every --every frames (needs a GPU adapter).
    #[arg(long, value_name = "DIR")]
    screenshots: Option<std::path::PathBuf>,
    /// Frames between screenshots.
    #[arg(long, default_value_t = 30)]
    every: u32,
    /// Run without a window (the only mode this build has; accepted for scripts).
    #[arg(long)]
    headless: bool,
}

/// The stats CSV's columns.
const STATS_HEADER: &str = "frame,objects,after_frustum,after_occlusion,clusters_in,clusters_out,triangles_in,\
triangles_out,draws,bounds_us,frustum_us,raster_us,occlusion_us,gpu_us,false_negatives,false_positives,\
image_error_pixels";

/// A loaded scene and the camera path it is flown along without `--camera-path`.
struct LoadedScene {
    scene: Scene,
    path: CameraPath,
    description: String,
}

/// The scene `--scene` names: the built-in city, or a glTF file (warnings printed, errors returned).
fn load_scene(args: &Args) -> Result<LoadedScene, String> {
    let city_objects = match args.scene.split_once(':') {
        None if args.scene == "city" => Some(Ok(100_000)),
        Some(("city", count)) => Some(count.parse().map_err(|_| format!("bad object count in --scene {}", args.scene))),
        _ => None,
    };
    let mut loaded = match city_objects {
        Some(objects) => {
            let city = CityScene::generate(CityParams::with_objects(objects?));
            let path = city.flythrough();
            LoadedScene {
                description: format!("city of {} objects", city.scene.objects.len()),
                scene: city.scene,
                path,
            }
        }
        None => {
            let file = std::path::Path::new(&args.scene);
            let extension = file.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
            if !matches!(extension.as_deref(), Some("gltf" | "glb")) {
                return Err(format!("unknown scene '{}': expected city, city:N or a .gltf/.glb file", args.scene));
            }
            let gltf = load_gltf(file).map_err(|e| e.to_string())?;
            for warning in &gltf.warnings {
                eprintln!("warning: {}: {warning}", args.scene);
            }
            let path = gltf.scene.orbit_path();
            LoadedScene {
                description: format!(
                    "{}: {} objects, {} triangles, {} artist occluder nodes",
                    args.scene,
                    gltf.scene.objects.len(),
                    gltf.scene.triangle_count(),
                    gltf.occluder_nodes
                ),
                scene: gltf.scene,
                path,
            }
        }
    };
    if args.auto_occluders {
        let added = add_auto_occluders(&mut loaded.scene, &AutoOccluderSettings::default());
        loaded.description.push_str(&format!(", {added} automatic occluders"));
    }
    Ok(loaded)
}

fn parse_resolution(resolution: &str) -> Result<(u32, u32), String> {
    let parsed = resolution.split_once('x').and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)));
    match parsed {
        Some((w, h)) if w > 0 && h > 0 => Ok((w, h)),
        _ => Err(format!("bad --resolution '{resolution}', expected WIDTHxHEIGHT")),
    }
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()))
        .init();
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("cullet-game: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: &Args) -> Result<(), String> {
    let (width, height) = parse_resolution(&args.resolution)?;
    let aspect = width as f32 / height as f32;
    let (occlusion_width, occlusion_height) = parse_resolution(&args.occlusion_resolution)?;
    let occlusion = OcclusionSettings {
        enabled: !args.no_occlusion,
        width: occlusion_width,
        height: occlusion_height,
        mode: if args.fast_occlusion { RasterMode::Fast } else { RasterMode::Conservative },
        triangle_budget: args.occluder_budget,
    };

    let start = Instant::now();
    let LoadedScene { scene, path, description } = load_scene(args)?;
    let path = match &args.camera_path {
        Some(file) => {
            let json = std::fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))?;
            CameraPath::from_json(&json).map_err(|e| format!("{}: {e}", file.display()))?
        }
        None => path,
    };
    let mut flight = Flight::new(path, aspect, args.frames, occlusion, |world| {
        scene.spawn(world);
    });
    println!(
        "{description}; loaded and spawned in {:.0} ms; {} frames along a {:.0} s path",
        start.elapsed().as_secs_f64() * 1e3,
        args.frames,
        flight.path.duration()
    );

    let mut gpu = if args.cpu_only {
        println!("--cpu-only: GPU cluster culling, triangle culling and the draw are skipped");
        None
    } else {
        match GpuContext::new() {
            Ok(context) => {
                let info = &context.adapter_info;
                println!("GPU: {} ({:?}, {:?})", info.name, info.backend, info.device_type);
                let scene =
                    GpuScene::new(&context, ClusterLibrary::build(&scene.meshes), instances_from_world(&flight.world));
                let culler = GpuCuller::new(&context, scene, width, height, occlusion_width, occlusion_height);
                Some((context, culler))
            }
            Err(error) => {
                println!(
                    "{error}: running the CPU stages only (cluster and triangle culling and the draw are skipped)"
                );
                None
            }
        }
    };
    let mut gpu_frames: Vec<GpuFrameOutput> = Vec::new();
    let mut per_frame = Vec::with_capacity(args.frames as usize);
    let judge = JudgeSettings {
        reference: ReferenceSettings { width, height, ..ReferenceSettings::default() },
        occlusion_ideal: false,
    };
    let mut accuracy = PathMetrics::default();
    let mut csv = String::from(STATS_HEADER);
    csv.push('\n');
    if let Some(dir) = &args.screenshots {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        if gpu.is_none() {
            println!("--screenshots: no GPU adapter, so nothing is drawn and no screenshot is saved");
        }
    }
    let progress = args.quiet.then(|| indicatif::ProgressBar::new(u64::from(args.frames)));
    for frame in 0..args.frames {
        if let Some(bar) = &progress {
            bar.inc(1);
        }
        let stats = flight.run_frame(frame);
        let mut frame_accuracy = None;
        if args.validate {
            let metrics = judge_frame(&flight.world, &scene.meshes, &judge).metrics;
            frame_accuracy = Some((
                metrics.false_negatives.len(),
                metrics.stages.last().map_or(0, |s| s.false_positives),
                metrics.image_error_pixels,
            ));
            if !args.quiet || !metrics.false_negatives.is_empty() {
                println!(
                    "frame {frame:4}  visible {:6}  false negatives {:4}  false positives {:7}  image error {:6} px",
                    metrics.visible,
                    metrics.false_negatives.len(),
                    metrics.stages.last().map_or(0, |s| s.false_positives),
                    metrics.image_error_pixels
                );
            }
            for missed in &metrics.false_negatives {
                let entity = flight.world.resource::<BoundsStore>().entities()[missed.object];
                println!("  false negative: {entity:?} (store slot {}) culled by {}", missed.object, missed.stage);
            }
            accuracy.add(&metrics);
        }
        if let Some(error) = stats.frustum_error {
            return Err(format!("frame {frame}: {error}"));
        }
        if !args.quiet {
            let camera = flight.world.resource::<Camera>();
            println!(
                "frame {frame:4}  camera ({:8.1} {:6.1} {:8.1})  objects {:8}  bounds updated {:6} in {:7.1} us  \
                 after frustum {:8} in {:7.1} us  occluders {:5} ({:6} tris) in {:7.1} us  \
                 after occlusion {:8} in {:7.1} us",
                camera.position.x,
                camera.position.y,
                camera.position.z,
                stats.objects,
                stats.bounds_recomputed,
                micros(stats.bounds_time),
                stats.after_frustum,
                micros(stats.frustum_time),
                stats.occluders,
                stats.occluder_triangles,
                micros(stats.raster_time),
                stats.after_occlusion,
                micros(stats.occlusion_time),
            );
        }
        let mut gpu_output = None;
        if let Some((context, culler)) = gpu.as_mut() {
            let output = culler.run_world(context, &mut flight.world, &GpuCullSettings::default());
            if let Some(dir) = args.screenshots.as_ref().filter(|_| frame % args.every.max(1) == 0) {
                let image = culler.read_image(context);
                let pixels: Vec<u8> = image.color.iter().flatten().copied().collect();
                let file = dir.join(format!("frame_{frame:05}.png"));
                image::RgbaImage::from_raw(image.width, image.height, pixels)
                    .ok_or("screenshot size mismatch")?
                    .save(&file)
                    .map_err(|e| format!("{}: {e}", file.display()))?;
            }
            gpu_output = Some(output.counters);
            if !args.quiet {
                let c = output.counters;
                println!(
                    "           GPU: clusters {:7} -> {:7}  triangles {:9} -> {:9}  draws {:6}  in {:8.1} us",
                    c.clusters_in,
                    c.clusters_out,
                    c.triangles_in,
                    c.triangles_out,
                    c.draws,
                    micros(output.wall_time)
                );
            }
            gpu_frames.push(output);
        }
        if args.stats.is_some() {
            let c = gpu_output.unwrap_or_default();
            let gpu_us = gpu_frames.last().filter(|_| gpu_output.is_some()).map_or(0.0, |o| micros(o.wall_time));
            let (false_negatives, false_positives, image_error) = frame_accuracy
                .map_or((String::new(), String::new(), String::new()), |(a, b, c)| {
                    (a.to_string(), b.to_string(), c.to_string())
                });
            csv.push_str(&format!(
                "{frame},{},{},{},{},{},{},{},{},{:.1},{:.1},{:.1},{:.1},{gpu_us:.1},{false_negatives},{false_positives},{image_error}\n",
                stats.objects,
                stats.after_frustum,
                stats.after_occlusion,
                c.clusters_in,
                c.clusters_out,
                c.triangles_in,
                c.triangles_out,
                c.draws,
                micros(stats.bounds_time),
                micros(stats.frustum_time),
                micros(stats.raster_time),
                micros(stats.occlusion_time),
            ));
        }
        per_frame.push(stats);
    }
    let errors = flight.world.resource_mut::<BoundsStore>().take_errors();
    for error in &errors {
        eprintln!("rejected: {error}");
    }
    if let Some(bar) = progress {
        bar.finish_and_clear();
    }
    if let Some(file) = &args.stats {
        std::fs::write(file, csv).map_err(|e| format!("{}: {e}", file.display()))?;
        println!("per-frame statistics written to {}", file.display());
    }
    print_summary(&per_frame);
    print_gpu_summary(&gpu_frames);
    if args.validate {
        println!(
            "\nvalidation over {} frames: {} false negatives ({} frames), culling efficiency frustum {:.1}%, \
             + occlusion {:.1}%, image error {} pixels in all",
            accuracy.frames,
            accuracy.false_negatives,
            accuracy.frames_with_false_negatives,
            100.0 * accuracy.efficiency(0),
            100.0 * accuracy.efficiency(1),
            accuracy.image_error_pixels
        );
        let conservative = occlusion.mode == RasterMode::Conservative || !occlusion.enabled;
        if conservative && accuracy.false_negatives > 0 {
            return Err("validation failed: a conservative configuration culled visible objects".into());
        }
    }
    Ok(())
}

fn micros(duration: Duration) -> f64 {
    duration.as_secs_f64() * 1e6
}

fn print_gpu_summary(frames: &[GpuFrameOutput]) {
    if frames.is_empty() {
        return;
    }
    let n = frames.len() as f64;
    let mean = |f: fn(&GpuCounters) -> u32| frames.iter().map(|o| f64::from(f(&o.counters))).sum::<f64>() / n;
    let mut times: Vec<f64> = frames.iter().map(|o| micros(o.wall_time)).collect();
    times.sort_by(f64::total_cmp);
    let wall = times.iter().sum::<f64>() / n;
    println!(
        "{:<10} {wall:>12.1} {:>12.1} {:>12.1} {:>12} {:>9.1}%",
        "clusters",
        times[times.len() / 2],
        times[times.len() - 1],
        format!("{:.0}", mean(|c| c.clusters_out)),
        100.0 * (1.0 - mean(|c| c.clusters_out) / mean(|c| c.clusters_in).max(1.0))
    );
    println!(
        "{:<10} {:>12} {:>12} {:>12} {:>12} {:>9.1}%",
        "triangles",
        "(GPU,",
        "all passes)",
        "",
        format!("{:.0}", mean(|c| c.triangles_out)),
        100.0 * (1.0 - mean(|c| c.triangles_out) / mean(|c| c.triangles_in).max(1.0))
    );
    println!("{:<10} {:>12} {:>12} {:>12} {:>12.0}", "draws", "", "", "", mean(|c| c.draws));
    if let Some(times) = GpuPassTimes::mean(frames) {
        println!("GPU time per pass (mean): {times}");
    }
}

fn print_summary(frames: &[CullStats]) {
    if frames.is_empty() {
        return;
    }
    let n = frames.len() as f64;
    let summarize = |times: Vec<f64>| {
        let mut sorted = times;
        sorted.sort_by(f64::total_cmp);
        let mean = sorted.iter().sum::<f64>() / n;
        (mean, sorted[sorted.len() / 2], sorted[sorted.len() - 1])
    };
    let objects = frames[0].objects as f64;
    let kept = frames.iter().map(|f| f.after_frustum as f64).sum::<f64>() / n;
    println!("\nsummary over {} frames, {} objects", frames.len(), frames[0].objects);
    println!("{:<10} {:>12} {:>12} {:>12} {:>12} {:>10}", "stage", "mean us", "median us", "max us", "kept", "culled");
    let (mean, median, max) = summarize(frames.iter().map(|f| micros(f.bounds_time)).collect());
    let updated = frames.iter().map(|f| f.bounds_recomputed as f64).sum::<f64>() / n;
    println!("{:<10} {mean:>12.1} {median:>12.1} {max:>12.1} {:>12} {:>10}", "bounds", format!("{updated:.0} upd"), "");
    let (mean, median, max) = summarize(frames.iter().map(|f| micros(f.frustum_time)).collect());
    println!(
        "{:<10} {mean:>12.1} {median:>12.1} {max:>12.1} {kept:>12.0} {:>9.1}%",
        "frustum",
        100.0 * (1.0 - kept / objects.max(1.0))
    );
    let triangles = frames.iter().map(|f| f.occluder_triangles as f64).sum::<f64>() / n;
    let (mean, median, max) = summarize(frames.iter().map(|f| micros(f.raster_time)).collect());
    println!(
        "{:<10} {mean:>12.1} {median:>12.1} {max:>12.1} {:>12} {:>10}",
        "raster",
        format!("{triangles:.0} tris"),
        ""
    );
    let after = frames.iter().map(|f| f.after_occlusion as f64).sum::<f64>() / n;
    let (mean, median, max) = summarize(frames.iter().map(|f| micros(f.occlusion_time)).collect());
    println!(
        "{:<10} {mean:>12.1} {median:>12.1} {max:>12.1} {after:>12.0} {:>9.1}%",
        "occlusion",
        100.0 * (1.0 - after / kept.max(1.0))
    );
}
