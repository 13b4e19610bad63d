//! The occlusion benches' fixture: a city seen from its street-corner benchmark camera, with its bounds, the
//! frustum survivors and its occluders.

use bevy_ecs::entity::Entity;
use cullet::depth::{DepthPyramid, ScreenView};
use cullet::frustum::{FrustumOptions, cull_frustum};
use cullet::occluders::{Occluder, OccluderInstance, select_occluders};
use cullet::occlusion::{OcclusionStats, test_occlusion};
use cullet::scene::city::{CityParams, CityScene};
use cullet::{BoundsStore, Camera, ObjectTransform, VisibleSet};
use std::collections::HashMap;

/// A city from its street-corner benchmark camera: bounds, frustum survivors and its occluders.
pub struct StreetView {
    pub store: BoundsStore,
    pub camera: Camera,
    pub frustum_visible: VisibleSet,
    /// Occluder and transform by store slot.
    pub occluders: HashMap<usize, (Occluder, glam::Affine3A)>,
}

impl StreetView {
    /// The city of `objects` objects, its frustum culled for the street camera.
    pub fn new(objects: usize) -> Self {
        let city = CityScene::generate(CityParams::with_objects(objects));
        let mut store = BoundsStore::default();
        let mut occluders = HashMap::new();
        for (i, object) in city.scene.objects.iter().enumerate() {
            let entity = Entity::from_raw_u32(i as u32 + 1).unwrap();
            let local = city.scene.mesh_bounds[object.mesh as usize];
            let slot = store.update(entity, &local, &ObjectTransform(object.transform)).unwrap();
            if let Some(occluder) = &object.occluder {
                store.set_occluder(slot, true).unwrap();
                occluders.insert(slot, (occluder.clone(), object.transform));
            }
        }
        let camera = city.benchmark_cameras()[0].1;
        let mut frustum_visible = VisibleSet::default();
        cull_frustum(&store, &camera.frustum().unwrap(), FrustumOptions::default(), &mut frustum_visible);
        Self { store, camera, frustum_visible, occluders }
    }

    /// The best occluders in view, up to `budget` triangles, as the pipeline chooses them.
    pub fn select(&self, budget: usize) -> Vec<OccluderInstance<'_>> {
        select_occluders(&self.store, &self.frustum_visible, self.camera.position, budget, |slot| {
            let (occluder, transform) = self.occluders.get(&slot)?;
            Some(OccluderInstance { occluder, transform: *transform })
        })
        .into_iter()
        .map(|(_, instance)| instance)
        .collect()
    }

    /// The occludee test of every frustum survivor against `pyramid`.
    pub fn test(
        &self,
        view: &ScreenView,
        pyramid: &DepthPyramid,
        visible: &mut VisibleSet,
        occluded: &mut VisibleSet,
    ) -> OcclusionStats {
        test_occlusion(&self.store, &self.frustum_visible, view, pyramid, None, visible, occluded)
    }
}
