//! Prints how the frustum stage's groups of 64 classify for the city's benchmark cameras.
use cullet::BoundsStore;
use cullet::frustum::GroupClass;
use cullet::scene::city::{CityParams, CityScene};
use std::time::Instant;

fn main() {
    let city = CityScene::generate(CityParams::with_objects(1_000_000));
    let mut store = BoundsStore::default();
    for (i, object) in city.scene.objects.iter().enumerate() {
        let entity = bevy_ecs::entity::Entity::from_raw_u32(i as u32 + 1).unwrap();
        let local = city.scene.mesh_bounds[object.mesh as usize];
        store.update(entity, &local, &cullet::ObjectTransform(object.transform)).unwrap();
    }
    let mut visible = cullet::VisibleSet::default();
    for (name, camera) in city.benchmark_cameras() {
        let frustum = camera.frustum().unwrap();
        let (mut out, mut inside, mut crossing) = (0, 0, 0);
        for group in store.groups() {
            match frustum.classify_group(group) {
                GroupClass::Outside => out += 1,
                GroupClass::Inside => inside += 1,
                GroupClass::Crossing => crossing += 1,
            }
        }
        let start = Instant::now();
        let mut kept = 0;
        for _ in 0..20 {
            kept = cullet::frustum::cull_frustum(
                &store,
                &frustum,
                cullet::frustum::FrustumOptions::default(),
                &mut visible,
            );
        }
        println!(
            "{name}: out {out} in {inside} crossing {crossing}; kept {kept}; {:.3} ms",
            start.elapsed().as_secs_f64() * 50.0
        );
    }
}
