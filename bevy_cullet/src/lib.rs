//! # bevy_cullet
//!
//! [Cullet](cullet)'s frustum and occlusion culling in a Bevy 0.20 app, in place of Bevy's CPU visibility
//! check. Add [`CulletPlugin`] after Bevy's `CameraPlugin` (part of `DefaultPlugins`): every active camera's
//! `VisibleEntities` and every entity's `ViewVisibility` then hold what Cullet keeps, so Bevy's renderer draws
//! exactly that.
//!
//! # What it does each frame (`PostUpdate`)
//! 1. [`CulletSystems::Mirror`], after transform propagation and Bevy's bounds: entities with an `Aabb` and a
//!    `GlobalTransform` are mirrored into a [`cullet::bounds::BoundsStore`] (SoA arrays) when either changed;
//!    despawns and removals leave the store at once (observers). Entities with `NoFrustumCulling` or
//!    `NoCpuCulling` are not mirrored.
//! 2. [`CulletSystems::Cull`], in Bevy's `VisibilitySystems::CheckVisibility`: for each active camera, Cullet's
//!    frustum stage, then (perspective cameras, [`CulletSettings::occlusion`] on, no [`NoCulletOcclusion`]) its
//!    occluder raster and occlusion test, then the survivors' `ViewVisibility` and the camera's
//!    `VisibleEntities`, honouring `InheritedVisibility`, `RenderLayers` and `VisibilityRange` as Bevy does.
//!    Entities Cullet does not mirror get Bevy's own rules: a bounding `Sphere` is tested against the camera's
//!    frustum, anything else is visible. Each camera's light views are culled in the same pass (see "Lights").
//! 3. [`CulletSystems::Lights`], in Bevy's `SimulationLightSystems::CheckLightVisibility`: each light's shadow
//!    casters written to Bevy's per-light lists, and made visible so that Bevy draws them into its shadow maps.
//!
//! # How it takes over from Bevy's check
//! [`CulletPlugin`] removes Bevy's `check_visibility_cpu_culling` from `PostUpdate`
//! (`App::remove_systems_in_set`) and runs its own [`CulletSystems::Cull`] in the same set; it adds Bevy's
//! check back there with a run condition, so that it runs instead while [`CulletSettings::enabled`] is off. The rest of Bevy's
//! visibility stays: `reset_view_visibility` before it, `mark_newly_hidden_entities_invisible` after it, and
//! `check_visibility_gpu_culling` for entities with `NoCpuCulling`, so `ViewVisibility` keeps its contract
//! (change detection fires on hidden-to-visible and visible-to-hidden only). A camera with `NoCpuCulling` sees
//! every entity in its layers, as in Bevy.
//!
//! # Occluders
//! An entity with an `Aabb`, a `GlobalTransform` and a [`cullet::Occluder`] (triangles in its local space,
//! lying inside what it draws) hides what is behind it. It occludes in the views whose layers it is in, and
//! only while its `InheritedVisibility` is visible (or it has none): a hidden wall hides nothing. An occluder
//! that must not be drawn is an entity without a mesh, not a hidden one: mark a `Mesh3d` entity with
//! [`OccluderMesh`], or name it (or its glTF node) `*_occluder`, and the plugin turns its mesh into its
//! occluder and stops drawing it ([`CulletSystems::Occluders`]).
//!
//! # Lights
//! With Bevy's `LightPlugin` in the app (part of `DefaultPlugins`; add [`CulletPlugin`] after it), the plugin
//! also takes over Bevy's `check_dir_light_mesh_visibility` and `check_point_light_mesh_visibility`, which
//! run again while [`CulletSettings::lights`] (or [`CulletSettings::enabled`]) is off. For each active camera
//! it builds, from Bevy's own matrices:
//! - every cascade Bevy built for the camera of each visible `DirectionalLight` with shadows;
//! - each cube face of each `PointLight`, and the map of each `SpotLight`, with shadows, whose range meets
//!   the camera's frustum (the lights Bevy's own check takes), cut at the light's range.
//!
//! These light views are culled in the camera's frustum pass, one pass over the bounds for the camera and all
//! its lights, and each keeps only the casters whose shadows can fall inside the camera's frustum
//! ([`cullet::frustum::View::shadow_casters`]): a caster behind the camera whose shadow falls away from it is
//! dropped, one between the light and the map's near plane kept. Each view is then occlusion culled from its
//! light ([`CulletSettings::light_occlusion`], with its own benefit gate): a caster hidden from the light behind
//! occluders that are themselves drawn into that light's maps (visible `Mesh3d` shadow casters in its layers)
//! changes no texel of the map. [`CulletSystems::Lights`] then writes a directional light's
//! `CascadesVisibleEntities` per camera and cascade, a point light's `CubemapVisibleEntities` and a spot light's
//! `VisibleMeshEntities` (a lamp seen by several cameras gets the union), each sorted, after Bevy's rules:
//! `Mesh3d` casters without `NotShadowCaster` or `NoCpuCulling`, visible, in the light's `RenderLayers`, in
//! `VisibilityRange` of the camera (of the shadow LOD origin for lamps); entities the plugin does not mirror
//! are in every map of a light it culls, as in Bevy. A light with `shadow_maps_enabled` off lists nothing; one
//! with [`NoCulletLightCulling`] keeps every caster its own maps hold, as Bevy's checks do.
//! [`CulletView::light_views`] and [`ViewStats`] give each camera's light views and counts,
//! [`CulletLightStats`] the write's.
//!
//! What the plugin lists is a subset of what Bevy's checks list (up to boxes touching a map's edge, which the
//! plugin's rounding slack keeps, and rotated boxes, whose world box is looser than Bevy's oriented one), and
//! it holds every caster whose shadow can reach the camera's view: `tests/lights.rs` checks both against the
//! exact judge, from Bevy's own matrices, over a camera path with cuts.
//!
//! # Levels of detail
//! Insert a [`CulletLod`] resource (each mesh's levels and the pixel error, hysteresis and triangle budget)
//! and give entities a [`cullet::MeshRef`] naming their mesh's chain: after culling, [`CulletSystems::Lod`]
//! chooses a level for each entity the main camera (the active perspective camera of lowest order) keeps and
//! writes it as a [`LodLevel`] component where it changed. [`mesh_levels`] makes a Bevy mesh's levels and the
//! chain for the library; an entity given their handles as [`LodMeshes`] gets its `Mesh3d` swapped to the
//! level chosen, and leaves the main camera's visible list while the budget drops it (without [`LodMeshes`],
//! swap the mesh on `Changed<LodLevel>`). [`CulletLodStats`] holds what the last frame chose. Lossy, and off
//! without the resource.
//!
//! # Conservative
//! The frustum test keeps every box the exact test keeps (Cullet's planes add a slack that bounds their f32
//! rounding); it tests each object's world box, which for rotated objects is looser than Bevy's oriented box,
//! so it may keep a few more. The occlusion test hides only what the occluders provably hide. An entity whose
//! bounds Cullet rejects (not finite, say) is logged, listed in [`CulletStore::rejected`] and always visible;
//! a camera whose matrices give no frustum keeps everything and reports it in [`cullet::culler::ViewStats::frustum_error`].
//!
//! # Threads
//! Cullet's stages, and the plugin's write of what they keep, run on rayon's global pool, beside Bevy's task
//! pools. [`CulletSystems::Cull`] runs on the main thread, which otherwise waits while rayon's threads cull.
//! Make that thread one of rayon's, first thing in `main` (with `rayon` among your dependencies; see
//! [Cullet's "Threads"](cullet#threads)):
//! ```no_run
//! rayon::ThreadPoolBuilder::new().use_current_thread().build_global().expect("rayon's global pool, once");
//! ```
//! It then works on each stage at once instead of waking a pool thread to start it, which wakes the next: a
//! woken thread can join after the stage is over. The plugin's bench (`cargo bench -p bevy_cullet --bench
//! visibility`) does it; its README measures what it saves.
//!
//! # Example
//! ```
//! use bevy_app::prelude::*;
//! use bevy_camera::{Camera3d, primitives::Aabb, visibility::Visibility};
//! use bevy_cullet::{CulletPlugin, CulletView};
//! use bevy_math::Vec3;
//! use bevy_transform::prelude::*;
//!
//! let mut app = App::new();
//! app.add_plugins((TaskPoolPlugin::default(), TransformPlugin, bevy_camera::CameraPlugin, CulletPlugin));
//! # app.init_resource::<bevy_asset::Assets<bevy_mesh::Mesh>>();
//! # app.init_resource::<bevy_asset::Assets<bevy_mesh::skinning::SkinnedMeshInverseBindposes>>();
//! let camera = app.world_mut().spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 10.0))).id();
//! let unit = Aabb::from_min_max(Vec3::splat(-0.5), Vec3::splat(0.5));
//! let in_view = app.world_mut().spawn((unit, Transform::IDENTITY, Visibility::default())).id();
//! let behind = app.world_mut().spawn((unit, Transform::from_xyz(0.0, 0.0, 20.0), Visibility::default())).id();
//! app.update();
//!
//! let world = app.world();
//! assert!(world.get::<bevy_camera::visibility::ViewVisibility>(in_view).unwrap().get());
//! assert!(!world.get::<bevy_camera::visibility::ViewVisibility>(behind).unwrap().get());
//! assert_eq!(world.get::<CulletView>(camera).unwrap().stats().after_frustum, 1);
//! ```

#![warn(missing_docs)]

mod convert;
mod cull;
mod light_lists;
mod lights;
mod lod;
mod mirror;
mod occluders;
mod scene;

pub use cull::{CulletView, ViewStats};
pub use light_lists::CulletLightStats;
pub use lod::{CulletLod, CulletLodStats, LodLevel, LodMeshes};
#[cfg(feature = "lod")]
pub use lod::{MeshLevels, MeshLevelsError, mesh_levels};
pub use mirror::CulletStore;
pub use occluders::{GLTF_EXTRAS, OCCLUDER_SUFFIX, OccluderMesh};
pub use scene::spawn_scene;

use bevy_app::{App, Plugin, PostUpdate};
use bevy_camera::Camera;
use bevy_camera::visibility::{VisibilitySystems, check_visibility_cpu_culling};
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleCleanupPolicy;
use bevy_light::{SimulationLightSystems, check_dir_light_mesh_visibility, check_point_light_mesh_visibility};
use bevy_transform::TransformSystems;
use cullet::culler::{AdaptiveSettings, LightOcclusionSettings, OcclusionSettings};
use cullet::scene::auto_occluders::AutoOccluderSettings;

/// Replaces Bevy's CPU visibility check with Cullet's culling; see the [crate documentation](crate).
///
/// # Panics
/// When built into an app without Bevy's `CameraPlugin`: the plugin replaces a system that plugin adds.
#[derive(Default)]
pub struct CulletPlugin;

/// What the plugin culls with, for every camera (a camera opts out of occlusion with [`NoCulletOcclusion`]).
/// Change it between frames; the next frame uses it.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct CulletSettings {
    /// Whether the plugin culls. Off, Bevy's own `check_visibility_cpu_culling` runs in its place (for
    /// comparison: a key in the demo switches it); the plugin still mirrors bounds, so it resumes at once.
    pub enabled: bool,
    /// Frustum culling of the mirrored entities. Off keeps all of them in every view (for comparison).
    pub frustum: bool,
    /// Automatic occluders: where set, large drawn meshes without an occluder get one from their own largest
    /// triangles (see [`cullet::scene::auto_occluders`]). Off by default, as in the sample game.
    pub auto_occluders: Option<AutoOccluderSettings>,
    /// The software occlusion stage: on or off, its buffer's resolution and mode, and the most occluder
    /// triangles rasterized per view and frame. By default each camera gets [`OcclusionSettings::for_frame`]'s
    /// choice for its viewport: a masked buffer standing for the viewport's pixels, at most 960x540 (on the
    /// city's fly-through at 1920x1080, 97.2% of what is hidden culled in about the time of the 256x144
    /// buffer's 94.6%). A pixel-centre or masked buffer ([`cullet::raster::RasterMode::samples_pixel_centres`])
    /// is conservative only for the frame it samples, so each camera's follows its physical viewport
    /// ([`OcclusionSettings::resized_to`]); a camera whose size Bevy does not know yet (no render target) gets
    /// [`OcclusionSettings::default`]'s 256x144 conservative buffer, conservative at any size. A conservative
    /// or fast buffer keeps `width` x `height` for every camera.
    pub occlusion: OcclusionSettings,
    /// What each camera skips when it cannot pay off, as in Cullet's own pipeline (defaults: its
    /// [`AdaptiveSettings::default`]). The plugin follows `reuse_unchanged` (an unchanged view over unchanged
    /// bounds and occluders keeps its last result; where only entities without occluders moved, their
    /// occlusion alone is re-tested against the last depth buffer: [`cullet::culler::ViewStats::retested`]),
    /// `plane_coherence`, and `min_occlusion_benefit` with
    /// `low_benefit_frames` and `reprobe_every` (a camera whose occlusion removed under 1% of its frustum
    /// survivors for 8 frames in a row skips it for 30 frames, then tries again:
    /// [`cullet::culler::ViewStats::occlusion_gated`]), and `min_light_occlusion_benefit` for each light view.
    /// It always selects hidden occluders, so `skip_hidden_occluders` does nothing here. Skipping only ever keeps
    /// more entities visible.
    pub adaptive: AdaptiveSettings,
    /// Whether the plugin culls the lights' shadow maps too (see the crate's "Lights"). Off, Bevy's own
    /// `check_dir_light_mesh_visibility` and `check_point_light_mesh_visibility` run in their place.
    pub lights: bool,
    /// The light views' occlusion: each cascade, cube face or spot map gets a conservative depth buffer of the
    /// occluders among its casters, as its light sees them, and drops the casters hidden behind them (gated by
    /// [`AdaptiveSettings::min_light_occlusion_benefit`]).
    pub light_occlusion: LightOcclusionSettings,
}

impl Default for CulletSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            frustum: true,
            auto_occluders: None,
            occlusion: OcclusionSettings::for_frame(1920, 1080),
            adaptive: AdaptiveSettings::default(),
            lights: true,
            light_occlusion: LightOcclusionSettings::default(),
        }
    }
}

/// A camera with this component gets frustum culling only: its views skip the occlusion stage.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct NoCulletOcclusion;

/// A light (directional, point or spot) with this component keeps every caster its own shadow maps hold, as
/// Bevy's light checks do: its maps are still culled by the plugin, in the cameras' pass, but not narrowed to
/// the casters whose shadows reach a camera's view, nor occluded from the light. For a map a renderer uses
/// beyond the cameras' views.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct NoCulletLightCulling;

/// The plugin's systems, in `PostUpdate`, in this order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CulletSystems {
    /// Turns [`OccluderMesh`] entities (and `*_occluder` names) into occluders once their mesh is loaded.
    Occluders,
    /// Mirrors changed bounds into [`CulletStore`].
    Mirror,
    /// Gives large meshes automatic occluders, where [`CulletSettings::auto_occluders`] is set.
    AutoOccluders,
    /// Culls every camera's view, its light views with it, and writes the camera's visibility (inside
    /// `VisibilitySystems::CheckVisibility`).
    Cull,
    /// Writes each light's shadow casters and makes them visible (inside Bevy's
    /// `SimulationLightSystems::CheckLightVisibility`).
    Lights,
    /// Chooses each kept entity's level of detail, where a [`CulletLod`] resource asks for it.
    Lod,
}

/// Run condition: [`CulletSettings::enabled`].
fn enabled(settings: Res<CulletSettings>) -> bool {
    settings.enabled
}

/// Run condition: [`CulletSettings::enabled`] and [`CulletSettings::lights`].
fn lights_enabled(settings: Res<CulletSettings>) -> bool {
    settings.enabled && settings.lights
}

impl Plugin for CulletPlugin {
    fn build(&self, app: &mut App) {
        let removed = app.remove_systems_in_set(
            PostUpdate,
            check_visibility_cpu_culling,
            ScheduleCleanupPolicy::RemoveSystemsOnly,
        );
        assert!(
            removed.is_ok_and(|count| count > 0),
            "CulletPlugin replaces Bevy's check_visibility_cpu_culling: add it after bevy_camera's CameraPlugin"
        );
        // Bevy's light checks, where its `LightPlugin` added them, give way to the plugin's in the same way.
        let light_checks = [
            app.remove_systems_in_set(
                PostUpdate,
                check_dir_light_mesh_visibility,
                ScheduleCleanupPolicy::RemoveSystemsOnly,
            ),
            app.remove_systems_in_set(
                PostUpdate,
                check_point_light_mesh_visibility,
                ScheduleCleanupPolicy::RemoveSystemsOnly,
            ),
        ];
        if light_checks.iter().all(|removed| removed.as_ref().is_ok_and(|count| *count > 0)) {
            app.add_systems(
                PostUpdate,
                (check_dir_light_mesh_visibility, check_point_light_mesh_visibility)
                    .in_set(SimulationLightSystems::CheckLightVisibility)
                    .after(VisibilitySystems::CalculateBounds)
                    .after(TransformSystems::Propagate)
                    .after(SimulationLightSystems::UpdateLightFrusta)
                    .after(VisibilitySystems::CheckVisibility)
                    .before(VisibilitySystems::MarkNewlyHiddenEntitiesInvisible)
                    .run_if(not(lights_enabled)),
            );
        }
        app.init_resource::<CulletSettings>()
            .init_resource::<CulletStore>()
            .init_resource::<CulletLightStats>()
            .init_resource::<CulletLodStats>()
            .register_required_components::<Camera, CulletView>()
            .configure_sets(
                PostUpdate,
                (
                    CulletSystems::Occluders.before(CulletSystems::Mirror),
                    CulletSystems::Mirror
                        .after(TransformSystems::Propagate)
                        .after(VisibilitySystems::CalculateBounds)
                        .before(VisibilitySystems::CheckVisibility),
                    CulletSystems::AutoOccluders.after(CulletSystems::Mirror).before(CulletSystems::Cull),
                    CulletSystems::Cull
                        .in_set(VisibilitySystems::CheckVisibility)
                        .after(SimulationLightSystems::UpdateDirectionalLightCascades),
                    CulletSystems::Lights
                        .in_set(SimulationLightSystems::CheckLightVisibility)
                        .after(CulletSystems::Cull)
                        .before(VisibilitySystems::MarkNewlyHiddenEntitiesInvisible),
                    CulletSystems::Lod.after(CulletSystems::Cull),
                ),
            )
            .add_systems(
                PostUpdate,
                (
                    (
                        occluders::mark_named_occluders,
                        occluders::mark_extras_occluders,
                        occluders::build_occluder_meshes,
                    )
                        .chain()
                        .in_set(CulletSystems::Occluders),
                    mirror::mirror_bounds.in_set(CulletSystems::Mirror),
                    occluders::add_auto_occluders.in_set(CulletSystems::AutoOccluders),
                    cull::cull_views.in_set(CulletSystems::Cull).after(CulletSystems::Mirror).run_if(enabled),
                    light_lists::write_light_views.in_set(CulletSystems::Lights).run_if(lights_enabled),
                    (lod::choose_levels, lod::swap_meshes).chain().in_set(CulletSystems::Lod).run_if(enabled),
                    // Bevy's check, where it was, for when the plugin is switched off.
                    check_visibility_cpu_culling.in_set(VisibilitySystems::CheckVisibility).run_if(not(enabled)),
                ),
            );
        mirror::add_observers(app);
    }
}
