//! The pipeline's stages as systems: the bounds are synced by [`super::bounds::sync_bounds`], then the
//! camera's [`ViewCuller`](crate::culler::ViewCuller) culls in two systems (frustum, occlusion), the light views with it.

use super::{CameraCuller, CullStats, FrustumSettings, LightViews, LightViewsVisible, PipelineMemory};
use crate::bounds::{BoundsStore, ObjectTransform};
use crate::camera::Camera;
use crate::culler::{
    AdaptiveSettings, LightOcclusion, LightOcclusionSettings, LightViewVisible, OcclusionSettings, ViewFrame,
    ViewInput, ViewSettings,
};
use crate::detail::DetailSettings;
use crate::frustum::{LightView, View, ViewError};
use crate::occluders::{Occluder, OccluderInstance};
use crate::visible::VisibleSet;
use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemParam;
use std::time::Instant;

/// The settings of every stage, as the systems read them.
#[derive(SystemParam)]
pub(super) struct StageSettings<'w> {
    frustum: Res<'w, FrustumSettings>,
    occlusion: Res<'w, OcclusionSettings>,
    light_occlusion: Res<'w, LightOcclusionSettings>,
    adaptive: Res<'w, AdaptiveSettings>,
    detail: Res<'w, DetailSettings>,
}

impl StageSettings<'_> {
    /// What the camera's culler culls with.
    fn view(&self) -> ViewSettings {
        let (frustum, occlusion, adaptive) = (self.frustum.enabled, *self.occlusion, *self.adaptive);
        ViewSettings { frustum, occlusion, adaptive, detail: *self.detail }
    }
}

/// The light views, as the systems read and write them.
#[derive(SystemParam)]
pub(super) struct Lights<'w> {
    sources: Res<'w, LightViews>,
    views: ResMut<'w, LightViewsVisible>,
    memory: ResMut<'w, PipelineMemory>,
}

/// Culls the store against the [`Camera`]'s frustum ([`CameraCuller`]), and for the [`LightViews`] into
/// [`LightViewsVisible`], all views in one pass over the bounds. A camera that gives no valid frustum culls
/// nothing (everything stays visible, here and in the occlusion stage) and reports the error in
/// [`CullStats`]; so does a stage turned off in [`FrustumSettings`]. With
/// [`AdaptiveSettings::reuse_unchanged`] it keeps last frame's result when nothing changed, and, without light
/// views, re-tests only the moved objects when nothing else did ([`CullStats::retested`]).
pub(super) fn frustum_stage(
    mut store: ResMut<BoundsStore>,
    camera: Res<Camera>,
    settings: StageSettings,
    mut lights: Lights,
    mut culler: ResMut<CameraCuller>,
    mut stats: ResMut<CullStats>,
) {
    let start = Instant::now();
    stats.bounds_recomputed = store.recomputed_last_sync();
    stats.bounds_time = store.last_sync_time();
    let moves = store.take_moves();
    let memory = &mut *lights.memory;
    let light_settings = *settings.light_occlusion;
    let lights_changed = memory
        .last_lights
        .as_ref()
        .is_none_or(|(sources, light)| *sources != *lights.sources || *light != light_settings);
    if lights_changed {
        memory.last_lights = Some(((*lights.sources).clone(), light_settings));
    }
    let frame = ViewFrame {
        view: ViewInput::of_camera(&camera),
        settings: settings.view(),
        moves: moves.as_ref(),
        // A changed occluder changes the store's layout (`Occluder` is immutable: its observers see each).
        changed: lights_changed,
    };
    // This frame's light views, culled with the camera; none are built where the camera's last result stands
    // (and with it, last frame's light views).
    let lit = if lights.sources.0.is_empty() {
        stats.light_view_error = None;
        Vec::new()
    } else if culler.reuses(&store, &frame) {
        Vec::new()
    } else {
        light_views_of(&lights.sources, &camera, &mut stats.light_view_error)
    };
    let also: Vec<View> = lit.iter().map(|(_, light)| light.view.clone()).collect();
    let mut sets = std::mem::take(&mut memory.spare_sets);
    let kept = culler.cull_frustum(&store, &frame, &also, &mut sets);
    let view = culler.stats();
    match kept {
        Some(counts) => {
            let culled = lit.into_iter().zip(sets.drain(..also.len())).zip(counts);
            let fresh = culled
                .map(|(((light, view), visible), kept)| LightViewVisible { light, view, visible, kept, occluded: 0 })
                .collect();
            let old = std::mem::replace(&mut lights.views.0, fresh);
            sets.extend(old.into_iter().map(|view| view.visible));
        }
        // Last frame's light views, occlusion included, stand.
        None if view.reused => {}
        // Not culled this frame (the stage is off, or the camera has no frustum): every light view keeps
        // everything.
        None => {
            let all = |(light, view)| LightViewVisible {
                light,
                view,
                visible: VisibleSet::all(store.len()),
                kept: store.len(),
                occluded: 0,
            };
            lights.views.0 = lit.into_iter().map(all).collect();
        }
    }
    memory.spare_sets = sets;
    (stats.reused, stats.retested, stats.frustum_error) = (view.reused, view.retested, view.frustum_error);
    (stats.objects, stats.after_frustum) = (view.objects, view.after_frustum);
    if view.reused {
        (stats.raster_time, stats.occlusion_time) = (view.raster_time, view.occlusion_time);
    } else {
        stats.light_views = lights.views.0.len();
        stats.light_view_casters = lights.views.0.iter().map(|view| view.kept).sum();
    }
    stats.frustum_time = start.elapsed();
}

/// The light views of every light in `lights` for `camera`, each with its light's index; a light whose views
/// cannot be built is left out and its error kept in `error` (cleared where none fails).
fn light_views_of(lights: &LightViews, camera: &Camera, error: &mut Option<ViewError>) -> Vec<(usize, LightView)> {
    *error = None;
    let mut views = Vec::new();
    for (index, light) in lights.0.iter().enumerate() {
        match light.light_views(camera) {
            Ok(built) => views.extend(built.into_iter().map(|view| (index, view))),
            Err(why) => {
                tracing::warn!("light {index} has no views this frame: {why}");
                *error = Some(why);
            }
        }
    }
    views
}

/// Selects occluders among the frustum survivors, rasterizes them into the camera's depth buffer, builds its
/// pyramid and tests every frustum survivor against it ([`ViewCuller::cull_occlusion`](crate::culler::ViewCuller::cull_occlusion)). With no occluder in
/// view it rasterizes and tests nothing; where the frustum stage re-tested only moved objects, so does this
/// stage, against last frame's pyramid; after frames of too little benefit it is skipped for a while
/// ([`AdaptiveSettings::min_occlusion_benefit`]).
pub(super) fn occlusion_stage(
    store: Res<BoundsStore>,
    mut culler: ResMut<CameraCuller>,
    mut stats: ResMut<CullStats>,
    occluders: Query<(&Occluder, &ObjectTransform)>,
) {
    if stats.reused {
        return;
    }
    culler.cull_occlusion(&store, |slot| {
        let (occluder, transform) = occluders.get(store.entities()[slot]).ok()?;
        Some(OccluderInstance { occluder, transform: transform.0 })
    });
    let view = culler.stats();
    (stats.occluders, stats.occluder_triangles, stats.occluders_hidden) =
        (view.occluders, view.occluder_triangles, view.occluders_hidden);
    (stats.after_occlusion, stats.occlusion_gated, stats.occlusion_error) =
        (view.after_occlusion, view.occlusion_gated, view.occlusion_error);
    // Detail culling runs in the occlusion test: the frustum's count leaves out what it dropped.
    (stats.after_frustum, stats.detail_culled) = (view.after_frustum, view.detail_culled);
    (stats.raster_time, stats.occlusion_time) = (view.raster_time, view.occlusion_time);
}

/// Occlusion culls each light view of [`LightViewsVisible`] from its light ([`LightOcclusion::occlude`],
/// with [`LightOcclusionSettings`]), recording its counts in [`CullStats`]. Runs only on frames whose frustum
/// stage culled the light views afresh.
pub(super) fn light_occlusion_stage(
    store: Res<BoundsStore>,
    stage_settings: StageSettings,
    mut light_views: ResMut<LightViewsVisible>,
    mut occlusion: ResMut<LightOcclusion>,
    mut stats: ResMut<CullStats>,
    occluders: Query<(&Occluder, &ObjectTransform)>,
) {
    if stats.reused {
        return; // Last frame's light views, occlusion included, stand.
    }
    let (settings, adaptive) = (&*stage_settings.light_occlusion, &*stage_settings.adaptive);
    let light = occlusion.occlude(&store, &mut light_views.0, settings, adaptive, |slot| {
        let (occluder, transform) = occluders.get(store.entities()[slot]).ok()?;
        Some(OccluderInstance { occluder, transform: transform.0 })
    });
    (stats.light_view_occluded, stats.light_occlusion_gated) = (light.occluded, light.gated);
    (stats.light_occlusion_error, stats.light_occlusion_time) = (light.error, light.time);
    stats.light_view_casters = light_views.0.iter().map(|view| view.kept).sum();
}
