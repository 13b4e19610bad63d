//! Stage 3's input in a Bevy app: occluders from meshes.
//!
//! - An entity whose `Mesh3d` is an occluder, not something to draw ([`OccluderMesh`]; a glTF node named
//!   `*_occluder`, or whose `extras` say `"occluder": true`, through Bevy's loader), gets a
//!   [`cullet::Occluder`] of that mesh's triangles and is drawn no more.
//! - With [`crate::CulletSettings::auto_occluders`], large drawn meshes without an occluder get one from their
//!   own largest triangles, as the sample game's `--auto-occluders` gives them
//!   ([`cullet::scene::auto_occluders`]).

use crate::{CulletSettings, CulletStore};
use bevy_asset::{AssetId, Assets};
use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::VisibilityClass;
use bevy_ecs::hierarchy::{ChildOf, Children};
use bevy_ecs::name::Name;
use bevy_ecs::prelude::*;
use bevy_ecs::reflect::{AppTypeRegistry, ReflectComponent};
use bevy_mesh::{Mesh, Mesh3d, PrimitiveTopology, VertexAttributeValues};
use bevy_reflect::{Reflect, ReflectRef};
use cullet::scene::auto_occluders::occluder_from_mesh;
use cullet::{LocalBounds, Occluder};
use std::collections::HashMap;

/// Suffix of a `Name` that marks an occluder, as in Cullet's own glTF import: Bevy's glTF loader names each
/// node's entity after the node.
pub const OCCLUDER_SUFFIX: &str = "_occluder";

/// The short type path of the component Bevy's glTF loader puts a node's or a primitive's `extras` in
/// (`bevy_gltf::GltfExtras`, a JSON string in its `value` field). The plugin finds it in the app's type
/// registry rather than depending on `bevy_gltf` (and through it on Bevy's renderer).
pub const GLTF_EXTRAS: &str = "GltfExtras";

/// Marks an entity whose `Mesh3d` is an occluder and is not drawn.
///
/// Once the mesh asset is loaded, the plugin gives the entity a [`cullet::Occluder`] of the mesh's triangles
/// (in the entity's local space) and an `Aabb` around them, and removes its `Mesh3d` and `VisibilityClass`, so
/// Bevy's renderer no longer draws it; the marker is then removed. The plugin adds it to every `Mesh3d` entity
/// named `*_occluder`, and to the `Mesh3d` children of such an entity (a glTF node's primitives), and to every
/// new `Mesh3d` entity whose glTF extras, or its node's, say `"occluder": true` ([`GLTF_EXTRAS`]).
///
/// The mesh must be a triangle list with its data kept in the main world (`RenderAssetUsages::MAIN_WORLD`, the
/// default of Bevy's glTF loader); otherwise it is drawn as usual and a warning says why.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct OccluderMesh;

/// Marks `Mesh3d` entities named `*_occluder`, and their `Mesh3d` children, with [`OccluderMesh`].
pub(crate) fn mark_named_occluders(
    mut commands: Commands,
    named: Query<(Entity, &Name, Option<&Children>), Added<Name>>,
    meshes: Query<(), (With<Mesh3d>, Without<OccluderMesh>)>,
) {
    for (entity, name, children) in &named {
        if !name.as_str().ends_with(OCCLUDER_SUFFIX) {
            continue;
        }
        for mesh_entity in std::iter::once(entity).chain(children.into_iter().flatten().copied()) {
            if meshes.contains(mesh_entity) {
                commands.entity(mesh_entity).insert(OccluderMesh);
            }
        }
    }
}

/// New `Mesh3d` entities not yet marked, with the node they belong to, if any.
type NewMeshes<'w, 's> = Query<'w, 's, (Entity, Option<&'static ChildOf>), (Added<Mesh3d>, Without<OccluderMesh>)>;

/// Marks new `Mesh3d` entities with [`OccluderMesh`] where their glTF extras ([`GLTF_EXTRAS`]), or those of
/// the node they are a primitive of (their parent), are a JSON object with `"occluder": true`. Does nothing in
/// an app without that component type registered.
pub(crate) fn mark_extras_occluders(
    mut commands: Commands,
    registry: Option<Res<AppTypeRegistry>>,
    added: NewMeshes,
    entities: Query<EntityRef>,
) {
    let Some(registry) = registry.filter(|_| !added.is_empty()) else { return };
    let registry = registry.read();
    let Some(extras) = registry.get_with_short_type_path(GLTF_EXTRAS).and_then(|r| r.data::<ReflectComponent>()) else {
        return;
    };
    let marked = |entity: Entity| {
        let reflected = entities.get(entity).ok().and_then(|entity| extras.reflect(entity));
        reflected.is_some_and(extras_mark_occluder)
    };
    for (entity, node) in &added {
        if marked(entity) || node.is_some_and(|node| marked(node.parent())) {
            commands.entity(entity).insert(OccluderMesh);
        }
    }
}

/// Whether reflected glTF extras (a struct whose `value` is a JSON string) hold `"occluder": true`.
fn extras_mark_occluder(extras: &dyn Reflect) -> bool {
    let ReflectRef::Struct(extras) = extras.reflect_ref() else { return false };
    let json = extras.field("value").and_then(|value| value.try_downcast_ref::<String>());
    let parsed = json.and_then(|json| serde_json::from_str::<serde_json::Value>(json).ok());
    parsed.is_some_and(|value| value.get("occluder") == Some(&serde_json::Value::Bool(true)))
}

/// Turns [`OccluderMesh`] entities whose mesh is loaded into occluders that are not drawn.
pub(crate) fn build_occluder_meshes(
    mut commands: Commands,
    pending: Query<(Entity, &Mesh3d), With<OccluderMesh>>,
    meshes: Res<Assets<Mesh>>,
) {
    for (entity, mesh) in &pending {
        let Some(mesh) = meshes.get(&mesh.0) else { continue }; // Not loaded yet.
        let mut entity = commands.entity(entity);
        entity.remove::<OccluderMesh>();
        match triangle_soup(mesh) {
            Ok(triangles) => {
                // `triangle_soup` returns at least one triangle of finite vertices.
                let bounds = LocalBounds::from_points(&triangles).expect("finite, non-empty vertices");
                let v = |v: glam::Vec3| bevy_math::Vec3A::from_array(v.to_array());
                let aabb = Aabb { center: v(bounds.center), half_extents: v(bounds.half_extent) };
                entity.insert((Occluder::new(triangles), aabb)).remove::<(Mesh3d, VisibilityClass)>();
            }
            Err(why) => tracing::warn!("{} stays a drawn mesh, not an occluder: {why}", entity.id()),
        }
    }
}

/// The triangles of a triangle-list mesh, three vertices each, in its local space.
fn triangle_soup(mesh: &Mesh) -> Result<Vec<glam::Vec3>, &'static str> {
    if mesh.primitive_topology() != PrimitiveTopology::TriangleList {
        return Err("its mesh is not a triangle list");
    }
    let Ok(Some(VertexAttributeValues::Float32x3(positions))) = mesh.try_attribute_option(Mesh::ATTRIBUTE_POSITION)
    else {
        return Err("its mesh has no f32x3 positions in the main world (RenderAssetUsages::MAIN_WORLD)");
    };
    let vertex = |index: usize| positions.get(index).map(|&p| glam::Vec3::from_array(p));
    let triangles: Option<Vec<glam::Vec3>> = match mesh.try_indices_option() {
        Ok(Some(indices)) => indices.iter().map(vertex).collect(),
        Ok(None) => Some(positions.iter().map(|&p| glam::Vec3::from_array(p)).collect()),
        Err(_) => return Err("its mesh's indices are not in the main world"),
    };
    let mut triangles = triangles.ok_or("its mesh has an index past its vertices")?;
    triangles.truncate(triangles.len() / 3 * 3);
    if triangles.is_empty() || !triangles.iter().all(|v| v.is_finite()) {
        return Err("its mesh has no triangle, or a vertex that is not finite");
    }
    Ok(triangles)
}

/// Marks a `Mesh3d` entity the automatic occluders looked at: each is judged once, when first mirrored with
/// its mesh loaded.
#[derive(Component)]
pub(crate) struct AutoOccluderJudged;

/// Gives large `Mesh3d` entities without an occluder one from their mesh's largest triangles, where
/// [`CulletSettings::auto_occluders`] is on: an entity qualifies when its world bounding-sphere radius is at
/// least `min_radius_fraction` of the radius of everything mirrored so far. Entities sharing a mesh share its
/// occluder.
#[allow(clippy::type_complexity)]
pub(crate) fn add_auto_occluders(
    mut commands: Commands,
    settings: Res<CulletSettings>,
    cullet: Res<CulletStore>,
    candidates: Query<(Entity, &Mesh3d), (Without<Occluder>, Without<OccluderMesh>, Without<AutoOccluderJudged>)>,
    meshes: Res<Assets<Mesh>>,
    mut by_mesh: Local<HashMap<AssetId<Mesh>, Option<Occluder>>>,
) {
    let Some(auto) = settings.auto_occluders else { return };
    let store = &cullet.store;
    let Some(scene_radius) =
        store.supergroups().iter().copied().reduce(|a, b| a.union(&b)).map(|all| (all.max - all.min).length() * 0.5)
    else {
        return;
    };
    let min_radius = scene_radius * auto.min_radius_fraction;
    for (entity, mesh) in &candidates {
        let (Some(slot), Some(loaded)) = (store.slot_of(entity), meshes.get(&mesh.0)) else { continue };
        commands.entity(entity).insert(AutoOccluderJudged);
        let radius = store.get(slot).map_or(0.0, |bounds| bounds.half_extent.length());
        if radius.partial_cmp(&min_radius).is_none_or(std::cmp::Ordering::is_lt) {
            continue;
        }
        let occluder = by_mesh.entry(mesh.id()).or_insert_with(|| {
            let positions = triangle_soup(loaded).ok()?;
            let indices = (0..positions.len() as u32).collect();
            occluder_from_mesh(&cullet::mesh::Mesh { positions, indices }, &auto)
        });
        if let Some(occluder) = occluder {
            commands.entity(entity).insert(occluder.clone());
        }
    }
}
