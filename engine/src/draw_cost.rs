//! What each stage saved the draw in a frame: the triangles it kept away from the GPU, and from them an estimate
//! of the draw time saved. A stage's cost (its time, in [`crate::pipeline::CullStats`] and the GPU pass times)
//! set against this benefit says whether it pays in a scene.
//!
//! Accounting only: it reads the stages' outputs after the frame and changes nothing, so it costs the
//! pipeline nothing where it is not called.

use crate::bounds::BoundsStore;
use crate::gpu::GpuFrameOutput;
use crate::mesh::Mesh;
use crate::mesh::MeshRef;
use crate::pipeline::CameraCuller;
use crate::visible::VisibleSet;
use bevy_ecs::world::World;

/// Triangles each stage removed from the draw in one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DrawSavings {
    /// Triangles of every object in the store: what drawing without culling would submit.
    pub total: u64,
    /// Triangles of the objects the frustum stage removed.
    pub frustum: u64,
    /// Triangles of the objects the occlusion stage removed.
    pub occlusion: u64,
    /// Triangles of the clusters the GPU cluster pass removed.
    pub clusters: u64,
    /// Triangles the GPU triangle pass removed.
    pub triangles: u64,
}

impl DrawSavings {
    /// The savings of `world`'s last frame, with the triangle counts of its objects. Without `gpu` (no GPU
    /// pass ran) the GPU passes saved nothing.
    pub fn of_frame(world: &World, triangles: &SlotTriangles, gpu: Option<&GpuFrameOutput>) -> Self {
        let culler = world.resource::<CameraCuller>();
        Self::of_sets(triangles, culler.frustum_visible(), culler.visible(), gpu)
    }

    /// The savings of a frame whose frustum stage kept `after_frustum` and whose culler kept `kept` in the end
    /// (a culler of your own, [`crate::culler::Culler`]), with the triangle counts of the objects. Without
    /// `gpu` (no GPU pass ran) the GPU passes saved nothing.
    pub fn of_sets(
        triangles: &SlotTriangles,
        after_frustum: &VisibleSet,
        kept: &VisibleSet,
        gpu: Option<&GpuFrameOutput>,
    ) -> Self {
        let total = triangles.total;
        let after_frustum = triangles.sum(after_frustum);
        let after_occlusion = triangles.sum(kept);
        let (clusters, triangles) = gpu.map_or((0, 0), |output| {
            let c = output.counters;
            // Without the triangle pass, the clusters kept are drawn whole and it removed nothing.
            let (after_clusters, triangle_pass) = if output.triangle_pass_skipped {
                (c.triangles_out, 0)
            } else {
                (c.triangles_in, c.triangles_in - c.triangles_out)
            };
            (after_occlusion.saturating_sub(u64::from(after_clusters)), u64::from(triangle_pass))
        });
        Self {
            total,
            frustum: total - after_frustum,
            occlusion: after_frustum.saturating_sub(after_occlusion),
            clusters,
            triangles,
        }
    }

    /// The savings of each stage in pipeline order, named: frustum, occlusion, clusters, triangles.
    pub fn by_stage(&self) -> [(&'static str, u64); 4] {
        [
            ("frustum", self.frustum),
            ("occlusion", self.occlusion),
            ("clusters", self.clusters),
            ("triangles", self.triangles),
        ]
    }
}

/// The triangle count of each stored object's mesh, by store slot, and their total: taken once, valid while
/// no object is added or removed.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SlotTriangles {
    /// Triangles of each store slot's mesh (0 for an object without a mesh).
    per_slot: Vec<u32>,
    /// Their sum: what drawing without culling would submit.
    total: u64,
}

impl SlotTriangles {
    /// The counts of `world`'s stored objects, whose [`MeshRef`]s index `meshes`.
    pub fn of_world(world: &World, meshes: &[Mesh]) -> Self {
        let per_slot: Vec<u32> = world
            .resource::<BoundsStore>()
            .entities()
            .iter()
            .map(|&entity| {
                world
                    .get::<MeshRef>(entity)
                    .and_then(|mesh| meshes.get(mesh.0 as usize))
                    .map_or(0, |mesh| mesh.triangle_count() as u32)
            })
            .collect();
        let total = per_slot.iter().map(|&t| u64::from(t)).sum();
        Self { per_slot, total }
    }

    /// Triangles of the objects in `set`.
    pub fn sum(&self, set: &VisibleSet) -> u64 {
        set.iter().map(|slot| u64::from(self.per_slot[slot])).sum()
    }
}

/// Mean GPU draw time per drawn triangle over `frames`, in nanoseconds: the rate at which a removed triangle's
/// draw time is estimated. `None` without timestamp queries or drawn triangles.
pub fn draw_ns_per_triangle(frames: &[GpuFrameOutput]) -> Option<f64> {
    let times: Option<Vec<_>> = frames.iter().map(|f| f.pass_times.map(|t| t.draw)).collect();
    let draw_ns: f64 = times?.iter().map(|t| t.as_secs_f64() * 1e9).sum();
    let drawn: u64 = frames.iter().map(|f| u64::from(f.counters.triangles_out)).sum();
    (drawn > 0).then(|| draw_ns / drawn as f64)
}
