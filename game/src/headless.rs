//! The headless run: the camera path flown frame by frame, with statistics, validation and screenshots.

use crate::report::{
    LightViewColumns, LightViewTotals, STATS_HEADER, gating_and_savings_columns, lod_columns, micros,
    print_gpu_summary, print_lod_summary, print_savings, print_summary,
};
use crate::validation::Validation;
use crate::{Args, CullerChoice, Prepared, gpu_error_message};
use cullet::culler::{CullScene, Culled, Culler, ShadowFrustaCuller, ShadowFrustaSettings};
use cullet::depth::DepthBuffer;
use cullet::draw_cost::{DrawSavings, SlotTriangles};
use cullet::gpu::{GpuContext, GpuCullSettings, GpuCuller, GpuFrameOutput, ReadBack};
use cullet::gpu::{QueryGridCuller, QueryGridSettings, QueryGridStats};
use cullet::lod::LodSelection;
use cullet::{BoundsStore, Camera};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressFinish, ProgressStyle};
use std::io::IsTerminal;
use std::time::Instant;

/// The run's progress bar, on stderr: hidden where stderr is not a terminal, with `--quiet` (the summary only)
/// and with `--verbose` (whose line per frame shows the progress).
fn progress_bar(args: &Args) -> ProgressBar {
    if args.quiet || args.verbose || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let style = ProgressStyle::with_template("{msg} [{wide_bar}] {pos}/{len} frames, {eta} left")
        .expect("a valid progress bar template")
        .progress_chars("=> ");
    ProgressBar::with_draw_target(Some(u64::from(args.headless_frames())), ProgressDrawTarget::stderr())
        .with_style(style)
        .with_message("flying the camera path")
        // Cleared when dropped too, as on an error: the message follows on a clean line.
        .with_finish(ProgressFinish::AndClear)
}

/// A culler other than the pipeline's stages, chosen with `--culler`.
enum OwnCuller {
    ShadowFrusta(ShadowFrustaCuller),
    QueryGrid(Box<QueryGridCuller>),
}

impl OwnCuller {
    fn culler(&mut self) -> &mut dyn Culler {
        match self {
            Self::ShadowFrusta(culler) => culler,
            Self::QueryGrid(culler) => culler.as_mut(),
        }
    }
}

/// The query grid's work over the run.
#[derive(Default)]
struct QueryGridTotals {
    frames: usize,
    queries: usize,
    cells_in_frustum: usize,
    cells_drawn: usize,
    starved: usize,
    late: usize,
}

impl QueryGridTotals {
    fn add(&mut self, stats: &QueryGridStats) {
        self.frames += 1;
        self.queries += stats.queries;
        self.cells_in_frustum += stats.cells_in_frustum;
        self.cells_drawn += stats.cells_drawn;
        self.starved += stats.starved;
        self.late += usize::from(stats.results_late);
    }

    /// One line a frame on average, where the query grid ran.
    fn print(&self) {
        if self.frames == 0 {
            return;
        }
        let per_frame = |n: usize| n as f64 / self.frames as f64;
        println!(
            "query grid: {:.0} cells in view a frame, {:.0} drawn, {:.0} queries, {:.0} starved by the cap; \
             results late in {} of {} frames",
            per_frame(self.cells_in_frustum),
            per_frame(self.cells_drawn),
            per_frame(self.queries),
            per_frame(self.starved),
            self.late,
            self.frames
        );
    }
}

/// Flies the camera path frame by frame without a window: a progress bar (or with `--verbose` a line per
/// frame), the stats CSV, screenshots, validation against the ground truth, and the summary.
pub fn run(args: &Args, prepared: Prepared) -> Result<(), String> {
    let Prepared { scene, mut flight, resolution: (width, height), .. } = prepared;
    let mut gpu = if args.cpu_only {
        println!("--cpu-only: GPU cluster culling, triangle culling and the draw are skipped");
        None
    } else {
        match GpuContext::new() {
            Ok(context) => {
                let info = &context.adapter_info;
                println!("GPU: {} ({:?}, {:?})", info.name, info.backend, info.device_type);
                let mut culler = GpuCuller::for_world(&context, &flight.world, &scene.meshes, (width, height));
                if args.late_readback {
                    culler.set_read_back(ReadBack::Late);
                    println!("--late-readback: each frame's GPU counters are read at the next frame");
                }
                Some((context, culler))
            }
            Err(error) => {
                println!(
                    "{}\nrunning the CPU stages only: cluster and triangle culling and the draw are skipped",
                    gpu_error_message(&error)
                );
                None
            }
        }
    };
    let mut gpu_frames: Vec<GpuFrameOutput> = Vec::new();
    let mut per_frame = Vec::with_capacity(args.headless_frames() as usize);
    let mut lod_frames = Vec::new();
    let mut savings = Vec::with_capacity(args.headless_frames() as usize);
    let slot_triangles = SlotTriangles::of_world(&flight.world, &scene.meshes);
    let mut validation = args.validate.then(|| Validation::new(width, height));
    let mut light_views = LightViewTotals::default();
    let light_view_columns = LightViewColumns::of_world(&flight.world);
    let mut csv = format!("{STATS_HEADER}{}\n", light_view_columns.header());
    if let Some(dir) = &args.screenshots {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        if gpu.is_none() {
            println!("--screenshots: no GPU adapter, so nothing is drawn and no screenshot is saved");
        }
    }
    // A culler other than the stages, run after the pipeline (whose occlusion stage is then off).
    let mut own_culler = match args.culler {
        CullerChoice::Stages => None,
        CullerChoice::ShadowFrusta => {
            let budget = args.occluder_budget.unwrap_or(ShadowFrustaSettings::default().triangle_budget);
            let settings = ShadowFrustaSettings { triangle_budget: budget, ..Default::default() };
            Some(OwnCuller::ShadowFrusta(ShadowFrustaCuller::new(settings)))
        }
        CullerChoice::QueryGrid => {
            let Some((context, _)) = gpu.as_ref() else {
                return Err("--culler query-grid draws and queries on the GPU: it needs a GPU adapter".into());
            };
            let defaults = QueryGridSettings::default();
            let query_cap = args.query_cap.map_or(defaults.query_cap, |cap| (cap > 0).then_some(cap));
            let settings = QueryGridSettings { cell_size: args.cell_size, query_cap, ..defaults };
            let culler = QueryGridCuller::new(context, &flight.world, &scene.meshes, (width, height), settings);
            Some(OwnCuller::QueryGrid(Box::new(culler)))
        }
    };
    if let Some(culler) = own_culler.as_mut() {
        println!("culler: {}", culler.culler().name());
    }
    let own_is_conservative = own_culler.as_mut().is_none_or(|c| c.culler().is_conservative((width, height)));
    let mut query_grid = QueryGridTotals::default();
    let progress = progress_bar(args);
    let frames_start = Instant::now();
    for frame in 0..args.headless_frames() {
        let mut stats = flight.run_frame(frame);
        let camera = *flight.world.resource::<Camera>();
        let own: Option<Culled> =
            own_culler.as_mut().map(|culler| culler.culler().cull(&CullScene::new(&flight.world), &camera));
        if let Some(culled) = &own {
            let own = &culled.stats;
            (stats.after_occlusion, stats.occluders, stats.occluder_triangles) =
                (own.after_occlusion, own.occluders, own.occluder_triangles);
            (stats.raster_time, stats.occlusion_time) = (own.raster_time, own.occlusion_time);
        }
        light_views.add(&flight.world);
        let mut frame_accuracy = None;
        if let Some(validation) = validation.as_mut() {
            let metrics = match &own {
                Some(culled) => {
                    let conservative = own_is_conservative;
                    validation.judge_culled(&flight.world, &camera, culled, conservative, &scene.meshes)
                }
                None => validation.judge(&flight.world, &scene.meshes),
            };
            frame_accuracy = Some((
                metrics.false_negatives.len(),
                metrics.stages.last().map_or(0, |s| s.false_positives),
                metrics.image_error_pixels,
            ));
            // A frame with false negatives is printed whatever the flags, above the progress bar.
            progress.suspend(|| {
                if args.verbose || !metrics.false_negatives.is_empty() {
                    println!(
                        "frame {frame:4}  visible {:6}  false negatives {:4}  false positives {:7}  image error {:6} \
                         px",
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
            });
        }
        if let Some(error) = stats.frustum_error {
            return Err(format!("frame {frame}: {error}"));
        }
        if args.verbose {
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
        // The culler's sets borrow only the culler: the world stays free for the GPU passes.
        let kept_sets = own.as_ref().map(|culled| (culled.stages[0].1, culled.kept()));
        let mut gpu_output: Option<GpuFrameOutput> = None;
        if let Some((context, culler)) = gpu.as_mut() {
            let settings = GpuCullSettings { two_phase: args.two_phase, ..GpuCullSettings::default() };
            let output = match kept_sets {
                Some((_, kept)) => {
                    let visible: Vec<u32> = kept.iter().map(|slot| slot as u32).collect();
                    culler.run_world_culled(context, &mut flight.world, &visible, &DepthBuffer::default(), &settings)
                }
                None => culler.run_world(context, &mut flight.world, &settings),
            }
            .map_err(|e| e.to_string())?;
            if let Some(dir) = args.screenshots.as_ref().filter(|_| frame % args.every.max(1) == 0) {
                let image = culler.read_image(context).map_err(|e| e.to_string())?;
                let pixels: Vec<u8> = image.color.iter().flatten().copied().collect();
                let file = dir.join(format!("frame_{frame:05}.png"));
                image::RgbaImage::from_raw(image.width, image.height, pixels)
                    .ok_or("screenshot size mismatch")?
                    .save(&file)
                    .map_err(|e| format!("{}: {e}", file.display()))?;
            }
            gpu_output = Some(output.clone());
            if args.verbose {
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
            // Read a frame late, the first frame's counters never come: it returns none.
            if !(output.counters_late && frame == 0) {
                gpu_frames.push(output);
            }
        }
        let saved = match kept_sets {
            Some((after_frustum, kept)) => {
                DrawSavings::of_sets(&slot_triangles, after_frustum, kept, gpu_output.as_ref())
            }
            None => DrawSavings::of_frame(&flight.world, &slot_triangles, gpu_output.as_ref()),
        };
        if args.stats.is_some() {
            let c = gpu_output.as_ref().map(|o| o.counters).unwrap_or_default();
            let gpu_us = gpu_output.as_ref().map_or(0.0, |o| micros(o.wall_time));
            let (false_negatives, false_positives, image_error) = frame_accuracy
                .map_or((String::new(), String::new(), String::new()), |(a, b, c)| {
                    (a.to_string(), b.to_string(), c.to_string())
                });
            csv.push_str(&format!(
                "{frame},{},{},{},{},{},{},{},{},{:.1},{:.1},{:.1},{:.1},{gpu_us:.1},{false_negatives},{false_positives},{image_error},{},{},{},{},{}{}\n",
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
                u8::from(stats.reused),
                stats.retested,
                u8::from(stats.occlusion_gated),
                gating_and_savings_columns(gpu_output.as_ref(), &saved),
                lod_columns(flight.world.get_resource::<LodSelection>().map(LodSelection::stats)),
                light_view_columns.row(&flight.world),
            ));
        }
        per_frame.push(stats);
        if let Some(selection) = flight.world.get_resource::<LodSelection>() {
            lod_frames.push(selection.stats());
        }
        savings.push(saved);
        if let Some(OwnCuller::QueryGrid(grid)) = &own_culler {
            query_grid.add(&grid.stats());
        }
        progress.inc(1);
    }
    progress.finish_and_clear();
    let frames_time = frames_start.elapsed();
    let errors = flight.world.resource_mut::<BoundsStore>().take_errors();
    for error in &errors {
        eprintln!("rejected: {error}");
    }
    if let Some(file) = &args.stats {
        std::fs::write(file, csv).map_err(|e| format!("{}: {e}", file.display()))?;
        println!("per-frame statistics written to {}", file.display());
    }
    print_summary(&per_frame);
    print_lod_summary(&lod_frames);
    query_grid.print();
    println!(
        "{} frames in {:.2} s: {:.2} ms a frame, wall time (every stage{}, and all this run adds)",
        per_frame.len(),
        frames_time.as_secs_f64(),
        frames_time.as_secs_f64() * 1e3 / per_frame.len().max(1) as f64,
        match (gpu.is_some(), args.late_readback) {
            (false, _) => "",
            (true, true) => ", the GPU's work overlapping the next frame's CPU stages",
            (true, false) => ", the GPU's work waited for",
        }
    );
    light_views.print();
    print_gpu_summary(&gpu_frames);
    if args.late_readback {
        // A frame's savings pair its CPU sets with its GPU counters, which came with the next frame.
        println!("--late-readback: the draw savings are not summarized");
    } else {
        print_savings(&savings, &gpu_frames);
    }
    if let Some(validation) = validation {
        println!("\n{}", validation.summary());
        validation.verdict()?;
    }
    Ok(())
}
