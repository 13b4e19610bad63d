//! Light views in a Bevy app: for each camera, the shadow cascades of every shadow-mapped directional light,
//! and the cube faces of the point lights and the cone of the spot lights that light its view, are culled in
//! the camera's own frustum pass ([`cullet::culler::ViewCuller::cull_frustum`]), keeping only the casters
//! whose shadows can fall inside the camera's frustum ([`cullet::frustum::View::shadow_casters`]); then each
//! is occlusion culled from its light ([`LightOcclusion`]). [`write_light_views`] then writes them to Bevy's
//! per-light visible entities, which Bevy's shadow passes draw.

use crate::convert;
use crate::cull::CulletView;
use crate::mirror::CulletStore;
use bevy_camera::primitives::{Aabb, CUBE_MAP_FACES, Frustum as BevyFrustum, Sphere};
use bevy_camera::visibility::{
    CascadesVisibleEntities, CubemapVisibleEntities, InheritedVisibility, NoCpuCulling, NoFrustumCulling, RenderLayers,
    SetViewVisibility, ViewVisibility, VisibilityRange, VisibleEntityRanges, VisibleMeshEntities,
};
use bevy_camera::{Camera, RenderTarget, ShadowLodOrigin};
use bevy_ecs::entity::EntityHashMap;
use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemParam;
use bevy_light::{Cascades, DirectionalLight, NotShadowCaster, PointLight, SpotLight, spot_light_world_from_view};
use bevy_mesh::Mesh3d;
use bevy_transform::components::{GlobalTransform, Transform};
use cullet::bounds::BoundsStore;
use cullet::camera::DepthConvention;
use cullet::culler::{LightOcclusion, LightViewVisible};
use cullet::frustum::{Frustum, Light, LightView, View, ViewError};
use cullet::visible::{VisibleSet, set_slots};
use glam::{DMat4, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Which of a light's shadow maps a light view draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(crate) enum ShadowMap {
    /// Cascade `n` of a directional light, for the camera whose view it is.
    Cascade(usize),
    /// Face `n` of a point light's cube map, in Bevy's `CUBE_MAP_FACES` order.
    Face(usize),
    /// A spot light's map.
    Spot,
}

/// One shadow map of a light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct LightMap {
    /// The light.
    pub(crate) light: Entity,
    /// Which of its maps.
    pub(crate) map: ShadowMap,
    /// A lamp's position and range: what lies wholly beyond it is not lit, so casts no shadow that matters.
    pub(crate) reach: Option<(Vec3, f32)>,
}

/// One camera's light views of the frame and what it keeps of them from frame to frame.
#[derive(Default, Debug)]
pub(crate) struct CameraLights {
    /// Each light view's light and shadow map, in the order of `views` (the views that could be built).
    pub(crate) maps: Vec<LightMap>,
    /// Each light view's casters (store slots).
    pub(crate) views: Vec<LightViewVisible>,
    /// Shadow maps whose view could not be built (a degenerate light or cascade): they keep every caster.
    pub(crate) unculled: Vec<LightMap>,
    /// The light views' occlusion, view by view.
    pub(crate) occlusion: LightOcclusion,
    /// Visible sets of views gone, reused for the next frame's.
    pub(crate) spare: Vec<VisibleSet>,
}

/// A directional light as the culling reads it.
type DirectionalItem<'a> = (Entity, &'a DirectionalLight, &'a GlobalTransform, &'a Cascades, &'a InheritedVisibility);
/// A point or spot light as the culling reads it.
type LampItem<'a, L> = (Entity, &'a L, &'a GlobalTransform, &'a InheritedVisibility, Option<&'a RenderLayers>);

/// The lights a camera's light views are built from.
#[derive(SystemParam)]
pub(crate) struct LightSources<'w, 's> {
    directional: Query<'w, 's, DirectionalItem<'static>>,
    point: Query<'w, 's, LampItem<'static, PointLight>>,
    spot: Query<'w, 's, LampItem<'static, SpotLight>>,
}

impl LightSources<'_, '_> {
    /// The light views of `camera` (entity and its Cullet position), whose frustum is `receivers` and layers
    /// `camera_layers`, with `bevy_frustum` Bevy's frustum of it: every cascade Bevy built for it of each
    /// visible directional light with shadows, and each face of each point light and the map of each spot light
    /// with shadows whose range meets the camera's frustum, as Bevy's own check chooses the lights.
    ///
    /// Each view keeps the casters whose shadows can fall inside `receivers` (where the camera has no frustum,
    /// inside the light's own view). A map whose view cannot be built is listed in `unculled`.
    pub(crate) fn views_of(
        &self,
        camera: Entity,
        origin: Vec3,
        receivers: Option<&Frustum>,
        camera_layers: &RenderLayers,
        bevy_frustum: &BevyFrustum,
        unculled: &mut Vec<LightMap>,
    ) -> Vec<(LightMap, LightView)> {
        unculled.clear();
        let mut views = Vec::new();
        let mut add = |map: LightMap, built: Result<LightView, ViewError>| match built {
            Ok(view) => views.push((map, view)),
            Err(error) => {
                tracing::warn!("{:?} of light {} keeps every caster: {error}", map.map, map.light);
                unculled.push(map);
            }
        };
        for (entity, light, transform, cascades, inherited) in &self.directional {
            if !(light.shadow_maps_enabled && inherited.get()) {
                continue;
            }
            let direction = convert::vec3(transform.forward().into());
            for (index, cascade) in cascades.cascades.get(&camera).into_iter().flatten().enumerate() {
                let clip_from_world = DMat4::from_cols_array(&cascade.clip_from_world.to_cols_array().map(f64::from));
                let built = cascade_view(origin, clip_from_world, direction, receivers);
                add(LightMap { light: entity, map: ShadowMap::Cascade(index), reach: None }, built);
            }
        }
        let lit = |transform: &GlobalTransform,
                   range: f32,
                   inherited: &InheritedVisibility,
                   layers: Option<&RenderLayers>| {
            let sphere = Sphere { center: transform.translation_vec3a(), radius: range };
            inherited.get()
                && camera_layers.intersects(layers.unwrap_or_default())
                && bevy_frustum.intersects_sphere(&sphere, false)
        };
        for (entity, light, transform, inherited, layers) in &self.point {
            if !(light.shadow_maps_enabled && lit(transform, light.range, inherited, layers)) {
                continue;
            }
            let position = convert::vec3(transform.translation());
            let reach = Some((position, light.range));
            for (index, face) in CUBE_MAP_FACES.iter().enumerate() {
                let rotation = Transform::IDENTITY.looking_at(face.target, face.up).rotation;
                let (forward, up) = (rotation * bevy_math::Vec3::NEG_Z, rotation * bevy_math::Vec3::Y);
                let face = lamp_camera(position, forward, up, std::f32::consts::FRAC_PI_2, light.shadow_map_near_z);
                let map = LightMap { light: entity, map: ShadowMap::Face(index), reach };
                add(map, lamp_view(face, light.range, receivers));
            }
        }
        for (entity, light, transform, inherited, layers) in &self.spot {
            if !(light.shadow_maps_enabled && lit(transform, light.range, inherited, layers)) {
                continue;
            }
            let position = convert::vec3(transform.translation());
            let basis = spot_light_world_from_view(transform).matrix3;
            let (forward, up) = (-basis.z_axis, basis.y_axis);
            let cone =
                lamp_camera(position, forward.into(), up.into(), 2.0 * light.outer_angle, light.shadow_map_near_z);
            let map = LightMap { light: entity, map: ShadowMap::Spot, reach: Some((position, light.range)) };
            add(map, lamp_view(cone, light.range, receivers));
        }
        views
    }
}

/// Drops from `view` the casters whose box lies wholly beyond a lamp's `reach` (position and range), as Bevy's
/// own check does with its oriented boxes (a world box holds its oriented box, so this keeps at least what
/// Bevy keeps); a little slack keeps the boxes that only touch the sphere.
pub(crate) fn keep_within_reach(store: &BoundsStore, view: &mut LightViewVisible, (center, range): (Vec3, f32)) {
    let limit = range * (1.0 + 1e-5) + 1e-5;
    let beyond: Vec<usize> = view
        .visible
        .iter()
        .filter(|&slot| {
            let bounds = store.get(slot).expect("a kept slot is stored");
            let outside = ((bounds.center - center).abs() - bounds.half_extent).max(Vec3::ZERO);
            outside.length_squared() > limit * limit
        })
        .collect();
    for &slot in &beyond {
        view.visible.set(slot, false);
    }
    view.kept -= beyond.len();
}

/// The camera of a lamp's shadow map at `position` looking along `forward`, square, `fov` radians wide, its
/// near plane at `near` (far set by [`lamp_view`]), reversed depth as Bevy draws it.
fn lamp_camera(position: Vec3, forward: bevy_math::Vec3, up: bevy_math::Vec3, fov: f32, near: f32) -> cullet::Camera {
    cullet::Camera {
        position,
        forward: convert::vec3(forward),
        up: convert::vec3(up),
        fov_y: fov,
        aspect: 1.0,
        near,
        far: None,
        depth: DepthConvention::Reversed,
    }
}

/// The light view of a lamp's map drawn by `camera`, cut at the light's `range` (nothing beyond it is lit, so
/// nothing beyond it casts a shadow that matters), keeping the casters that shadow `receivers`.
fn lamp_view(mut camera: cullet::Camera, range: f32, receivers: Option<&Frustum>) -> Result<LightView, ViewError> {
    camera.far = Some(range);
    let frustum = camera.frustum()?;
    let light = Light::Point { position: camera.position };
    Ok(LightView {
        view: View::shadow_casters(frustum, light, receivers.unwrap_or(&frustum))?,
        clip_from_relative: camera.clip_from_relative_f64(),
        origin: camera.position,
        depth: camera.depth,
        near: Some(camera.near),
    })
}

/// The light view of a directional light's cascade drawn with `clip_from_world` (Bevy's orthographic box,
/// reversed depth, whose near plane Bevy clamps rather than clips), travelling along `direction`, relative to
/// `origin`, keeping the casters that shadow `receivers`.
fn cascade_view(
    origin: Vec3,
    clip_from_world: DMat4,
    direction: Vec3,
    receivers: Option<&Frustum>,
) -> Result<LightView, ViewError> {
    let clip_from_relative = clip_from_world * DMat4::from_translation(origin.as_dvec3());
    let frustum = Frustum::from_clip_from_relative_f64(origin, clip_from_relative, DepthConvention::Reversed)?;
    let light = Light::Directional { direction };
    Ok(LightView {
        view: View::shadow_casters(frustum, light, receivers.unwrap_or(&frustum))?,
        clip_from_relative,
        origin,
        depth: DepthConvention::Reversed,
        near: None,
    })
}

/// Counts and time of the last write of the lights' lists ([`crate::CulletSystems::Lights`]).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct CulletLightStats {
    /// Shadow maps written (cascades per camera, cube faces, spot maps).
    pub maps: usize,
    /// Casters listed, summed over the maps.
    pub casters: usize,
    /// Time spent writing the maps' lists and the casters' `ViewVisibility`.
    pub write_time: Duration,
}

/// What a shadow caster's entry in a light's lists reads: Bevy's rules for shadow casters.
type CasterItem<'a> = (&'a InheritedVisibility, Option<&'a RenderLayers>, Has<VisibilityRange>);
/// Shadow casters as Bevy's light checks find them.
type CasterFilter = (With<Mesh3d>, Without<NotShadowCaster>, Without<DirectionalLight>, Without<NoCpuCulling>);
/// Shadow casters the plugin does not mirror: in every map of a light, as in Bevy.
type OtherCasterFilter = (CasterFilter, Or<(Without<Aabb>, With<NoFrustumCulling>)>);

/// A shadow caster as the classification walks its table.
type CasterRow<'a> = (Entity, &'a InheritedVisibility, Has<RenderLayers>, Has<VisibilityRange>);

/// The store's slots by what Bevy's rules for shadow casters say of them, before any light: `plain` for a
/// visible caster in the default layer only and without a visibility range (a caster of every light in that
/// layer), `special` for a visible caster with layers or a range of its own (each light checks it).
struct CasterClasses {
    plain: VisibleSet,
    special: VisibleSet,
}

/// Rows of a table one task of the classification walks.
const CLASSIFY_ROWS: usize = 4096;

/// Classifies every stored entity ([`CasterClasses`]), walking the casters' tables in parallel; an entity
/// that is not a caster, or not visible, is in neither set.
fn classify_casters(store: &BoundsStore, rows: &Query<CasterRow, CasterFilter>) -> CasterClasses {
    let words = store.len().div_ceil(64);
    let marks: [Vec<AtomicU64>; 2] = std::array::from_fn(|_| (0..words).map(|_| AtomicU64::new(0)).collect());
    let mark = |class: usize, slot: usize| {
        marks[class][slot / 64].fetch_or(1 << (slot % 64), Ordering::Relaxed);
    };
    match rows.contiguous_iter() {
        Ok(tables) => {
            let mut ranges = Vec::new();
            for (entities, inherited, has_layers, has_range) in tables {
                let class = usize::from(has_layers || has_range);
                for first in (0..entities.len()).step_by(CLASSIFY_ROWS) {
                    let end = (first + CLASSIFY_ROWS).min(entities.len());
                    ranges.push((&entities[first..end], &inherited[first..end], class));
                }
            }
            ranges.into_par_iter().for_each(|(entities, inherited, class)| {
                for (&entity, inherited) in entities.iter().zip(inherited) {
                    if let Some(slot) = store.slot_of(entity).filter(|_| inherited.get()) {
                        mark(class, slot);
                    }
                }
            });
        }
        // Not stored in tables (not the case of Bevy's components): one walk on this thread.
        Err(_) => {
            for (entity, inherited, has_layers, has_range) in rows {
                if let Some(slot) = store.slot_of(entity).filter(|_| inherited.get()) {
                    mark(usize::from(has_layers || has_range), slot);
                }
            }
        }
    }
    let [plain, special] = marks.map(|words| {
        let mut set = VisibleSet::new(store.len());
        set.words_mut().iter_mut().zip(words).for_each(|(word, mark)| *word = mark.into_inner());
        set
    });
    CasterClasses { plain, special }
}

/// How the store's slots run against the order of their entities (Bevy's `Entity` order, which Bevy sorts its
/// lists in), kept while the store's layout stays.
#[derive(Default)]
pub(crate) struct EntityOrder {
    layout: Option<u64>,
    order: SlotOrder,
}

/// The order of a store's slots by their entities.
#[derive(Default)]
enum SlotOrder {
    /// Increasing.
    #[default]
    Slots,
    /// Decreasing: as the mirroring leaves entities spawned together (Bevy orders entities of increasing
    /// index the other way).
    Reversed,
    /// Neither: the slots in the order of their entities.
    Ranked(Vec<u32>),
}

impl EntityOrder {
    /// The order of the slots of `store` by their entities.
    fn of(&mut self, store: &BoundsStore) -> &SlotOrder {
        if self.layout != Some(store.layout_generation()) {
            self.layout = Some(store.layout_generation());
            let entities = store.entities();
            self.order = if entities.is_sorted() {
                SlotOrder::Slots
            } else if entities.is_sorted_by(|a, b| a >= b) {
                SlotOrder::Reversed
            } else {
                let mut slots: Vec<u32> = (0..store.len() as u32).collect();
                slots.par_sort_unstable_by_key(|&slot| entities[slot as usize]);
                SlotOrder::Ranked(slots)
            };
        }
        &self.order
    }
}

/// Slots of a light view's list gathered by one task, in entity order.
const ORDER_RUN: usize = 8192;

/// Words of a light view's casters in one task of the write: a rayon task costs microseconds to hand out here.
const WRITE_WORDS: usize = 64;

/// One shadow map's casters gathered over the cameras: the union of their store slots, or every caster.
enum Gathered {
    Slots(VisibleSet),
    Every,
}

/// The lights whose lists the write fills.
#[derive(SystemParam)]
pub(crate) struct LightLists<'w, 's> {
    directional: Query<
        'w,
        's,
        (Entity, &'static mut CascadesVisibleEntities, Option<&'static RenderLayers>),
        With<DirectionalLight>,
    >,
    point:
        Query<'w, 's, (Entity, &'static mut CubemapVisibleEntities, Option<&'static RenderLayers>), With<PointLight>>,
    spot: Query<'w, 's, (Entity, &'static mut VisibleMeshEntities, Option<&'static RenderLayers>), With<SpotLight>>,
}

/// Writes every light's shadow casters from the cameras' light views: a directional light's
/// `CascadesVisibleEntities` per camera and cascade, a point light's `CubemapVisibleEntities` and a spot
/// light's `VisibleMeshEntities` (the union over the cameras that see its light), each sorted, after Bevy's
/// rules (`InheritedVisibility`, the light's `RenderLayers`, `VisibilityRange` from the camera or the shadow
/// LOD origin, `NotShadowCaster`); and makes each listed caster visible (`ViewVisibility`), so that Bevy
/// extracts it for its shadow pass. A light no camera culled this frame lists nothing.
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
pub(crate) fn write_light_views(
    cullet: Res<CulletStore>,
    cameras: Query<(Entity, &Camera, &CulletView, Option<&RenderLayers>)>,
    mut lists: LightLists,
    casters: Query<CasterItem, CasterFilter>,
    caster_rows: Query<CasterRow, CasterFilter>,
    others: Query<(Entity, CasterItem), OtherCasterFilter>,
    mut visibility: Query<&mut ViewVisibility>,
    ranges: Option<Res<VisibleEntityRanges>>,
    lod_origins: Query<Entity, With<ShadowLodOrigin>>,
    targets: Query<(Entity, &RenderTarget), With<Camera>>,
    mut stats: ResMut<CulletLightStats>,
    mut entity_order: Local<EntityOrder>,
) {
    let start = Instant::now();
    let store = &cullet.store;
    let active: Vec<(Entity, &CulletView)> =
        cameras.iter().filter(|(_, camera, ..)| camera.is_active).map(|(entity, _, view, _)| (entity, view)).collect();
    // Each map's casters: a cascade per camera; a lamp's maps as the union over the cameras.
    let mut cascades: EntityHashMap<Vec<(Entity, usize, Gathered)>> = EntityHashMap::default();
    let mut lamps: EntityHashMap<Vec<(ShadowMap, Gathered)>> = EntityHashMap::default();
    for &(camera, view) in &active {
        let lights = view.lights();
        let culled = lights.maps.iter().zip(&lights.views).map(|(map, view)| (map, Some(&view.visible)));
        for (&LightMap { light, map, .. }, visible) in culled.chain(lights.unculled.iter().map(|map| (map, None))) {
            let gathered = || visible.map_or(Gathered::Every, |set| Gathered::Slots(set.clone()));
            match map {
                ShadowMap::Cascade(index) => cascades.entry(light).or_default().push((camera, index, gathered())),
                ShadowMap::Face(_) | ShadowMap::Spot => {
                    let maps = lamps.entry(light).or_default();
                    match maps.iter_mut().find(|(listed, _)| *listed == map) {
                        None => maps.push((map, gathered())),
                        Some((_, Gathered::Every)) => {}
                        Some((_, gathered_so_far)) => match (gathered_so_far, visible) {
                            (Gathered::Slots(union), Some(set)) => {
                                union.words_mut().iter_mut().zip(set.words()).for_each(|(a, b)| *a |= b)
                            }
                            (slot, None) => *slot = Gathered::Every,
                            (Gathered::Every, _) => {}
                        },
                    }
                }
            }
        }
    }
    let lod_origin = shadow_lod_origin(&lod_origins, &targets);
    let classes = classify_casters(store, &caster_rows);
    let order = entity_order.of(store);
    let ranges = ranges.as_deref();
    let mut shown = VisibleSet::new(store.len());
    let mut unmirrored_shown = Vec::new();
    let (mut maps, mut listed) = (0, 0);
    // Lists one map's casters, in entity order, marking the stored ones in `shown`.
    let mut list = |gathered: &Gathered, layers: &RenderLayers, range_view: Option<Entity>, out: &mut Vec<Entity>| {
        let passes =
            |entity: Entity,
             (inherited, entity_layers, has_range): (&InheritedVisibility, Option<&RenderLayers>, bool)| {
                inherited.get()
                    && layers.intersects(entity_layers.unwrap_or_default())
                    && (!has_range
                        || ranges.is_none_or(|ranges| {
                            range_view.is_none_or(|view| ranges.entity_is_in_range_of_view(entity, view))
                        }))
            };
        out.clear();
        let every = VisibleSet::all(store.len());
        let set = match gathered {
            Gathered::Slots(set) => set,
            Gathered::Every => &every,
        };
        let entities = store.entities();
        // The casters by the rules that are the same for every light, a word at a time; the others one by one.
        let plain_lit = layers.intersects(&RenderLayers::default());
        let mut accepted = VisibleSet::new(store.len());
        (accepted.words_mut().par_chunks_mut(WRITE_WORDS))
            .zip(set.words().par_chunks(WRITE_WORDS))
            .zip(classes.plain.words().par_chunks(WRITE_WORDS))
            .zip(classes.special.words().par_chunks(WRITE_WORDS))
            .enumerate()
            .for_each(|(chunk, (((accepted, words), plain), special))| {
                let words = words.iter().zip(plain).zip(special);
                for (index, (out, ((&word, &plain), &special))) in accepted.iter_mut().zip(words).enumerate() {
                    *out = if plain_lit { word & plain } else { 0 };
                    for slot in set_slots(chunk * WRITE_WORDS + index, &[word & special]) {
                        let entity = entities[slot];
                        if casters.get(entity).is_ok_and(|item| passes(entity, item)) {
                            *out |= 1 << (slot % 64);
                        }
                    }
                }
            });
        shown.words_mut().iter_mut().zip(accepted.words()).for_each(|(word, accepted)| *word |= accepted);
        // Listed in entity order, as Bevy sorts its lists: in slot order, or its reverse, where the store holds
        // its entities so (as the mirroring leaves entities spawned together), else the slots walked in their
        // entities' order.
        let in_slot_order = || -> Vec<Vec<Entity>> {
            (accepted.words().par_chunks(ORDER_RUN / 64).enumerate())
                .map(|(chunk, words)| set_slots(chunk * ORDER_RUN / 64, words).map(|slot| entities[slot]).collect())
                .collect()
        };
        let runs = match order {
            SlotOrder::Slots => in_slot_order(),
            SlotOrder::Reversed => {
                let mut runs = in_slot_order();
                runs.reverse();
                runs.iter_mut().for_each(|run| run.reverse());
                runs
            }
            SlotOrder::Ranked(order) => (order.par_chunks(ORDER_RUN))
                .map(|run| {
                    let kept = run.iter().map(|&slot| slot as usize).filter(|&slot| accepted.contains(slot));
                    kept.map(|slot| entities[slot]).collect()
                })
                .collect(),
        };
        runs.into_iter().for_each(|run| out.extend(run));
        // Entities Cullet does not mirror, or whose bounds it refused, are in every map, as Bevy has them.
        let before = out.len();
        out.extend(others.iter().filter(|&(entity, item)| passes(entity, item)).map(|(entity, _)| entity));
        let refused = cullet.rejected.iter().filter(|&&entity| casters.get(entity).is_ok_and(|i| passes(entity, i)));
        out.extend(refused);
        unmirrored_shown.extend_from_slice(&out[before..]);
        if !out.is_sorted() {
            eprintln!("sorting {} ({:?})", out.len(), matches!(order, SlotOrder::Reversed));
            out.sort_unstable();
        }
        maps += 1;
        listed += out.len();
    };
    let mut out = Vec::new();
    for (light, mut visible, layers) in &mut lists.directional {
        let layers = layers.unwrap_or_default();
        let culled = cascades.remove(&light).unwrap_or_default();
        visible.entities.retain(|camera, _| culled.iter().any(|(culled, ..)| culled == camera));
        for (camera, lists) in visible.entities.iter_mut() {
            lists.iter_mut().for_each(|list| list.entities.clear());
            let count = culled.iter().filter(|(culled, ..)| culled == camera).count();
            lists.resize(count, VisibleMeshEntities::default());
        }
        for (camera, index, gathered) in &culled {
            let lists = visible.entities.entry(*camera).or_default();
            if lists.len() <= *index {
                lists.resize(index + 1, VisibleMeshEntities::default());
            }
            list(gathered, layers, Some(*camera), &mut out);
            lists[*index].entities.clone_from(&out);
        }
    }
    let lamp_maps = |light: Entity| lamps.get(&light).map(Vec::as_slice).unwrap_or_default();
    for (light, mut visible, layers) in &mut lists.point {
        let gathered = lamp_maps(light);
        for (face, target) in visible.iter_mut().enumerate() {
            target.entities.clear();
            if let Some((_, gathered)) = gathered.iter().find(|(map, _)| *map == ShadowMap::Face(face)) {
                list(gathered, layers.unwrap_or_default(), lod_origin, &mut out);
                target.entities.clone_from(&out);
            }
        }
    }
    for (light, mut visible, layers) in &mut lists.spot {
        visible.entities.clear();
        if let Some((_, gathered)) = lamp_maps(light).first() {
            list(gathered, layers.unwrap_or_default(), lod_origin, &mut out);
            visible.entities.clone_from(&out);
        }
    }
    // Every listed caster is drawn into a shadow map, so Bevy must extract it. A caster of the plain class that
    // a camera in the default layer keeps was made visible by that camera's write already.
    let default_layer = RenderLayers::default();
    for (_, camera, view, layers) in &cameras {
        let kept = view.kept();
        if camera.is_active && layers.unwrap_or_default().intersects(&default_layer) && kept.len() == store.len() {
            let shown_by_camera = kept.words().iter().zip(classes.plain.words());
            shown
                .words_mut()
                .iter_mut()
                .zip(shown_by_camera)
                .for_each(|(word, (kept, plain))| *word &= !(kept & plain));
        }
    }
    let entities = store.entities();
    shown.words().par_chunks(WRITE_WORDS).enumerate().for_each(|(chunk, words)| {
        let stored = set_slots(chunk * WRITE_WORDS, words).map(|slot| entities[slot]);
        // SAFETY: `iter_many_unsafe` may give two items the same entity's component: no chunk, and no two
        // chunks, hold an entity twice, as chunks hold distinct slots and the store holds each entity in one
        // slot at most. `visibility` is borrowed exclusively by this system until every chunk is done.
        let mut items = unsafe { visibility.iter_many_unsafe(stored) };
        while let Some(item) = items.fetch_next() {
            if let Ok(mut view_visibility) = item {
                view_visibility.set_visible();
            }
        }
    });
    let mut items = visibility.iter_many_mut(&unmirrored_shown);
    while let Some(item) = items.fetch_next() {
        if let Ok(mut view_visibility) = item {
            view_visibility.set_visible();
        }
    }
    *stats = CulletLightStats { maps, casters: listed, write_time: start.elapsed() };
}

/// The view point and spot lights' casters are in visibility range of, as Bevy chooses it: an entity with
/// `ShadowLodOrigin`, else a camera drawing to a window, else any camera (the lowest entity of each kind).
fn shadow_lod_origin(
    origins: &Query<Entity, With<ShadowLodOrigin>>,
    targets: &Query<(Entity, &RenderTarget), With<Camera>>,
) -> Option<Entity> {
    let windows = targets.iter().filter(|(_, target)| matches!(target, RenderTarget::Window(_)));
    (origins.iter().min())
        .or_else(|| windows.map(|(entity, _)| entity).min())
        .or_else(|| targets.iter().map(|(entity, _)| entity).min())
}
