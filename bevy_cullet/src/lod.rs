//! Levels of detail in a Bevy app (opt-in): a level for each entity the main camera keeps, chosen by Cullet's
//! selection ([`cullet::lod::LodSelection`]) over the plugin's store, and written as [`LodLevel`] where it
//! changed, for the app to swap the entity's mesh.

use crate::convert;
use crate::cull::CulletView;
use crate::mirror::CulletStore;
use bevy_camera::{Camera, Projection};
use bevy_ecs::prelude::*;
use bevy_transform::components::GlobalTransform;
use cullet::MeshRef;
use cullet::bounds::largest_axis_scale;
use cullet::lod::{LodLibrary, LodSelection, LodSettings, LodStats};

/// Switches levels of detail on: insert it as a resource. Entities with a [`MeshRef`] (the chain of their mesh
/// in `library`) and bounds the plugin mirrors get a [`LodLevel`].
#[derive(Resource, Clone, Debug)]
pub struct CulletLod {
    /// Every mesh's levels (`LodLibrary::build` with Cullet's feature `lod`, or `LodLibrary::from_chains` for
    /// levels of your own): level `l` of chain `c` is `library.meshes()[library.mesh_of(c, l)]`.
    pub library: LodLibrary,
    /// The error threshold in pixels, the hysteresis and the triangle budget.
    pub settings: LodSettings,
}

/// The level of detail an entity draws, written by the plugin when it changes (an entity the main camera has
/// not kept yet has none).
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct LodLevel {
    /// 0 is full detail.
    pub level: u8,
    /// The triangle budget dropped the entity this frame: draw nothing.
    pub dropped: bool,
}

/// What the last selection chose, for the app's statistics.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct CulletLodStats(pub LodStats);

/// The selection kept between frames.
#[derive(Default)]
pub(crate) struct LodState {
    selection: LodSelection,
    /// The store layout the per-slot tables were filled for.
    layout: Option<u64>,
}

/// Chooses the levels for the active perspective camera of lowest order, then writes [`LodLevel`] where an
/// entity's level or dropped state changed.
#[allow(clippy::type_complexity)]
pub(crate) fn choose_levels(
    mut commands: Commands,
    lod: Option<Res<CulletLod>>,
    cullet: Res<CulletStore>,
    cameras: Query<(&Camera, &GlobalTransform, &Projection, &CulletView)>,
    objects: Query<(Option<&MeshRef>, &GlobalTransform)>,
    mut state: Local<LodState>,
    mut stats: ResMut<CulletLodStats>,
) {
    let Some(lod) = lod else { return };
    let main = cameras
        .iter()
        .filter(|(camera, ..)| camera.is_active)
        .filter_map(|(camera, transform, projection, view)| {
            convert::view_of(transform, projection).camera.map(|culled| (camera.order, culled, view))
        })
        .min_by_key(|(order, ..)| *order);
    let Some((_, camera, view)) = main else { return };
    let store = &cullet.store;
    let state = &mut *state;
    // The per-slot tables: every slot after the layout changed, else those whose bounds moved.
    let slots: Vec<usize> = match (&cullet.moves, state.layout == Some(store.layout_generation())) {
        (Some(moves), true) => moves.slots.iter().map(|&slot| slot as usize).collect(),
        _ => (0..store.len()).collect(),
    };
    for slot in slots {
        let (mesh, scale) = objects.get(store.entities()[slot]).map_or((None, 1.0), |(mesh, transform)| {
            (mesh.map(|m| m.0), largest_axis_scale(&convert::affine(transform)))
        });
        state.selection.set_object(slot, mesh, scale);
    }
    state.layout = Some(store.layout_generation());
    state.selection.select(&lod.library, store, &camera, view.kept(), &lod.settings);
    stats.0 = state.selection.stats();
    // Written where the level changed, and where the budget dropped or restored an entity.
    let selection = &state.selection;
    for &slot in selection.changed() {
        let slot = slot as usize;
        let level = LodLevel { level: selection.level(slot).unwrap_or(0), dropped: selection.dropped().contains(slot) };
        commands.entity(store.entities()[slot]).try_insert(level);
    }
}
