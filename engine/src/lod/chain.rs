//! Generating a mesh's levels with meshoptimizer's simplifier, each level's geometric error measured against
//! the full-detail mesh in the mesh's own space.

use super::{LodError, LodLevel};
use crate::mesh::Mesh;

/// Error, as a fraction of the mesh's extent, below which a level counts as lossless: a thousandth of the
/// object's size, under a pixel until the object is a thousand pixels tall.
const LOSSLESS: f32 = 1e-3;

/// How [`build_chain`] simplifies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChainSettings {
    /// Most levels a chain has, the full-detail mesh included (at least 1, at most [`super::MAX_LEVELS`]).
    pub max_levels: usize,
    /// Each level aims at this fraction of the previous level's triangles, in `(0, 1)`.
    pub reduction: f32,
    /// No level deviates from the full-detail mesh by more than this fraction of the mesh's extent (its
    /// largest side): a coarser level would only be chosen where the whole object is a few pixels tall.
    pub max_relative_error: f32,
}

impl Default for ChainSettings {
    /// Up to 6 levels, halving the triangles, up to 10% of the extent.
    fn default() -> Self {
        Self { max_levels: 6, reduction: 0.5, max_relative_error: 0.1 }
    }
}

/// The levels of `mesh`, finest first: the mesh itself (error 0), then simplified levels with fewer triangles
/// and a larger error each (in `mesh`'s units: how far the level's surface may lie from the full-detail one).
/// A level's error is the larger of meshoptimizer's estimate and the distance measured between the surfaces
/// (from each sample of the level, and from each vertex of `mesh`: `Surface::distance_to_level`), so that a
/// pixel threshold holds for the surfaces, not only for the estimate.
/// A level no coarser, or no more accurate, than its neighbours is left out, so that every level is the
/// coarsest for some error. Vertices are welded by position before simplifying (the meshes carry positions
/// only), so faces that share an edge stay joined.
///
/// # Errors
/// [`LodError`] for a mesh the simplifier must not read: indices not a whole number of triangles, an index
/// past the positions, a position not finite. The mesh itself is then the only level
/// ([`super::LodLibrary::build`] keeps it so).
pub fn build_chain(mesh: &Mesh, settings: &ChainSettings) -> Result<Vec<LodLevel>, LodError> {
    simplified_chain(mesh, settings, Vertices::Welded)
}

/// [`build_chain`], with every level indexing `mesh`'s own vertices: each level's positions are all of `mesh`'s,
/// in its order, and none is welded to another (vertices that share a position but differ in other attributes,
/// a seam, stay apart; meshoptimizer keeps the seam where it collapses edges). For a renderer whose vertices
/// carry more than positions (normals, texture coordinates): it draws a level with the mesh's vertex buffer and
/// the level's indices. A level's bounds are the mesh's.
///
/// # Errors
/// As [`build_chain`].
pub fn build_chain_keeping_vertices(mesh: &Mesh, settings: &ChainSettings) -> Result<Vec<LodLevel>, LodError> {
    simplified_chain(mesh, settings, Vertices::Kept)
}

/// Which vertices a chain's levels index.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Vertices {
    /// Welded by position, and only those each level uses.
    Welded,
    /// All of the mesh's.
    Kept,
}

fn simplified_chain(mesh: &Mesh, settings: &ChainSettings, vertices: Vertices) -> Result<Vec<LodLevel>, LodError> {
    validate(mesh)?;
    let full = LodLevel { mesh: mesh.clone(), error: 0.0 };
    let max_levels = settings.max_levels.clamp(1, super::MAX_LEVELS);
    if max_levels == 1 || mesh.indices.is_empty() {
        return Ok(vec![full]);
    }
    let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    // Validated above: every index is below `positions.len()`, the count a multiple of 3.
    let (positions, indices) = match vertices {
        Vertices::Welded => {
            let (unique, remap) = meshopt::generate_vertex_remap(&positions, Some(&mesh.indices));
            let indices = meshopt::remap_index_buffer(Some(&mesh.indices), positions.len(), &remap);
            (meshopt::remap_vertex_buffer(&positions, unique, &remap), indices)
        }
        Vertices::Kept => (positions, mesh.indices.clone()),
    };
    let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&positions), 12, 0)
        .expect("12-byte positions at offset 0 fit their own buffer");
    let extent = meshopt::simplify_scale(&adapter);
    let options = meshopt::SimplifyOptions::ErrorAbsolute;
    let error_limit = settings.max_relative_error.max(0.0) * extent;

    let surface = super::distance::Surface::of(mesh);
    let mut levels = vec![full];
    let mut triangles = indices.len() / 3;
    // First the coarsest level that is as good as lossless (coplanar triangles merged: over-tessellated flat
    // faces, as in the city's boxes), then halving.
    let mut lossless = true;
    while levels.len() < max_levels {
        let (target, limit) = if lossless {
            (0, LOSSLESS * extent)
        } else {
            (((triangles as f32 * settings.reduction.clamp(0.01, 0.99)) as usize).max(1) * 3, error_limit)
        };
        let mut error = 0.0;
        let simplified = meshopt::simplify(&indices, &adapter, target, limit, options, Some(&mut error));
        let was_lossless = std::mem::replace(&mut lossless, false);
        let kept = simplified.len() / 3;
        // The simplifier stops at the error limit or where collapses would tear the mesh: no real saving.
        if kept == 0 || kept as f32 > 0.9 * triangles as f32 {
            if was_lossless {
                continue;
            }
            break;
        }
        let level = match vertices {
            Vertices::Welded => compact(&positions, simplified),
            Vertices::Kept => Mesh { positions: mesh.positions.clone(), indices: simplified },
        };
        let measured = surface.as_ref().map_or(0.0, |surface| surface.distance_to_level(&level));
        let error = error.max(measured).max(levels.last().map_or(0.0, |l| l.error));
        let level = LodLevel { mesh: level, error };
        // A coarser level as accurate as the one before replaces it (never the full-detail mesh).
        if levels.len() > 1 && levels.last().is_some_and(|last| last.error >= error) {
            levels.pop();
        }
        levels.push(level);
        triangles = kept;
    }
    Ok(levels)
}

/// The levels of `mesh` from the coarser `given` ones a scene brings (finest first, in `mesh`'s space), each
/// with its error measured as the distance between its surface and `mesh`'s ([`super::surface_distance`],
/// through one grid of `mesh`'s triangles for every level),
/// raised where needed so that errors never decrease down the chain. The first level is `mesh` itself (error 0).
///
/// A given level that cannot serve is left out, and why is returned with the levels: one the simplifier's
/// checks refuse ([`build_chain`]'s errors), one with no fewer triangles than the level kept before it
/// ([`LodError::NotCoarser`]), one farther from `mesh` than `mesh` is large or without triangles
/// ([`LodError::StrayLevel`]), and those past [`super::MAX_LEVELS`] ([`LodError::LevelCount`]). Where `mesh`
/// itself is refused, it is its only level.
pub fn given_chain(mesh: &Mesh, given: &[Mesh]) -> (Vec<LodLevel>, Vec<LodError>) {
    let mut levels = vec![LodLevel { mesh: mesh.clone(), error: 0.0 }];
    if let Err(error) = validate(mesh) {
        return (levels, vec![error]);
    }
    let mut refused = Vec::new();
    let (surface, bounds) = (super::distance::Surface::of(mesh), mesh.local_bounds());
    let size = bounds.map_or(0.0, |b| 2.0 * b.half_extent.max_element());
    for (l, level) in given.iter().enumerate().map(|(i, level)| (i + 1, level)) {
        if levels.len() == super::MAX_LEVELS {
            refused.push(LodError::LevelCount { levels: 1 + given.len() });
            break;
        }
        let finer = levels.last().map_or(0, |last| last.mesh.triangle_count());
        let triangles = level.triangle_count();
        if let Err(error) = validate(level) {
            refused.push(error);
            continue;
        }
        if triangles >= finer {
            refused.push(LodError::NotCoarser { level: l, triangles, finer });
            continue;
        }
        // The boxes' farthest sides bound the distance from below: a stray level is refused before the
        // (costlier) measurement.
        let distance = match (bounds, level.local_bounds()) {
            (Some(a), Some(b)) => {
                let (centres, extents) = (a.center - b.center, a.half_extent - b.half_extent);
                ((centres - extents).abs().max((centres + extents).abs())).max_element()
            }
            _ => f32::INFINITY,
        };
        let measured = |surface: &super::distance::Surface| surface.distance_to(level);
        let distance = if distance <= size { surface.as_ref().map_or(f32::INFINITY, measured) } else { distance };
        if distance.is_nan() || distance > size {
            refused.push(LodError::StrayLevel { level: l, distance, size });
            continue;
        }
        let error = distance.max(levels.last().map_or(0.0, |last| last.error));
        levels.push(LodLevel { mesh: level.clone(), error });
    }
    (levels, refused)
}

/// The mesh of `indices` into `positions`, with only the positions it uses, in first-use order.
fn compact(positions: &[[f32; 3]], mut indices: Vec<u32>) -> Mesh {
    let used = meshopt::optimize_vertex_fetch(&mut indices, positions);
    let vertices = indices.iter().copied().max().map_or(0, |m| m as usize + 1);
    Mesh { positions: used[..vertices].iter().map(|&p| glam::Vec3::from_array(p)).collect(), indices }
}

/// Checks what meshoptimizer relies on: whole triangles, indices in range, finite positions.
fn validate(mesh: &Mesh) -> Result<(), LodError> {
    if !mesh.indices.len().is_multiple_of(3) {
        return Err(LodError::PartialTriangle { indices: mesh.indices.len() });
    }
    if let Some(&index) = mesh.indices.iter().find(|&&i| i as usize >= mesh.positions.len()) {
        return Err(LodError::IndexOutOfRange { index, positions: mesh.positions.len() });
    }
    if let Some(vertex) = mesh.positions.iter().position(|p| !p.is_finite()) {
        return Err(LodError::NonFinitePosition { vertex });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_subdivided_box_simplifies_to_twelve_triangles_without_error() {
        let levels = build_chain(&Mesh::unit_cube(8), &ChainSettings::default()).unwrap();
        assert_eq!(levels[0].mesh.triangle_count(), 768);
        let coarsest = levels.last().unwrap();
        assert_eq!(coarsest.mesh.triangle_count(), 12);
        assert!(coarsest.error < LOSSLESS, "{}", coarsest.error);
        assert_eq!(levels.len(), 2, "no level between: the lossless one comes first");
    }

    #[test]
    fn bad_meshes_are_refused_not_read() {
        let mut mesh = Mesh::unit_cube(1);
        mesh.indices.push(0);
        assert!(matches!(build_chain(&mesh, &ChainSettings::default()), Err(LodError::PartialTriangle { .. })));
        mesh.indices.extend_from_slice(&[1, 99]);
        assert!(matches!(build_chain(&mesh, &ChainSettings::default()), Err(LodError::IndexOutOfRange { .. })));
        let mut mesh = Mesh::unit_cube(1);
        mesh.positions[3].x = f32::NAN;
        assert!(matches!(build_chain(&mesh, &ChainSettings::default()), Err(LodError::NonFinitePosition { .. })));
    }
}
