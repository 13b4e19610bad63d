//! The last step of the light views in a Bevy app ([`crate::lights`] builds them, [`crate::cull`] culls them
//! with each camera): each light's shadow casters written to Bevy's per-light lists, and made visible.

use crate::cull::CulletView;
use crate::lights::{LightMap, ShadowMap};
use crate::mirror::CulletStore;
use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::{
    CascadesVisibleEntities, CubemapVisibleEntities, InheritedVisibility, NoCpuCulling, NoFrustumCulling, RenderLayers,
    SetViewVisibility, ViewVisibility, VisibilityRange, VisibleEntityRanges, VisibleMeshEntities,
};
use bevy_camera::{Camera, RenderTarget, ShadowLodOrigin};
use bevy_ecs::change_detection::ContiguousMut;
use bevy_ecs::entity::EntityHashMap;
use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemParam;
use bevy_light::{DirectionalLight, NotShadowCaster, PointLight, SpotLight};
use bevy_mesh::Mesh3d;
use cullet::bounds::BoundsStore;
use cullet::visible::{VisibleSet, set_slots};
use rayon::prelude::*;
use std::borrow::Cow;
use std::time::{Duration, Instant};

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

/// The casters' classification ([`CasterClasses`]) kept from frame to frame, with the rows it was made from:
/// each caster's entity and flags (visible, special) in the order the query walks its tables. A frame whose
/// rows are all the same, on a store of the same layout (each entity in the same slot), has the same classes.
/// Comparing the rows reads them in order; classifying looks each entity's slot up.
#[derive(Default)]
pub(crate) struct CasterCache {
    layout: Option<u64>,
    entities: Vec<Entity>,
    flags: Vec<u8>,
    /// Each row's store slot ([`NOT_STORED`] for an entity the store does not hold).
    slots: Vec<u32>,
    classes: Option<CasterClasses>,
}

/// A row's slot in [`CasterCache`] where the store does not hold its entity.
const NOT_STORED: u32 = u32::MAX;

/// Caster rows one task of [`CasterCache::mark_visible`] walks.
const MARK_ROWS: usize = 4096;

/// Rows [`CasterCache::mark_visible`] walks for the time of one entity looked up: below one caster to mark in
/// this many rows, looking them up costs less.
const ROWS_PER_LOOKUP: usize = 4;

/// A row's flags in [`CasterCache`].
const VISIBLE: u8 = 1;
const SPECIAL: u8 = 2;

/// One task's share of the caster rows: its first row's index over all tables, the rows' entities and
/// visibility, and whether their table's casters are special (layers or a range of their own).
type RowRange<'a> = (usize, &'a [Entity], &'a [InheritedVisibility], bool);

impl CasterCache {
    /// The classes of the casters `rows` walks, over `store`'s slots: the last frame's where nothing they
    /// depend on changed, else classified again (in parallel over the tables).
    fn classes(&mut self, store: &BoundsStore, rows: &Query<CasterRow, CasterFilter>) -> &CasterClasses {
        let Ok(tables) = rows.contiguous_iter() else {
            // Not stored in tables (not the case of Bevy's components): one walk on this thread, not kept.
            let mut classes = CasterClasses::empty(store.len());
            for (entity, inherited, has_layers, has_range) in rows {
                classes.mark(store, entity, inherited.get(), has_layers || has_range);
            }
            self.layout = None;
            self.entities.clear();
            return self.classes.insert(classes);
        };
        let mut ranges: Vec<RowRange> = Vec::new();
        let mut total = 0;
        for (entities, inherited, has_layers, has_range) in tables {
            for first in (0..entities.len()).step_by(CLASSIFY_ROWS) {
                let end = (first + CLASSIFY_ROWS).min(entities.len());
                ranges.push((total + first, &entities[first..end], &inherited[first..end], has_layers || has_range));
            }
            total += entities.len();
        }
        let flags = |inherited: &InheritedVisibility, special: bool| {
            if inherited.get() { VISIBLE | if special { SPECIAL } else { 0 } } else { 0 }
        };
        let unchanged = self.classes.is_some()
            && self.layout == Some(store.layout_generation())
            && self.entities.len() == total
            && ranges.par_iter().all(|&(offset, entities, inherited, special)| {
                let rows = offset..offset + entities.len();
                entities == &self.entities[rows.clone()]
                    && inherited
                        .iter()
                        .zip(&self.flags[rows])
                        .all(|(inherited, &kept)| flags(inherited, special) == kept)
            });
        if !unchanged {
            self.layout = Some(store.layout_generation());
            self.entities.clear();
            self.flags.clear();
            for &(_, entities, inherited, special) in &ranges {
                self.entities.extend_from_slice(entities);
                self.flags.extend(inherited.iter().map(|inherited| flags(inherited, special)));
            }
            let slot = |entity: &Entity| store.slot_of(*entity).map_or(NOT_STORED, |slot| slot as u32);
            self.slots = self.entities.par_iter().map(slot).collect();
            // Each task marks sets of its own (a few kilobytes each), merged after: no atomic per entity.
            let empty = || CasterClasses::empty(store.len());
            let classes = (ranges.into_par_iter())
                .fold(empty, |mut classes, (_, entities, inherited, special)| {
                    for (&entity, inherited) in entities.iter().zip(inherited) {
                        classes.mark(store, entity, inherited.get(), special);
                    }
                    classes
                })
                .reduce(empty, |mut a, b| {
                    a.plain.or(&b.plain);
                    a.special.or(&b.special);
                    a
                });
            self.classes = Some(classes);
        }
        self.classes.as_ref().expect("classified above")
    }

    /// Makes visible (`ViewVisibility`) each caster whose store slot is in `shown`, walking `rows` table by
    /// table in the order the last [`CasterCache::classes`] saw them, in parallel within a table: no entity is
    /// looked up. Returns `false`, leaving `shown` to mark by looking its entities up, where that costs less
    /// (few casters to mark for the rows to walk), and where the tables do not hold the rows the cache has
    /// (another query order, or casters without `ViewVisibility`: some of `shown` may then be left).
    ///
    /// A caster hidden last frame becomes visible with its change marked, one visible last frame without, as
    /// Bevy's `set_visible` does. Both are written as `ViewVisibility::VISIBLE`, whose "visible last frame" bit
    /// Bevy reads only from the next frame's reset on, which overwrites it.
    fn mark_visible(&self, shown: &VisibleSet, rows: &mut Query<(Entity, &mut ViewVisibility), CasterFilter>) -> bool {
        if self.layout.is_none() || shown.count() * ROWS_PER_LOOKUP < self.entities.len() {
            return false;
        }
        let Ok(tables) = rows.contiguous_iter_mut() else { return false };
        let mut offset = 0;
        for (entities, visibility) in tables {
            let rows = offset..offset + entities.len();
            if self.entities.get(rows.clone()) != Some(entities) {
                return false;
            }
            let (values, mut ticks) = ContiguousMut::bypass_change_detection_split(visibility);
            let newly_visible: Vec<u32> = (values.par_chunks_mut(MARK_ROWS))
                .zip(self.slots[rows].par_chunks(MARK_ROWS))
                .enumerate()
                .flat_map_iter(|(chunk, (values, slots))| {
                    let mut newly_visible = Vec::new();
                    for (row, (value, &slot)) in values.iter_mut().zip(slots).enumerate() {
                        if slot != NOT_STORED && !value.get() && shown.contains(slot as usize) {
                            if *value == ViewVisibility::HIDDEN {
                                newly_visible.push((chunk * MARK_ROWS + row) as u32);
                            }
                            *value = ViewVisibility::VISIBLE;
                        }
                    }
                    newly_visible
                })
                .collect();
            for row in newly_visible {
                ticks.reborrow().slice(row..row + 1).mark_all_as_changed();
            }
            offset += entities.len();
        }
        offset == self.entities.len()
    }
}

impl CasterClasses {
    /// No stored entity in either class.
    fn empty(len: usize) -> Self {
        Self { plain: VisibleSet::new(len), special: VisibleSet::new(len) }
    }

    /// Puts `entity`, if `store` holds it and it is `visible`, in the special class or the plain one.
    fn mark(&mut self, store: &BoundsStore, entity: Entity, visible: bool, special: bool) {
        if let Some(slot) = store.slot_of(entity).filter(|_| visible) {
            let class = if special { &mut self.special } else { &mut self.plain };
            class.words_mut()[slot / 64] |= 1 << (slot % 64);
        }
    }
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

/// One shadow map's casters gathered over the cameras: their store slots (a camera's own set, or the union of
/// several cameras'), or every caster.
enum Gathered<'a> {
    Slots(Cow<'a, VisibleSet>),
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
    mut visibility: ParamSet<(Query<(Entity, &mut ViewVisibility), CasterFilter>, Query<&mut ViewVisibility>)>,
    ranges: Option<Res<VisibleEntityRanges>>,
    lod_origins: Query<Entity, With<ShadowLodOrigin>>,
    targets: Query<(Entity, &RenderTarget), With<Camera>>,
    mut stats: ResMut<CulletLightStats>,
    mut entity_order: Local<EntityOrder>,
    mut caster_cache: Local<CasterCache>,
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
            let gathered = || visible.map_or(Gathered::Every, |set| Gathered::Slots(Cow::Borrowed(set)));
            match map {
                ShadowMap::Cascade(index) => cascades.entry(light).or_default().push((camera, index, gathered())),
                ShadowMap::Face(_) | ShadowMap::Spot => {
                    let maps = lamps.entry(light).or_default();
                    match maps.iter_mut().find(|(listed, _)| *listed == map) {
                        None => maps.push((map, gathered())),
                        Some((_, Gathered::Every)) => {}
                        Some((_, gathered_so_far)) => match (gathered_so_far, visible) {
                            (Gathered::Slots(union), Some(set)) => union.to_mut().or(set),
                            (slot, None) => *slot = Gathered::Every,
                            (Gathered::Every, _) => {}
                        },
                    }
                }
            }
        }
    }
    let lod_origin = shadow_lod_origin(&lod_origins, &targets);
    let classes = caster_cache.classes(store, &caster_rows);
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
        let every;
        let set = match gathered {
            Gathered::Slots(set) => set,
            Gathered::Every => {
                every = VisibleSet::all(store.len());
                &every
            }
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
        shown.or(&accepted);
        // Listed in entity order, as Bevy sorts its lists: in slot order, or its reverse, where the store holds
        // its entities so (as the mirroring leaves entities spawned together), else the slots walked in their
        // entities' order.
        match order {
            SlotOrder::Slots => append_entities(&accepted, entities, false, out),
            SlotOrder::Reversed => append_entities(&accepted, entities, true, out),
            SlotOrder::Ranked(order) => {
                let runs: Vec<Vec<Entity>> = (order.par_chunks(ORDER_RUN))
                    .map(|run| {
                        let kept = run.iter().map(|&slot| slot as usize).filter(|&slot| accepted.contains(slot));
                        kept.map(|slot| entities[slot]).collect()
                    })
                    .collect();
                runs.into_iter().for_each(|run| out.extend(run));
            }
        }
        // Entities Cullet does not mirror, or whose bounds it refused, are in every map, as Bevy has them.
        let before = out.len();
        out.extend(others.iter().filter(|&(entity, item)| passes(entity, item)).map(|(entity, _)| entity));
        let refused = cullet.rejected.iter().filter(|&&entity| casters.get(entity).is_ok_and(|i| passes(entity, i)));
        out.extend(refused);
        unmirrored_shown.extend_from_slice(&out[before..]);
        // The stored casters came in entity order; only entities added after them can break it.
        if out.len() > before && !out.is_sorted() {
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
            std::mem::swap(&mut lists[*index].entities, &mut out);
        }
    }
    let lamp_maps = |light: Entity| lamps.get(&light).map(Vec::as_slice).unwrap_or_default();
    for (light, mut visible, layers) in &mut lists.point {
        let gathered = lamp_maps(light);
        for (face, target) in visible.iter_mut().enumerate() {
            target.entities.clear();
            if let Some((_, gathered)) = gathered.iter().find(|(map, _)| *map == ShadowMap::Face(face)) {
                list(gathered, layers.unwrap_or_default(), lod_origin, &mut out);
                std::mem::swap(&mut target.entities, &mut out);
            }
        }
    }
    for (light, mut visible, layers) in &mut lists.spot {
        visible.entities.clear();
        if let Some((_, gathered)) = lamp_maps(light).first() {
            list(gathered, layers.unwrap_or_default(), lod_origin, &mut out);
            std::mem::swap(&mut visible.entities, &mut out);
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
    let marked = caster_cache.mark_visible(&shown, &mut visibility.p0());
    let mut visibility = visibility.p1();
    let entities = store.entities();
    let unmarked = if marked { VisibleSet::new(0) } else { shown };
    unmarked.words().par_chunks(WRITE_WORDS).enumerate().for_each(|(chunk, words)| {
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

/// Appends to `out` the entities (`entities`, by store slot) of the slots set in `set`, in slot order or, where
/// `reversed`, the reverse; in parallel over runs of [`ORDER_RUN`] slots, each writing its own part of `out`.
fn append_entities(set: &VisibleSet, entities: &[Entity], reversed: bool, out: &mut Vec<Entity>) {
    const RUN_WORDS: usize = ORDER_RUN / 64;
    let runs: Vec<&[u64]> = set.words().chunks(RUN_WORDS).collect();
    let counts: Vec<usize> = runs.iter().map(|words| words.iter().map(|w| w.count_ones() as usize).sum()).collect();
    let start = out.len();
    out.resize(start + counts.iter().sum::<usize>(), Entity::PLACEHOLDER);
    // Each run's part of `out`: the runs in order, or in reverse.
    let mut parts = Vec::with_capacity(runs.len());
    let mut rest = &mut out[start..];
    for run in 0..runs.len() {
        let run = if reversed { runs.len() - 1 - run } else { run };
        let (part, tail) = std::mem::take(&mut rest).split_at_mut(counts[run]);
        parts.push((run, part));
        rest = tail;
    }
    parts.into_par_iter().for_each(|(run, part)| {
        let first = run * RUN_WORDS * 64;
        // Slots ascending; filled from the part's end where reversed.
        let mut written = 0;
        for (index, &word) in runs[run].iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                let slot = first + index * 64 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let at = if reversed { part.len() - 1 - written } else { written };
                part[at] = entities[slot];
                written += 1;
            }
        }
    });
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
