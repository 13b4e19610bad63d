//! Cullet's scenes (the built-in city, glTF imports) as Bevy entities, for examples, tests and benchmarks.

use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::Visibility;
use bevy_ecs::prelude::*;
use bevy_ecs::world::EntityWorldMut;
use bevy_transform::components::Transform;
use cullet::scene::{Scene, SceneObject};

/// Spawns every object of `scene` as an entity with an `Aabb` (its mesh's local bounds), a `Transform` (its
/// placement, decomposed into scale, rotation and translation), `Visibility::Inherited` and, where it has one,
/// its [`cullet::Occluder`]; `extra` then adds what the app draws with (a `Mesh3d`, a material). Moving objects
/// are spawned where they start. Returns the entities in object order.
pub fn spawn_scene(
    world: &mut World,
    scene: &Scene,
    mut extra: impl FnMut(&SceneObject, &mut EntityWorldMut),
) -> Vec<Entity> {
    scene
        .objects
        .iter()
        .map(|object| {
            let bounds = &scene.mesh_bounds[object.mesh as usize];
            let aabb = Aabb {
                center: bevy_math::Vec3A::from_array(bounds.center.to_array()),
                half_extents: bevy_math::Vec3A::from_array(bounds.half_extent.to_array()),
            };
            let matrix = bevy_math::Mat4::from_cols_array(&glam::Mat4::from(object.transform).to_cols_array());
            let mut entity = world.spawn((aabb, Transform::from_matrix(matrix), Visibility::default()));
            if let Some(occluder) = &object.occluder {
                entity.insert(occluder.clone());
            }
            extra(object, &mut entity);
            entity.id()
        })
        .collect()
}
