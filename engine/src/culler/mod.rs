//! Culling one view, and the interface every culler implements.
//!
//! [`ViewCuller`] is the per-view core: the frustum stage, then the occluder selection, raster and occlusion
//! test, with the state they keep from frame to frame. The ECS pipeline ([`crate::pipeline`]) wraps one for
//! its camera, the Bevy plugin one per camera; anything else that culls a view against a [`BoundsStore`]
//! can too. A camera's light views (shadow cascades, a lamp's faces) are culled in its frustum pass
//! ([`ViewCuller::cull_frustum`]), then each from its own light by [`LightOcclusion`]: the pipeline's light
//! views and the plugin's lights alike.
//!
//! [`Culler`] is what the judge, the benches and the sample game run to compare ways of culling over the
//! same scenes, paths and frames: given the scene and a camera, a culler returns the store slots it keeps
//! and its counts. [`StageCuller`] (the pipeline's stages with any [`ViewSettings`], frustum-only among them)
//! is its first implementation; a culler that keeps state across frames keeps it in `self`.
//! [`ShadowFrustaCuller`] culls with the occluders' shadow frusta instead of a depth buffer;
//! [`HierarchyCuller`] culls down a bounding volume hierarchy instead of over the linear arrays;
//! [`PortalCuller`] through the cells and portals of an interior ([`crate::cells`]), then by occlusion;
//! `cullet::gpu::QueryGridCuller` (feature `gpu`) with GPU occlusion queries over a uniform grid, a frame late.

mod adaptive;
mod hierarchy;
mod light;
mod portals;
mod settings;
mod shadow_frusta;
mod view;

pub use adaptive::{BenefitGate, RetestCost};
pub use hierarchy::{Bvh, HierarchyCuller, HierarchySettings};
pub use light::{LightOcclusion, LightOcclusionSettings, LightOcclusionStats, LightViewVisible};
pub use portals::{PortalCuller, PortalSettings, PortalStats};
pub use settings::{
    AdaptiveSettings, MAX_OCCLUSION_SAMPLES, MAX_OCCLUSION_SIDE, OcclusionSettings, SettingsError, ViewSettings,
};
pub use shadow_frusta::{ShadowFrustaCuller, ShadowFrustaSettings};
pub use view::{ViewCuller, ViewFrame, ViewInput, ViewStats};

use crate::bounds::{BoundsStore, ObjectTransform, StoreMoves};
use crate::camera::Camera;
use crate::occluders::{Occluder, OccluderInstance};
use crate::visible::VisibleSet;
use bevy_ecs::world::World;

/// The scene a [`Culler`] culls one frame of: a world whose [`BoundsStore`] is up to date for the frame
/// (the pipeline's bounds stage has run: [`crate::pipeline::CullStage::Bounds`]), with the objects' occluders
/// as components ([`Occluder`] and [`ObjectTransform`]).
#[derive(Clone, Copy)]
pub struct CullScene<'w> {
    /// The world.
    pub world: &'w World,
    /// What moved in place since the store's generation `moves.from`, where the caller keeps it
    /// ([`BoundsStore::take_moves`]); `None` where unknown.
    pub moves: Option<&'w StoreMoves>,
}

impl<'w> CullScene<'w> {
    /// The scene of `world`, nothing known of what moved.
    ///
    /// # Panics
    /// Where `world` has no [`BoundsStore`] (see [`crate::install`]).
    pub fn new(world: &'w World) -> Self {
        assert!(world.contains_resource::<BoundsStore>(), "a scene to cull needs a BoundsStore: see cullet::install");
        Self { world, moves: None }
    }

    /// The objects' bounds.
    pub fn store(&self) -> &'w BoundsStore {
        self.world.resource::<BoundsStore>()
    }

    /// The occluders [`crate::occluders::select_occluders`] chooses among `visible` for an eye at `eye`
    /// within `triangle_budget` triangles, best first.
    pub(crate) fn occluders_among(
        &self,
        visible: &VisibleSet,
        eye: glam::Vec3,
        triangle_budget: usize,
    ) -> Vec<OccluderInstance<'w>> {
        crate::occluders::select_occluders(self.store(), visible, eye, triangle_budget, |slot| self.occluder_of(slot))
            .into_iter()
            .map(|(_, occluder)| occluder)
            .collect()
    }

    /// The occluder of the object in store slot `slot`, where it has one.
    pub fn occluder_of(&self, slot: usize) -> Option<OccluderInstance<'w>> {
        let entity = *self.store().entities().get(slot)?;
        let occluder = self.world.get::<Occluder>(entity)?;
        let transform = self.world.get::<ObjectTransform>(entity)?;
        Some(OccluderInstance { occluder, transform: transform.0 })
    }
}

/// What changed in a scene's store since a culler last brought a structure of its own (a tree, a grid) up to
/// date, at the store's generation and layout generation `synced` ([`CullScene::change_since`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum StoreChange<'w> {
    /// Nothing.
    None,
    /// Bounds changed in place: the slots, where the scene lists them; `None` where it does not.
    Moved(Option<&'w [u32]>),
    /// Objects came or went (or nothing was brought up to date yet): build again.
    Layout,
}

impl<'w> CullScene<'w> {
    /// What changed in the store since it was at `synced` (its generation and layout generation then).
    pub(crate) fn change_since(&self, synced: Option<(u64, u64)>) -> StoreChange<'w> {
        let store = self.store();
        let now = (store.generation(), store.layout_generation());
        match synced {
            Some(then) if then == now => StoreChange::None,
            Some((generation, layout)) if layout == now.1 => {
                let listed = self.moves.filter(|m| (m.from, m.to) == (generation, now.0));
                StoreChange::Moved(listed.map(|m| m.slots.as_slice()))
            }
            _ => StoreChange::Layout,
        }
    }

    /// The store's generation and layout generation now: what [`CullScene::change_since`] compares with.
    pub(crate) fn generations(&self) -> (u64, u64) {
        (self.store().generation(), self.store().layout_generation())
    }
}

/// What a [`Culler`] kept in one frame.
#[derive(Clone, Debug)]
pub struct Culled<'a> {
    /// The store slots each of the culler's stages kept, in order, named; the last is the result. A culler of
    /// one stage gives one.
    pub stages: Vec<(&'static str, &'a VisibleSet)>,
    /// Its counts and times.
    pub stats: ViewStats,
}

impl Culled<'_> {
    /// The store slots the culler kept: its last stage's.
    pub fn kept(&self) -> &VisibleSet {
        self.stages.last().map(|(_, kept)| *kept).expect("a culler has at least one stage")
    }
}

/// The camera's frustum; or, for a camera without one (invalid, its error in `stats`), `None` with both of a
/// culler's sets keeping all `len` objects, as every stage does, and `stats.frustum_time` since `start`.
pub(crate) fn frustum_or_keep_everything(
    camera: &Camera,
    len: usize,
    frustum_visible: &mut VisibleSet,
    kept: &mut VisibleSet,
    stats: &mut ViewStats,
    start: std::time::Instant,
) -> Option<crate::frustum::Frustum> {
    let error = match camera.frustum() {
        Ok(frustum) => return Some(frustum),
        Err(error) => error,
    };
    stats.frustum_error = Some(error);
    *frustum_visible = VisibleSet::all(len);
    kept.clone_from(frustum_visible);
    (stats.after_frustum, stats.after_occlusion) = (len, len);
    stats.frustum_time = start.elapsed();
    None
}

/// A way of culling, run frame by frame over a scene: the judge, the benches and the sample game compare
/// cullers through it on the same scenes, paths and frames.
///
/// A culler keeps whatever it needs across frames in `self` (last frame's results, a GPU's query results).
/// It must keep every object a rendering through `camera` shows, unless it says otherwise in
/// [`Culler::is_conservative`].
pub trait Culler {
    /// A short name for tables and plots.
    fn name(&self) -> String;

    /// Whether it never removes an object a rendering of `viewport` (width, height) pixels shows.
    fn is_conservative(&self, viewport: (u32, u32)) -> bool;

    /// Culls one frame of `scene` through `camera`.
    fn cull(&mut self, scene: &CullScene, camera: &Camera) -> Culled<'_>;
}

/// The pipeline's CPU stages for one camera, with given settings: a [`ViewCuller`] behind [`Culler`].
#[derive(Clone, Debug, Default)]
pub struct StageCuller {
    name: String,
    /// What the stages cull with; change it between frames.
    pub settings: ViewSettings,
    view: ViewCuller,
}

impl StageCuller {
    /// The stages with `settings`, called `name` in tables.
    pub fn new(name: impl Into<String>, settings: ViewSettings) -> Self {
        Self { name: name.into(), settings, view: ViewCuller::default() }
    }

    /// The frustum stage alone.
    pub fn frustum_only() -> Self {
        let occlusion = OcclusionSettings { enabled: false, ..OcclusionSettings::default() };
        Self::new("frustum only", ViewSettings { occlusion, ..ViewSettings::default() })
    }

    /// The view's culling state.
    pub fn view(&self) -> &ViewCuller {
        &self.view
    }
}

impl Culler for StageCuller {
    fn name(&self) -> String {
        self.name.clone()
    }

    fn is_conservative(&self, viewport: (u32, u32)) -> bool {
        self.settings.occlusion.is_conservative_for(viewport) && !self.settings.detail.enabled()
    }

    fn cull(&mut self, scene: &CullScene, camera: &Camera) -> Culled<'_> {
        let frame = ViewFrame { moves: scene.moves, ..ViewFrame::new(ViewInput::of_camera(camera), self.settings) };
        let stats = *self.view.cull(scene.store(), &frame, |slot| scene.occluder_of(slot));
        let mut stages = vec![("frustum", self.view.frustum_visible())];
        if self.settings.occlusion.enabled {
            stages.push(("occlusion", self.view.visible()));
        }
        Culled { stages, stats }
    }
}
