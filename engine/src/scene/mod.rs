//! Scenes: the input of the pipeline. A [`Scene`] is a library of triangle meshes and the objects that place
//! them, spawned into a `bevy_ecs` world as the components the culling stages read.
//!
//! - `city` generates the built-in procedural city (dense, occluded), `field` an open field (nothing to
//!   occlude), `cad` an assembly always entirely on screen (nothing for the frustum to cull), `building` floors of
//!   rooms with their cells and portals (the portal culler's scene): feature `scenes`;
//! - `gltf_import` loads a glTF 2.0 file (`.gltf` or `.glb`), artist occluders included; `gltf_export` writes
//!   a scene as glTF, so the project ships test scenes its own generator made: feature `gltf`;
//! - `auto_occluders` gives occluders to large meshes of scenes that have none;
//! - [`flight`] flies a camera along a path through a spawned scene, frame by frame, moving the objects that
//!   have a [`Velocity`] (the demo's movers): the sample game, the tests and the benchmarks drive the
//!   pipeline through it.

pub mod auto_occluders;
#[cfg(feature = "scenes")]
pub mod building;
#[cfg(feature = "scenes")]
pub mod cad;
#[cfg(feature = "scenes")]
pub mod city;
#[cfg(feature = "scenes")]
pub mod field;
pub mod flight;
#[cfg(feature = "gltf")]
pub mod gltf_export;
#[cfg(feature = "gltf")]
pub mod gltf_import;

pub use flight::{Flight, FrameDelta};

use crate::bounds::{LocalBounds, ObjectTransform, Static};
use crate::camera::{CameraKey, CameraPath};
use crate::cells::Cells;
use crate::mesh::{Mesh, MeshRef, ObjectColor};
use crate::occluders::Occluder;
use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3};

/// Velocity of a moving object of a demo scene, in units per second; [`flight::move_objects`] moves it.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Velocity(pub Vec3);

/// One object of a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneObject {
    /// Index into [`Scene::meshes`].
    pub mesh: u32,
    /// Placement in the world.
    pub transform: Affine3A,
    /// Occluder in the object's local space; shared between objects of the same shape.
    pub occluder: Option<Occluder>,
    /// Velocity in units per second for moving objects; `None` for static ones.
    pub velocity: Option<Vec3>,
    /// Flat colour, RGBA8.
    pub color: [u8; 4],
}

/// A mesh library and the objects that reference it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scene {
    /// Shared meshes, indexed by [`SceneObject::mesh`]. A mesh may have vertices and no triangles: its objects
    /// draw nothing but have bounds (glTF occluders without a drawn parent are carried so).
    pub meshes: Vec<Mesh>,
    /// Local bounds of each mesh (a zero box at the origin for a mesh without vertices).
    pub mesh_bounds: Vec<LocalBounds>,
    /// The objects.
    pub objects: Vec<SceneObject>,
    /// The interior's cells and portals, where the scene has them ([`crate::cells`]): spawned as a resource.
    pub cells: Option<Cells>,
    /// Coarser levels of detail the scene brings for some of its meshes (glTF `MSFT_lod`): `(mesh, levels)`,
    /// finest first after the mesh itself, in the mesh's space. Add them with [`Scene::give_levels`], which
    /// grows the mesh's bounds to hold them; `cullet::lod::LodLibrary::for_scene` measures their error.
    pub given_levels: Vec<(u32, Vec<Mesh>)>,
}

impl Scene {
    /// A scene of `meshes` and `objects`; every object's mesh index must be in range.
    pub fn new(meshes: Vec<Mesh>, objects: Vec<SceneObject>) -> Self {
        let mesh_bounds = meshes
            .iter()
            .map(|m| m.local_bounds().unwrap_or(LocalBounds { center: Vec3::ZERO, half_extent: Vec3::ZERO }))
            .collect();
        debug_assert!(objects.iter().all(|o| (o.mesh as usize) < meshes.len()));
        Self { meshes, mesh_bounds, objects, cells: None, given_levels: Vec::new() }
    }

    /// Gives `mesh` the coarser `levels` (finest first, in the mesh's space), replacing any it had, and grows
    /// the mesh's bounds to hold every level, so that culling stays conservative whichever is drawn. Nothing
    /// changes for a mesh index out of range or no levels.
    pub fn give_levels(&mut self, mesh: u32, levels: Vec<Mesh>) {
        if levels.is_empty() || mesh as usize >= self.meshes.len() {
            return;
        }
        let every_level = std::iter::once(&self.meshes[mesh as usize]).chain(&levels);
        let points: Vec<Vec3> = every_level.flat_map(|m| m.positions.iter().copied()).collect();
        if let Some(bounds) = LocalBounds::from_points(&points) {
            self.mesh_bounds[mesh as usize] = bounds;
        }
        self.given_levels.retain(|(m, _)| *m != mesh);
        self.given_levels.push((mesh, levels));
    }

    /// Spawns every object as an entity with [`LocalBounds`], [`ObjectTransform`], [`MeshRef`],
    /// [`ObjectColor`], [`Static`] or [`Velocity`], and its [`Occluder`] if it has one. Returns the entities in
    /// object order. The scene's [`Cells`], where it has them, become a resource.
    pub fn spawn(&self, world: &mut World) -> Vec<Entity> {
        if let Some(cells) = &self.cells {
            world.insert_resource(cells.clone());
        }
        self.objects
            .iter()
            .map(|object| {
                let mut entity = world.spawn((
                    self.mesh_bounds[object.mesh as usize],
                    ObjectTransform(object.transform),
                    MeshRef(object.mesh),
                    ObjectColor(object.color),
                ));
                match object.velocity {
                    Some(velocity) => entity.insert(Velocity(velocity)),
                    None => entity.insert(Static),
                };
                if let Some(occluder) = &object.occluder {
                    entity.insert(occluder.clone());
                }
                entity.id()
            })
            .collect()
    }

    /// Moves every object (and cell) by `offset` (in f32, as a world that far from its origin would store it).
    pub fn translate(&mut self, offset: Vec3) {
        for object in &mut self.objects {
            object.transform.translation += glam::Vec3A::from(offset);
        }
        if let Some(cells) = &mut self.cells {
            cells.translate(offset);
        }
    }

    /// Number of triangles drawn by all objects.
    pub fn triangle_count(&self) -> usize {
        self.objects.iter().map(|o| self.meshes[o.mesh as usize].triangle_count()).sum()
    }

    /// Number of objects carrying an occluder.
    pub fn occluder_count(&self) -> usize {
        self.objects.iter().filter(|o| o.occluder.is_some()).count()
    }

    /// Minimum and maximum corner of the box around every object's world box, or `None` without objects.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.objects
            .iter()
            .map(|o| {
                let (center, extent) = world_box(&self.mesh_bounds[o.mesh as usize], &o.transform);
                (center - extent, center + extent)
            })
            .filter(|(min, max)| min.is_finite() && max.is_finite())
            .reduce(|(a_min, a_max), (b_min, b_max)| (a_min.min(b_min), a_max.max(b_max)))
    }

    /// The default camera path of a scene without one: one slow orbit around the scene's bounds at 30 degrees
    /// elevation, from a distance that keeps the whole box in a 60-degree view, always looking at its centre;
    /// 20 seconds, near plane at 1/10 000 of the distance, infinite far.
    pub fn orbit_path(&self) -> CameraPath {
        let (min, max) = self.bounds().unwrap_or((Vec3::splat(-1.0), Vec3::splat(1.0)));
        let center = (min + max) * 0.5;
        let radius = ((max - min).length() * 0.5).max(1e-3);
        // A sphere of `radius` fits a 60-degree cone from `radius / sin(30 deg)` = twice the radius.
        let distance = radius * 2.2;
        let keys = (0..=8)
            .map(|i| {
                let angle = i as f32 / 8.0 * std::f32::consts::TAU;
                let elevation = 30f32.to_radians();
                let direction =
                    Vec3::new(angle.cos() * elevation.cos(), elevation.sin(), angle.sin() * elevation.cos());
                CameraKey { t: i as f32 * 2.5, position: center + direction * distance, look_at: center }
            })
            .collect();
        CameraPath { fov_y_deg: 60.0, near: distance * 1e-4, far: None, keys }
    }
}

/// Centre and half-extent of the world box around `local` placed by `transform` (f32, not rounded outwards:
/// for scene statistics and camera placement, not for culling).
fn world_box(local: &LocalBounds, transform: &Affine3A) -> (Vec3, Vec3) {
    let m = transform.matrix3;
    let extent = m.x_axis.abs() * local.half_extent.x
        + m.y_axis.abs() * local.half_extent.y
        + m.z_axis.abs() * local.half_extent.z;
    (transform.transform_point3(local.center), extent.into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_sees_the_whole_scene_from_outside() {
        let mesh = Mesh::unit_cube(1);
        let objects = vec![SceneObject {
            mesh: 0,
            transform: Affine3A::from_scale_rotation_translation(
                Vec3::new(10.0, 2.0, 4.0),
                glam::Quat::IDENTITY,
                Vec3::new(100.0, 0.0, 0.0),
            ),
            occluder: None,
            velocity: None,
            color: [255; 4],
        }];
        let scene = Scene::new(vec![mesh], objects);
        let (min, max) = scene.bounds().unwrap();
        assert_eq!((min, max), (Vec3::new(95.0, -1.0, -2.0), Vec3::new(105.0, 1.0, 2.0)));
        let path = scene.orbit_path();
        for t in [0.0, 3.0, 11.0, 20.0] {
            let (position, look_at) = path.sample(t);
            assert!(look_at.abs_diff_eq(Vec3::new(100.0, 0.0, 0.0), 1e-3));
            assert!(position.distance(look_at) > (max - min).length());
        }
    }
}
