//! Frustum culling of the built-in city: Cullet's SoA SIMD path against Bevy's `Frustum::intersects_obb` on the
//! same objects and cameras, thread scaling, the memory bandwidth bound of reading the SoA arrays, and plane
//! coherence (last frame's rejecting plane first) over consecutive frames of the fly-through.
//!
//! `cargo bench -p cullet-benches --bench frustum`

use bevy_camera::primitives::{Aabb, Frustum as BevyFrustum};
use bevy_shape::ViewFrustum;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use cullet::frustum::{FrustumOptions, PlaneCoherence, SimdBackend, cull_frustum};
use cullet::scene::city::{CityParams, CityScene};
use cullet::{BoundsStore, Frustum, VisibleSet};
use rayon::prelude::*;
use std::hint::black_box;
use std::time::Duration;

#[path = "bevy_frustum/mod.rs"]
mod bevy_frustum;
use bevy_frustum::cull_bevy;

const SIZES: [usize; 3] = [10_000, 100_000, 1_000_000];

/// One city: Cullet's store, and the same objects as Bevy keeps them (local AABB plus world transform).
struct Fixture {
    store: BoundsStore,
    /// The same objects in a scattered order: no group of 64 is spatially coherent, so every object is tested.
    shuffled: BoundsStore,
    bevy_objects: Vec<(Aabb, bevy_math::Affine3A)>,
    cullet_frusta: Vec<Frustum>,
    bevy_frusta: Vec<BevyFrustum>,
}

fn fixture(objects: usize) -> Fixture {
    let city = CityScene::generate(CityParams::with_objects(objects));
    let mut store = BoundsStore::default();
    let mut bevy_objects = Vec::with_capacity(objects);
    for (i, object) in city.scene.objects.iter().enumerate() {
        let local = city.scene.mesh_bounds[object.mesh as usize];
        let entity = bevy_ecs_entity(i);
        store.update(entity, &local, &cullet::ObjectTransform(object.transform)).unwrap();
        let aabb = Aabb {
            center: bevy_math::Vec3A::from_array(local.center.to_array()),
            half_extents: bevy_math::Vec3A::from_array(local.half_extent.to_array()),
        };
        let m = object.transform.to_cols_array();
        bevy_objects.push((aabb, bevy_math::Affine3A::from_cols_array(&m)));
    }
    let mut shuffled = BoundsStore::default();
    for i in 0..store.len() {
        let slot = (i * 7919) % store.len(); // 7919 is prime and never divides a tested size
        shuffled.insert(bevy_ecs_entity(i), &store.get(slot).unwrap()).unwrap();
    }
    let cameras = city.benchmark_cameras();
    let cullet_frusta = cameras.iter().map(|(_, c)| c.frustum().unwrap()).collect();
    let bevy_frusta = cameras
        .iter()
        .map(|(_, c)| {
            let m = bevy_math::Mat4::from_cols_array(&c.clip_from_world().to_cols_array());
            BevyFrustum(ViewFrustum::from_clip_from_world(&m))
        })
        .collect();
    Fixture { store, shuffled, bevy_objects, cullet_frusta, bevy_frusta }
}

fn bevy_ecs_entity(i: usize) -> bevy_ecs::entity::Entity {
    bevy_ecs::entity::Entity::from_raw_u32(i as u32 + 1).unwrap()
}

/// Sum with 8 independent accumulators, so the compiler vectorizes it and the loop is bound by memory.
fn wide_sum(values: &[f32]) -> f32 {
    let lanes = values.chunks_exact(8).fold([0f32; 8], |mut acc, chunk| {
        for (a, v) in acc.iter_mut().zip(chunk) {
            *a += v;
        }
        acc
    });
    lanes.iter().sum()
}

fn frustum(c: &mut Criterion) {
    let mut group = c.benchmark_group("frustum");
    group.sample_size(30).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    let mut visible = VisibleSet::default();
    for &n in &SIZES {
        let fixture = fixture(n);
        let cameras = fixture.cullet_frusta.len() as u64;
        group.throughput(Throughput::Elements(n as u64 * cameras));
        group.bench_function(BenchmarkId::new("cullet", n), |b| {
            b.iter(|| {
                for frustum in &fixture.cullet_frusta {
                    black_box(cull_frustum(
                        &fixture.store,
                        frustum,
                        FrustumOptions { backend: SimdBackend::Auto, ..Default::default() },
                        &mut visible,
                    ));
                }
            })
        });
        group.bench_function(BenchmarkId::new("cullet-shuffled", n), |b| {
            b.iter(|| {
                for frustum in &fixture.cullet_frusta {
                    black_box(cull_frustum(
                        &fixture.shuffled,
                        frustum,
                        FrustumOptions { backend: SimdBackend::Auto, ..Default::default() },
                        &mut visible,
                    ));
                }
            })
        });
        group.bench_function(BenchmarkId::new("cullet-scalar", n), |b| {
            b.iter(|| {
                for frustum in &fixture.cullet_frusta {
                    black_box(cull_frustum(
                        &fixture.store,
                        frustum,
                        FrustumOptions { backend: SimdBackend::Scalar, ..Default::default() },
                        &mut visible,
                    ));
                }
            })
        });
        group.bench_function(BenchmarkId::new("bevy", n), |b| {
            b.iter(|| {
                for frustum in &fixture.bevy_frusta {
                    black_box(cull_bevy(&fixture.bevy_objects, frustum, &mut visible));
                }
            })
        });
    }
    group.finish();
}

fn threads(c: &mut Criterion) {
    let fixture = fixture(1_000_000);
    let mut group = c.benchmark_group("frustum");
    group.sample_size(30).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    group.throughput(Throughput::Elements(1_000_000 * fixture.cullet_frusta.len() as u64));
    let max_threads = std::thread::available_parallelism().map_or(2, |n| n.get()).max(2);
    let mut visible = VisibleSet::default();
    for threads in 1..=max_threads {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        group.bench_function(BenchmarkId::new("threads", threads), |b| {
            pool.install(|| {
                b.iter(|| {
                    for frustum in &fixture.cullet_frusta {
                        black_box(cull_frustum(
                            &fixture.store,
                            frustum,
                            FrustumOptions { backend: SimdBackend::Auto, ..Default::default() },
                            &mut visible,
                        ));
                    }
                })
            })
        });
    }
    group.finish();

    // The bandwidth bound: the time to merely read the seven SoA arrays of 1e6 objects, in parallel.
    let mut group = c.benchmark_group("bandwidth");
    group.sample_size(30).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    let store = &fixture.store;
    let arrays = store.soa().all();
    group.throughput(Throughput::Bytes((arrays.len() * store.padded_len() * 4) as u64));
    group.bench_function("read_soa/1000000", |b| {
        b.iter(|| {
            let sum: f32 = (0..store.padded_len() / 4096)
                .into_par_iter()
                .map(|block| {
                    let range = block * 4096..(block + 1) * 4096;
                    arrays.iter().map(|a| wide_sum(&a[range.clone()])).sum::<f32>()
                })
                .sum();
            black_box(sum)
        })
    });
    group.finish();
}

/// Consecutive frames (30 a second) of the city's fly-through, culled with and without plane coherence, in the
/// city's spatial store order and shuffled (where every group crosses the frustum and every object is tested).
fn coherence(c: &mut Criterion) {
    let objects = 100_000;
    let city = CityScene::generate(CityParams::with_objects(objects));
    let path = city.flythrough();
    let frusta: Vec<Frustum> =
        (0..60).map(|frame| path.camera_at(5.0 + frame as f32 / 30.0, 16.0 / 9.0).frustum().unwrap()).collect();
    let fixture = fixture(objects);
    let mut group = c.benchmark_group("coherence");
    group.sample_size(30).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    group.throughput(Throughput::Elements((objects * frusta.len()) as u64));
    let mut visible = VisibleSet::default();
    for (name, store) in [("city", &fixture.store), ("shuffled", &fixture.shuffled)] {
        group.bench_function(BenchmarkId::new("all-planes", name), |b| {
            b.iter(|| {
                for frustum in &frusta {
                    black_box(cull_frustum(
                        store,
                        frustum,
                        FrustumOptions { backend: SimdBackend::Auto, ..Default::default() },
                        &mut visible,
                    ));
                }
            })
        });
        group.bench_function(BenchmarkId::new("coherent", name), |b| {
            b.iter(|| {
                let mut coherence = PlaneCoherence::default();
                for frustum in &frusta {
                    black_box(cull_frustum(
                        store,
                        frustum,
                        FrustumOptions {
                            backend: SimdBackend::Auto,
                            coherence: Some(&mut coherence),
                            ..Default::default()
                        },
                        &mut visible,
                    ));
                }
            })
        });
    }
    group.finish();
}

criterion_group!(benches, frustum, threads, coherence);
criterion_main!(benches);
