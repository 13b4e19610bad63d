//! Clusters (meshlets): every mesh split once, at load, into clusters of at most [`MAX_CLUSTER_VERTICES`]
//! vertices and [`MAX_CLUSTER_TRIANGLES`] triangles by meshoptimizer, each with its bounding sphere and normal
//! cone, laid out as the GPU reads them.

use crate::mesh::Mesh;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// Most vertices in a cluster: 64, NVIDIA's recommendation for meshlets, which meshoptimizer follows.
pub const MAX_CLUSTER_VERTICES: usize = 64;
/// Most triangles in a cluster: 124 (meshoptimizer wants a multiple of 4; 124 keeps 64 vertices' worth), so the
/// triangle pass runs one 128-thread workgroup per cluster.
pub const MAX_CLUSTER_TRIANGLES: usize = 124;
/// meshoptimizer's cone weight: 0.25 trades a little cluster compactness for tighter normal cones.
const CONE_WEIGHT: f32 = 0.25;

/// A cluster as the shaders read it (`Cluster` in `common.wgsl`): bounds in mesh space, and where its
/// triangles are in [`ClusterLibrary::indices`].
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuCluster {
    /// Bounding-sphere centre.
    pub center: [f32; 3],
    /// Bounding-sphere radius.
    pub radius: f32,
    /// Normal-cone apex.
    pub cone_apex: [f32; 3],
    /// Cosine bound of the cone: the cluster faces away from a viewer `v` when
    /// `dot(normalize(apex - v), axis) >= cone_cutoff`; 1 for clusters that never face away as a whole.
    pub cone_cutoff: f32,
    /// Normal-cone axis (unit length).
    pub cone_axis: [f32; 3],
    /// First index of its triangles in the index buffer.
    pub first_index: u32,
    /// Half-size along each mesh axis of a box about `center` that holds the cluster (each at most `radius`):
    /// the box the HZB test projects, tighter than the sphere's for a flat or long cluster.
    pub extent: [f32; 3],
    /// Number of triangles.
    pub triangle_count: u32,
}

/// Where a mesh's clusters are (`MeshInfo` in the shaders).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct GpuMesh {
    /// Index of its first cluster.
    pub first_cluster: u32,
    /// Number of clusters.
    pub cluster_count: u32,
}

/// All meshes of a scene in cluster form: one vertex array, one index array (three global vertex indices per
/// triangle, cluster by cluster) and the cluster and mesh tables.
#[derive(Clone, Debug, Default)]
pub struct ClusterLibrary {
    /// Every mesh's vertex positions, mesh after mesh.
    pub positions: Vec<Vec3>,
    /// Triangles, cluster after cluster, as indices into `positions`.
    pub indices: Vec<u32>,
    /// Every mesh's clusters, mesh after mesh.
    pub clusters: Vec<GpuCluster>,
    /// Per mesh, its range of clusters.
    pub meshes: Vec<GpuMesh>,
}

impl ClusterLibrary {
    /// Splits `meshes` into clusters. Triangles with an index out of range are dropped (with a warning):
    /// they cannot be drawn. An empty mesh has no clusters.
    pub fn build(meshes: &[Mesh]) -> Self {
        let mut library = Self::default();
        for (mesh_index, mesh) in meshes.iter().enumerate() {
            let base_vertex = library.positions.len() as u32;
            library.positions.extend_from_slice(&mesh.positions);
            let vertex_count = mesh.positions.len() as u32;
            let indices: Vec<u32> = mesh
                .indices
                .chunks_exact(3)
                .filter(|t| t.iter().all(|&i| i < vertex_count))
                .flatten()
                .copied()
                .collect();
            if indices.len() != mesh.indices.len() / 3 * 3 {
                tracing::warn!("mesh {mesh_index}: triangles with out-of-range indices dropped");
            }
            let first_cluster = library.clusters.len() as u32;
            if !indices.is_empty() {
                let flat: Vec<f32> = mesh.positions.iter().flat_map(|p| p.to_array()).collect();
                let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&flat), 12, 0)
                    .expect("tightly packed positions");
                let meshlets = meshopt::build_meshlets(
                    &indices,
                    &adapter,
                    MAX_CLUSTER_VERTICES,
                    MAX_CLUSTER_TRIANGLES,
                    CONE_WEIGHT,
                );
                for meshlet in meshlets.iter() {
                    let bounds = meshopt::compute_meshlet_bounds(meshlet, &adapter);
                    let center = Vec3::from(bounds.center);
                    let extent = meshlet
                        .vertices
                        .iter()
                        .fold(Vec3::ZERO, |extent, &v| extent.max((mesh.positions[v as usize] - center).abs()));
                    let first_index = library.indices.len() as u32;
                    library
                        .indices
                        .extend(meshlet.triangles.iter().map(|&local| base_vertex + meshlet.vertices[local as usize]));
                    library.clusters.push(GpuCluster {
                        center: bounds.center,
                        radius: bounds.radius,
                        cone_apex: bounds.cone_apex,
                        cone_cutoff: bounds.cone_cutoff,
                        cone_axis: bounds.cone_axis,
                        first_index,
                        extent: extent.min(Vec3::splat(bounds.radius)).to_array(),
                        triangle_count: (meshlet.triangles.len() / 3) as u32,
                    });
                }
            }
            let cluster_count = library.clusters.len() as u32 - first_cluster;
            library.meshes.push(GpuMesh { first_cluster, cluster_count });
        }
        library
    }

    /// The clusters of mesh `mesh` (none for a mesh index out of range, such as [`super::scene::NO_MESH`]).
    pub fn clusters_of(&self, mesh: u32) -> &[GpuCluster] {
        let range = self.cluster_range(mesh);
        &self.clusters[range.start as usize..range.end as usize]
    }

    /// The indices in [`ClusterLibrary::clusters`] of mesh `mesh`'s clusters (empty as for `clusters_of`).
    pub fn cluster_range(&self, mesh: u32) -> std::ops::Range<u32> {
        self.meshes.get(mesh as usize).map_or(0..0, |info| info.first_cluster..info.first_cluster + info.cluster_count)
    }

    /// The three corner positions of triangle `triangle` of `cluster`.
    pub fn triangle(&self, cluster: &GpuCluster, triangle: u32) -> [Vec3; 3] {
        let first = (cluster.first_index + 3 * triangle) as usize;
        [0, 1, 2].map(|k| self.positions[self.indices[first + k] as usize])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clusters_cover_every_triangle_once_within_size_limits() {
        let meshes = [Mesh::unit_cube(6), Mesh::unit_cube(1), Mesh::default()];
        let library = ClusterLibrary::build(&meshes);
        assert_eq!(library.meshes.len(), 3);
        assert_eq!(library.meshes[2].cluster_count, 0);
        for (mesh_index, mesh) in meshes.iter().enumerate() {
            let clusters = library.clusters_of(mesh_index as u32);
            let triangles: usize = clusters.iter().map(|c| c.triangle_count as usize).sum();
            assert_eq!(triangles, mesh.triangle_count());
            let mut ours: Vec<[u32; 3]> = Vec::new();
            for cluster in clusters {
                assert!(cluster.triangle_count as usize <= MAX_CLUSTER_TRIANGLES);
                let first = cluster.first_index as usize;
                let corners = &library.indices[first..first + 3 * cluster.triangle_count as usize];
                let mut distinct = corners.to_vec();
                distinct.sort_unstable();
                distinct.dedup();
                assert!(distinct.len() <= MAX_CLUSTER_VERTICES);
                for t in corners.chunks_exact(3) {
                    // Each triangle's corners lie in the sphere.
                    for &v in t {
                        let p = library.positions[v as usize];
                        let d = p.distance(Vec3::from(cluster.center));
                        assert!(d <= cluster.radius * 1.0001 + 1e-6);
                    }
                    // Canonical rotation so that the same triangle compares equal whatever corner starts it.
                    let r = (0..3).map(|k| [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]).min().unwrap();
                    ours.push(r);
                }
            }
            let offset = library.positions.len() as u32
                - meshes[mesh_index..].iter().map(|m| m.positions.len() as u32).sum::<u32>();
            let mut theirs: Vec<[u32; 3]> = mesh
                .indices
                .chunks_exact(3)
                .map(|t| (0..3).map(|k| [t[k], t[(k + 1) % 3], t[(k + 2) % 3]].map(|i| i + offset)).min().unwrap())
                .collect();
            ours.sort_unstable();
            theirs.sort_unstable();
            assert_eq!(ours, theirs, "mesh {mesh_index}: same triangles, same winding");
        }
    }
}
