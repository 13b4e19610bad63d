//! A headless stand-in for Bevy's own `bevy_city` example (`examples/large_scenes/bevy_city` of Bevy's
//! repository, as measured in Bevy's pull request #23107): its layout, entity counts, sun and camera, with
//! each Kenney model as one `Mesh3d` entity whose `Aabb` is the model's size, and no assets.
//!
//! What follows the example: a 30 x 30 grid of 5.5 x 4 blocks under one root; each block a crossroad, two
//! road parents with a stretched road each, a ground tile, and 30 car slots filled with probability 0.4 (cars
//! are children of their road and drive along it at 1.5 units a second); each block's zone by a density field
//! (forest under 0.45: a 13 x 9 lattice of none, small or large trees; low under 0.6: 4 houses, 7 fences, 18
//! small trees; medium under 0.7: 10 commercial buildings, 18 large trees, 11 stone paths, 22 fences; high: 6
//! towers); a sun 6 degrees above the horizon with Bevy's default four cascades; the camera at (15, 10, 20)
//! looking at the origin. What differs: the density field is a value noise of our own, not the example's
//! OpenSimplex, the random picks come from a generator of our own, and the model sizes are approximate.

#![allow(dead_code)]

use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::Visibility;
use bevy_ecs::prelude::*;
use bevy_light::DirectionalLight;
use bevy_math::{Quat, Vec3};
use bevy_mesh::Mesh3d;
use bevy_transform::prelude::*;
use std::f32::consts::{FRAC_PI_2, PI};

/// A car driving along its road: the road's start and direction, its lane's offset, how far it has gone and
/// the road's length.
#[derive(Clone, Copy, Debug)]
pub struct Car {
    pub entity: Entity,
    start: Vec3,
    direction: Vec3,
    offset: Vec3,
    distance: f32,
    length: f32,
}

/// The city as spawned.
pub struct BevyCity {
    /// Every `Mesh3d` entity.
    pub meshes: Vec<Entity>,
    pub cars: Vec<Car>,
    pub sun: Entity,
    /// Blocks of each zone: forest, low, medium, high.
    pub zones: [usize; 4],
}

/// splitmix64: the picks' random numbers.
struct Random(u64);

impl Random {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..1`.
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// A smooth value noise in about `-0.7..0.7`, standing in for the example's OpenSimplex field.
fn noise(seed: u64, x: f32, z: f32) -> f32 {
    let lattice = |i: i64, j: i64| {
        let mut random = Random(seed ^ (i as u64).wrapping_mul(0x9e37_79b9) ^ (j as u64).wrapping_mul(0x85eb_ca6b));
        random.unit() * 1.4 - 0.7
    };
    let (i, j) = (x.floor() as i64, z.floor() as i64);
    let (fx, fz) = (x - x.floor(), z - z.floor());
    let smooth = |t: f32| t * t * (3.0 - 2.0 * t);
    let (sx, sz) = (smooth(fx), smooth(fz));
    let top = lattice(i, j) * (1.0 - sx) + lattice(i + 1, j) * sx;
    let bottom = lattice(i, j + 1) * (1.0 - sx) + lattice(i + 1, j + 1) * sx;
    top * (1.0 - sz) + bottom * sz
}

/// Approximate sizes (x, height, z) of the Kenney models, origin at the base.
const HOUSES: [[f32; 3]; 12] = [
    [1.83, 1.14, 1.14],
    [1.29, 1.03, 1.03],
    [1.76, 1.24, 1.03],
    [1.30, 1.14, 1.03],
    [1.43, 1.14, 1.41],
    [1.45, 0.77, 1.18],
    [1.30, 0.74, 0.92],
    [1.29, 0.74, 1.03],
    [0.92, 1.15, 1.02],
    [1.03, 1.05, 1.02],
    [1.27, 1.14, 1.03],
    [1.43, 1.14, 1.09],
];
const COMMERCIAL: [[f32; 3]; 7] = [
    [0.88, 1.29, 0.94],
    [0.97, 1.29, 0.94],
    [0.88, 0.89, 1.09],
    [0.84, 1.29, 0.90],
    [0.84, 1.69, 1.03],
    [0.97, 1.69, 0.92],
    [0.88, 1.29, 1.01],
];
const TOWERS: [[f32; 3]; 7] = [
    [1.36, 2.88, 1.36],
    [1.36, 4.48, 1.36],
    [1.28, 4.08, 1.39],
    [1.28, 5.47, 1.39],
    [1.29, 4.08, 1.24],
    [1.24, 3.15, 1.24],
    [1.37, 2.27, 1.40],
];
const SMALL_TREE: [f32; 3] = [0.3, 0.6, 0.3];
const LARGE_TREE: [f32; 3] = [0.45, 0.85, 0.45];
const FENCE: [f32; 3] = [0.4, 0.25, 0.05];
const PATH: [f32; 3] = [0.4, 0.02, 0.2];
const TILE: [f32; 3] = [1.0, 0.1, 1.0];
const CAR: [f32; 3] = [1.0, 1.0, 2.5];

/// Spawns the city into `world` with `size` x `size` blocks, cars in each slot with probability
/// `car_density`, picks from `seed`.
pub fn spawn_bevy_city(world: &mut World, size: i32, car_density: f32, seed: u64) -> BevyCity {
    let mut random = Random(seed);
    let noise_seed = random.next();
    let root = world.spawn((Transform::IDENTITY, Visibility::default())).id();
    let mut meshes = Vec::new();
    let mut cars = Vec::new();
    let mut zones = [0; 4];
    let mut mesh = |world: &mut World, parent: Entity, [w, h, d]: [f32; 3], transform: Transform| {
        let aabb = Aabb::from_min_max(Vec3::new(-w / 2.0, 0.0, -d / 2.0), Vec3::new(w / 2.0, h, d / 2.0));
        let entity = world.spawn((Mesh3d::default(), aabb, transform, Visibility::default(), ChildOf(parent))).id();
        meshes.push(entity);
        entity
    };
    let half = size / 2;
    for x in -half..half {
        for z in -half..half {
            let origin = Vec3::new(x as f32 * 5.5, 0.0, z as f32 * 4.0);
            let at = |offset: Vec3| Transform::from_translation(origin + offset);
            let yawed = |offset: Vec3, yaw: f32| at(offset).with_rotation(Quat::from_rotation_y(yaw));
            mesh(world, root, TILE, at(Vec3::ZERO));
            // Two roads, each a parent of its stretched piece and of its cars.
            let roads = [
                (Vec3::new(0.75, 0.0, 0.0), Vec3::X, 4.5, 2.75, 9, [(-1.0, 3.0 * FRAC_PI_2), (1.0, FRAC_PI_2)]),
                (Vec3::new(0.0, 0.0, 0.75), Vec3::Z, 3.0, 2.0, 6, [(1.0, 0.0), (-1.0, PI)]),
            ];
            for (start, direction, length, middle, pairs, lanes) in roads {
                let road = world.spawn((at(Vec3::ZERO), Visibility::default(), ChildOf(root))).id();
                let piece = Transform::from_translation(direction * middle)
                    .with_scale(Vec3::new(length, 1.0, 1.0))
                    .with_rotation(Quat::from_rotation_arc(Vec3::X, direction));
                mesh(world, road, TILE, piece);
                for i in 0..pairs {
                    for (sign, yaw) in lanes {
                        if random.unit() >= car_density {
                            continue;
                        }
                        let offset = if direction == Vec3::X {
                            if sign < 0.0 { Vec3::new(4.25, 0.0, -0.15) } else { Vec3::new(-0.25, 0.0, 0.15) }
                        } else if sign > 0.0 {
                            Vec3::new(-0.15, 0.0, -0.25)
                        } else {
                            Vec3::new(0.15, 0.0, 2.75)
                        };
                        let car = Car {
                            entity: Entity::PLACEHOLDER,
                            start,
                            direction: direction * sign,
                            offset,
                            distance: i as f32 * 0.5 % length,
                            length,
                        };
                        let transform = Transform::from_translation(car.position())
                            .with_rotation(Quat::from_rotation_y(yaw))
                            .with_scale(Vec3::splat(0.15));
                        let entity = mesh(world, road, CAR, transform);
                        cars.push(Car { entity, ..car });
                    }
                }
            }
            let density = noise(noise_seed, origin.x * 0.025, origin.z * 0.025) * 0.5 + 0.5;
            let zone = [0.45, 0.6, 0.7].iter().filter(|&&bound| density >= bound).count();
            zones[zone] += 1;
            let mut spawn = |world: &mut World, model: [f32; 3], transform: Transform| {
                mesh(world, root, model, transform);
            };
            match zone {
                0 => {
                    for i in 0..13 {
                        for j in 0..9 {
                            let place = at(Vec3::new(0.75 + 0.325 * i as f32, 0.0, 0.85 + 0.3 * j as f32));
                            match random.below(3) {
                                1 => spawn(world, SMALL_TREE, place),
                                2 => spawn(world, LARGE_TREE, place),
                                _ => {}
                            }
                        }
                    }
                }
                1 => {
                    for (x, z, yaw) in [(1.8, 1.25, 0.0), (3.6, 1.25, 0.0), (1.8, 2.75, PI), (3.6, 2.75, PI)] {
                        spawn(world, HOUSES[random.below(HOUSES.len())], yawed(Vec3::new(x, 0.0, z), yaw));
                    }
                    for i in 0..7 {
                        spawn(world, FENCE, yawed(Vec3::new(2.75, 0.0, 0.75 + 0.4 * i as f32), FRAC_PI_2));
                    }
                    for x in [0.75, 4.75] {
                        for k in 0..9 {
                            spawn(world, SMALL_TREE, at(Vec3::new(x, 0.0, 0.75 + 0.3 * k as f32)));
                        }
                    }
                }
                2 => {
                    for k in 1..=5 {
                        for (z, yaw) in [(1.0, 0.0), (3.0, PI)] {
                            let model = COMMERCIAL[random.below(COMMERCIAL.len())];
                            spawn(world, model, yawed(Vec3::new(0.9 * k as f32, 0.0, z), yaw));
                        }
                    }
                    for k in 0..9 {
                        for z in [1.75, 2.25] {
                            spawn(world, LARGE_TREE, at(Vec3::new(0.75 + 0.45 * k as f32, 0.0, z)));
                        }
                    }
                    for k in 0..11 {
                        let path = yawed(Vec3::new(0.75 + 0.4 * k as f32, 0.02, 2.0), FRAC_PI_2);
                        spawn(world, PATH, path.with_scale(Vec3::new(1.0, 2.0, 1.0)));
                    }
                    for k in 0..11 {
                        for z in [1.85, 2.15] {
                            spawn(world, FENCE, at(Vec3::new(0.75 + 0.4 * k as f32, 0.0, z)));
                        }
                    }
                }
                _ => {
                    for k in 0..3 {
                        for (z, yaw) in [(1.25, 0.0), (2.75, PI)] {
                            let model = TOWERS[random.below(TOWERS.len())];
                            spawn(world, model, yawed(Vec3::new(1.25 + 1.5 * k as f32, 0.0, z), yaw));
                        }
                    }
                }
            }
        }
    }
    let sun = world
        .spawn((
            DirectionalLight { shadow_maps_enabled: true, ..Default::default() },
            Transform::from_xyz(1.0, 0.15, 1.0).looking_at(Vec3::ZERO, Vec3::Y),
        ))
        .id();
    BevyCity { meshes, cars, sun, zones }
}

impl Car {
    /// Its position relative to its road.
    fn position(&self) -> Vec3 {
        self.start + self.offset + self.direction * self.distance
    }
}

/// Drives every car `dt` seconds at 1.5 units a second, back to its road's start past its end, as the
/// example's `simulate_cars` does.
pub fn drive(world: &mut World, cars: &mut [Car], dt: f32) {
    for car in cars {
        car.distance += 1.5 * dt;
        if car.distance > car.length {
            car.distance = 0.0;
        }
        world.get_mut::<Transform>(car.entity).unwrap().translation = car.position();
    }
}

/// The example's camera transform: at (15, 10, 20) looking at the origin.
pub fn example_camera() -> Transform {
    Transform::from_xyz(15.0, 10.0, 20.0).looking_at(Vec3::ZERO, Vec3::Y)
}
