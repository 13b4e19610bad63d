//! GPU passes over the city's fly-through: time per pass (timestamp queries where the adapter has them, else
//! only the wall time of a finished queue), what each test removes, and draws per frame.
//!
//! `cargo bench -p cullet-benches --bench gpu`; `CULLET_GPU_OBJECTS` (default 100000), `CULLET_GPU_FRAMES`
//! (default 100) and `CULLET_GPU_RESOLUTIONS` (default `1920x1080`, a comma-separated list) size the run. On a
//! software adapter (lavapipe) times mean little: read the counts and ratios.
//!
//! `CULLET_GPU_GATES=1` adds what tunes [`GpuGating`]: on the city, the field and the CAD scene, every pass
//! against the triangle pass skipped (its cost against the draw time it saves, and the share of triangles it
//! must remove to pay); and on cities of 10 to 100 000 objects, the cluster pass against none (the candidate
//! clusters under which it cannot pay).
//!
//! `CULLET_GPU_TWO_PHASE=1` adds one phase against two ([`GpuCullSettings::two_phase`]) with the software
//! occluders on and off, on the city and on truck_town and zdm2 from `../shared/scenes` (automatic occluders
//! where on: they have no artist ones): triangles and draws a frame, what each phase drew (and of the late
//! phase, its occluder step), and GPU time; and
//! two phases with the CPU occluder stage gated by what it saves ([`GpuGating::min_occluder_benefit`]), with
//! the stage's CPU time and the frames it ran.
use cullet::CameraPath;
use cullet::culler::OcclusionSettings;
use cullet::gpu::cluster_cull::ClusterVerdict;
use cullet::gpu::triangle_cull::TriangleVerdict;
use cullet::gpu::{GpuContext, GpuCounters, GpuCullSettings, GpuCuller, GpuFrameOutput, GpuGating, GpuPassTimes};
use cullet::pipeline::{CameraCuller, CullStats};
use cullet::scene::Scene;
use cullet::scene::auto_occluders::{AutoOccluderSettings, add_auto_occluders};
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use cullet::scene::gltf_import::load_gltf;
use std::time::Duration;

fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// `CULLET_GPU_RESOLUTIONS`: `WIDTHxHEIGHT` sizes, comma-separated.
fn resolutions() -> Vec<(u32, u32)> {
    let list = std::env::var("CULLET_GPU_RESOLUTIONS").unwrap_or_else(|_| "1920x1080".into());
    list.split(',')
        .filter_map(|size| {
            let (width, height) = size.trim().split_once('x')?;
            Some((width.parse().ok()?, height.parse().ok()?))
        })
        .collect()
}

fn city(objects: usize) -> (Scene, CameraPath) {
    let city = CityScene::generate(CityParams::with_objects(objects));
    let path = city.flythrough();
    (city.scene, path)
}

/// Flies `frames` frames of `path` over `scene` at `size`, the CPU stages then the GPU passes with `gating`;
/// the outputs of every frame, and the mesh library's clusters and triangles.
fn fly(
    context: &GpuContext,
    scene: &(Scene, CameraPath),
    frames: u32,
    size: (u32, u32),
    gating: GpuGating,
) -> (Vec<GpuFrameOutput>, (usize, usize)) {
    let (outputs, library, _, _) =
        fly_with(context, scene, frames, size, (gating, GpuCullSettings::default(), OcclusionSettings::default()));
    (outputs, library)
}

/// [`fly`] with GPU `settings` and CPU `occlusion` settings; also the triangles of the frustum stage's
/// survivors, each frame (what every later test removes from), and each frame's CPU stats.
fn fly_with(
    context: &GpuContext,
    (scene, path): &(Scene, CameraPath),
    frames: u32,
    size: (u32, u32),
    (gating, settings, occlusion): (GpuGating, GpuCullSettings, OcclusionSettings),
) -> (Vec<GpuFrameOutput>, (usize, usize), Vec<f64>, Vec<CullStats>) {
    let aspect = size.0 as f32 / size.1 as f32;
    let mut flight = Flight::new(path.clone(), aspect, frames, occlusion, |world| {
        scene.spawn(world);
    });
    let mut culler = GpuCuller::for_world(context, &flight.world, &scene.meshes, size);
    culler.set_gating(gating);
    let library = &culler.scene().library;
    let library = (library.clusters.len(), library.indices.len() / 3);
    let (mut in_frustum, mut cpu) = (Vec::new(), Vec::new());
    let outputs = (0..frames)
        .map(|frame| {
            cpu.push(flight.run_frame(frame));
            let gpu_scene = culler.scene();
            let frustum = flight.world.resource::<CameraCuller>().frustum_visible();
            let triangles = frustum.iter().flat_map(|slot| {
                gpu_scene.library.clusters_of(gpu_scene.instances()[slot].mesh).iter().map(|c| c.triangle_count)
            });
            in_frustum.push(triangles.map(f64::from).sum());
            culler.run_world(context, &mut flight.world, &settings).expect("GPU frame")
        })
        .collect();
    (outputs, library, in_frustum, cpu)
}

/// One phase against two, software occluders on and off, and two phases with the occluder stage gated
/// ([`GpuGating::min_occluder_benefit`], every other pass every frame), on `scene` (`name`): per frame, the
/// triangles drawn and the share of the frustum's survivors' triangles removed, draws, the triangles each
/// phase drew, GPU time (timestamps where the adapter has them), and the CPU occluder stage's time and
/// frames run.
fn two_phase_rows(context: &GpuContext, name: &str, scene: &(Scene, CameraPath), frames: u32, size: (u32, u32)) {
    let gated = GpuGating { min_occluder_benefit: GpuGating::default().min_occluder_benefit, ..GpuGating::fixed() };
    let gated = GpuGating { reprobe_every: GpuGating::default().reprobe_every, ..gated };
    let rows = [("on", false, GpuGating::fixed()), ("on", true, GpuGating::fixed()), ("gated", true, gated)];
    let rows = rows.into_iter().chain([("off", false, GpuGating::fixed()), ("off", true, GpuGating::fixed())]);
    for (occluders, two_phase, gating) in rows {
        let occlusion = OcclusionSettings { enabled: occluders != "off", ..OcclusionSettings::default() };
        let settings = GpuCullSettings { two_phase, ..GpuCullSettings::default() };
        // Every pass every frame: the gates would decide differently for the two (fewer candidates leave the
        // triangle pass less to remove), which is not what the table compares.
        let (outputs, _, in_frustum, cpu) = fly_with(context, scene, frames, size, (gating, settings, occlusion));
        let drawn = mean_of(&outputs, |o| f64::from(o.counters.triangles_out));
        let removed = 100.0 * (1.0 - drawn / (in_frustum.iter().sum::<f64>() / frames as f64).max(1.0));
        let phase = |f: fn(&cullet::gpu::PhaseCounters) -> u32| {
            mean_of(&outputs, |o| o.phases.map_or(0.0, |p| f64::from(f(&p))))
        };
        let gpu = GpuPassTimes::mean(&outputs).map_or(String::from("-"), |t| {
            let total = t.hzb + t.clusters + t.triangles + t.draw;
            let late = t.merge + t.late_clusters + t.late_triangles + t.late_draw + t.final_merge + t.final_marks;
            let step = t.occluder_clusters + t.occluder_triangles + t.occluder_draw + t.occluder_merge;
            format!("{:.0}", us(total + late + step))
        });
        let occluder_stage = cpu.iter().map(|stats| us(stats.raster_time + stats.occlusion_time)).sum::<f64>();
        let stage_ran = cpu.iter().filter(|stats| stats.occluders > 0).count();
        println!(
            "{name:<11} {occluders:>9} {:>6} {drawn:>10.0} {removed:>8.1}% {:>7.0} {:>10.0} {:>10.0} {:>10.0} {:>9.0} \
             {gpu:>10} {:>9.0} {:>9.0} {stage_ran:>6}",
            if two_phase { "two" } else { "one" },
            mean_of(&outputs, |o| f64::from(o.counters.draws)),
            phase(|p| p.early.triangles_out),
            phase(|p| p.late.triangles_out),
            phase(|p| p.late_occluders.map_or(0, |step| step.triangles_out)),
            phase(|p| p.late.clusters_hzb),
            mean_of(&outputs, |o| us(o.wall_time)),
            occluder_stage / frames as f64,
        );
    }
}

/// The scenes of the two-phase table: the city, and the shared third-party scenes present, with automatic
/// occluders.
fn two_phase_table(context: &GpuContext, city: &(Scene, CameraPath), objects: usize, frames: u32, size: (u32, u32)) {
    println!(
        "\none phase against two, {frames} frames at {}x{}, every pass every frame (per frame; removed: of the \
         frustum's survivors' triangles; GPU: every pass, timestamps)",
        size.0, size.1
    );
    println!(
        "{:<11} {:>9} {:>6} {:>10} {:>9} {:>7} {:>10} {:>10} {:>10} {:>9} {:>10} {:>9} {:>9} {:>6}",
        "scene",
        "occluders",
        "phases",
        "triangles",
        "removed",
        "draws",
        "early tris",
        "late tris",
        "step tris",
        "late HZB",
        "GPU us",
        "wall us",
        "occl. us",
        "ran"
    );
    two_phase_rows(context, &format!("city:{objects}"), city, frames, size);
    let shared = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes");
    for (name, file) in [("truck_town", "truck_town/town_model.gltf"), ("zdm2", "zdm2/zdm2.glb")] {
        match load_gltf(&shared.join(file)) {
            Ok(mut loaded) => {
                add_auto_occluders(&mut loaded.scene, &AutoOccluderSettings::default());
                let path = loaded.scene.orbit_path();
                two_phase_rows(context, name, &(loaded.scene, path), frames, size);
            }
            Err(error) => println!("SKIPPED {name}: {error}"),
        }
    }
}

fn mean_of(outputs: &[GpuFrameOutput], f: impl Fn(&GpuFrameOutput) -> f64) -> f64 {
    outputs.iter().map(f).sum::<f64>() / outputs.len().max(1) as f64
}

fn us(duration: Duration) -> f64 {
    duration.as_secs_f64() * 1e6
}

/// Counts, ratios and pass times of the default pipeline on the city at `size`.
fn report(context: &GpuContext, scene: &(Scene, CameraPath), objects: usize, frames: u32, size: (u32, u32)) {
    let (outputs, (clusters, triangles)) = fly(context, scene, frames, size, GpuGating::default());
    println!(
        "\n{objects}-object city, {frames} frames at {}x{}; clusters of at most 64 vertices / 124 triangles: \
         {clusters} clusters for {triangles} triangles in the mesh library",
        size.0, size.1
    );
    let sum = |f: fn(&GpuCounters) -> u32| mean_of(&outputs, |o| f64::from(f(&o.counters)));
    let pct = |part: f64, whole: f64| if whole > 0.0 { 100.0 * part / whole } else { 0.0 };
    let (clusters_in, triangles_in) = (sum(|c| c.clusters_in), sum(|c| c.triangles_in));
    println!("per frame, mean over {frames} frames");
    println!("instances from the CPU stages  {:>10.0}", sum(|c| c.instances));
    println!("clusters in                    {clusters_in:>10.0}");
    let culled = |name: &str, count: f64, whole: f64| println!("  {name:<29}{count:>10.0} ({:.1}%)", pct(count, whole));
    for (name, verdict) in [
        ("culled by frustum", ClusterVerdict::Frustum),
        ("culled by normal cone", ClusterVerdict::Cone),
        ("culled by HZB", ClusterVerdict::Hzb),
        ("culled as small", ClusterVerdict::Small),
    ] {
        culled(name, mean_of(&outputs, |o| f64::from(o.counters.clusters(verdict))), clusters_in);
    }
    println!("clusters out                   {:>10.0}", sum(|c| c.clusters_out));
    println!("triangles in                   {triangles_in:>10.0}");
    for (name, verdict) in [
        ("culled as degenerate", TriangleVerdict::Degenerate),
        ("culled as back-facing", TriangleVerdict::Backface),
        ("culled off screen", TriangleVerdict::Frustum),
        ("culled as small (eq. 19.4)", TriangleVerdict::Small),
    ] {
        culled(name, mean_of(&outputs, |o| f64::from(o.counters.triangles(verdict))), triangles_in);
    }
    println!(
        "triangles out                  {:>10.0} ({:.1}% kept)",
        sum(|c| c.triangles_out),
        pct(sum(|c| c.triangles_out), triangles_in)
    );
    println!("indirect draws                 {:>10.0} in one multi-draw-indirect-count", sum(|c| c.draws));
    println!("wall time, submit to counters back: {:.3} ms", mean_of(&outputs, |o| o.wall_time.as_secs_f64() * 1e3));
    if let Some(times) = GpuPassTimes::mean(&outputs) {
        println!("GPU time per pass (timestamps, mean): {times}");
        println!("cluster and triangle passes together: {:.1} us", us(times.clusters) + us(times.triangles));
    } else {
        println!("no timestamp queries on this adapter: per-pass GPU times not measured");
    }
}

/// Mean GPU time of the culling passes and the draw (HZB excluded: it runs either way), in microseconds, over
/// every frame but the first (start-up, and the frame that probes a gate).
fn culling_and_draw(outputs: &[GpuFrameOutput]) -> Option<(f64, f64, f64)> {
    let times = GpuPassTimes::mean(outputs.get(1..)?)?;
    Some((us(times.clusters), us(times.triangles), us(times.draw)))
}

/// The triangle pass against none on `scene`: what it costs, what it saves the draw, and the share of its
/// triangles it must remove to pay for itself there.
fn triangle_gate(context: &GpuContext, name: &str, scene: &(Scene, CameraPath), frames: u32, size: (u32, u32)) {
    let never_skip = GpuGating::fixed();
    // Every frame removes less than twice what it tests: skipped from the second frame on, never re-probed.
    let always_skip =
        GpuGating { min_triangle_benefit: 2.0, low_benefit_frames: 1, reprobe_every: u32::MAX, ..never_skip };
    let (with, _) = fly(context, scene, frames, size, never_skip);
    let (without, _) = fly(context, scene, frames, size, always_skip);
    let (Some((_, pass, draw_with)), Some((_, _, draw_without))) =
        (culling_and_draw(&with), culling_and_draw(&without))
    else {
        println!("{name:<12} no timestamps: not measured");
        return;
    };
    let tested = mean_of(&with[1..], |o| f64::from(o.counters.triangles_in));
    let removed = tested - mean_of(&with[1..], |o| f64::from(o.counters.triangles_out));
    let share = removed / tested.max(1.0);
    let saved = draw_without - draw_with;
    // The draw saves about the same per removed triangle at any share, so the pass pays above this share.
    let break_even = if saved > 0.0 { format!("{:.1}%", 100.0 * share * pass / saved) } else { "never".into() };
    println!(
        "{name:<12} {tested:>10.0} {:>8.1}% {pass:>9.1} {draw_with:>9.1} {draw_without:>9.1} {:>9.1} {break_even:>10}",
        100.0 * share,
        saved - pass
    );
}

/// The cluster pass against none (the CPU lists every candidate cluster) on a city of `objects`.
fn cluster_gate(context: &GpuContext, objects: usize, frames: u32, size: (u32, u32)) {
    let never_skip = GpuGating::fixed();
    let always_skip = GpuGating { tiny_scene_clusters: u32::MAX, ..never_skip };
    let scene = city(objects);
    let (with, _) = fly(context, &scene, frames, size, never_skip);
    let (without, _) = fly(context, &scene, frames, size, always_skip);
    let total = |outputs: &[GpuFrameOutput]| culling_and_draw(outputs).map(|(c, t, d)| c + t + d);
    let wall = |outputs: &[GpuFrameOutput]| mean_of(&outputs[1..], |o| us(o.wall_time));
    let clusters = mean_of(&with[1..], |o| f64::from(o.counters.clusters_in));
    let (Some(gpu_with), Some(gpu_without)) = (total(&with), total(&without)) else {
        println!("{objects:>8} no timestamps: not measured");
        return;
    };
    println!(
        "{objects:>8} {clusters:>10.0} {gpu_with:>11.1} {gpu_without:>11.1} {:>11.1} {:>11.1}",
        wall(&with),
        wall(&without)
    );
}

fn main() {
    if std::env::args().skip(1).any(|a| !a.starts_with('-') && !"gpu".contains(a.as_str())) {
        return;
    }
    let context = match GpuContext::new() {
        Ok(context) => context,
        Err(error) => {
            eprintln!("SKIPPED: no GPU adapter ({error})");
            return;
        }
    };
    let info = &context.adapter_info;
    println!(
        "adapter: {} ({:?}, {:?}), timestamps: {}, draw count: {}",
        info.name, info.backend, info.device_type, context.has_timestamps, context.has_draw_count
    );
    let objects = env_or("CULLET_GPU_OBJECTS", 100_000);
    let frames = env_or("CULLET_GPU_FRAMES", 100) as u32;
    let scene = city(objects);
    for size in resolutions() {
        report(&context, &scene, objects, frames, size);
    }
    if env_or("CULLET_GPU_TWO_PHASE", 0) != 0 {
        for size in resolutions() {
            two_phase_table(&context, &scene, objects, frames, size);
        }
    }
    if env_or("CULLET_GPU_GATES", 0) == 0 {
        return;
    }
    let size = (1920, 1080);
    println!(
        "\ntriangle pass against none, {frames} frames at 1920x1080 (GPU us per frame, every frame but the first)"
    );
    println!(
        "{:<12} {:>10} {:>9} {:>9} {:>9} {:>9} {:>9} {:>10}",
        "scene", "tested", "removed", "pass", "draw", "draw w/o", "net gain", "break-even"
    );
    let small = env_or("CULLET_GPU_GATE_OBJECTS", 20_000);
    triangle_gate(&context, &format!("city:{objects}"), &scene, frames, size);
    triangle_gate(&context, &format!("field:{small}"), &cullet::scene::field::field(small), frames, size);
    triangle_gate(&context, &format!("cad:{small}"), &cullet::scene::cad::cad(small), frames, size);
    println!("\ncluster pass against none on cities of each size, {frames} frames at 1920x1080 (us per frame)");
    println!(
        "{:>8} {:>10} {:>11} {:>11} {:>11} {:>11}",
        "objects", "clusters", "GPU with", "GPU w/o", "wall with", "wall w/o"
    );
    for objects in [10, 100, 300, 1000, 3000, 10_000, 30_000, 100_000] {
        cluster_gate(&context, objects, frames, size);
    }
}
