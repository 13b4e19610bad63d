//! GPU passes over the city's fly-through: time per pass (timestamp queries where the adapter has them, else
//! only the wall time of a finished queue), what each test removes, and draws per frame.
//!
//! `cargo bench -p cullet-benches --bench gpu`; `CULLET_GPU_OBJECTS` (default 100000) and `CULLET_GPU_FRAMES`
//! (default 100) size the run. On a software adapter (lavapipe) times mean little: read the counts and ratios.

use cullet::gpu::cluster_cull::ClusterVerdict;
use cullet::gpu::triangle_cull::TriangleVerdict;
use cullet::gpu::{GpuContext, GpuCounters, GpuCullSettings, GpuCuller, GpuFrameOutput, GpuPassTimes};
use cullet::pipeline::OcclusionSettings;
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use std::time::Duration;

fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
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
    let (width, height) = (1920, 1080);
    let city = CityScene::generate(CityParams::with_objects(objects));
    let mut flight =
        Flight::new(city.flythrough(), width as f32 / height as f32, frames, OcclusionSettings::default(), |world| {
            city.spawn(world);
        });
    let mut culler = GpuCuller::for_world(&context, &flight.world, &city.scene.meshes, (width, height));
    let library = &culler.scene().library;
    println!(
        "{objects}-object city, {frames} frames at {width}x{height}; clusters of at most 64 vertices / 124 triangles: {} \
         clusters for {} triangles in the mesh library",
        library.clusters.len(),
        library.indices.len() / 3
    );
    let settings = GpuCullSettings::default();
    let mut outputs: Vec<GpuFrameOutput> = Vec::new();
    let mut written = 0;
    for frame in 0..frames {
        flight.run_frame(frame);
        outputs.push(culler.run_world(&context, &mut flight.world, &settings).expect("GPU frame"));
        written += culler.scene().instances_written_last_update;
    }
    let n = outputs.len() as f64;
    let sum = |f: fn(&GpuCounters) -> u32| outputs.iter().map(|o| f64::from(f(&o.counters))).sum::<f64>() / n;
    let pct = |part: f64, whole: f64| if whole > 0.0 { 100.0 * part / whole } else { 0.0 };
    let (clusters_in, triangles_in) = (sum(|c| c.clusters_in), sum(|c| c.triangles_in));
    println!(
        "\nper frame, mean over {frames} frames (instances written: {:.0} per frame after the first)",
        written as f64 / n
    );
    println!("instances from the CPU stages  {:>10.0}", sum(|c| c.instances));
    println!("clusters in                    {clusters_in:>10.0}");
    let culled = |name: &str, count: f64, whole: f64| println!("  {name:<29}{count:>10.0} ({:.1}%)", pct(count, whole));
    for (name, verdict) in [
        ("culled by frustum", ClusterVerdict::Frustum),
        ("culled by normal cone", ClusterVerdict::Cone),
        ("culled by HZB", ClusterVerdict::Hzb),
        ("culled as small", ClusterVerdict::Small),
    ] {
        let count = outputs.iter().map(|o| f64::from(o.counters.clusters(verdict))).sum::<f64>() / n;
        culled(name, count, clusters_in);
    }
    println!("clusters out                   {:>10.0}", sum(|c| c.clusters_out));
    println!("triangles in                   {triangles_in:>10.0}");
    for (name, verdict) in [
        ("culled as degenerate", TriangleVerdict::Degenerate),
        ("culled as back-facing", TriangleVerdict::Backface),
        ("culled off screen", TriangleVerdict::Frustum),
        ("culled as small (eq. 19.4)", TriangleVerdict::Small),
    ] {
        let count = outputs.iter().map(|o| f64::from(o.counters.triangles(verdict))).sum::<f64>() / n;
        culled(name, count, triangles_in);
    }
    println!(
        "triangles out                  {:>10.0} ({:.1}% kept)",
        sum(|c| c.triangles_out),
        pct(sum(|c| c.triangles_out), triangles_in)
    );
    println!("indirect draws                 {:>10.0} in one multi-draw-indirect-count", sum(|c| c.draws));
    let mean = |f: fn(&GpuFrameOutput) -> Duration| outputs.iter().map(|o| f(o).as_secs_f64() * 1e3).sum::<f64>() / n;
    println!("\nwall time, submit to counters back: {:.3} ms", mean(|o| o.wall_time));
    if let Some(times) = GpuPassTimes::mean(&outputs) {
        println!("GPU time per pass (timestamps, mean): {times}");
    } else {
        println!("no timestamp queries on this adapter: per-pass GPU times not measured");
    }
}
