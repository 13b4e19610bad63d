//! The built-in procedural city: a deterministic, seeded grid of blocks of buildings (each with an inner box as
//! its artist occluder) and streets full of small props (cars, lamps, crates), a few of them moving.
//!
//! Objects are generated block by block, so neighbours in the store are neighbours in space: SIMD blocks of
//! the frustum stage then tend to be all-in or all-out.

use super::{Scene, SceneObject};
use crate::camera::{Camera, CameraKey, CameraPath};
use crate::mesh::Mesh;
use crate::occluders::Occluder;
use bevy_ecs::prelude::*;
use glam::{Affine3A, Quat, Vec3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Distance between block centres: a 64-unit block plus a 16-unit street.
pub const BLOCK_PITCH: f32 = 80.0;
const BLOCK_SIZE: f32 = 64.0;
/// How much smaller than its building an occluder box is on each side, as a fraction of the building: the
/// occluder must lie strictly inside the rendered surface.
const OCCLUDER_INSET: f32 = 0.02;

/// What a city object is; it picks the object's colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum ObjectKind {
    Ground,
    Building,
    Car,
    Lamp,
    Crate,
}

impl ObjectKind {
    fn color(self) -> [u8; 4] {
        match self {
            Self::Ground => [120, 120, 126, 255],
            Self::Building => [214, 196, 160, 255],
            Self::Car => [196, 60, 52, 255],
            Self::Lamp => [60, 64, 72, 255],
            Self::Crate => [150, 104, 60, 255],
        }
    }
}

/// Object count of the glTF test scene the project ships (`tests/scenes/city_small.gltf`, written by the
/// `write_test_scene` example).
pub const TEST_SCENE_OBJECTS: usize = 600;

/// Parameters of the generator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CityParams {
    /// Seed: the same seed and object count always give the same city.
    pub seed: u64,
    /// Exact number of objects to generate.
    pub objects: usize,
    /// Fraction of cars that drive.
    pub moving_fraction: f32,
}

impl CityParams {
    /// `objects` objects from the default seed, 2% of cars driving.
    pub fn with_objects(objects: usize) -> Self {
        Self { seed: 0xC11E7, objects, moving_fraction: 0.02 }
    }
}

/// A generated city: a scene whose objects come block by block, and the size of its grid.
#[derive(Clone, Debug)]
pub struct CityScene {
    /// Meshes and objects; buildings carry occluders, 2% of cars (by default) a [`super::Velocity`].
    pub scene: Scene,
    /// Number of blocks along each side of the (square) grid.
    pub blocks_per_side: u32,
}

/// Mesh indices of the library built by [`CityScene::generate`].
mod meshes {
    pub const GROUND: u32 = 0;
    pub const BUILDING: u32 = 1;
    pub const CAR: u32 = 2;
    pub const LAMP: u32 = 3;
    pub const CRATE: u32 = 4;
}

fn mesh_library() -> Vec<Mesh> {
    let ground = Mesh::unit_cube(1);
    // 8x8 quads a face: 128 triangles, more than a cluster holds, so clusters stay within one face and their
    // normal cones are tight enough for cone culling.
    let building = Mesh::unit_cube(8);
    let mut car = Mesh::unit_cube(1).scaled(Vec3::new(4.2, 0.9, 1.8), Vec3::new(0.0, 0.65, 0.0));
    car.append(&Mesh::unit_cube(1).scaled(Vec3::new(2.2, 0.6, 1.6), Vec3::new(-0.3, 1.4, 0.0)));
    let mut lamp = Mesh::unit_cube(1).scaled(Vec3::new(0.15, 5.0, 0.15), Vec3::new(0.0, 2.5, 0.0));
    lamp.append(&Mesh::unit_cube(1).scaled(Vec3::new(0.7, 0.3, 0.7), Vec3::new(0.0, 5.1, 0.0)));
    let crate_box = Mesh::unit_cube(2).scaled(Vec3::ONE, Vec3::new(0.0, 0.5, 0.0));
    vec![ground, building, car, lamp, crate_box]
}

impl CityScene {
    /// Generates exactly `params.objects` objects, deterministically from `params.seed`.
    pub fn generate(params: CityParams) -> Self {
        let meshes = mesh_library();
        let occluder = Occluder::new(
            Mesh::unit_cube(1).scaled(Vec3::splat(1.0 - 2.0 * OCCLUDER_INSET), Vec3::ZERO).triangle_soup(),
        );
        // About 50 objects a block; lay the blocks out on a square grid around the origin.
        let blocks = params.objects.div_ceil(50).max(1);
        let blocks_per_side = (blocks as f64).sqrt().ceil() as u32;
        let mut objects = Vec::with_capacity(params.objects);
        let mut rng = Pcg64Mcg::seed_from_u64(params.seed);
        'grid: for (bx, bz) in grid_from_centre(blocks_per_side) {
            let origin = Vec3::new(bx as f32 * BLOCK_PITCH, 0.0, bz as f32 * BLOCK_PITCH);
            let mut block = Vec::new();
            generate_block(&mut rng, origin, &occluder, params.moving_fraction, &mut block);
            for object in block {
                if objects.len() == params.objects {
                    break 'grid;
                }
                objects.push(object);
            }
        }
        Self { scene: Scene::new(meshes, objects), blocks_per_side }
    }

    /// Half the side length of the city's square footprint.
    pub fn half_size(&self) -> f32 {
        self.blocks_per_side as f32 * BLOCK_PITCH * 0.5
    }

    /// Spawns the city's objects (see [`Scene::spawn`]); returns the entities in object order.
    pub fn spawn(&self, world: &mut World) -> Vec<Entity> {
        self.scene.spawn(world)
    }

    /// The built-in fly-through: down a street at eye height, up over the roofs, and back down across the city
    /// centre; 20 seconds, 60 degrees, near 0.1, infinite far.
    pub fn flythrough(&self) -> CameraPath {
        // Streets run along x at z = k * pitch + pitch / 2 (between blocks), and along z likewise.
        let street = BLOCK_PITCH * 0.5;
        let reach = (self.half_size() - BLOCK_PITCH).max(BLOCK_PITCH);
        let keys = [
            (0.0, Vec3::new(-reach, 1.8, street), Vec3::new(0.0, 2.0, street)),
            (4.0, Vec3::new(-reach * 0.4, 2.5, street), Vec3::new(reach, 2.0, street)),
            (7.0, Vec3::new(-street, 12.0, street), Vec3::new(street, 8.0, reach)),
            (10.0, Vec3::new(street, 90.0, -street), Vec3::new(reach, 0.0, reach)),
            (13.0, Vec3::new(reach * 0.5, 140.0, reach * 0.2), Vec3::new(0.0, 0.0, 0.0)),
            (16.0, Vec3::new(street, 30.0, reach * 0.5), Vec3::new(street, 2.0, -reach)),
            (20.0, Vec3::new(street, 1.8, -reach * 0.3), Vec3::new(street, 1.8, -reach)),
        ];
        CameraPath {
            fov_y_deg: 60.0,
            near: 0.1,
            far: None,
            keys: keys.into_iter().map(|(t, position, look_at)| CameraKey { t, position, look_at }).collect(),
        }
    }

    /// Fixed cameras for benchmarks: at a street corner, above the roofs looking down a street, and an
    /// overview from high above the centre.
    pub fn benchmark_cameras(&self) -> Vec<(&'static str, Camera)> {
        let street = BLOCK_PITCH * 0.5;
        let reach = self.half_size();
        vec![
            ("street", Camera::looking_at(Vec3::new(street, 1.8, street), Vec3::new(reach, 2.0, street))),
            ("roofs", Camera::looking_at(Vec3::new(street, 80.0, street), Vec3::new(reach, 0.0, reach))),
            ("overview", Camera::looking_at(Vec3::new(0.0, reach, -reach), Vec3::ZERO)),
        ]
    }
}

/// Block coordinates in square rings of growing distance from the centre, each ring walked around its
/// perimeter: any object count gives a compact city, and consecutive blocks are neighbours, so consecutive
/// store slots stay close in space.
fn grid_from_centre(side: u32) -> impl Iterator<Item = (i32, i32)> {
    let half = side as i32 / 2;
    let low = -half;
    let high = low + side as i32 - 1;
    let mut cells: Vec<(i32, i32)> = (low..=high).flat_map(|x| (low..=high).map(move |z| (x, z))).collect();
    let angle = |x: i32, z: i32| (z as f64).atan2(x as f64);
    cells.sort_by(|&(ax, az), &(bx, bz)| {
        let ring = |x: i32, z: i32| x.abs().max(z.abs());
        ring(ax, az).cmp(&ring(bx, bz)).then(angle(ax, az).total_cmp(&angle(bx, bz)))
    });
    cells.into_iter()
}

fn generate_block(
    rng: &mut Pcg64Mcg,
    origin: Vec3,
    occluder: &Occluder,
    moving_fraction: f32,
    out: &mut Vec<SceneObject>,
) {
    let place = |kind: ObjectKind, mesh, transform| SceneObject {
        mesh,
        transform,
        occluder: None,
        velocity: None,
        color: kind.color(),
    };
    out.push(place(
        ObjectKind::Ground,
        meshes::GROUND,
        Affine3A::from_scale_rotation_translation(
            // The slab reaches the middle of the streets around the block, so streets have a surface too.
            Vec3::new(BLOCK_PITCH, 0.2, BLOCK_PITCH),
            Quat::IDENTITY,
            origin + Vec3::new(0.0, -0.1, 0.0),
        ),
    ));

    // Buildings on a lots x lots grid, inside a 6-unit pavement.
    let lots = rng.random_range(2..=3);
    let lot = (BLOCK_SIZE - 12.0) / lots as f32;
    for i in 0..lots {
        for j in 0..lots {
            let width = lot * rng.random_range(0.6..0.9);
            let depth = lot * rng.random_range(0.6..0.9);
            let height =
                if rng.random_bool(0.08) { rng.random_range(90.0..160.0) } else { rng.random_range(8.0..50.0) };
            let centre = origin
                + Vec3::new(
                    -BLOCK_SIZE * 0.5 + 6.0 + lot * (i as f32 + 0.5),
                    height * 0.5,
                    -BLOCK_SIZE * 0.5 + 6.0 + lot * (j as f32 + 0.5),
                );
            out.push(SceneObject {
                occluder: Some(occluder.clone()),
                ..place(
                    ObjectKind::Building,
                    meshes::BUILDING,
                    Affine3A::from_scale_rotation_translation(Vec3::new(width, height, depth), Quat::IDENTITY, centre),
                )
            });
        }
    }

    // Lamps every 13 units along the four kerbs.
    let kerb = BLOCK_SIZE * 0.5 - 1.0;
    for side in 0..4 {
        let rotation = Quat::from_rotation_y(side as f32 * std::f32::consts::FRAC_PI_2);
        for k in 0..5 {
            let along = -BLOCK_SIZE * 0.5 + 6.0 + k as f32 * 13.0;
            let position = origin + rotation * Vec3::new(along, 0.0, kerb);
            out.push(place(ObjectKind::Lamp, meshes::LAMP, Affine3A::from_translation(position)));
        }
    }

    // Cars in the street lanes along the block's +z and +x sides; some drive.
    for k in 0..12 {
        let along_x = k % 2 == 0;
        let offset = rng.random_range(-BLOCK_PITCH * 0.5..BLOCK_PITCH * 0.5);
        let lane = BLOCK_PITCH * 0.5 + if rng.random_bool(0.5) { -3.5 } else { 3.5 };
        let (position, yaw, direction) = if along_x {
            (origin + Vec3::new(offset, 0.0, lane), 0.0, Vec3::X)
        } else {
            (origin + Vec3::new(lane, 0.0, offset), std::f32::consts::FRAC_PI_2, Vec3::NEG_Z)
        };
        let moving = rng.random_bool(moving_fraction as f64);
        let speed = if rng.random_bool(0.5) { 8.0 } else { -8.0 };
        out.push(SceneObject {
            velocity: moving.then_some(direction * speed),
            ..place(
                ObjectKind::Car,
                meshes::CAR,
                Affine3A::from_rotation_translation(Quat::from_rotation_y(yaw), position),
            )
        });
    }

    // Crates scattered on the pavement, any size and yaw.
    for _ in 0..rng.random_range(8..=14) {
        let along = rng.random_range(-BLOCK_SIZE * 0.5 + 1.0..BLOCK_SIZE * 0.5 - 1.0);
        let across = BLOCK_SIZE * 0.5 - rng.random_range(2.0..5.0);
        let rotation = Quat::from_rotation_y(rng.random_range(0..4) as f32 * std::f32::consts::FRAC_PI_2);
        let position = origin + rotation * Vec3::new(along, 0.0, across);
        out.push(place(
            ObjectKind::Crate,
            meshes::CRATE,
            Affine3A::from_scale_rotation_translation(
                Vec3::splat(rng.random_range(0.4..1.3)),
                Quat::from_rotation_y(rng.random_range(0.0..std::f32::consts::TAU)),
                position,
            ),
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generation_is_deterministic_and_exact() {
        let a = CityScene::generate(CityParams::with_objects(5_000));
        let b = CityScene::generate(CityParams::with_objects(5_000));
        let (a, b) = (&a.scene.objects, &b.scene.objects);
        assert_eq!(a.len(), 5_000);
        assert!(a.iter().zip(b).all(|(x, y)| x.transform == y.transform && x.mesh == y.mesh));
        let buildings = a.iter().filter(|o| o.mesh == meshes::BUILDING).count();
        assert!(buildings > 300, "{buildings} buildings");
        assert!(a.iter().all(|o| o.occluder.is_some() == (o.mesh == meshes::BUILDING)));
        assert!(a.iter().any(|o| o.velocity.is_some()));
    }

    #[test]
    fn occluders_lie_inside_their_buildings() {
        let city = CityScene::generate(CityParams::with_objects(200));
        let building = &city.scene.mesh_bounds[meshes::BUILDING as usize];
        let object = city.scene.objects.iter().find(|o| o.mesh == meshes::BUILDING).unwrap();
        for &p in object.occluder.as_ref().unwrap().triangles().iter() {
            assert!(((p - building.center).abs() - building.half_extent).max_element() < 0.0);
        }
    }
}
