//! What an object draws: triangle [`Mesh`]es (which the GPU stages split into clusters), the [`MeshRef`]
//! component naming an object's mesh, and its flat [`ObjectColor`].

use crate::bounds::LocalBounds;
use bevy_ecs::prelude::*;
use glam::Vec3;

/// Which mesh of the scene's mesh library the object draws (an index into the meshes the GPU culler was built
/// with). An object without one has bounds but draws nothing.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct MeshRef(pub u32);

/// Flat colour an object is drawn with, RGBA8 (alpha unused). Without it the draw pass picks a colour from the
/// object's store slot.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct ObjectColor(pub [u8; 4]);

/// An indexed triangle list in the object's local space.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Every three indices form one counter-clockwise (front-facing) triangle.
    pub indices: Vec<u32>,
}

impl Mesh {
    /// The axis-aligned box `-0.5..=0.5` on each axis, each face split into `subdivisions` x `subdivisions`
    /// quads (two triangles each), faces wound counter-clockwise seen from outside.
    pub fn unit_cube(subdivisions: u32) -> Self {
        let n = subdivisions.max(1);
        let mut mesh = Self::default();
        // Each face: its outward normal axis, and two tangent axes whose cross product is the normal.
        let faces = [
            (Vec3::X, Vec3::NEG_Z, Vec3::Y),
            (Vec3::NEG_X, Vec3::Z, Vec3::Y),
            (Vec3::Y, Vec3::X, Vec3::NEG_Z),
            (Vec3::NEG_Y, Vec3::X, Vec3::Z),
            (Vec3::Z, Vec3::X, Vec3::Y),
            (Vec3::NEG_Z, Vec3::NEG_X, Vec3::Y),
        ];
        for (normal, u_axis, v_axis) in faces {
            let first = mesh.positions.len() as u32;
            for j in 0..=n {
                for i in 0..=n {
                    let (u, v) = (i as f32 / n as f32 - 0.5, j as f32 / n as f32 - 0.5);
                    mesh.positions.push(normal * 0.5 + u_axis * u + v_axis * v);
                }
            }
            for j in 0..n {
                for i in 0..n {
                    let a = first + j * (n + 1) + i;
                    let (b, c, d) = (a + 1, a + n + 2, a + n + 1);
                    mesh.indices.extend_from_slice(&[a, b, c, a, c, d]);
                }
            }
        }
        mesh
    }

    /// A copy with every vertex moved by `scale * p + offset`.
    pub fn scaled(&self, scale: Vec3, offset: Vec3) -> Self {
        Self { positions: self.positions.iter().map(|&p| p * scale + offset).collect(), indices: self.indices.clone() }
    }

    /// Appends `other`'s triangles.
    pub fn append(&mut self, other: &Mesh) {
        let first = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.indices.extend(other.indices.iter().map(|&i| i + first));
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// The box around all vertices, or `None` for an empty mesh.
    pub fn local_bounds(&self) -> Option<LocalBounds> {
        LocalBounds::from_points(&self.positions)
    }

    /// The triangles as a flat list of corner positions, three per triangle.
    pub fn triangle_soup(&self) -> Vec<Vec3> {
        self.indices.iter().map(|&i| self.positions[i as usize]).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_cube_is_closed_and_outward_facing() {
        let cube = Mesh::unit_cube(3);
        assert_eq!(cube.triangle_count(), 6 * 9 * 2);
        let bounds = cube.local_bounds().unwrap();
        assert_eq!(bounds.half_extent, Vec3::splat(0.5));
        for tri in cube.triangle_soup().chunks(3) {
            let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
            let centroid = (tri[0] + tri[1] + tri[2]) / 3.0;
            assert!(normal.dot(centroid) > 0.0, "triangle faces inward");
        }
    }
}
