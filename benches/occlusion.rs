//! Software occlusion culling on the city: occluder rasterization at several buffer sizes and triangle counts,
//! the occludee test at several object counts, the two together (the 10k-triangle, 1e5-object target), thread
//! scaling, and the cullers side by side through the culler interface on one frame of the city's fly-through
//! (the pipeline's stages with the default settings and with those for the 1920x1080 frame, and the occluders'
//! shadow frusta at the default budget).
//!
//! `cargo bench -p cullet-benches --bench occlusion`

#[path = "street/mod.rs"]
mod street;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use cullet::VisibleSet;
use cullet::depth::{DepthPyramid, ScreenView};
use cullet::raster::{RasterMode, rasterize};
use std::hint::black_box;
use std::time::Duration;
use street::StreetView;

fn fixture(objects: usize) -> StreetView {
    StreetView::new(objects)
}

fn configure(group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>) {
    group.sample_size(30).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
}

fn raster(c: &mut Criterion) {
    let fixture = fixture(1_000_000);
    let mut group = c.benchmark_group("occlusion");
    configure(&mut group);
    let mut pyramid = DepthPyramid::default();
    for triangles in [1_000, 10_000, 100_000] {
        let occluders = fixture.select(triangles);
        let submitted: usize = occluders.iter().map(|o| o.occluder.triangle_count()).sum();
        group.throughput(Throughput::Elements(submitted as u64));
        for (width, height) in [(128, 72), (256, 144), (512, 288), (1024, 576)] {
            let view = ScreenView::new(&fixture.camera, width, height);
            let id = BenchmarkId::new(format!("raster/{triangles}"), format!("{width}x{height}"));
            group.bench_function(id, |b| {
                b.iter(|| black_box(rasterize(&view, &occluders, RasterMode::Conservative, &mut pyramid)))
            });
        }
    }
    group.finish();
}

fn test(c: &mut Criterion) {
    let mut group = c.benchmark_group("occlusion");
    configure(&mut group);
    let (mut visible, mut occluded) = (VisibleSet::default(), VisibleSet::default());
    for objects in [10_000, 100_000, 1_000_000] {
        let fixture = fixture(objects);
        let view = ScreenView::new(&fixture.camera, 256, 144);
        let mut pyramid = DepthPyramid::default();
        rasterize(&view, &fixture.select(10_000), RasterMode::Conservative, &mut pyramid);
        group.throughput(Throughput::Elements(fixture.frustum_visible.count() as u64));
        group.bench_function(BenchmarkId::new("test", objects), |b| {
            b.iter(|| black_box(fixture.test(&view, &pyramid, &mut visible, &mut occluded)))
        });
    }
    group.finish();
}

/// The whole stage: select 10k occluder triangles, rasterize at 256x144, build the pyramid, test the frustum
/// survivors of a 400k-object city (about 1e5 from the street camera); with 1, 2, ... threads. Also without the
/// selection: the 1.5 ms target counts rasterizing 10k triangles and testing 1e5 occludees.
fn combined(c: &mut Criterion) {
    let fixture = fixture(400_000);
    let mut group = c.benchmark_group("occlusion");
    configure(&mut group);
    let max_threads = std::thread::available_parallelism().map_or(2, |n| n.get()).max(2);
    let view = ScreenView::new(&fixture.camera, 256, 144);
    let (mut visible, mut occluded) = (VisibleSet::default(), VisibleSet::default());
    let mut pyramid = DepthPyramid::default();
    group.throughput(Throughput::Elements(fixture.frustum_visible.count() as u64));
    for threads in 1..=max_threads {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        // The target's measure: 10k occluder triangles rasterized (with their pyramid) and every survivor tested;
        // the occluders are selected beforehand.
        let selected = fixture.select(10_000);
        group.bench_function(BenchmarkId::new("raster10k+pyramid+test/threads", threads), |b| {
            pool.install(|| {
                b.iter(|| {
                    rasterize(&view, &selected, RasterMode::Conservative, &mut pyramid);
                    black_box(fixture.test(&view, &pyramid, &mut visible, &mut occluded))
                })
            })
        });
        group.bench_function(BenchmarkId::new("raster10k+test/threads", threads), |b| {
            pool.install(|| {
                b.iter(|| {
                    let occluders = fixture.select(10_000);
                    rasterize(&view, &occluders, RasterMode::Conservative, &mut pyramid);
                    black_box(fixture.test(&view, &pyramid, &mut visible, &mut occluded))
                })
            })
        });
    }
    group.finish();
}

fn cullers(c: &mut Criterion) {
    use cullet::culler::{AdaptiveSettings, Culler, OcclusionSettings, ShadowFrustaCuller, StageCuller, ViewSettings};
    use cullet::scene::city::{CityParams, CityScene};
    use cullet::scene::flight::Flight;
    let city = CityScene::generate(CityParams::with_objects(100_000));
    let frames = 200;
    let mut flight = Flight::for_cullers(city.flythrough(), 16.0 / 9.0, frames, |world| {
        city.spawn(world);
    });
    // A frame along the street, mid-path.
    let mut probe = StageCuller::frustum_only();
    let _ = flight.cull_frame(frames / 2, &mut probe);
    let camera = *flight.world.resource::<cullet::Camera>();
    let scene = cullet::culler::CullScene::new(&flight.world);
    // Every iteration culls the same frame: the stages must not keep the last result.
    let adaptive = AdaptiveSettings { reuse_unchanged: false, ..AdaptiveSettings::default() };
    let default = ViewSettings { adaptive, ..ViewSettings::default() };
    let for_frame = ViewSettings { occlusion: OcclusionSettings::for_frame(1920, 1080), ..default };
    let mut cullers: Vec<Box<dyn Culler>> = vec![
        Box::new(StageCuller::new("stages default", default)),
        Box::new(StageCuller::new("stages for_frame", for_frame)),
        Box::new(ShadowFrustaCuller::default()),
    ];
    let mut group = c.benchmark_group("cullers/city1e5");
    configure(&mut group);
    for culler in &mut cullers {
        let name = culler.name();
        let stats = culler.cull(&scene, &camera).stats;
        println!(
            "{name}: kept {} of {} after the frustum's {}; frustum {:?}, occluders {:?}, test {:?}",
            stats.after_occlusion,
            stats.objects,
            stats.after_frustum,
            stats.frustum_time,
            stats.raster_time,
            stats.occlusion_time
        );
        group.bench_function(name.as_str(), |b| {
            b.iter(|| black_box(culler.cull(&scene, &camera).stats.after_occlusion))
        });
    }
    group.finish();
}

criterion_group!(benches, raster, test, combined, cullers);
criterion_main!(benches);
