//! How far apart two meshes' surfaces lie: a level's error, measured. A scene's own levels come with no other,
//! and meshoptimizer's estimate for a level it made can fall short of the distance.

use crate::mesh::Mesh;
use glam::Vec3;
use rayon::prelude::*;

/// Most grid cells a [`TriangleGrid`] allocates, whatever the mesh.
const MAX_CELLS: usize = 1 << 21;

/// The distance between the surfaces of `a` and `b` in their (shared) units, both ways: the largest distance
/// from a sample of either surface to the nearest point of the other's. The samples are every vertex a
/// triangle uses, every edge's midpoint and every triangle's centroid, so a bulge between samples of a large
/// triangle can go unmeasured: an estimate of the Hausdorff distance from below, exact for meshes whose
/// farthest points are vertices.
///
/// Returns 0 for two meshes with no triangle, and infinity where only one has none. Indices past the
/// positions and partial triangles are skipped; a non-finite position gives a non-finite result.
pub fn surface_distance(a: &Mesh, b: &Mesh) -> f32 {
    match Surface::of(a) {
        Some(a) => a.distance_to(b),
        None if triangles(b).is_empty() => 0.0,
        None => f32::INFINITY,
    }
}

/// A mesh's surface binned for nearest-point queries, with the vertices its triangles use: built once, it
/// measures every simplified level of the mesh.
pub(super) struct Surface {
    grid: TriangleGrid,
    vertices: Vec<Vec3>,
}

impl Surface {
    /// The surface of `mesh`; `None` for a mesh without a whole triangle.
    pub(super) fn of(mesh: &Mesh) -> Option<Self> {
        let triangles = triangles(mesh);
        if triangles.is_empty() {
            return None;
        }
        let mut used = vec![false; mesh.positions.len()];
        for &i in &mesh.indices {
            if let Some(used) = used.get_mut(i as usize) {
                *used = true;
            }
        }
        let vertices = mesh.positions.iter().zip(used).filter(|(_, used)| *used).map(|(p, _)| *p).collect();
        Some(Self { grid: TriangleGrid::new(triangles), vertices })
    }

    /// [`surface_distance`] from this surface to `other`: infinite where `other` has no triangle.
    pub(super) fn distance_to(&self, other: &Mesh) -> f32 {
        let other = triangles(other);
        if other.is_empty() {
            return f32::INFINITY;
        }
        let other = TriangleGrid::new(other);
        farthest_sample(&self.grid.triangles, &other).max(farthest_sample(&other.triangles, &self.grid))
    }

    /// How far `level`, a simplification of this surface, lies from it: the largest distance from a sample of
    /// `level` (as [`surface_distance`] samples) to this surface, and from a vertex of this surface to
    /// `level`'s (where a simplification's farthest points are: the vertices it removed). Infinite for a
    /// level without triangles.
    pub(super) fn distance_to_level(&self, level: &Mesh) -> f32 {
        let level = triangles(level);
        if level.is_empty() {
            return f32::INFINITY;
        }
        let level = TriangleGrid::new(level);
        let from_vertices = self.vertices.par_iter().map(|&p| level.distance(p)).reduce(|| 0.0, f32::max);
        farthest_sample(&level.triangles, &self.grid).max(from_vertices)
    }
}

/// The largest distance from a sample of `from` (vertices, edge midpoints, centroid) to the surface of `to`.
fn farthest_sample(from: &[[Vec3; 3]], to: &TriangleGrid) -> f32 {
    from.par_iter()
        .map(|&[p, q, r]| {
            let samples = [p, q, r, (p + q) * 0.5, (q + r) * 0.5, (r + p) * 0.5, (p + q + r) / 3.0];
            samples.iter().map(|&s| to.distance(s)).fold(0.0, f32::max)
        })
        .reduce(|| 0.0, f32::max)
}

/// The whole triangles of `mesh` whose indices are in range.
fn triangles(mesh: &Mesh) -> Vec<[Vec3; 3]> {
    let vertex = |i: u32| mesh.positions.get(i as usize).copied();
    mesh.indices.chunks_exact(3).filter_map(|t| Some([vertex(t[0])?, vertex(t[1])?, vertex(t[2])?])).collect()
}

/// Triangles binned by the uniform grid cells their boxes overlap, for nearest-point queries.
struct TriangleGrid {
    triangles: Vec<[Vec3; 3]>,
    origin: Vec3,
    cell: f32,
    dims: [usize; 3],
    /// Cell `c`'s triangles are `members[starts[c]..starts[c + 1]]`.
    starts: Vec<u32>,
    members: Vec<u32>,
}

impl TriangleGrid {
    fn new(triangles: Vec<[Vec3; 3]>) -> Self {
        let (min, max) = triangles
            .iter()
            .flatten()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(min, max), &p| (min.min(p), max.max(p)));
        let extent = (max - min).max_element();
        // About two cells a triangle along the mesh's largest side; one cell for a point-sized or non-finite
        // mesh.
        let per_side = ((triangles.len() as f32).cbrt() * 2.0).clamp(1.0, 128.0);
        let mut cell = extent / per_side;
        if !(cell.is_finite() && cell > 0.0) {
            return Self::single_cell(triangles, min);
        }
        let cells_along = |cell: f32| ((max - min) / cell).floor().as_uvec3().to_array().map(|n| n as usize + 1);
        while cells_along(cell).iter().product::<usize>() > MAX_CELLS {
            cell *= 2.0;
        }
        let dims = cells_along(cell);
        let mut grid = Self { triangles, origin: min, cell, dims, starts: Vec::new(), members: Vec::new() };
        let count = dims.iter().product::<usize>();
        let mut counts = vec![0u32; count + 1];
        grid.for_each_cell_of_triangles(|c, _| counts[c + 1] += 1);
        for c in 0..count {
            counts[c + 1] += counts[c];
        }
        let mut fill = counts.clone();
        let mut members = vec![0; counts[count] as usize];
        grid.for_each_cell_of_triangles(|c, t| {
            members[fill[c] as usize] = t;
            fill[c] += 1;
        });
        (grid.starts, grid.members) = (counts, members);
        grid
    }

    /// Every triangle in one cell: the grid of a mesh with no extent.
    fn single_cell(triangles: Vec<[Vec3; 3]>, origin: Vec3) -> Self {
        let members = (0..triangles.len() as u32).collect();
        let starts = vec![0, triangles.len() as u32];
        Self { triangles, origin, cell: f32::INFINITY, dims: [1; 3], starts, members }
    }

    /// Calls `visit(cell, triangle)` for every cell each triangle's box overlaps.
    fn for_each_cell_of_triangles(&self, mut visit: impl FnMut(usize, u32)) {
        for (t, &[p, q, r]) in self.triangles.iter().enumerate() {
            let lo = self.cell_of(p.min(q).min(r));
            let hi = self.cell_of(p.max(q).max(r));
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    for x in lo[0]..=hi[0] {
                        visit(self.index([x, y, z]), t as u32);
                    }
                }
            }
        }
    }

    /// The cell holding `p`, clamped into the grid.
    fn cell_of(&self, p: Vec3) -> [usize; 3] {
        let at = ((p - self.origin) / self.cell).floor().to_array();
        std::array::from_fn(|axis| (at[axis].max(0.0) as usize).min(self.dims[axis] - 1))
    }

    fn index(&self, [x, y, z]: [usize; 3]) -> usize {
        (z * self.dims[1] + y) * self.dims[0] + x
    }

    /// The distance from `p` to the nearest triangle: the cells in rings around `p`'s, until no unvisited
    /// cell can hold a nearer point (a cell `r + 1` rings out lies at least `r` cells away).
    fn distance(&self, p: Vec3) -> f32 {
        if !p.is_finite() {
            return f32::NAN;
        }
        let centre = self.cell_of(p);
        let mut best = f32::INFINITY;
        let rings = self.dims.iter().max().copied().unwrap_or(1);
        for ring in 0..rings {
            let lo = centre.map(|c| c.saturating_sub(ring));
            let hi: [usize; 3] = std::array::from_fn(|a| (centre[a] + ring).min(self.dims[a] - 1));
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    // Inside the ring's cube, a row meets the ring only at its two ends.
                    let row_on_ring = z.abs_diff(centre[2]) == ring || y.abs_diff(centre[1]) == ring;
                    let step = if row_on_ring || ring == 0 { 1 } else { 2 * ring };
                    for x in (centre[0] as isize - ring as isize..=(centre[0] + ring) as isize).step_by(step) {
                        if x < lo[0] as isize || x > hi[0] as isize {
                            continue;
                        }
                        let c = self.index([x as usize, y, z]);
                        for &t in &self.members[self.starts[c] as usize..self.starts[c + 1] as usize] {
                            best = best.min(point_triangle_distance(p, self.triangles[t as usize]));
                        }
                    }
                }
            }
            if best <= ring as f32 * self.cell {
                break;
            }
        }
        best
    }
}

/// The distance from `p` to the triangle `[a, b, c]` (the closest point by its Voronoi region, after
/// Ericson's Real-Time Collision Detection, 5.1.5); a degenerate triangle is its longest edge.
fn point_triangle_distance(p: Vec3, [a, b, c]: [Vec3; 3]) -> f32 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return p.distance(a);
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return p.distance(b);
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return p.distance(c);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return p.distance(a + ab * (d1 / (d1 - d3)));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return p.distance(a + ac * (d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return p.distance(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    let denominator = va + vb + vc;
    if denominator.abs() <= f32::MIN_POSITIVE {
        return segment_distance(p, a, b).min(segment_distance(p, b, c)).min(segment_distance(p, c, a));
    }
    let (v, w) = (vb / denominator, vc / denominator);
    p.distance(a + ab * v + ac * w)
}

/// The distance from `p` to the segment `[a, b]`.
fn segment_distance(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    p.distance(a + ab * t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mesh_is_at_no_distance_from_itself_or_a_retessellation() {
        let fine = Mesh::unit_cube(6);
        assert!(surface_distance(&fine, &fine) < 1e-6);
        assert!(surface_distance(&fine, &Mesh::unit_cube(1)) < 1e-6);
    }

    #[test]
    fn a_grown_box_is_as_far_as_it_grew_both_ways() {
        let unit = Mesh::unit_cube(4);
        let grown = unit.scaled(Vec3::splat(1.5), Vec3::ZERO);
        // Faces 0.25 apart; the corners sqrt(3) * 0.25 apart, and a corner is the farthest sample.
        let expected = 3f32.sqrt() * 0.25;
        assert!((surface_distance(&unit, &grown) - expected).abs() < 1e-5);
        assert!((surface_distance(&grown, &unit) - expected).abs() < 1e-5);
        let moved = unit.scaled(Vec3::ONE, Vec3::new(0.0, 3.0, 0.0));
        assert!((surface_distance(&unit, &moved) - 3.0).abs() < 1e-5);
    }

    #[test]
    fn brute_force_agrees_with_the_grid() {
        let to = triangles(&Mesh::unit_cube(5).scaled(Vec3::new(4.0, 0.5, 2.0), Vec3::new(1.0, -2.0, 0.0)));
        let grid = TriangleGrid::new(to.clone());
        for i in 0..500 {
            let t = i as f32;
            let p = Vec3::new((t * 0.37).sin() * 6.0, (t * 0.53).cos() * 4.0, (t * 0.71).sin() * 5.0);
            let brute = to.iter().map(|&tri| point_triangle_distance(p, tri)).fold(f32::INFINITY, f32::min);
            assert!((grid.distance(p) - brute).abs() < 1e-5, "{p}: {} vs {brute}", grid.distance(p));
        }
    }

    #[test]
    fn empty_flat_and_degenerate_meshes_have_answers() {
        let empty = Mesh::default();
        assert_eq!(surface_distance(&empty, &empty), 0.0);
        assert_eq!(surface_distance(&empty, &Mesh::unit_cube(1)), f32::INFINITY);
        let point = Mesh { positions: vec![Vec3::ONE; 3], indices: vec![0, 1, 2] };
        assert!((surface_distance(&point, &point)).abs() < 1e-6);
        let sliver = Mesh { positions: vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0], indices: vec![0, 1, 2] };
        assert!(
            (point_triangle_distance(Vec3::new(1.0, 1.0, 0.0), [Vec3::ZERO, Vec3::X, Vec3::X * 2.0]) - 1.0).abs()
                < 1e-6
        );
        assert!(surface_distance(&sliver, &point).is_finite());
    }
}
