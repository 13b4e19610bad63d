//! Judging a `bevy_ecs` world that has just run the culling schedule: the exact visible set of its objects,
//! in store-slot order, against the stages' outputs.

use crate::metrics::{FrameMetrics, OcclusionIdeal};
use crate::occluders::ExactOccluderDepth;
use crate::render::{ExactVisibility, IdBuffer, ReferenceObject, ReferenceSettings, render_ids};
use bevy_ecs::world::World;
use cullet::culler::{CullScene, Culled, Culler, ViewCuller};
use cullet::mesh::Mesh;
use cullet::pipeline::CameraCuller;
use cullet::{BoundsStore, Camera, LocalBounds, MeshRef, ObjectTransform, Occluder};
use glam::Vec3;

/// Names of the stages [`judge_frame`] reports, in pipeline order.
pub const STAGES: [&str; 2] = ["frustum", "occlusion"];

/// What [`judge_frame`] measures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct JudgeSettings {
    /// Resolution and face culling of the exact rendering.
    pub reference: ReferenceSettings,
    /// Also rasterize this frame's occluders exactly at the reference resolution and measure the occlusion
    /// stage against that ideal (about doubles the cost).
    pub occlusion_ideal: bool,
}

/// One judged frame.
#[derive(Clone, Debug)]
pub struct Judgement {
    /// Accuracy of each stage; object indices are store slots.
    pub metrics: FrameMetrics,
    /// The exact rendering: object IDs are store slots.
    pub truth: IdBuffer,
}

/// The objects of `world` in store-slot order, each drawing `meshes[MeshRef]`; an object without a (valid)
/// mesh is drawn as its bounding box.
pub fn reference_objects<'a>(world: &World, meshes: &'a [Mesh]) -> Vec<ReferenceObject<'a>> {
    let store = world.resource::<BoundsStore>();
    store
        .entities()
        .iter()
        .map(|&entity| {
            let transform = world.get::<ObjectTransform>(entity).map_or(glam::Affine3A::IDENTITY, |t| t.0);
            match world.get::<MeshRef>(entity).and_then(|m| meshes.get(m.0 as usize)) {
                Some(mesh) => ReferenceObject::new(mesh, transform),
                None => {
                    let bounds = world
                        .get::<LocalBounds>(entity)
                        .copied()
                        .unwrap_or(LocalBounds { center: Vec3::ZERO, half_extent: Vec3::ZERO });
                    ReferenceObject::from_bounds(&bounds, transform)
                }
            }
        })
        .collect()
}

/// Judges the frame `world` has just culled for its [`Camera`] against the exact rendering of every object's
/// mesh: [`render_world`], then [`stage_metrics`] and, if asked, [`occlusion_ideal`].
pub fn judge_frame(world: &World, meshes: &[Mesh], settings: &JudgeSettings) -> Judgement {
    let truth = render_world(world, meshes, &settings.reference);
    let mut metrics = stage_metrics(world, &truth.visibility());
    if settings.occlusion_ideal {
        metrics.occlusion_ideal = Some(occlusion_ideal(world, &settings.reference));
    }
    Judgement { metrics, truth }
}

/// Runs `culler` on the frame of `world` (its bounds up to date: the pipeline's bounds stage has run) seen
/// through `camera`, and judges what each of its stages kept against the exact rendering of every object's
/// mesh from that camera. Any [`Culler`] is judged so, on the same scenes, paths and frames as the pipeline.
pub fn judge_culler(
    culler: &mut dyn Culler,
    world: &World,
    camera: &Camera,
    meshes: &[Mesh],
    settings: &JudgeSettings,
) -> Judgement {
    let culled = culler.cull(&CullScene::new(world), camera);
    judge_culled(world, camera, &culled, meshes, settings)
}

/// Judges what a culler kept (`culled`, from [`Culler::cull`] or [`cullet::culler::ViewCuller::culled`]) in
/// the frame of `world` seen through `camera`, against the exact rendering of every object's mesh. With
/// [`JudgeSettings::occlusion_ideal`], the ideal is not measured here (it needs the culler's occluders:
/// [`occlusion_ideal_of`]).
pub fn judge_culled(
    world: &World,
    camera: &Camera,
    culled: &Culled<'_>,
    meshes: &[Mesh],
    settings: &JudgeSettings,
) -> Judgement {
    let truth = render_ids(camera, &reference_objects(world, meshes), &settings.reference);
    let metrics = FrameMetrics::new(&truth.visibility(), &culled.stages);
    Judgement { metrics, truth }
}

/// The exact rendering of `world`'s objects (IDs are store slots) from its [`Camera`].
pub fn render_world(world: &World, meshes: &[Mesh], reference: &ReferenceSettings) -> IdBuffer {
    render_ids(world.resource::<Camera>(), &reference_objects(world, meshes), reference)
}

/// The frustum stage ([`cullet::culler::ViewCuller::frustum_visible`]) and the occlusion stage ([`cullet::culler::ViewCuller::visible`]) of `world`'s
/// last frame against `truth`.
pub fn stage_metrics(world: &World, truth: &ExactVisibility) -> FrameMetrics {
    let frustum = &world.resource::<CameraCuller>().frustum_visible();
    let occlusion = &world.resource::<CameraCuller>().visible();
    FrameMetrics::new(truth, &[(STAGES[0], frustum), (STAGES[1], occlusion)])
}

/// The occlusion stage's culled count in `world`'s last frame next to that of an exact buffer of the same
/// occluders at the reference resolution.
pub fn occlusion_ideal(world: &World, reference: &ReferenceSettings) -> OcclusionIdeal {
    occlusion_ideal_of(world, world.resource::<Camera>(), world.resource::<CameraCuller>(), reference)
}

/// [`occlusion_ideal`] for the last frame `state` culled of `world` through `camera`: a culler of one's own
/// ([`cullet::culler::StageCuller::view`]) rather than the pipeline's.
pub fn occlusion_ideal_of(
    world: &World,
    camera: &Camera,
    state: &ViewCuller,
    reference: &ReferenceSettings,
) -> OcclusionIdeal {
    let store = world.resource::<BoundsStore>();
    let frustum = state.frustum_visible();
    let culled = frustum.count() - state.visible().count();
    if state.occluder_slots().is_empty() {
        return OcclusionIdeal { culled, ideal_culled: 0 };
    }
    let occluders: Vec<(&[Vec3], glam::Affine3A)> = state
        .occluder_slots()
        .iter()
        .filter_map(|&slot| {
            let entity = store.entities()[slot as usize];
            Some((world.get::<Occluder>(entity)?.triangles(), world.get::<ObjectTransform>(entity)?.0))
        })
        .collect();
    let exact = ExactOccluderDepth::rasterize(camera, &occluders, reference.width, reference.height);
    let ideal_culled = frustum
        .iter()
        .filter(|&slot| {
            let bounds = store.get(slot).expect("a slot below the store length");
            !exact.box_visible(bounds.center, bounds.half_extent)
        })
        .count();
    OcclusionIdeal { culled, ideal_culled }
}
