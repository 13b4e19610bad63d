//! Levels of detail in a Bevy app (opt-in): a level for each entity the main camera keeps, chosen by Cullet's
//! selection ([`cullet::lod::LodSelection`]) over the plugin's store, and written as [`LodLevel`] where it
//! changed; an entity with [`LodMeshes`] gets its level's mesh, and one the budget drops leaves the main
//! camera's visible list.

use crate::convert;
use crate::cull::CulletView;
use crate::mirror::CulletStore;
use bevy_asset::Handle;
use bevy_camera::visibility::VisibleEntities;
use bevy_camera::{Camera, Projection};
use bevy_ecs::prelude::*;
use bevy_mesh::{Mesh, Mesh3d};
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

/// An entity's mesh at each level of its chain, finest first (as [`mesh_levels`] makes them): the plugin sets
/// the entity's [`Mesh3d`] to the level chosen (the coarsest given where the chain has more levels).
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct LodMeshes(pub Vec<Handle<Mesh>>);

/// A Bevy mesh's levels of detail: the chain for [`CulletLod::library`] and each level as a Bevy mesh.
#[cfg(feature = "lod")]
#[derive(Clone, Debug)]
pub struct MeshLevels {
    /// The levels as Cullet selects them (positions and error), finest first; give
    /// [`LodLibrary::from_chains`] this chain.
    pub chain: Vec<cullet::lod::LodLevel>,
    /// Each level as a Bevy mesh: the mesh itself, then copies of it (every vertex and attribute) with the
    /// level's triangles; add them to `Assets<Mesh>` for [`LodMeshes`].
    pub meshes: Vec<Mesh>,
}

/// Why [`mesh_levels`] cannot make a mesh's levels.
#[cfg(feature = "lod")]
#[derive(Debug, thiserror::Error)]
pub enum MeshLevelsError {
    /// The mesh's data lives only in the render world (its `RenderAssetUsages` lack `MAIN_WORLD`).
    #[error("the mesh's data is not in the main world (keep RenderAssetUsages::MAIN_WORLD to make levels)")]
    NotInMainWorld,
    /// Only triangle lists are simplified.
    #[error("the mesh is a {0:?}, not a triangle list")]
    NotTriangles(bevy_mesh::PrimitiveTopology),
    /// No `Mesh::ATTRIBUTE_POSITION` of three floats.
    #[error("the mesh has no positions of three floats")]
    NoPositions,
    /// The simplifier refused the mesh.
    #[error(transparent)]
    Lod(#[from] cullet::lod::LodError),
}

/// The levels of detail of `mesh` ([`cullet::lod::build_chain_keeping_vertices`]): each level keeps every vertex
/// of `mesh` with all of its attributes and draws fewer triangles, so a level looks like the mesh, seams
/// included, and its bounds are the mesh's. Level 0 is `mesh` itself.
///
/// # Errors
/// [`MeshLevelsError`] for a mesh whose data is not in the main world, that is not a triangle list, has no
/// positions, or that the simplifier refuses (indices past the vertices, positions not finite).
///
/// # Example
/// ```
/// use bevy_cullet::mesh_levels;
/// use bevy_mesh::Meshable;
/// use cullet::lod::ChainSettings;
///
/// let sphere = bevy_shape::Sphere::new(1.0).mesh().ico(5).unwrap();
/// let levels = mesh_levels(&sphere, &ChainSettings::default()).unwrap();
/// assert!(levels.meshes.len() > 1 && levels.meshes.len() == levels.chain.len());
/// assert!(levels.chain[1].mesh.triangle_count() < levels.chain[0].mesh.triangle_count());
/// ```
#[cfg(feature = "lod")]
pub fn mesh_levels(mesh: &Mesh, settings: &cullet::lod::ChainSettings) -> Result<MeshLevels, MeshLevelsError> {
    use bevy_mesh::{Indices, PrimitiveTopology, VertexAttributeValues};
    if mesh.primitive_topology() != PrimitiveTopology::TriangleList {
        return Err(MeshLevelsError::NotTriangles(mesh.primitive_topology()));
    }
    let positions = match mesh.try_attribute_option(Mesh::ATTRIBUTE_POSITION) {
        Err(_) => return Err(MeshLevelsError::NotInMainWorld),
        Ok(Some(VertexAttributeValues::Float32x3(positions))) => positions,
        Ok(_) => return Err(MeshLevelsError::NoPositions),
    };
    let indices = match mesh.try_indices_option() {
        Err(_) => return Err(MeshLevelsError::NotInMainWorld),
        Ok(Some(indices)) => indices.iter().map(|i| i as u32).collect(),
        Ok(None) => (0..positions.len() as u32).collect(),
    };
    let full =
        cullet::mesh::Mesh { positions: positions.iter().map(|&p| glam::Vec3::from_array(p)).collect(), indices };
    let chain = cullet::lod::build_chain_keeping_vertices(&full, settings)?;
    let meshes = chain
        .iter()
        .enumerate()
        .map(|(l, level)| match l {
            0 => mesh.clone(),
            _ => mesh.clone().with_inserted_indices(Indices::U32(level.mesh.indices.clone())),
        })
        .collect();
    Ok(MeshLevels { chain, meshes })
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
    mut cameras: Query<(&Camera, &GlobalTransform, &Projection, &CulletView, &mut VisibleEntities)>,
    objects: Query<(Option<&MeshRef>, &GlobalTransform)>,
    mut state: Local<LodState>,
    mut stats: ResMut<CulletLodStats>,
) {
    let Some(lod) = lod else { return };
    let main = cameras
        .iter_mut()
        .filter(|(camera, ..)| camera.is_active)
        .filter_map(|(camera, transform, projection, view, visible)| {
            convert::view_of(transform, projection).camera.map(|culled| (camera.order, culled, view, visible))
        })
        .min_by_key(|(order, ..)| *order);
    let Some((_, camera, view, mut visible)) = main else { return };
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
    // What the budget dropped leaves the camera's lists (sorted by entity, as the cull wrote them).
    let selection = &state.selection;
    if selection.stats().dropped > 0 {
        let mut dropped: Vec<Entity> = selection.dropped().iter().map(|slot| store.entities()[slot]).collect();
        dropped.sort_unstable();
        for list in visible.entities.values_mut() {
            list.retain(|entity| dropped.binary_search(entity).is_err());
        }
    }
    // Written where the level changed, and where the budget dropped or restored an entity.
    for &slot in selection.changed() {
        let slot = slot as usize;
        let level = LodLevel { level: selection.level(slot).unwrap_or(0), dropped: selection.dropped().contains(slot) };
        commands.entity(store.entities()[slot]).try_insert(level);
    }
}

/// Sets each entity with [`LodMeshes`] to the mesh of the level the selection chose, where it changed.
pub(crate) fn swap_meshes(mut entities: Query<(&LodLevel, &LodMeshes, &mut Mesh3d), Changed<LodLevel>>) {
    for (level, meshes, mut mesh) in &mut entities {
        let chosen = meshes.0.get(level.level as usize).or(meshes.0.last());
        if let Some(chosen) = chosen.filter(|&chosen| *chosen != mesh.0) {
            mesh.0 = chosen.clone();
        }
    }
}
