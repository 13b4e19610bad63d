//! Statistics printed after a run, and the stats CSV's columns.

use cullet::draw_cost::{DrawSavings, draw_ns_per_triangle};
use cullet::frustum::{LightSource, cube_face_cameras};
use cullet::gpu::{GpuCounters, GpuFrameOutput, GpuPassTimes};
use cullet::lod::LodStats;
use cullet::pipeline::{CullStats, LightViews, LightViewsVisible};
use std::time::Duration;

/// The stats CSV's columns.
pub const STATS_HEADER: &str = "frame,objects,after_frustum,after_occlusion,clusters_in,clusters_out,triangles_in,\
triangles_out,draws,bounds_us,frustum_us,raster_us,occlusion_us,gpu_us,false_negatives,false_positives,\
image_error_pixels,reused,retested,occlusion_gated,cluster_pass_skipped,triangle_pass_skipped,saved_triangles_frustum,\
saved_triangles_occlusion,saved_triangles_clusters,saved_triangles_triangles,lod_triangles_full,lod_triangles,\
lod_switches,lod_dropped,lod_us";

/// Microseconds of `duration`.
pub fn micros(duration: Duration) -> f64 {
    duration.as_secs_f64() * 1e6
}

/// Prints the GPU stages' means over `frames`.
pub fn print_gpu_summary(frames: &[GpuFrameOutput]) {
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
    let phases: Vec<_> = frames.iter().filter_map(|o| o.phases).collect();
    if !phases.is_empty() {
        let m = phases.len() as f64;
        let mean = |f: fn(&cullet::gpu::PhaseCounters) -> u32| phases.iter().map(|p| f64::from(f(p))).sum::<f64>() / m;
        println!(
            "two-phase occlusion ({} frames): triangles drawn early {:.0}, late {:.0} (its occluder step {:.0}, on \
             {} frames); the merged HZB hid {:.0} of {:.0} clusters a frame",
            phases.len(),
            mean(|p| p.early.triangles_out),
            mean(|p| p.late.triangles_out),
            mean(|p| p.late_occluders.map_or(0, |step| step.triangles_out)),
            phases.iter().filter(|p| p.late_occluders.is_some()).count(),
            mean(|p| p.late.clusters_hzb),
            mean(|p| p.late.clusters_in)
        );
    }
    let shadow_frames: Vec<&GpuCounters> = frames.iter().flat_map(|o| &o.light_views).collect();
    if !shadow_frames.is_empty() {
        let total = |f: fn(&GpuCounters) -> u32| shadow_frames.iter().map(|c| f64::from(f(c))).sum::<f64>() / n;
        println!(
            "shadow maps (GPU, per frame over every cascade): clusters {:.0} -> {:.0}, triangles {:.0} -> {:.0}, {:.0} draws",
            total(|c| c.clusters_in),
            total(|c| c.clusters_out),
            total(|c| c.triangles_in),
            total(|c| c.triangles_out),
            total(|c| c.draws)
        );
    }
    let skipped = |f: fn(&GpuFrameOutput) -> bool| frames.iter().filter(|o| f(o)).count();
    println!(
        "GPU gating: cluster pass skipped in {} of {} frames (too few clusters, or it had removed under its \
         threshold), triangle pass in {} (it had removed under its threshold)",
        skipped(|o| o.cluster_pass_skipped),
        frames.len(),
        skipped(|o| o.triangle_pass_skipped)
    );
}

/// Prints each stage's mean benefit over the frames of `savings`: the triangles it kept from the draw and,
/// where `gpu_frames` were timed, the draw time that is at their measured time per drawn triangle.
pub fn print_savings(savings: &[DrawSavings], gpu_frames: &[GpuFrameOutput]) {
    let Some(first) = savings.first() else { return };
    let n = savings.len() as f64;
    let rate = draw_ns_per_triangle(gpu_frames);
    match rate {
        Some(ns) => {
            println!("\nestimated draw cost saved per frame (mean), at this GPU's {ns:.2} ns per drawn triangle")
        }
        None => println!("\nestimated draw cost saved per frame (mean), in triangles (no GPU draw timings)"),
    }
    let total = savings.iter().map(|s| s.total as f64).sum::<f64>() / n;
    println!("{:<10} {:>14} {:>10} {:>12}", "stage", "triangles", "of all", "draw ms");
    for (stage, (name, _)) in first.by_stage().iter().enumerate() {
        let mean = savings.iter().map(|s| s.by_stage()[stage].1 as f64).sum::<f64>() / n;
        let time = rate.map_or(String::from("-"), |ns| format!("{:.2}", mean * ns / 1e6));
        println!("{name:<10} {mean:>14.0} {:>9.1}% {time:>12}", 100.0 * mean / total.max(1.0));
    }
}

/// The stats CSV's columns from `cluster_pass_skipped` on, for one frame.
pub fn gating_and_savings_columns(gpu: Option<&GpuFrameOutput>, savings: &DrawSavings) -> String {
    let flag = |f: fn(&GpuFrameOutput) -> bool| gpu.map_or(String::new(), |o| u8::from(f(o)).to_string());
    format!(
        "{},{},{},{},{},{}",
        flag(|o| o.cluster_pass_skipped),
        flag(|o| o.triangle_pass_skipped),
        savings.frustum,
        savings.occlusion,
        savings.clusters,
        savings.triangles
    )
}

/// The stats CSV's level-of-detail columns of a frame (empty where levels of detail are off).
pub fn lod_columns(lod: Option<LodStats>) -> String {
    match lod.filter(|s| s.objects > 0) {
        Some(s) => format!("{},{},{},{},{:.1}", s.triangles_full, s.triangles, s.switches, s.dropped, micros(s.time)),
        None => ",,,,".into(),
    }
}

/// Mean, median, 95th and 99th percentiles and maximum of some per-frame figures.
pub struct Spread {
    pub mean: f64,
    pub median: f64,
    pub p95: f64,
    pub p99: f64,
    pub max: f64,
}

impl Spread {
    /// The spread of `values`; all zero for none.
    pub fn of(mut values: Vec<f64>) -> Self {
        if values.is_empty() {
            return Self { mean: 0.0, median: 0.0, p95: 0.0, p99: 0.0, max: 0.0 };
        }
        values.sort_by(f64::total_cmp);
        let percentile = |p: usize| values[(values.len() * p / 100).min(values.len() - 1)];
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        let (median, p95, p99) = (percentile(50), percentile(95), percentile(99));
        Self { mean, median, p95, p99, max: values[values.len() - 1] }
    }
}

/// Each light view of `world`'s last frame, named, with the casters it kept; empty without light views.
pub fn kept_by_light_view(world: &bevy_ecs::world::World) -> Vec<(String, usize)> {
    match (world.get_resource::<LightViewsVisible>(), world.get_resource::<LightViews>()) {
        (Some(results), Some(lights)) => results.kept_by_view(lights),
        _ => Vec::new(),
    }
}

/// The stats CSV's light-view columns (`--light-views`): two a view, the shadow casters it kept and those its
/// occlusion hid from the light (`sun_cascade_1_kept,sun_cascade_1_occluded,...,lamp_plus_x_kept,...`), for
/// every view of the lights listed when the run starts, in their order. The columns stay the same all run: a
/// frame without one of those views (its light's views could not be built for that camera) leaves its two
/// cells empty.
pub struct LightViewColumns {
    /// Per pair of columns: the view's light (its index in [`LightViews`]) and its index among that light's.
    views: Vec<(usize, usize)>,
    /// The header's part: `,NAME_kept,NAME_occluded` per view.
    header: String,
}

impl LightViewColumns {
    /// The columns of the light views `world` lists ([`LightViews`]); none without.
    pub fn of_world(world: &bevy_ecs::world::World) -> Self {
        let (mut views, mut names) = (Vec::new(), Vec::<String>::new());
        for (light, source) in world.get_resource::<LightViews>().map_or(&[][..], |lights| &lights.0).iter().enumerate()
        {
            let count = match source {
                LightSource::Sun { splits, .. } => splits.len().saturating_sub(1),
                LightSource::Lamp { position, near, range } => cube_face_cameras(*position, *near, *range).len(),
            };
            for index in 0..count {
                let base = column_name(&source.view_name(index));
                // Two lights of a kind name their views alike: the later ones are numbered.
                let mut name = base.clone();
                for n in 2.. {
                    if !names.contains(&name) {
                        break;
                    }
                    name = format!("{base}_{n}");
                }
                names.push(name);
                views.push((light, index));
            }
        }
        let header = names.iter().map(|name| format!(",{name}_kept,{name}_occluded")).collect();
        Self { views, header }
    }

    /// The header's columns, each after a comma (empty without light views).
    pub fn header(&self) -> &str {
        &self.header
    }

    /// The frame `world` has just culled: each view's kept and occluded casters, each after a comma, empty
    /// where the frame lacks the view.
    pub fn row(&self, world: &bevy_ecs::world::World) -> String {
        let mut cells = vec![None; self.views.len()];
        if let Some(results) = world.get_resource::<LightViewsVisible>() {
            // A light's views follow each other, in its order (as `LightViewsVisible::kept_by_view` counts them).
            let mut index = 0;
            for (i, view) in results.0.iter().enumerate() {
                index = if i > 0 && results.0[i - 1].light == view.light { index + 1 } else { 0 };
                if let Some(column) = self.views.iter().position(|&key| key == (view.light, index)) {
                    cells[column] = Some((view.kept, view.occluded));
                }
            }
        }
        cells
            .into_iter()
            .map(|cell| cell.map_or_else(|| String::from(",,"), |(kept, occluded)| format!(",{kept},{occluded}")))
            .collect()
    }
}

/// A light view's name as a CSV column's: lower case words joined by `_`, a face's sign spelt out
/// (`lamp +x` is `lamp_plus_x`).
fn column_name(view: &str) -> String {
    let spelt: String = view
        .to_lowercase()
        .chars()
        .map(|c| match c {
            '+' => String::from(" plus "),
            '-' => String::from(" minus "),
            c if c.is_ascii_alphanumeric() => c.to_string(),
            _ => String::from(" "),
        })
        .collect();
    spelt.split_whitespace().collect::<Vec<_>>().join("_")
}

/// The casters each light view kept, added up over the frames of a run (see `--light-views`).
#[derive(Default)]
pub struct LightViewTotals {
    /// Per light view: its name and the casters it kept, summed.
    kept: Vec<(String, usize)>,
    frames: usize,
}

impl LightViewTotals {
    /// Adds the frame `world` has just culled.
    pub fn add(&mut self, world: &bevy_ecs::world::World) {
        let kept = kept_by_light_view(world);
        if kept.is_empty() {
            return;
        }
        if kept.len() != self.kept.len() {
            (self.kept, self.frames) = (kept.iter().map(|(name, _)| (name.clone(), 0)).collect(), 0);
        }
        for ((_, total), (_, count)) in self.kept.iter_mut().zip(kept) {
            *total += count;
        }
        self.frames += 1;
    }

    /// Prints each light view's mean casters a frame, where there were light views.
    pub fn print(&self) {
        if self.kept.is_empty() || self.frames == 0 {
            return;
        }
        let views: Vec<String> =
            self.kept.iter().map(|(name, total)| format!("{name} {:.0}", *total as f64 / self.frames as f64)).collect();
        println!("casters per light view (mean a frame): {}", views.join(", "));
    }
}

/// Prints each CPU stage's mean, median and worst time and what it kept over `frames`.
pub fn print_summary(frames: &[CullStats]) {
    if frames.is_empty() {
        return;
    }
    let n = frames.len() as f64;
    let summarize = |times: Vec<f64>| {
        let spread = Spread::of(times);
        (spread.mean, spread.median, spread.max)
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
    // The light views' casters after their frustum pass, before their occlusion.
    let light_casters = frames.iter().map(|f| (f.light_view_casters + f.light_view_occluded) as f64).sum::<f64>() / n;
    if frames[0].light_views > 0 {
        let (views, casters) = (frames[0].light_views, light_casters);
        println!(
            "{:<10} {:>38} {casters:>12.0} {:>9.1}%   ({views} light views, culled in the frustum's pass)",
            "lights",
            "",
            100.0 * (1.0 - casters / (objects * views as f64).max(1.0))
        );
    }
    let triangles = frames.iter().map(|f| f.occluder_triangles as f64).sum::<f64>() / n;
    let (mean, median, max) = summarize(frames.iter().map(|f| micros(f.raster_time)).collect());
    println!(
        "{:<10} {mean:>12.1} {median:>12.1} {max:>12.1} {:>12} {:>10}",
        "raster",
        format!("{triangles:.0} tris"),
        ""
    );
    let after = frames.iter().map(|f| f.after_occlusion as f64).sum::<f64>() / n;
    let reused = frames.iter().filter(|f| f.reused).count();
    let retested = frames.iter().filter(|f| f.retested > 0).count();
    let gated = frames.iter().filter(|f| f.occlusion_gated).count();
    let (mean, median, max) = summarize(frames.iter().map(|f| micros(f.occlusion_time)).collect());
    println!(
        "{:<10} {mean:>12.1} {median:>12.1} {max:>12.1} {after:>12.0} {:>9.1}%",
        "occlusion",
        100.0 * (1.0 - after / kept.max(1.0))
    );
    if frames[0].light_views > 0 {
        let after = frames.iter().map(|f| f.light_view_casters as f64).sum::<f64>() / n;
        let gated = frames.iter().map(|f| f.light_occlusion_gated).sum::<usize>();
        let (mean, median, max) = summarize(frames.iter().map(|f| micros(f.light_occlusion_time)).collect());
        println!(
            "{:<10} {mean:>12.1} {median:>12.1} {max:>12.1} {after:>12.0} {:>9.1}%   (casters hidden from their \
             lights; {gated} view-frames gated)",
            "light occ",
            100.0 * (1.0 - after / light_casters.max(1.0))
        );
    }
    println!(
        "gating: {reused} of {} frames reused the last result (nothing changed), {retested} re-tested only the \
         objects that moved (same view); occlusion skipped in {gated} (it had removed under the threshold, or \
         beside two phases the frame's own depth hid as much)",
        frames.len()
    );
    let detail = frames.iter().map(|f| f.detail_culled as f64).sum::<f64>() / n;
    if detail > 0.0 {
        println!(
            "detail culling (lossy): {detail:.0} objects a frame dropped for projecting too small, in `kept` above"
        );
    }
}

/// Prints the levels of detail's means over `frames` (nothing where they were off throughout).
pub fn print_lod_summary(frames: &[LodStats]) {
    if frames.iter().all(|s| s.objects == 0) {
        return;
    }
    let n = frames.len() as f64;
    let mean = |f: fn(&LodStats) -> f64| frames.iter().map(f).sum::<f64>() / n;
    let (full, drawn) = (mean(|s| s.triangles_full as f64), mean(|s| s.triangles as f64));
    let time = Spread::of(frames.iter().map(|s| micros(s.time)).collect());
    let most = frames.iter().map(|s| s.triangles).max().unwrap_or(0);
    println!(
        "levels of detail (lossy): kept objects' triangles {full:.0} -> {drawn:.0} a frame ({:.1}% fewer, at most \
         {most} in a frame), {:.1} level switches and {:.1} objects dropped by the budget a frame; selection \
         {:.1} us (median {:.1}; tables {:.1})",
        100.0 * (1.0 - drawn / full.max(1.0)),
        mean(|s| s.switches as f64),
        mean(|s| s.dropped as f64),
        time.mean,
        time.median,
        Spread::of(frames.iter().map(|s| micros(s.tables_time)).collect()).median,
    );
}

#[cfg(test)]
mod tests {
    use super::{LightViewColumns, Spread, column_name};
    use cullet::frustum::LightSource;
    use cullet::pipeline::LightViews;

    #[test]
    fn spread_of_a_few_frames() {
        let spread = Spread::of(vec![4.0, 1.0, 3.0, 2.0]);
        assert_eq!((spread.mean, spread.median, spread.p95, spread.max), (2.5, 3.0, 4.0, 4.0));
        let none = Spread::of(Vec::new());
        assert_eq!((none.mean, none.max), (0.0, 0.0));
    }

    #[test]
    fn light_view_columns_are_named_after_the_views() {
        assert_eq!(column_name("sun cascade 1"), "sun_cascade_1");
        assert_eq!(column_name("lamp +x"), "lamp_plus_x");
        assert_eq!(column_name("lamp -z"), "lamp_minus_z");
        let mut world = bevy_ecs::world::World::new();
        assert_eq!(LightViewColumns::of_world(&world).header(), "");
        let sun = LightSource::Sun { direction: glam::Vec3::NEG_Y, splits: vec![0.1, 10.0, 50.0] };
        let lamp = LightSource::Lamp { position: glam::Vec3::ZERO, near: 0.05, range: None };
        world.insert_resource(LightViews(vec![sun.clone(), lamp, sun]));
        let columns = LightViewColumns::of_world(&world);
        let header: Vec<&str> = columns.header().split(',').skip(1).collect();
        assert_eq!(header.len(), 2 * (2 + 6 + 2));
        assert_eq!(
            &header[..4],
            ["sun_cascade_1_kept", "sun_cascade_1_occluded", "sun_cascade_2_kept", "sun_cascade_2_occluded"]
        );
        assert_eq!(&header[4..6], ["lamp_plus_x_kept", "lamp_plus_x_occluded"]);
        assert_eq!(&header[16..18], ["sun_cascade_1_2_kept", "sun_cascade_1_2_occluded"]);
        // No frame culled yet: every cell empty, the row as long as the header.
        assert_eq!(columns.row(&world), ",".repeat(header.len()));
    }
}
