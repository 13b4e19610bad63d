//! The culling pipeline as `bevy_ecs` systems, one per stage, in a fixed order ([`CullStage`]): data flows one
//! way, each stage narrowing the [`VisibleSet`] of the stage before. [`install`] puts it into a world and a
//! schedule. The camera's frustum and occlusion stages are a [`ViewCuller`] ([`CameraCuller`]); the light
//! views ([`LightViews`]) are culled with the camera in the same pass over the bounds, then occlusion culled
//! each from its light.

mod bounds;
mod systems;

use systems::{frustum_stage, light_occlusion_stage, occlusion_stage};

use crate::bounds::BoundsStore;
use crate::culler::{
    AdaptiveSettings, LightOcclusion, LightOcclusionSettings, LightViewVisible, OcclusionSettings, SettingsError,
    ViewCuller,
};
use crate::detail::DetailSettings;
use crate::frustum::{FrustumError, LightSource, ViewError};
use crate::visible::VisibleSet;
use bevy_ecs::prelude::*;
use bounds::{on_bounds_inserted, on_bounds_removed, on_occluder_inserted, on_occluder_removed, sync_bounds};
use std::time::Duration;

/// The stages, in the order they run.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CullStage {
    /// Bring the SoA bounds up to date with changed entities.
    Bounds,
    /// Cull against the view frustum.
    Frustum,
    /// Rasterize artist occluders and test the frustum survivors against them; then the same for each light
    /// view, as its light sees them.
    Occlusion,
    /// Choose each kept object's level of detail; only in a world set up by [`crate::lod::install`].
    Lod,
}

/// The camera's culling: its [`ViewCuller`], which holds each stage's result ([`ViewCuller::frustum_visible`],
/// [`ViewCuller::visible`]), its occluder depth pyramid and what it keeps from frame to frame.
#[derive(Resource, Default, Debug, Clone)]
pub struct CameraCuller(pub ViewCuller);

impl std::ops::Deref for CameraCuller {
    type Target = ViewCuller;

    fn deref(&self) -> &ViewCuller {
        &self.0
    }
}

impl std::ops::DerefMut for CameraCuller {
    fn deref_mut(&mut self) -> &mut ViewCuller {
        &mut self.0
    }
}

/// Lights whose views the frustum stage culls with the camera, in the same pass over the bounds: a sun's
/// cascades, a lamp's cube faces ([`LightSource`]). Each light view keeps the shadow casters whose shadows can
/// fall inside the camera's frustum ([`crate::frustum::View::shadow_casters`]); the results are in [`LightViewsVisible`].
/// Empty by default.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct LightViews(pub Vec<LightSource>);

/// Output of the frustum stage for the [`LightViews`], narrowed by each view's occlusion
/// (in [`CullStage::Occlusion`]): every light view of the frame, lights in order. Where the frustum stage does
/// not cull (turned off), each view keeps every object its occlusion does not hide; a light whose views cannot
/// be built (or a camera without a valid frustum) has none, and [`CullStats::light_view_error`] says why.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct LightViewsVisible(pub Vec<LightViewVisible>);

impl LightViewsVisible {
    /// Each light view's name ([`LightSource::view_name`]) and the casters it kept this frame, in order.
    pub fn kept_by_view(&self, lights: &LightViews) -> Vec<(String, usize)> {
        let mut index_in_light = 0;
        self.0
            .iter()
            .enumerate()
            .map(|(i, view)| {
                index_in_light = if i > 0 && self.0[i - 1].light == view.light { index_in_light + 1 } else { 0 };
                let name = lights.0.get(view.light).map_or_else(String::new, |light| light.view_name(index_in_light));
                (name, view.kept)
            })
            .collect()
    }
}

/// Per-frame counts and timings of each stage.
#[derive(Resource, Default, Debug, Clone, Copy, PartialEq)]
pub struct CullStats {
    /// Objects in the store.
    pub objects: usize,
    /// Objects whose bounds were recomputed this frame.
    pub bounds_recomputed: usize,
    /// Objects left after frustum culling (and detail culling, where on).
    pub after_frustum: usize,
    /// Objects the frustum kept that detail culling dropped ([`DetailSettings`]; already left out of
    /// `after_frustum`). Inside the occlusion test it judges only the groups the pyramid does not hide whole:
    /// a small object in a hidden group is counted occluded.
    pub detail_culled: usize,
    /// Time spent bringing bounds up to date.
    pub bounds_time: Duration,
    /// Time spent frustum culling.
    pub frustum_time: Duration,
    /// Set when the camera could not produce a frustum (an invalid camera): both stages then keep every object.
    pub frustum_error: Option<FrustumError>,
    /// Set when the occlusion settings are invalid ([`OcclusionSettings::validate`]): the occlusion stage then
    /// keeps every object the frustum kept.
    pub occlusion_error: Option<SettingsError>,
    /// Light views culled with the camera this frame ([`LightViews`]).
    pub light_views: usize,
    /// Shadow casters those views keep, summed over the views.
    pub light_view_casters: usize,
    /// Set when a light of [`LightViews`] gave no views this frame (it is left out, and reported here).
    pub light_view_error: Option<ViewError>,
    /// Casters the light views' occlusion hid from their lights this frame, summed over the views (already
    /// left out of `light_view_casters`).
    pub light_view_occluded: usize,
    /// Set when the light views' occlusion settings are invalid ([`LightOcclusionSettings::validate`]): the
    /// light views then keep every caster their frusta kept.
    pub light_occlusion_error: Option<SettingsError>,
    /// Light views whose occlusion was skipped this frame for removing too little lately.
    pub light_occlusion_gated: usize,
    /// Time spent on the light views' occlusion: selecting and rasterizing their occluders and testing their
    /// casters.
    pub light_occlusion_time: Duration,
    /// Occluders rasterized this frame.
    pub occluders: usize,
    /// Occluder triangles rasterized this frame (after clipping, front faces only; none of the hidden
    /// occluders').
    pub occluder_triangles: usize,
    /// Occluders skipped without setting up their triangles, found hidden behind nearer ones wherever they
    /// reach ([`RasterStats::occluders_hidden`](crate::raster::RasterStats::occluders_hidden)).
    pub occluders_hidden: usize,
    /// Objects left after occlusion culling.
    pub after_occlusion: usize,
    /// Time spent selecting and rasterizing occluders and building the depth pyramid.
    pub raster_time: Duration,
    /// Time spent testing occludees.
    pub occlusion_time: Duration,
    /// Nothing moved and neither the camera nor a setting changed: the frustum and occlusion stages kept last
    /// frame's result without running ([`AdaptiveSettings::reuse_unchanged`]).
    pub reused: bool,
    /// Objects culled alone this frame because only they moved: the camera, the settings, which objects are
    /// stored where and every occluder were unchanged, so the frustum and occlusion stages re-tested just these
    /// against last frame's planes and depth pyramid. 0 when the frame ran in full or was reused.
    pub retested: usize,
    /// The occlusion stage was skipped because it had removed too little lately
    /// ([`AdaptiveSettings::min_occlusion_benefit`]); everything the frustum kept stays visible.
    pub occlusion_gated: bool,
}

impl CullStats {
    /// Objects the frustum stage removed this frame.
    pub fn frustum_removed(&self) -> usize {
        self.objects - self.after_frustum
    }

    /// Objects the occlusion stage removed this frame.
    pub fn occlusion_removed(&self) -> usize {
        self.after_frustum - self.after_occlusion
    }
}

/// Settings of the frustum stage.
#[derive(Resource, Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrustumSettings {
    /// Whether the stage culls; when off, every object stays visible (for comparison and debugging).
    pub enabled: bool,
}

impl Default for FrustumSettings {
    fn default() -> Self {
        Self { enabled: true }
    }
}

/// The settings of every CPU stage, installed together by [`install`]; each is a resource of the world
/// afterwards, to change between frames.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PipelineSettings {
    /// The frustum stage.
    pub frustum: FrustumSettings,
    /// The occlusion stage (buffer resolution, mode, triangle budget).
    pub occlusion: OcclusionSettings,
    /// The light views' occlusion.
    pub light_occlusion: LightOcclusionSettings,
    /// What the pipeline may skip or reuse when it cannot pay off.
    pub adaptive: AdaptiveSettings,
    /// Detail culling after the frustum stage (lossy; off by default): inside the occlusion test where that
    /// runs, a pass of its own where it does not.
    pub detail: DetailSettings,
}

/// What the pipeline remembers between frames besides the camera's culler.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
struct PipelineMemory {
    /// The light views and their occlusion settings of the last frame, to tell a frame that changed them.
    last_lights: Option<(LightViews, LightOcclusionSettings)>,
    /// Visible sets of light views gone, reused for the next frame's.
    spare_sets: Vec<VisibleSet>,
}

/// Installs the CPU culling pipeline: the [`BoundsStore`] and its observers, the stage outputs and `settings`
/// as resources of `world`, and the stages, in order ([`CullStage`]), in `schedule`. Each
/// `schedule.run(&mut world)` then culls one frame: entities with [`crate::bounds::LocalBounds`] and
/// [`crate::bounds::ObjectTransform`] (and optionally an [`crate::occluders::Occluder`]) are culled against the [`crate::Camera`] resource, which
/// the caller inserts before the first run; [`CameraCuller`]'s [`ViewCuller::visible`] holds the result, [`CullStats`] the
/// counts and times.
///
/// Call `world.clear_trackers()` after each run, as `bevy_ecs` apps do between frames, so that the next run's
/// change detection sees only that frame's changes.
///
/// # Example
/// ```
/// use bevy_ecs::prelude::*;
/// use cullet::prelude::*;
/// use glam::{Affine3A, Vec3};
///
/// let (mut world, mut schedule) = (World::new(), Schedule::default());
/// cullet::install(&mut world, &mut schedule, PipelineSettings::default());
/// world.insert_resource(Camera::looking_at(Vec3::new(0.0, 2.0, 10.0), Vec3::ZERO));
/// let unit = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) };
/// let in_view = world.spawn((unit, ObjectTransform(Affine3A::IDENTITY))).id();
/// let behind = world.spawn((unit, ObjectTransform(Affine3A::from_translation(Vec3::new(0.0, 0.0, 50.0))))).id();
///
/// schedule.run(&mut world);
/// world.clear_trackers();
///
/// let store = world.resource::<BoundsStore>();
/// let visible = world.resource::<CameraCuller>().visible();
/// assert!(visible.contains(store.slot_of(in_view).unwrap()));
/// assert!(!visible.contains(store.slot_of(behind).unwrap()));
/// ```
pub fn install(world: &mut World, schedule: &mut Schedule, settings: PipelineSettings) {
    init_world(world);
    world.insert_resource(settings.frustum);
    world.insert_resource(settings.occlusion);
    world.insert_resource(settings.light_occlusion);
    world.insert_resource(settings.adaptive);
    world.insert_resource(settings.detail);
    add_systems(schedule);
}

/// Installs the bounds stage alone ([`CullStage::Bounds`]): the [`BoundsStore`] kept up to date from the
/// entities, for a culler of your own ([`crate::culler::Culler`]) to cull from, each frame after
/// `schedule.run(&mut world)`, with [`BoundsStore::take_moves`] for what moved. No stage culls and nothing is
/// read from the settings resources: [`crate::scene::flight::Flight::for_cullers`] drives cullers so.
pub fn install_bounds(world: &mut World, schedule: &mut Schedule) {
    init_world(world);
    schedule.add_systems(sync_bounds.in_set(CullStage::Bounds));
}

/// Sets up a world for culling: the [`BoundsStore`], its insertion and removal observers, and the stage
/// outputs ([`install`] inserts the settings).
fn init_world(world: &mut World) {
    world.init_resource::<BoundsStore>();
    world.init_resource::<CameraCuller>();
    world.init_resource::<LightViews>();
    world.init_resource::<LightViewsVisible>();
    world.init_resource::<CullStats>();
    world.init_resource::<PipelineMemory>();
    world.init_resource::<LightOcclusion>();
    world.add_observer(on_bounds_inserted);
    world.add_observer(on_bounds_removed);
    world.add_observer(on_occluder_inserted);
    world.add_observer(on_occluder_removed);
}

/// Adds the culling stages to `schedule`, in order.
fn add_systems(schedule: &mut Schedule) {
    schedule.configure_sets((CullStage::Bounds, CullStage::Frustum, CullStage::Occlusion).chain());
    schedule.add_systems((
        sync_bounds.in_set(CullStage::Bounds),
        frustum_stage.in_set(CullStage::Frustum),
        (occlusion_stage, light_occlusion_stage).chain().in_set(CullStage::Occlusion),
    ));
}
