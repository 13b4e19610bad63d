//! Light views' occlusion: the per-view core that the ECS pipeline's light views and the Bevy plugin's lights
//! both run after their frustum pass ([`LightOcclusion::occlude`]).

use super::adaptive::BenefitGate;
use super::settings::{AdaptiveSettings, OcclusionSettings, SettingsError};
use crate::bounds::BoundsStore;
use crate::depth::{DepthPyramid, ScreenView};
use crate::frustum::LightView;
use crate::occluders::{OccluderInstance, select_occluders_for_view};
use crate::occlusion::occlude;
use crate::parallel::{self, Stage};
use crate::raster::RasterMode;
use crate::visible::VisibleSet;
use bevy_ecs::prelude::*;
use rayon::prelude::*;
use std::time::{Duration, Instant};

/// Settings of the light views' occlusion: each light view (a sun's cascade, a lamp's face) gets a
/// conservative depth buffer of its own, seen from its light, of the occluders among its casters that face
/// the light, and its casters hidden behind them are dropped.
///
/// A caster hidden from the light at every point of its box changes no texel of the shadow map: wherever it
/// would be drawn, a nearer occluder, inside geometry that is drawn into the same map (or whose own shadow
/// cannot reach the camera's view), already is. Each view has its own benefit gate
/// ([`AdaptiveSettings::min_light_occlusion_benefit`]), so a view whose occlusion hides too little soon costs
/// only its occluder selection.
#[derive(Resource, Clone, Copy, Debug, PartialEq, Eq)]
pub struct LightOcclusionSettings {
    /// Whether light views are occlusion culled; when off, each keeps every caster its frustum kept.
    pub enabled: bool,
    /// Width and height of each light view's depth buffer, in texels (the buffer is always
    /// [`RasterMode::Conservative`]: it never hides what a shadow map of any resolution shows).
    pub size: u32,
    /// Most occluder triangles rasterized per light view and frame.
    pub triangle_budget: usize,
    /// A light view with fewer casters than this is not occlusion culled: too little to gain for a raster.
    pub min_casters: usize,
}

impl LightOcclusionSettings {
    /// Whether each light view's buffer, `size` x `size` texels, is within the bounds of
    /// [`OcclusionSettings::validate`]. Where it is not, the light views keep their casters and
    /// [`LightOcclusionStats::error`] says why.
    ///
    /// # Errors
    /// [`SettingsError`] says which bound is broken.
    pub fn validate(&self) -> Result<(), SettingsError> {
        OcclusionSettings { width: self.size, height: self.size, ..OcclusionSettings::default() }.validate()
    }
}

impl Default for LightOcclusionSettings {
    /// On, 128x128 texels, 2048 triangles a view, views of 64 casters or more.
    fn default() -> Self {
        Self { enabled: true, size: 128, triangle_budget: 2048, min_casters: 64 }
    }
}

/// One light view's result of the frame: what its frustum pass kept, narrowed by its occlusion.
#[derive(Clone, Debug, PartialEq)]
pub struct LightViewVisible {
    /// The light it belongs to, as an index into the caller's list of lights.
    pub light: usize,
    /// Its view and the matrix to draw its shadow map with.
    pub view: LightView,
    /// Store slots of the shadow casters it keeps.
    pub visible: VisibleSet,
    /// How many.
    pub kept: usize,
    /// How many of the casters its frustum kept its occlusion then hid from the light
    /// ([`LightOcclusionSettings`]); already left out of `visible` and `kept`.
    pub occluded: usize,
}

/// Counts and time of one [`LightOcclusion::occlude`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LightOcclusionStats {
    /// Casters hidden from their lights, summed over the views.
    pub occluded: usize,
    /// Views whose occlusion was skipped for removing too little lately.
    pub gated: usize,
    /// Set when the settings are invalid ([`LightOcclusionSettings::validate`]): every view then keeps the
    /// casters its frustum kept.
    pub error: Option<SettingsError>,
    /// Time spent selecting and rasterizing occluders and testing casters.
    pub time: Duration,
}

/// The light views' occlusion of one camera's light views, frame after frame: each view's depth pyramid, the
/// casters it hid, and its benefit gate, in the order of the views given to [`LightOcclusion::occlude`].
#[derive(Resource, Clone, Debug, Default)]
pub struct LightOcclusion {
    pyramids: Vec<DepthPyramid>,
    occluded: Vec<VisibleSet>,
    survivors: Vec<VisibleSet>,
    gates: Vec<BenefitGate>,
}

impl LightOcclusion {
    /// Occlusion culls each of `views` (see [`LightOcclusionSettings`]): selects the occluders among its
    /// casters, best first within the budget, looked up by store slot through `occluder_of`; rasterizes them
    /// as its light sees them ([`ScreenView::of_light_view`]); and drops its casters hidden behind them,
    /// updating each view's `visible`, `kept` and `occluded`. A view with fewer casters than
    /// [`LightOcclusionSettings::min_casters`] or no occluder among them rasterizes nothing, and one whose
    /// occlusion keeps hiding too little is skipped for a while, each with its own gate (reset where the number
    /// of views changes). The views are rasterized and tested in parallel.
    ///
    /// `occluder_of` must give only occluders inside geometry that is drawn into the light's shadow map.
    pub fn occlude<'a>(
        &mut self,
        store: &BoundsStore,
        views: &mut [LightViewVisible],
        settings: &LightOcclusionSettings,
        adaptive: &AdaptiveSettings,
        occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>> + Sync,
    ) -> LightOcclusionStats {
        let start = Instant::now();
        let _stage = Stage::LightOcclusion.enter();
        let count = views.len();
        self.pyramids.resize_with(count, DepthPyramid::default);
        self.occluded.resize_with(count, VisibleSet::default);
        self.survivors.resize_with(count, VisibleSet::default);
        if self.gates.len() != count {
            self.gates = vec![BenefitGate::default(); count];
        }
        let error = settings.validate().err().filter(|_| settings.enabled);
        if let Some(error) = error {
            tracing::warn!("light views' occlusion skipped: {error}");
        }
        let enabled = settings.enabled && error.is_none();
        // Each view's screen and occluders (those among its casters), where its occlusion runs this frame.
        let mut gated = 0;
        let chosen: Vec<Option<(ScreenView, Vec<OccluderInstance>)>> = views
            .iter()
            .zip(&mut self.gates)
            .map(|(view, gate)| {
                if !enabled || view.kept < settings.min_casters {
                    return None;
                }
                if gate.skip_this_frame() {
                    gated += 1;
                    return None;
                }
                // A light view without a screen (not made by `LightSource::light_views`) keeps its casters.
                let screen = ScreenView::of_light_view(&view.view, settings.size)?;
                let instances: Vec<OccluderInstance> =
                    select_occluders_for_view(store, &view.visible, &screen, settings.triangle_budget, &occluder_of)
                        .into_iter()
                        .map(|(_, instance)| instance)
                        .collect();
                (!instances.is_empty()).then_some((screen, instances))
            })
            .collect();
        let work = views.par_iter_mut().zip(&mut self.pyramids).zip(&mut self.occluded);
        let work = work.zip(&mut self.survivors).zip(&chosen);
        parallel::region(|region| {
            work.for_each(|((((view, pyramid), occluded), survivors), chosen)| {
                region.task(|| {
                    view.occluded = 0;
                    let Some((screen, chosen)) = chosen else {
                        *pyramid = DepthPyramid::default();
                        occluded.reset(0);
                        return;
                    };
                    let tested = view.kept;
                    let mode = RasterMode::Conservative;
                    view.kept =
                        occlude(store, &view.visible, Some(screen), chosen, mode, None, pyramid, survivors, occluded)
                            .test
                            .visible;
                    std::mem::swap(&mut view.visible, survivors);
                    view.occluded = tested - view.kept;
                })
            })
        });
        for ((view, gate), chosen) in views.iter().zip(&mut self.gates).zip(&chosen) {
            if chosen.is_some() {
                let (min_benefit, low_frames, reprobe) =
                    (adaptive.min_light_occlusion_benefit, adaptive.low_benefit_frames, adaptive.reprobe_every);
                gate.record(view.occluded, view.kept + view.occluded, min_benefit, low_frames, reprobe);
            }
        }
        let occluded = views.iter().map(|view| view.occluded).sum();
        LightOcclusionStats { occluded, gated, error, time: start.elapsed() }
    }

    /// Each view's farthest-depth pyramid of the last [`LightOcclusion::occlude`]; empty where it rasterized
    /// nothing.
    pub fn pyramids(&self) -> &[DepthPyramid] {
        &self.pyramids
    }

    /// Each view's casters that its frustum kept and its occlusion hid in the last
    /// [`LightOcclusion::occlude`] (empty where its occlusion did not run).
    pub fn occluded(&self) -> &[VisibleSet] {
        &self.occluded
    }
}
