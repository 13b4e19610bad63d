//! Culls 60 consecutive frames (30 a second) of the city's fly-through with all planes and with plane
//! coherence, in the city's store order and shuffled, and checks both give the same bits. Wall time on a
//! shared machine is too noisy to compare the two; count their instructions instead (deterministic):
//! `valgrind --tool=callgrind --collect-atstart=no --toggle-collect='frustum_coherence::all_planes'
//! target/release/examples/frustum_coherence [city|shuffled]`, then the same with `frustum_coherence::coherent`.
//! It runs on the main thread alone, so that callgrind, which counts per thread from the toggle, sees all work.
//! `cargo build --release -p cullet --example frustum_coherence`
use cullet::bounds::WorldBounds;
use cullet::frustum::{FrustumOptions, PlaneCoherence, SimdBackend, cull_frustum};
use cullet::scene::city::{CityParams, CityScene};
use cullet::{BoundsStore, Frustum, VisibleSet};

/// Every frame culled with all planes; the visible sets.
#[inline(never)]
fn all_planes(store: &BoundsStore, frusta: &[Frustum]) -> Vec<VisibleSet> {
    let mut sets = vec![VisibleSet::default(); frusta.len()];
    for (frustum, visible) in frusta.iter().zip(&mut sets) {
        cull_frustum(store, frustum, FrustumOptions { backend: SimdBackend::Auto, ..Default::default() }, visible);
    }
    sets
}

/// Every frame culled with plane coherence; the visible sets.
#[inline(never)]
fn coherent(store: &BoundsStore, frusta: &[Frustum]) -> Vec<VisibleSet> {
    let mut coherence = PlaneCoherence::default();
    let mut sets = vec![VisibleSet::default(); frusta.len()];
    for (frustum, visible) in frusta.iter().zip(&mut sets) {
        cull_frustum(
            store,
            frustum,
            FrustumOptions { backend: SimdBackend::Auto, coherence: Some(&mut coherence), ..Default::default() },
            visible,
        );
    }
    sets
}

fn main() {
    rayon::ThreadPoolBuilder::new().num_threads(1).use_current_thread().build_global().expect("first pool");
    let city = CityScene::generate(CityParams::with_objects(100_000));
    let bounds: Vec<WorldBounds> = city
        .scene
        .objects
        .iter()
        .enumerate()
        .map(|(i, object)| {
            let entity = bevy_ecs::entity::Entity::from_raw_u32(i as u32 + 1).unwrap();
            WorldBounds::from_local(entity, &city.scene.mesh_bounds[object.mesh as usize], &object.transform).unwrap()
        })
        .collect();
    let store_of = |order: &dyn Fn(usize) -> usize| {
        let mut store = BoundsStore::default();
        for i in 0..bounds.len() {
            let entity = bevy_ecs::entity::Entity::from_raw_u32(i as u32 + 1).unwrap();
            store.insert(entity, &bounds[order(i)]).unwrap();
        }
        store
    };
    let path = city.flythrough();
    let frusta: Vec<Frustum> =
        (0..60).map(|frame| path.camera_at(5.0 + frame as f32 / 30.0, 16.0 / 9.0).frustum().unwrap()).collect();
    let n = bounds.len();
    let only = std::env::args().nth(1);
    for (name, order) in [("city", &(|i| i) as &dyn Fn(usize) -> usize), ("shuffled", &|i| (i * 7919) % n)] {
        if only.as_deref().is_some_and(|only| only != name) {
            continue;
        }
        let store = store_of(order);
        let (plain, with_coherence) = (all_planes(&store, &frusta), coherent(&store, &frusta));
        assert_eq!(plain, with_coherence, "{name}: coherence changed the result");
        let visible: usize = plain.iter().map(VisibleSet::count).sum();
        println!(
            "{name}: {} frames, {} visible a frame, same bits with and without coherence",
            frusta.len(),
            visible / 60
        );
    }
}
