//! The scene on the GPU: one vertex buffer, one cluster index buffer and the cluster and mesh tables for all
//! meshes, uploaded once; and the per-instance buffer, indexed by store slot, of which only changed instances
//! are written each frame.

use super::GpuContext;
use super::clusters::{ClusterLibrary, GpuCluster};
use bytemuck::{Pod, Zeroable};
use glam::{Affine3A, Vec3};
use wgpu::util::DeviceExt;

pub use super::interface::INSTANCE_CONE_SAFE;

/// [`GpuInstance::mesh`] of an object with no mesh: it has no clusters and draws nothing.
pub const NO_MESH: u32 = u32::MAX;

/// The meshes the GPU draws for `world`: [`crate::lod::LodLibrary::meshes`] where it has levels of detail,
/// else `meshes` (what its [`crate::mesh::MeshRef`]s index).
pub fn drawn_meshes<'a>(world: &'a bevy_ecs::world::World, meshes: &'a [crate::mesh::Mesh]) -> &'a [crate::mesh::Mesh] {
    world.get_resource::<crate::lod::LodLibrary>().map_or(meshes, |library| library.meshes())
}

/// The instances of `world`'s culled objects, indexed by store slot (see [`instance_of`]).
pub fn instances_from_world(world: &bevy_ecs::world::World) -> Vec<GpuInstance> {
    let store = world.resource::<crate::bounds::BoundsStore>();
    (0..store.len() as u32).map(|slot| instance_of(world, slot)).collect()
}

/// The instance in store slot `slot` of `world`: its [`crate::mesh::MeshRef`] with its
/// [`crate::bounds::ObjectTransform`]; an object without a mesh gets [`NO_MESH`]. In a world with levels of
/// detail ([`crate::lod::install`]) the mesh is the chosen level's in [`crate::lod::LodLibrary::meshes`]
/// ([`NO_MESH`] for an object the budget dropped).
pub fn instance_of(world: &bevy_ecs::world::World, slot: u32) -> GpuInstance {
    let entity = world.resource::<crate::bounds::BoundsStore>().entities()[slot as usize];
    let transform = world.get::<crate::bounds::ObjectTransform>(entity).map_or(Affine3A::IDENTITY, |t| t.0);
    let mesh = world.get::<crate::mesh::MeshRef>(entity).map_or(NO_MESH, |m| m.0);
    let mesh = match (world.get_resource::<crate::lod::LodLibrary>(), world.get_resource::<crate::lod::LodSelection>())
    {
        (Some(_), Some(selection)) if selection.dropped().contains(slot as usize) => NO_MESH,
        (Some(library), Some(selection)) if mesh != NO_MESH => {
            selection.mesh_of(slot as usize, library).or_else(|| library.mesh_of(mesh, 0)).unwrap_or(NO_MESH)
        }
        _ => mesh,
    };
    let color = world.get::<crate::mesh::ObjectColor>(entity).map(|c| c.0);
    GpuInstance::new(&transform, mesh).with_color(color)
}

/// One drawn object as the shaders read it (`Instance` in `common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuInstance {
    /// Rows of the 3x4 object-to-world matrix, translation in the last column.
    pub rows: [[f32; 4]; 3],
    /// Index of its mesh in the [`ClusterLibrary`].
    pub mesh: u32,
    /// [`INSTANCE_CONE_SAFE`] or 0.
    pub flags: u32,
    /// Largest axis scale of the matrix, to scale bounding spheres.
    pub max_scale: f32,
    /// Flat colour, RGBA8 packed little-endian (red in the low byte); 0 lets the draw pass pick one from the
    /// instance index.
    pub color: u32,
}

impl GpuInstance {
    /// The instance of `mesh` placed by `transform`.
    pub fn new(transform: &Affine3A, mesh: u32) -> Self {
        let m = transform.matrix3;
        let t = transform.translation;
        let rows = [
            [m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x],
            [m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y],
            [m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z],
        ];
        let max_scale = crate::bounds::largest_axis_scale(transform);
        let determinant = m.determinant();
        let cone_safe = determinant > 0.0 && determinant.is_finite();
        Self { rows, mesh, flags: if cone_safe { INSTANCE_CONE_SAFE } else { 0 }, max_scale, color: 0 }
    }

    /// The same instance drawn in `color` (RGBA8), or in a colour picked from its index for `None`.
    pub fn with_color(self, color: Option<[u8; 4]>) -> Self {
        Self { color: color.map_or(0, |c| u32::from_le_bytes([c[0], c[1], c[2], 255])), ..self }
    }

    /// A mesh-space point relative to `camera`, computed as the shaders do (`relative_point`).
    pub fn relative_point(&self, p: Vec3, camera: Vec3) -> Vec3 {
        let row = |r: &[f32; 4], c: f32| Vec3::new(r[0], r[1], r[2]).dot(p) + (r[3] - c);
        Vec3::new(row(&self.rows[0], camera.x), row(&self.rows[1], camera.y), row(&self.rows[2], camera.z))
    }

    /// The half-axes (columns), camera-relative, of the image of the mesh-space box with half-size `extent`
    /// along the mesh axes: the matrix's columns scaled by it (`box_axes` in `common.wgsl`).
    pub fn box_axes(&self, extent: Vec3) -> glam::Mat3 {
        let [a, b, c] = self.rows.map(|r| Vec3::new(r[0], r[1], r[2]));
        let matrix = glam::Mat3::from_cols(a, b, c).transpose();
        glam::Mat3::from_cols(matrix.x_axis * extent.x, matrix.y_axis * extent.y, matrix.z_axis * extent.z)
    }

    /// The camera in mesh space, computed as the shaders do (`camera_in_mesh_space`).
    pub fn camera_in_mesh_space(&self, camera: Vec3) -> Vec3 {
        let [a, b, c] = self.rows.map(|r| Vec3::new(r[0], r[1], r[2]));
        let v = Vec3::new(camera.x - self.rows[0][3], camera.y - self.rows[1][3], camera.z - self.rows[2][3]);
        (b.cross(c) * v.x + c.cross(a) * v.y + a.cross(b) * v.z) / a.dot(b.cross(c))
    }
}

/// The GPU copies of a [`ClusterLibrary`] and of the instances.
pub struct GpuScene {
    /// Vertex positions, 3 floats each (vertex and storage buffer).
    pub positions: wgpu::Buffer,
    /// Cluster triangles as global vertex indices (index and storage buffer).
    pub cluster_indices: wgpu::Buffer,
    /// [`GpuCluster`] table.
    pub clusters: wgpu::Buffer,
    /// [`super::clusters::GpuMesh`] table.
    pub meshes: wgpu::Buffer,
    /// [`GpuInstance`] per store slot.
    pub instances: wgpu::Buffer,
    /// The CPU copy of the instances, to find what changed.
    instance_data: Vec<GpuInstance>,
    /// Instances written by the last [`GpuScene::write_instances`].
    pub instances_written_last_update: usize,
    /// Changes whenever the instance count or an instance's mesh changes: the layout of per-cluster data.
    mesh_generation: u64,
    /// The cluster library the buffers hold.
    pub library: ClusterLibrary,
}

/// The instance buffer holding `instances`.
fn instance_buffer(context: &GpuContext, instances: &[GpuInstance]) -> wgpu::Buffer {
    context.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("instances"),
        contents: &non_empty(instances),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
    })
}

/// Storage buffers may not be empty: pad empty contents with one zero element.
fn non_empty<T: Pod + Zeroable>(data: &[T]) -> Vec<u8> {
    if data.is_empty() { vec![0; std::mem::size_of::<T>().max(4)] } else { bytemuck::cast_slice(data).to_vec() }
}

impl GpuScene {
    /// Uploads `library` and `instances` (indexed by store slot).
    pub fn new(context: &GpuContext, library: ClusterLibrary, instances: Vec<GpuInstance>) -> Self {
        let device = &context.device;
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC;
        let buffer = |label, contents: &[u8], usage| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let flat: Vec<f32> = library.positions.iter().flat_map(|p| p.to_array()).collect();
        let positions = buffer("positions", &non_empty(&flat), storage | wgpu::BufferUsages::VERTEX);
        let cluster_indices =
            buffer("cluster indices", &non_empty(&library.indices), storage | wgpu::BufferUsages::INDEX);
        let clusters = buffer("clusters", &non_empty::<GpuCluster>(&library.clusters), storage);
        let meshes = buffer("meshes", &non_empty(&library.meshes), storage);
        let instances_buffer = instance_buffer(context, &instances);
        Self {
            positions,
            cluster_indices,
            clusters,
            meshes,
            instances: instances_buffer,
            instance_data: instances,
            instances_written_last_update: 0,
            mesh_generation: 0,
            library,
        }
    }

    /// The instances, indexed by store slot.
    pub fn instances(&self) -> &[GpuInstance] {
        &self.instance_data
    }

    /// A number that changes whenever the instance count or an instance's mesh changes, and so the layout of
    /// data kept per cluster of every instance (two-phase occlusion's visibility).
    pub(crate) fn mesh_generation(&self) -> u64 {
        self.mesh_generation
    }

    /// Brings the GPU instances up to date with a store of `count` objects of which only `written` slots
    /// changed (see [`crate::bounds::BoundsStore::take_written_slots`]): only those are written, runs of
    /// neighbouring slots in one write. The instance buffer is regrown (and every instance rewritten) only when
    /// `count` exceeds its capacity.
    pub fn write_instances(
        &mut self,
        context: &GpuContext,
        count: usize,
        written: &[u32],
        instance_of: impl Fn(u32) -> GpuInstance,
    ) {
        let capacity = self.instances.size() as usize / std::mem::size_of::<GpuInstance>();
        if count != self.instance_data.len() {
            self.mesh_generation += 1;
        }
        if count > capacity {
            // Only the instance buffer grows; the mesh buffers stay as they are.
            self.instance_data = (0..count as u32).map(&instance_of).collect();
            self.instances = instance_buffer(context, &self.instance_data);
            self.instances_written_last_update = count;
            return;
        }
        self.instance_data.resize(count, GpuInstance { mesh: NO_MESH, ..GpuInstance::default() });
        let mut slots = written.iter().map(|&s| s as usize).filter(|&s| s < count).peekable();
        let mut total = 0;
        while let Some(start) = slots.next() {
            let mut end = start + 1;
            while slots.next_if_eq(&end).is_some() {
                end += 1;
            }
            for slot in start..end {
                let instance = instance_of(slot as u32);
                if instance.mesh != self.instance_data[slot].mesh {
                    self.mesh_generation += 1;
                }
                self.instance_data[slot] = instance;
            }
            let offset = (start * std::mem::size_of::<GpuInstance>()) as u64;
            context.queue.write_buffer(&self.instances, offset, bytemuck::cast_slice(&self.instance_data[start..end]));
            total += end - start;
        }
        self.instances_written_last_update = total;
    }
}
