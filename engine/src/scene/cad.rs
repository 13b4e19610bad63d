//! The built-in CAD assembly: a compact block of machine parts that the camera circles from outside, so that
//! every part is on screen in every frame. A scene where frustum culling cannot pay off; the large parts carry
//! occluders (inner boxes), so occlusion can still hide the parts inside the assembly.

use super::{Scene, SceneObject};
use crate::camera::{CameraKey, CameraPath};
use crate::mesh::Mesh;
use crate::occluders::Occluder;
use glam::{Affine3A, Quat, Vec3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// An assembly of `objects` parts from a fixed seed, and a camera path circling it.
pub fn cad(objects: usize) -> (Scene, CameraPath) {
    let mut rng = Pcg64Mcg::seed_from_u64(0xCAD);
    let meshes = vec![Mesh::unit_cube(4), Mesh::unit_cube(1)];
    let occluder = Occluder::new(Mesh::unit_cube(1).scaled(Vec3::splat(0.96), Vec3::ZERO).triangle_soup());
    // Parts fill a cube of side proportional to the cube root of their count, 1.5 units apart on average.
    let side = (objects.max(1) as f32).cbrt() * 1.5;
    let parts = (0..objects.max(1))
        .map(|_| {
            let center = Vec3::new(
                rng.random_range(-0.5..0.5) * side,
                rng.random_range(-0.5..0.5) * side,
                rng.random_range(-0.5..0.5) * side,
            );
            let large = rng.random_bool(0.15);
            let size = if large {
                Vec3::new(rng.random_range(2.0..5.0), rng.random_range(2.0..5.0), rng.random_range(0.5..3.0))
            } else {
                Vec3::new(rng.random_range(0.2..1.0), rng.random_range(0.2..1.0), rng.random_range(0.2..1.0))
            };
            let rotation = Quat::from_rotation_y(rng.random_range(0..4) as f32 * std::f32::consts::FRAC_PI_2);
            SceneObject {
                mesh: if large { 0 } else { 1 },
                transform: Affine3A::from_scale_rotation_translation(size, rotation, center),
                occluder: large.then(|| occluder.clone()),
                velocity: None,
                color: if large { [150, 160, 175, 255] } else { [210, 140, 60, 255] },
            }
        })
        .collect();
    // Far enough that the whole cube (radius side * sqrt(3) / 2, plus part sizes) fits a 60-degree view.
    let distance = side * 1.8 + 8.0;
    let keys = (0..=6)
        .map(|i| {
            let angle = i as f32 / 6.0 * std::f32::consts::TAU;
            let position = Vec3::new(angle.cos() * distance, side * 0.4, angle.sin() * distance);
            CameraKey { t: i as f32 * 3.0, position, look_at: Vec3::ZERO }
        })
        .collect();
    (Scene::new(meshes, parts), CameraPath { fov_y_deg: 60.0, near: 0.1, far: None, keys })
}
