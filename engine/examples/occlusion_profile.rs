//! Times the occlusion stage's parts on the city's street camera: selection, raster (with its pyramid), occludee test.
//! Prints the fastest of 30 runs of each part (the machine is noisy; the work is deterministic).
//! `cargo run --release -p cullet --example occlusion_profile [objects]`
use cullet::BoundsStore;
use cullet::depth::{DepthPyramid, ScreenView};
use cullet::frustum::{FrustumOptions, cull_frustum};
use cullet::occluders::OccluderInstance;
use cullet::occluders::select_occluders;
use cullet::occlusion::test_occlusion;
use cullet::raster::{RasterMode, rasterize};
use cullet::scene::city::{CityParams, CityScene};
use std::time::Instant;

fn main() {
    let objects = std::env::args().nth(1).and_then(|n| n.parse().ok()).unwrap_or(100_000);
    let city = CityScene::generate(CityParams::with_objects(objects));
    let mut store = BoundsStore::default();
    let mut occluders = Vec::new();
    for (i, object) in city.scene.objects.iter().enumerate() {
        let entity = bevy_ecs::entity::Entity::from_raw_u32(i as u32 + 1).unwrap();
        let local = city.scene.mesh_bounds[object.mesh as usize];
        let slot = store.update(entity, &local, &cullet::ObjectTransform(object.transform)).unwrap();
        if let Some(occluder) = &object.occluder {
            store.set_occluder(slot, true).unwrap();
            occluders.push((slot, occluder.clone(), object.transform));
        }
    }
    for (name, camera) in city.benchmark_cameras() {
        let mut frustum_visible = cullet::VisibleSet::default();
        cull_frustum(&store, &camera.frustum().unwrap(), FrustumOptions::default(), &mut frustum_visible);
        let by_slot: std::collections::HashMap<usize, (&cullet::Occluder, glam::Affine3A)> =
            occluders.iter().map(|(slot, occluder, transform)| (*slot, (occluder, *transform))).collect();
        let view = ScreenView::new(&camera, 256, 144);
        let mut pyramid = DepthPyramid::default();
        let (mut visible, mut occluded) = (cullet::VisibleSet::default(), cullet::VisibleSet::default());
        let mut times = [f64::INFINITY; 3];
        let runs = 30;
        let mut kept = 0;
        let mut tris = 0;
        for _ in 0..runs {
            let t = Instant::now();
            let instances = select_occluders(&store, &frustum_visible, camera.position, 10_000, |slot| {
                by_slot.get(&slot).map(|&(occluder, transform)| OccluderInstance { occluder, transform })
            })
            .into_iter()
            .map(|(_, instance)| instance)
            .collect::<Vec<_>>();
            times[0] = times[0].min(t.elapsed().as_secs_f64());
            let t = Instant::now();
            tris = rasterize(&view, &instances, RasterMode::Conservative, &mut pyramid).triangles_rasterized;
            times[1] = times[1].min(t.elapsed().as_secs_f64());
            let t = Instant::now();
            kept = test_occlusion(&store, &frustum_visible, &view, &pyramid, None, &mut visible, &mut occluded).visible;
            times[2] = times[2].min(t.elapsed().as_secs_f64());
        }
        if std::env::var("TEST_ONLY").is_ok() {
            for _ in 0..300 {
                test_occlusion(&store, &frustum_visible, &view, &pyramid, None, &mut visible, &mut occluded);
            }
        }
        let ms = times.map(|t| t * 1e3);
        println!(
            "{name}: frustum {} -> occlusion {kept}; {tris} tris; select {:.3} ms raster+pyramid {:.3} ms test {:.3} ms",
            frustum_visible.count(),
            ms[0],
            ms[1],
            ms[2]
        );
    }
}
