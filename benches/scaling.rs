//! Parallel scaling of the CPU stages and of the whole CPU frame, over the city's fly-through.
//!
//! - Strong scaling: for each city size (1e4, 1e5, 1e6 and, where memory allows, 1e7 objects), every stage is
//!   timed with 1 thread up to every core: speedup `T(1) / T(p)` and efficiency `speedup / p`.
//! - Weak scaling: `CULLET_SCALING_WEAK` objects (default 100 000) per thread, so the work per thread stays
//!   fixed: efficiency `T(1, n) / T(p, p n)`.
//! - The memory-bandwidth bound: the time to read the seven SoA arrays once, in parallel, per object.
//! - Work and span per stage and for the whole frame (`cullet::parallel`), measured on one thread: work is the
//!   time, span the time outside parallel tasks plus each parallel region's slowest task, and their ratio, the
//!   parallelism, bounds the speed-up on any number of cores. Recorded in a pass of its own (recording times
//!   each task).
//! - An Amdahl fit per stage, `T(p) = serial + parallel / p` (least squares over the thread counts), and the
//!   parts of the occlusion stage timed apart (selection, raster with its pyramid, test), which names the serial ones.
//!
//! Each configuration flies `CULLET_SCALING_FRAMES` frames (default 20) of the path three times with every
//! stage on every frame (no reuse, no gating); a frame's time is the fastest of its three passes (the work is
//! deterministic, the machine is not), a stage's figure the mean of those over the frames. The schedule runs on
//! one thread, inside a rayon pool of `p` threads, so the stages' own parallelism is what scales.
//!
//! The bounding volume hierarchy (`HierarchyCuller`, every stage on every frame) is a series of its own on the same
//! city: its strong scaling and its work and span, into `hierarchy_strong.csv` and `hierarchy_work_span.csv`.
//!
//! Writes `target/scaling/strong.csv`, `weak.csv`, `amdahl.csv`, `parts.csv`, `work_span.csv`, `scaling.png`
//! (speedup and efficiency against threads), `ns_per_object.png` (against object count, with the bandwidth
//! bound) and `parallelism.png` (work over span against object count, on one thread).
//!
//! `cargo bench -p cullet-benches --bench scaling`; `CULLET_SCALING_SIZES=10000,100000` and
//! `CULLET_SCALING_THREADS=1,2,4` choose other sizes and thread counts.

use bevy_ecs::schedule::SingleThreadedExecutor;
use cullet::depth::{DepthPyramid, ScreenView};
use cullet::frustum::{FrustumOptions, cull_frustum};
use cullet::occluders::{Occluder, OccluderInstance, select_occluders};
use cullet::occlusion::test_occlusion;
use cullet::parallel::{self, Stage};
use cullet::pipeline::CullStats;

use cullet::culler::{AdaptiveSettings, Culler, HierarchyCuller, HierarchySettings, OcclusionSettings};
use cullet::raster::rasterize;
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use cullet::{BoundsStore, ObjectTransform, VisibleSet};
use plotters::prelude::*;
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

/// Passes over the frames; each frame keeps its fastest.
const PASSES: usize = 3;
/// Bytes of one object in the SoA arrays: seven `f32`.
const BYTES_PER_OBJECT: f64 = 28.0;
/// Stages timed, in pipeline order, and the whole frame.
const STAGES: [&str; 5] = ["bounds", "frustum", "raster", "occlusion", "frame"];
/// Parts of the occlusion stages timed apart for the street camera.
const PARTS: [&str; 3] = ["select", "raster+pyramid", "test"];

fn env_list(name: &str, default: &[usize]) -> Vec<usize> {
    std::env::var(name)
        .ok()
        .map(|v| v.split(',').filter_map(|n| n.trim().parse::<f64>().ok().map(|n| n as usize)).collect())
        .unwrap_or_else(|| default.to_vec())
}

/// Thread counts from 1 to every core: every count up to 4, then powers of two and the core count.
fn thread_counts(cores: usize) -> Vec<usize> {
    let mut counts: Vec<usize> = (1..=cores.min(4)).chain((3..).map(|k| 1 << k).take_while(|&p| p < cores)).collect();
    counts.push(cores);
    counts.sort_unstable();
    counts.dedup();
    counts
}

/// The times of the culling stages of one frame, in [`STAGES`] order but the whole frame.
type StageTimes = [Duration; 4];

/// Runs frame `frame` of the pipeline's `flight`.
fn pipeline_frame(flight: &mut Flight, frame: u32) -> StageTimes {
    let stats: CullStats = flight.run_frame(frame);
    [stats.bounds_time, stats.frustum_time, stats.raster_time, stats.occlusion_time]
}

/// Runs frame `frame` of `flight` with `culler` (its bounds stage, then the culler).
fn culler_frame(flight: &mut Flight, culler: &mut dyn Culler, frame: u32) -> StageTimes {
    let (bounds_time, culled) = flight.cull_frame(frame, culler);
    [bounds_time, culled.stats.frustum_time, culled.stats.raster_time, culled.stats.occlusion_time]
}

/// Mean per-frame time of each of [`STAGES`], in nanoseconds, for `frames` frames run by `run`.
fn time_frames(frames: u32, mut run: impl FnMut(u32) -> StageTimes) -> [f64; 5] {
    let mut fastest = vec![[f64::INFINITY; 5]; frames as usize];
    for _ in 0..PASSES {
        for frame in 0..frames {
            let start = Instant::now();
            let [bounds, frustum, raster, occlusion] = run(frame);
            let wall = start.elapsed();
            let times = [bounds, frustum, raster, occlusion, wall];
            for (best, time) in fastest[frame as usize].iter_mut().zip(times) {
                *best = best.min(time.as_secs_f64() * 1e9);
            }
        }
    }
    std::array::from_fn(|stage| fastest.iter().map(|f| f[stage]).sum::<f64>() / f64::from(frames))
}

/// Work and span of each of [`STAGES`], in nanoseconds per frame (means over `frames` frames run by `run`,
/// each frame's from the fastest of [`PASSES`] passes), recorded on a pool of one thread.
fn work_span_frames(frames: u32, mut run: impl FnMut(u32) -> StageTimes) -> [(f64, f64); 5] {
    let mut fastest = vec![(Duration::MAX, [(0.0, 0.0); 5]); frames as usize];
    for frame in (0..PASSES).flat_map(|_| 0..frames) {
        parallel::take_recorded();
        parallel::set_recording(true);
        let start = Instant::now();
        let [bounds, frustum, raster, occlusion] = run(frame);
        let wall = start.elapsed();
        parallel::set_recording(false);
        let recorded = parallel::take_recorded();
        let stages = [
            (recorded.stage(Stage::Bounds), bounds),
            (recorded.stage(Stage::Frustum), frustum),
            (recorded.stage(Stage::Raster), raster),
            (recorded.stage(Stage::Occlusion), occlusion),
            (recorded.total(), wall),
        ];
        let best = &mut fastest[frame as usize];
        if wall < best.0 {
            *best =
                (wall, stages.map(|(times, wall)| (wall.as_secs_f64() * 1e9, times.span(wall).as_secs_f64() * 1e9)));
        }
    }
    std::array::from_fn(|stage| {
        let mean = |of: fn((f64, f64)) -> f64| fastest.iter().map(|f| of(f.1[stage])).sum::<f64>() / f64::from(frames);
        (mean(|ws| ws.0), mean(|ws| ws.1))
    })
}

/// A city flown with every stage on every frame, its schedule on the calling thread.
fn flight(objects: usize, frames: u32) -> (CityScene, Flight) {
    let city = CityScene::generate(CityParams::with_objects(objects));
    let mut flight = Flight::new(city.flythrough(), 16.0 / 9.0, frames, OcclusionSettings::default(), |world| {
        city.spawn(world);
    });
    flight.world.insert_resource(AdaptiveSettings::fixed());
    flight.schedule.set_executor(SingleThreadedExecutor::new());
    (city, flight)
}

/// Runs `f` on a rayon pool of `threads` threads.
fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool").install(f)
}

/// The fastest of `runs` runs of `f`, in nanoseconds.
fn fastest_ns(runs: usize, mut f: impl FnMut()) -> f64 {
    (0..runs)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed()
        })
        .min()
        .unwrap_or(Duration::ZERO)
        .as_secs_f64()
        * 1e9
}

/// Nanoseconds per object to read the store's seven arrays once, in parallel. The values are folded by XOR of
/// their bits, which the compiler vectorizes (a float sum would be bound by its own dependency chain).
fn read_ns_per_object(store: &BoundsStore) -> f64 {
    let arrays = store.soa().all();
    let ns = fastest_ns(20, || {
        let folded: u32 = (0..store.padded_len().div_ceil(4096))
            .into_par_iter()
            .map(|block| {
                let range = block * 4096..((block + 1) * 4096).min(store.padded_len());
                arrays.iter().fold(0, |acc, a| a[range.clone()].iter().fold(acc, |x, v| x ^ v.to_bits()))
            })
            .reduce(|| 0, |a, b| a ^ b);
        std::hint::black_box(folded);
    });
    ns / store.padded_len() as f64
}

/// The occlusion stages' parts for the city's street camera, timed apart: [`PARTS`], nanoseconds.
fn time_parts(city: &CityScene, flight: &Flight) -> [f64; 3] {
    let store = flight.world.resource::<BoundsStore>();
    let camera = city.benchmark_cameras()[0].1;
    let settings = OcclusionSettings::default();
    let mut frustum_visible = VisibleSet::default();
    cull_frustum(store, &camera.frustum().expect("a valid camera"), FrustumOptions::default(), &mut frustum_visible);
    let occluder_of = |slot: usize| {
        let entity = store.entities()[slot];
        let occluder = flight.world.get::<Occluder>(entity)?;
        let transform = flight.world.get::<ObjectTransform>(entity)?.0;
        Some(OccluderInstance { occluder, transform })
    };
    let select = || select_occluders(store, &frustum_visible, camera.position, settings.triangle_budget, occluder_of);
    let chosen: Vec<OccluderInstance> = select().into_iter().map(|(_, instance)| instance).collect();
    let view = ScreenView::new(&camera, settings.width, settings.height);
    let mut pyramid = DepthPyramid::default();
    let (mut visible, mut occluded) = (VisibleSet::default(), VisibleSet::default());
    let runs = 15;
    let select_ns = fastest_ns(runs, || {
        std::hint::black_box(select());
    });
    let raster_ns = fastest_ns(runs, || {
        rasterize(&view, &chosen, settings.mode, &mut pyramid);
    });
    let test_ns = fastest_ns(runs, || {
        test_occlusion(store, &frustum_visible, &view, &pyramid, None, &mut visible, &mut occluded);
    });
    [select_ns, raster_ns, test_ns]
}

/// Least-squares fit of `t = serial + parallel / p` over `(p, t)`: `(serial, parallel)`.
fn amdahl_fit(points: &[(usize, f64)]) -> (f64, f64) {
    let n = points.len() as f64;
    let xs: Vec<f64> = points.iter().map(|&(p, _)| 1.0 / p as f64).collect();
    let (mean_x, mean_t) = (xs.iter().sum::<f64>() / n, points.iter().map(|p| p.1).sum::<f64>() / n);
    let covariance: f64 = xs.iter().zip(points).map(|(x, (_, t))| (x - mean_x) * (t - mean_t)).sum();
    let variance: f64 = xs.iter().map(|x| (x - mean_x).powi(2)).sum();
    let parallel = if variance > 0.0 { covariance / variance } else { 0.0 };
    ((mean_t - parallel * mean_x).max(0.0), parallel.max(0.0))
}

/// Efficiency at `p` threads that a serial fraction `s` allows: `1 / (p s + 1 - s)`.
fn amdahl_efficiency(s: f64, p: f64) -> f64 {
    1.0 / (p * s + 1.0 - s)
}

/// Whether `objects` fit in memory, at about 1 KB each (scene, world, store and the judge-free pipeline), with
/// half the available memory to spare.
fn fits_in_memory(objects: usize) -> bool {
    let available_kb = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|info| {
            info.lines()
                .find(|l| l.starts_with("MemAvailable:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<usize>().ok())
        })
        .unwrap_or(usize::MAX);
    objects < available_kb / 2
}

struct Strong {
    objects: usize,
    threads: usize,
    ns: [f64; 5],
}

/// Work and span per frame of each of [`STAGES`] on one thread, nanoseconds.
struct WorkSpan {
    objects: usize,
    work_span: [(f64, f64); 5],
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    if std::env::args().skip(1).any(|a| !a.starts_with('-') && !"scaling".contains(a.as_str())) {
        return Ok(());
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = env_list("CULLET_SCALING_THREADS", &thread_counts(cores));
    let sizes = env_list("CULLET_SCALING_SIZES", &[10_000, 100_000, 1_000_000, 10_000_000]);
    let frames = env_list("CULLET_SCALING_FRAMES", &[20])[0] as u32;
    let weak_base = env_list("CULLET_SCALING_WEAK", &[100_000])[0];
    let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/scaling");
    std::fs::create_dir_all(&out)?;
    println!("{cores} cores; threads {threads:?}; {frames} frames, fastest of {PASSES} passes each");

    // Strong scaling, the bandwidth bound and the occlusion parts.
    let mut strong = Vec::new();
    let mut bandwidth: Vec<(usize, usize, f64)> = Vec::new();
    let mut parts: Vec<(usize, usize, [f64; 3])> = Vec::new();
    let mut work_span = Vec::new();
    let (mut hierarchy, mut hierarchy_work_span) = (Vec::new(), Vec::new());
    for &objects in &sizes {
        if !fits_in_memory(objects) {
            println!("{objects} objects: skipped, not enough memory");
            continue;
        }
        let start = Instant::now();
        let (city, mut flight) = flight(objects, frames);
        println!("{objects} objects: city built in {:.1} s", start.elapsed().as_secs_f64());
        for &p in &threads {
            let ns = with_threads(p, || time_frames(frames, |frame| pipeline_frame(&mut flight, frame)));
            let read = with_threads(p, || read_ns_per_object(flight.world.resource::<BoundsStore>()));
            let part_ns = with_threads(p, || time_parts(&city, &flight));
            println!(
                "  {p:2} threads: {}  | read {read:.3} ns/object | parts {}",
                STAGES.iter().zip(ns).map(|(s, t)| format!("{s} {:.3} ms", t / 1e6)).collect::<Vec<_>>().join(", "),
                PARTS.iter().zip(part_ns).map(|(s, t)| format!("{s} {:.3} ms", t / 1e6)).collect::<Vec<_>>().join(", ")
            );
            strong.push(Strong { objects, threads: p, ns });
            bandwidth.push((objects, p, read));
            parts.push((objects, p, part_ns));
        }
        // After the timed passes: the first frame stores every object.
        let measured = with_threads(1, || work_span_frames(frames, |frame| pipeline_frame(&mut flight, frame)));
        println!("  work/span on 1 thread: {}", work_span_line(&measured));
        work_span.push(WorkSpan { objects, work_span: measured });
        drop(flight);

        // The bounding volume hierarchy on the same city: its tree's build or refit is in its frustum time.
        let mut flight = Flight::for_cullers(city.flythrough(), 16.0 / 9.0, frames, |world| {
            city.spawn(world);
        });
        flight.schedule.set_executor(SingleThreadedExecutor::new());
        let settings = HierarchySettings { adaptive: AdaptiveSettings::fixed(), ..Default::default() };
        let mut culler = HierarchyCuller::new(settings);
        for &p in &threads {
            let ns = with_threads(p, || time_frames(frames, |frame| culler_frame(&mut flight, &mut culler, frame)));
            println!(
                "  hierarchy, {p:2} threads: {}",
                STAGES.iter().zip(ns).map(|(s, t)| format!("{s} {:.3} ms", t / 1e6)).collect::<Vec<_>>().join(", ")
            );
            hierarchy.push(Strong { objects, threads: p, ns });
        }
        let measured =
            with_threads(1, || work_span_frames(frames, |frame| culler_frame(&mut flight, &mut culler, frame)));
        println!("  hierarchy work/span on 1 thread: {}", work_span_line(&measured));
        hierarchy_work_span.push(WorkSpan { objects, work_span: measured });
    }

    // Weak scaling: the work per thread fixed.
    let mut weak = Vec::new();
    for &p in &threads {
        let objects = weak_base * p;
        if !fits_in_memory(objects) {
            continue;
        }
        let (_, mut flight) = flight(objects, frames);
        let ns = with_threads(p, || time_frames(frames, |frame| pipeline_frame(&mut flight, frame)));
        println!("weak: {p:2} threads, {objects} objects: frame {:.3} ms", ns[4] / 1e6);
        weak.push(Strong { objects, threads: p, ns });
    }

    // CSVs.
    std::fs::write(out.join("strong.csv"), strong_csv(&strong))?;
    std::fs::write(out.join("hierarchy_strong.csv"), strong_csv(&hierarchy))?;
    let mut csv = String::from("objects,threads,stage,ns_per_frame,efficiency\n");
    let weak_one = weak.iter().find(|r| r.threads == 1);
    for row in &weak {
        for (stage, (&t, t1)) in STAGES.iter().zip(row.ns.iter().zip(weak_one.map_or(row.ns, |r| r.ns))) {
            writeln!(csv, "{},{},{stage},{t:.0},{:.3}", row.objects, row.threads, t1 / t)?;
        }
    }
    std::fs::write(out.join("weak.csv"), &csv)?;
    let mut csv = String::from("objects,threads,part,ns\n");
    for (objects, p, part_ns) in &parts {
        for (part, ns) in PARTS.iter().zip(part_ns) {
            writeln!(csv, "{objects},{p},{part},{ns:.0}")?;
        }
    }
    std::fs::write(out.join("parts.csv"), &csv)?;
    std::fs::write(out.join("work_span.csv"), work_span_csv(&work_span))?;
    std::fs::write(out.join("hierarchy_work_span.csv"), work_span_csv(&hierarchy_work_span))?;

    // The Amdahl fit of every stage and part, per size.
    println!(
        "\nAmdahl fit T(p) = serial + parallel / p, serial fraction s, and the efficiency s allows at 16 threads:"
    );
    let mut csv = String::from("objects,what,serial_ns,parallel_ns,serial_fraction,efficiency_at_16\n");
    for &objects in &sizes {
        let rows: Vec<&Strong> = strong.iter().filter(|r| r.objects == objects).collect();
        let part_rows: Vec<_> = parts.iter().filter(|r| r.0 == objects).collect();
        if rows.len() < 2 {
            continue;
        }
        let named = STAGES
            .iter()
            .enumerate()
            .map(|(i, stage)| (format!("stage {stage}"), rows.iter().map(|r| (r.threads, r.ns[i])).collect::<Vec<_>>()))
            .chain(PARTS.iter().enumerate().map(|(i, part)| {
                (format!("part {part}"), part_rows.iter().map(|r| (r.1, r.2[i])).collect::<Vec<_>>())
            }));
        for (what, points) in named {
            let (serial, parallel) = amdahl_fit(&points);
            let s = serial / (serial + parallel).max(f64::MIN_POSITIVE);
            let e16 = amdahl_efficiency(s, 16.0);
            println!(
                "  {objects:>9} {what:<16} serial {:8.3} ms  parallel {:8.3} ms  s = {:5.3}  E(16) = {:5.1}%",
                serial / 1e6,
                parallel / 1e6,
                s,
                100.0 * e16
            );
            writeln!(csv, "{objects},{what},{serial:.0},{parallel:.0},{s:.4},{e16:.3}")?;
        }
    }
    std::fs::write(out.join("amdahl.csv"), &csv)?;

    plot_scaling(&strong, &weak, &out.join("scaling.png"))?;
    plot_per_object(&strong, &bandwidth, &out.join("ns_per_object.png"))?;
    plot_parallelism(&work_span, &out.join("parallelism.png"))?;
    println!("\nwrote {}", out.display());
    Ok(())
}

/// Each stage's work, span (ms) and parallelism, on one line.
fn work_span_line(measured: &[(f64, f64); 5]) -> String {
    let stage = |(name, (work, span)): (&&str, &(f64, f64))| {
        format!("{name} {:.3}/{:.3} ms = {:.1}", work / 1e6, span / 1e6, work / span)
    };
    STAGES.iter().zip(measured).map(stage).collect::<Vec<_>>().join(", ")
}

/// Strong scaling rows as CSV: per size, thread count and stage, the time a frame, per object, and the
/// speed-up and efficiency against one thread.
fn strong_csv(rows: &[Strong]) -> String {
    let mut csv = String::from("objects,threads,stage,ns_per_frame,ns_per_object,speedup,efficiency\n");
    for row in rows {
        let one = rows.iter().find(|r| r.objects == row.objects && r.threads == 1).unwrap_or(row);
        for (stage, (&t, &t1)) in STAGES.iter().zip(row.ns.iter().zip(&one.ns)) {
            let speedup = t1 / t;
            let (per_object, efficiency) = (t / row.objects as f64, speedup / row.threads as f64);
            let (objects, threads) = (row.objects, row.threads);
            writeln!(csv, "{objects},{threads},{stage},{t:.0},{per_object:.4},{speedup:.3},{efficiency:.3}").unwrap();
        }
    }
    csv
}

/// Work and span rows as CSV: per size and stage, work, span and their ratio.
fn work_span_csv(rows: &[WorkSpan]) -> String {
    let mut csv = String::from("objects,stage,work_ns,span_ns,parallelism\n");
    for row in rows {
        for (stage, (work, span)) in STAGES.iter().zip(row.work_span) {
            writeln!(csv, "{},{stage},{work:.0},{span:.0},{:.2}", row.objects, work / span).unwrap();
        }
    }
    csv
}

/// Colour of each of [`STAGES`].
fn stage_color(stage: usize) -> RGBColor {
    [RGBColor(230, 120, 0), BLUE, RGBColor(0, 150, 0), MAGENTA, BLACK][stage]
}

/// Stage `stage`'s `points` as a line with dots, in its colour, with a legend entry.
fn draw_stage<'a, DB, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    stage: usize,
    points: Vec<(f64, f64)>,
) -> Result<(), Box<dyn std::error::Error>>
where
    DB: DrawingBackend + 'a,
    DB::ErrorType: 'static,
    CT: CoordTranslate<From = (f64, f64)>,
{
    let color = stage_color(stage);
    chart
        .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))?
        .label(STAGES[stage])
        .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color.stroke_width(2)));
    chart.draw_series(points.into_iter().map(|p| Circle::new(p, 4, color.filled())))?;
    Ok(())
}

/// Speedup and efficiency against threads for the largest city measured on several threads, and weak-scaling
/// efficiency.
fn plot_scaling(strong: &[Strong], weak: &[Strong], path: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let Some(objects) = strong.iter().filter(|r| r.threads > 1).map(|r| r.objects).max() else { return Ok(()) };
    let rows: Vec<&Strong> = strong.iter().filter(|r| r.objects == objects).collect();
    let one = rows.iter().find(|r| r.threads == 1).map_or(rows[0].ns, |r| r.ns);
    let max_threads = rows.iter().map(|r| r.threads).max().unwrap_or(1) as f64;
    let root = BitMapBackend::new(path, (2100, 700)).into_drawing_area();
    root.fill(&WHITE)?;
    let root =
        root.titled(&format!("Cullet CPU stages: parallel scaling, {objects}-object city"), ("sans-serif", 26))?;
    let panels = root.split_evenly((1, 3));
    let weak_one = weak.iter().find(|r| r.threads == 1).map(|r| r.ns);
    type Series<'a> = (&'a str, Box<dyn Fn(&Strong, usize) -> f64 + 'a>, f64);
    let specs: [Series; 3] = [
        ("speedup (strong scaling)", Box::new(|r: &Strong, s: usize| one[s] / r.ns[s]), max_threads * 1.1),
        ("efficiency (strong scaling)", Box::new(|r: &Strong, s: usize| one[s] / r.ns[s] / r.threads as f64), 1.2),
        (
            "efficiency (weak scaling, objects per thread fixed)",
            Box::new(move |r: &Strong, s: usize| weak_one.map_or(1.0, |w| w[s] / r.ns[s])),
            1.2,
        ),
    ];
    for (panel, (label, value, max_y)) in panels.iter().zip(specs) {
        let source: Vec<&Strong> = if label.contains("weak") { weak.iter().collect() } else { rows.clone() };
        let mut chart = ChartBuilder::on(panel)
            .margin(20)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(0.5..max_threads + 0.5, 0.0..max_y)?;
        chart.configure_mesh().x_desc("threads").y_desc(label).draw()?;
        let ideal: Vec<(f64, f64)> = if label.starts_with("speedup") {
            vec![(1.0, 1.0), (max_threads, max_threads)]
        } else {
            vec![(1.0, 1.0), (max_threads, 1.0)]
        };
        chart.draw_series(LineSeries::new(ideal, BLACK.mix(0.3).stroke_width(1)))?;
        for s in 0..STAGES.len() {
            draw_stage(&mut chart, s, source.iter().map(|r| (r.threads as f64, value(r, s))).collect())?;
        }
        chart.configure_series_labels().position(SeriesLabelPosition::LowerLeft).border_style(BLACK).draw()?;
    }
    root.present()?;
    Ok(())
}

/// Nanoseconds per object against object count on the most threads, per stage, with the time to read one
/// object's 28 bytes at the bandwidth measured there.
fn plot_per_object(
    strong: &[Strong],
    bandwidth: &[(usize, usize, f64)],
    path: &Path,
) -> Result<(), Box<dyn std::error::Error>> {
    let Some(threads) = strong.iter().map(|r| r.threads).max() else { return Ok(()) };
    let rows: Vec<&Strong> = strong.iter().filter(|r| r.threads == threads).collect();
    let (min_n, max_n) = (
        rows.iter().map(|r| r.objects).min().unwrap_or(1) as f64,
        rows.iter().map(|r| r.objects).max().unwrap_or(1) as f64,
    );
    let per_object = |r: &Strong, s: usize| r.ns[s] / r.objects as f64;
    let max_y = rows.iter().flat_map(|r| (0..STAGES.len()).map(move |s| per_object(r, s))).fold(0.0, f64::max) * 1.5;
    let read = bandwidth.iter().filter(|b| b.1 == threads).map(|b| b.2).fold(f64::INFINITY, f64::min);
    let root = BitMapBackend::new(path, (1200, 800)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("Cullet CPU stages: time per object, {threads} threads"), ("sans-serif", 24))
        .margin(20)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d((min_n * 0.8..max_n * 1.25).log_scale(), (0.001..max_y.max(0.01)).log_scale())?;
    chart.configure_mesh().x_desc("objects").y_desc("ns per object per frame").draw()?;
    for s in 0..STAGES.len() {
        draw_stage(&mut chart, s, rows.iter().map(|r| (r.objects as f64, per_object(r, s))).collect())?;
    }
    if read.is_finite() {
        let label = format!(
            "bandwidth bound: reading one object's {BYTES_PER_OBJECT} bytes once ({:.1} GB/s)",
            BYTES_PER_OBJECT / read
        );
        chart
            .draw_series(LineSeries::new([(min_n * 0.8, read), (max_n * 1.25, read)], RED.stroke_width(2)))?
            .label(label)
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED.stroke_width(2)));
    }
    chart.configure_series_labels().position(SeriesLabelPosition::UpperRight).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}

/// Work over span against object count, per stage.
fn plot_parallelism(rows: &[WorkSpan], path: &Path) -> Result<(), Box<dyn std::error::Error>> {
    if rows.is_empty() {
        return Ok(());
    }
    let (min_n, max_n) = (
        rows.iter().map(|r| r.objects).min().unwrap_or(1) as f64,
        rows.iter().map(|r| r.objects).max().unwrap_or(1) as f64,
    );
    let parallelism = |r: &WorkSpan, s: usize| r.work_span[s].0 / r.work_span[s].1;
    let max_y = rows.iter().flat_map(|r| (0..STAGES.len()).map(move |s| parallelism(r, s))).fold(64.0, f64::max) * 1.5;
    let root = BitMapBackend::new(path, (1200, 800)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption("Cullet CPU stages: work over span, measured on one thread", ("sans-serif", 24))
        .margin(20)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d((min_n * 0.8..max_n * 1.25).log_scale(), (0.8..max_y).log_scale())?;
    chart.configure_mesh().x_desc("objects").y_desc("parallelism (work / span): the speed-up bound").draw()?;
    for s in 0..STAGES.len() {
        draw_stage(&mut chart, s, rows.iter().map(|r| (r.objects as f64, parallelism(r, s))).collect())?;
    }
    chart.configure_series_labels().position(SeriesLabelPosition::UpperLeft).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}
