//! The built-in open field: a wide flat ground of tiles, trees and rocks scattered over it, no occluders, and a
//! low flight across it. A scene where occlusion cannot pay off: everything in view is in front of open sky.

use super::{Scene, SceneObject};
use crate::camera::{CameraKey, CameraPath};
use crate::mesh::Mesh;
use glam::{Affine3A, Quat, Vec3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Side of one ground tile.
const TILE: f32 = 100.0;

/// A field of `objects` objects (ground tiles included) from a fixed seed, and its camera path.
pub fn field(objects: usize) -> (Scene, CameraPath) {
    let mut rng = Pcg64Mcg::seed_from_u64(0xF1E1D);
    let mut trunk = Mesh::unit_cube(1).scaled(Vec3::new(0.4, 4.0, 0.4), Vec3::new(0.0, 2.0, 0.0));
    trunk.append(&Mesh::unit_cube(2).scaled(Vec3::new(3.0, 3.0, 3.0), Vec3::new(0.0, 5.0, 0.0)));
    let meshes = vec![Mesh::unit_cube(1), trunk, Mesh::unit_cube(2)];
    // About one tile per 40 objects, on a square grid around the origin.
    let tiles_per_side = ((objects / 40).max(1) as f64).sqrt().ceil() as i32;
    let half = tiles_per_side as f32 * TILE * 0.5;
    let mut out = Vec::with_capacity(objects);
    let object = |mesh, transform, color| SceneObject { mesh, transform, occluder: None, velocity: None, color };
    'grid: for i in 0..tiles_per_side {
        for j in 0..tiles_per_side {
            let corner = Vec3::new(i as f32 * TILE - half, 0.0, j as f32 * TILE - half);
            let ground = Affine3A::from_scale_rotation_translation(
                Vec3::new(TILE, 0.2, TILE),
                Quat::IDENTITY,
                corner + Vec3::new(TILE * 0.5, -0.1, TILE * 0.5),
            );
            out.push(object(0, ground, [110, 150, 80, 255]));
            for _ in 0..39 {
                if out.len() >= objects {
                    break 'grid;
                }
                let at = corner + Vec3::new(rng.random_range(0.0..TILE), 0.0, rng.random_range(0.0..TILE));
                let yaw = Quat::from_rotation_y(rng.random_range(0.0..std::f32::consts::TAU));
                let (mesh, scale, color) = if rng.random_bool(0.6) {
                    (1, Vec3::splat(rng.random_range(0.7..1.4)), [60, 110, 50, 255])
                } else {
                    let s = rng.random_range(0.3..1.5);
                    (2, Vec3::new(s * 1.5, s, s), [140, 135, 125, 255])
                };
                out.push(object(mesh, Affine3A::from_scale_rotation_translation(scale, yaw, at), color));
            }
        }
    }
    out.truncate(objects.max(1));
    let reach = (half - TILE).max(TILE * 0.5);
    let keys = [
        (0.0, Vec3::new(-reach, 3.0, -reach * 0.3), Vec3::new(0.0, 2.0, 0.0)),
        (8.0, Vec3::new(0.0, 12.0, reach * 0.2), Vec3::new(reach, 0.0, reach * 0.5)),
        (16.0, Vec3::new(reach * 0.6, 2.5, -reach * 0.5), Vec3::new(-reach, 2.0, -reach)),
    ];
    let path = CameraPath {
        fov_y_deg: 60.0,
        near: 0.1,
        far: None,
        keys: keys.into_iter().map(|(t, position, look_at)| CameraKey { t, position, look_at }).collect(),
    };
    (Scene::new(meshes, out), path)
}
