//! Automatic occluders for scenes without artist ones (the game's `--auto-occluders`).
//!
//! A large object occludes with a subset of its own mesh: its largest triangles. Those triangles are the
//! rendered surface itself, so whatever they hide, the drawn mesh hides too; and the occluder raster, like
//! the draw pass, uses front faces only, so a triangle seen from behind hides nothing in either. Culling stays
//! conservative on any mesh, closed or open, with no inside-outside test and no simplification that could
//! move the surface outwards. The cost is coverage: the conservative raster writes only texels a triangle
//! union covers whole, so meshes made of large faces (walls, floors, terrain) occlude well and finely
//! tessellated ones little.

use super::Scene;
use crate::mesh::Mesh;
use crate::occluders::Occluder;
use glam::Vec3;
use std::collections::HashMap;

/// Which objects get an automatic occluder, and how large it is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AutoOccluderSettings {
    /// An object qualifies when its world bounding-sphere radius is at least this fraction of the scene's.
    pub min_radius_fraction: f32,
    /// Most triangles in one occluder: the largest of the mesh are taken.
    pub max_triangles: usize,
    /// Triangles smaller than this fraction of the mesh's largest one are not taken.
    pub min_area_fraction: f32,
}

impl Default for AutoOccluderSettings {
    fn default() -> Self {
        Self { min_radius_fraction: 0.02, max_triangles: 256, min_area_fraction: 0.01 }
    }
}

/// The occluder of `mesh` by [`AutoOccluderSettings`]: its largest triangles, in its local space, or `None`
/// if it has no triangle of non-zero area.
pub fn occluder_from_mesh(mesh: &Mesh, settings: &AutoOccluderSettings) -> Option<Occluder> {
    let soup = mesh.triangle_soup();
    let area = |t: &[Vec3]| (t[1] - t[0]).cross(t[2] - t[0]).length() * 0.5;
    let mut ranked: Vec<(f32, usize)> =
        soup.chunks_exact(3).enumerate().map(|(i, t)| (area(t), i)).filter(|&(a, _)| a > 0.0).collect();
    ranked.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let largest = ranked.first()?.0;
    ranked.truncate(settings.max_triangles);
    ranked.retain(|&(a, _)| a >= largest * settings.min_area_fraction);
    // Keep the mesh's order: neighbouring triangles stay together for the raster.
    ranked.sort_unstable_by_key(|&(_, i)| i);
    Some(Occluder::new(ranked.iter().flat_map(|&(_, i)| soup[3 * i..3 * i + 3].iter().copied()).collect::<Vec<_>>()))
}

/// Gives every large object of `scene` without an occluder one from its own mesh ([`occluder_from_mesh`]);
/// objects sharing a mesh share the occluder. Returns how many objects got one.
pub fn add_auto_occluders(scene: &mut Scene, settings: &AutoOccluderSettings) -> usize {
    let Some((min, max)) = scene.bounds() else { return 0 };
    let min_radius = (max - min).length() * 0.5 * settings.min_radius_fraction;
    let mut by_mesh: HashMap<u32, Option<Occluder>> = HashMap::new();
    let mut added = 0;
    for object in scene.objects.iter_mut().filter(|o| o.occluder.is_none()) {
        let (_, extent) = super::world_box(&scene.mesh_bounds[object.mesh as usize], &object.transform);
        if extent.length().partial_cmp(&min_radius).is_none_or(|o| o.is_lt()) {
            continue;
        }
        let occluder = by_mesh
            .entry(object.mesh)
            .or_insert_with(|| occluder_from_mesh(&scene.meshes[object.mesh as usize], settings));
        if let Some(occluder) = occluder {
            object.occluder = Some(occluder.clone());
            added += 1;
        }
    }
    added
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn occluder_is_the_meshes_largest_triangles_and_skips_degenerate_ones() {
        let mut mesh = Mesh::unit_cube(1).scaled(Vec3::new(10.0, 1.0, 10.0), Vec3::ZERO);
        let first = mesh.positions.len() as u32;
        mesh.positions.extend([Vec3::ZERO, Vec3::X, Vec3::X * 2.0]);
        mesh.indices.extend([first, first + 1, first + 2]);
        let settings = AutoOccluderSettings { max_triangles: 4, ..Default::default() };
        let occluder = occluder_from_mesh(&mesh, &settings).unwrap();
        assert_eq!(occluder.triangle_count(), 4);
        // The top and bottom faces (10 x 10) are the largest: every chosen vertex has |y| = 0.5.
        assert!(occluder.triangles().iter().all(|p| p.y.abs() == 0.5));
        assert!(occluder_from_mesh(&Mesh::default(), &settings).is_none());
    }
}
