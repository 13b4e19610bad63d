//! Where precision degrades: prints every stress case of `cullet_truth::stress` (CPU stages, and GPU passes
//! where an adapter exists) as a table, then flies the city at growing distances from the world origin and
//! reports culling efficiency and false negatives against the exact rendering. Writes
//! `target/stress/{cases,world_offset}.csv` and `world_offset.png`.
//!
//! `cargo bench -p cullet-benches --bench stress`

use cullet::culler::OcclusionSettings;
use cullet::gpu::GpuContext;
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use cullet_truth::stress::{cases, gpu_false_negatives, run_case};
use cullet_truth::{JudgeSettings, PathMetrics, ReferenceSettings, judge_frame};
use plotters::prelude::*;
use std::fmt::Write as _;

const OFFSETS: [f32; 9] = [0.0, 1e3, 1e4, 1e5, 1e6, 3e6, 1e7, 3e7, 1e8];
const CITY_OBJECTS: usize = 10_000;
const FRAMES: u32 = 40;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/stress");
    std::fs::create_dir_all(&out)?;
    let gpu = GpuContext::new().map_err(|e| println!("no GPU ({e}): CPU stages only")).ok();

    let mut csv = String::from(
        "sweep,value,objects,visible,kept,false_negatives,gpu_false_negatives,efficiency,plane_error,projection_error\n",
    );
    println!(
        "{:<18} {:>10} {:>8} {:>8} {:>6} {:>7} {:>11} {:>10} {:>10}",
        "sweep", "value", "visible", "kept", "FN", "GPU FN", "efficiency", "plane err", "proj err"
    );
    for case in cases() {
        let (outcome, mut flight) = run_case(&case);
        let gpu_missed =
            gpu.as_ref().map(|context| gpu_false_negatives(&case, &mut flight, context).expect("GPU frame"));
        let gpu_text = gpu_missed.map_or("-".to_string(), |n| n.to_string());
        println!(
            "{:<18} {:>10.3e} {:>8} {:>8} {:>6} {:>7} {:>10.1}% {:>10.1e} {:>10.1e}",
            outcome.sweep,
            outcome.value,
            outcome.visible,
            outcome.kept,
            outcome.false_negatives,
            gpu_text,
            100.0 * outcome.efficiency,
            outcome.plane_error,
            outcome.projection_error
        );
        writeln!(
            csv,
            "{},{},{},{},{},{},{},{:.4},{:e},{:e}",
            outcome.sweep,
            outcome.value,
            outcome.objects,
            outcome.visible,
            outcome.kept,
            outcome.false_negatives,
            gpu_text,
            outcome.efficiency,
            outcome.plane_error,
            outcome.projection_error
        )?;
    }
    std::fs::write(out.join("cases.csv"), csv)?;

    // The city far from the origin: the same fly-through, judged frame by frame.
    let mut rows = Vec::new();
    println!("\n{CITY_OBJECTS}-object city, {FRAMES} frames of its fly-through, moved away from the origin:");
    println!("{:>10} {:>12} {:>14} {:>6} {:>12}", "offset", "frustum", "+ occlusion", "FN", "image error");
    let city = CityScene::generate(CityParams::with_objects(CITY_OBJECTS));
    for offset in OFFSETS {
        let shift = glam::Vec3::new(offset, 0.0, -offset * 0.5);
        let mut scene = city.scene.clone();
        scene.translate(shift);
        let path = city.flythrough().translated(shift);
        let mut flight = Flight::new(path, 16.0 / 9.0, FRAMES, OcclusionSettings::default(), |world| {
            scene.spawn(world);
        });
        let settings = JudgeSettings {
            reference: ReferenceSettings { width: 960, height: 540, ..ReferenceSettings::default() },
            occlusion_ideal: false,
        };
        let mut metrics = PathMetrics::default();
        for frame in 0..FRAMES {
            flight.run_frame(frame);
            metrics.add(&judge_frame(&flight.world, &scene.meshes, &settings).metrics);
        }
        let row =
            (offset, metrics.efficiency(0), metrics.efficiency(1), metrics.false_negatives, metrics.image_error_pixels);
        println!("{:>10.0e} {:>11.1}% {:>13.1}% {:>6} {:>12}", row.0, 100.0 * row.1, 100.0 * row.2, row.3, row.4);
        rows.push(row);
    }
    let mut csv = String::from("offset,frustum_efficiency,occlusion_efficiency,false_negatives,image_error_pixels\n");
    for r in &rows {
        writeln!(csv, "{},{:.4},{:.4},{},{}", r.0, r.1, r.2, r.3, r.4)?;
    }
    std::fs::write(out.join("world_offset.csv"), csv)?;
    plot(&rows, &out.join("world_offset.png"))?;
    println!("\nwritten to {}", out.display());
    Ok(())
}

/// Culling efficiency of the frustum stage and of frustum plus occlusion against the world offset.
fn plot(rows: &[(f32, f64, f64, usize, usize)], path: &std::path::Path) -> Result<(), Box<dyn std::error::Error>> {
    let root = BitMapBackend::new(path, (900, 520)).into_drawing_area();
    root.fill(&WHITE)?;
    let x = |offset: f32| f64::from(offset.max(1.0)).log10();
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("Culling efficiency against world offset ({CITY_OBJECTS}-object city, {FRAMES} frames, 0 false negatives)"),
            ("sans-serif", 20),
        )
        .margin(20)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..8.2, 0.0..100.0)?;
    chart
        .configure_mesh()
        .x_desc("world offset, log10 units (0 = at the origin)")
        .y_desc("culling efficiency (%)")
        .draw()?;
    for (name, color, value) in [
        ("frustum", BLUE, (|r: &(f32, f64, f64, usize, usize)| r.1) as fn(&_) -> f64),
        ("frustum + occlusion", RED, |r| r.2),
    ] {
        let points: Vec<(f64, f64)> = rows.iter().map(|r| (x(r.0), 100.0 * value(r))).collect();
        chart
            .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))?
            .label(name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color.stroke_width(2)));
        chart.draw_series(points.into_iter().map(|p| Circle::new(p, 4, color.filled())))?;
    }
    chart.configure_series_labels().position(SeriesLabelPosition::LowerLeft).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}
