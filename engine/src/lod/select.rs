//! Choosing each kept object's level, frame by frame: the coarsest level whose geometric error projects under
//! a threshold in pixels, with hysteresis against flicker, over the SoA bounds in parallel.

use super::LodLibrary;
use super::library::ChainTable;
use crate::bounds::{BoundsStore, ObjectTransform, largest_axis_scale};
use crate::camera::Camera;
use crate::mesh::MeshRef;
use crate::parallel::{self, Stage};
use crate::pipeline::{CameraCuller, CullStage};
use crate::visible::{VisibleSet, set_slots};
use bevy_ecs::prelude::*;
use rayon::prelude::*;
use std::time::{Duration, Instant};

/// Bitset words (of 64 objects) one task of the selection looks at.
const WORDS_PER_TASK: usize = 128;
/// Kept objects in a word from which the word's distances are computed all at once.
const DENSE_WORD: u32 = 16;
/// [`LodSelection::chain`] of an object without a mesh: it has no levels.
const NO_CHAIN: u32 = u32::MAX;
/// [`LodSelection::level`] of an object not chosen for since it was stored.
const UNCHOSEN: u8 = u8::MAX;

/// How levels are chosen; a resource of a world set up by [`install`]. Off (every object at full detail)
/// with neither a pixel error nor a budget.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct LodSettings {
    /// Each object draws the coarsest level whose geometric error projects to at most this many pixels; 0
    /// (the default), or anything not above 0, keeps full detail unless a budget asks for less.
    pub max_error_pixels: f32,
    /// The height of the frame in pixels, which sizes a pixel.
    pub viewport_height: u32,
    /// An object goes to a coarser level only once that level's error projects under `1 - hysteresis` of the
    /// threshold, so that one near the threshold does not switch back and forth; in `[0, 1)`. To a finer
    /// level it goes at once: the threshold always holds.
    pub hysteresis: f32,
    /// At most this many triangles a frame over the objects the camera keeps: levels coarser than the
    /// threshold's, chosen best-first ([`super::budget`]), and objects dropped, smallest on screen first, where
    /// even every object's coarsest level does not fit. `None` for no budget.
    pub triangle_budget: Option<u64>,
}

impl Default for LodSettings {
    /// Off: full detail, no budget; hysteresis 0.25 for when it is switched on.
    fn default() -> Self {
        Self { max_error_pixels: 0.0, viewport_height: 1080, hysteresis: 0.25, triangle_budget: None }
    }
}

impl LodSettings {
    /// Levels whose error projects to at most `pixels` in a frame `viewport_height` pixels tall; no budget.
    pub fn pixels(pixels: f32, viewport_height: u32) -> Self {
        Self { max_error_pixels: pixels, viewport_height, ..Self::default() }
    }

    /// Whether it chooses anything but full detail.
    pub fn enabled(&self) -> bool {
        self.viewport_height > 0 && (self.max_error_pixels > 0.0 || self.triangle_budget.is_some())
    }

    /// The focal length in pixels of `camera` in a frame of this height: what turns a length at a distance
    /// into pixels.
    pub(crate) fn focal_pixels(&self, camera: &Camera) -> f32 {
        camera.focal_pixels(self.viewport_height)
    }
}

/// What the last selection chose.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LodStats {
    /// Kept objects with levels (a [`MeshRef`] naming a chain).
    pub objects: usize,
    /// Their triangles at full detail.
    pub triangles_full: u64,
    /// Their triangles at the chosen levels (dropped objects count none).
    pub triangles: u64,
    /// Kept objects whose level differs from their level the last time they were kept: popping.
    pub switches: usize,
    /// Objects dropped to keep the budget.
    pub dropped: usize,
    /// Wall time of the selection, its per-object tables brought up to date and the budget included.
    pub time: Duration,
    /// Of `time`, bringing the per-object tables (mesh, scale) up to date with the entities.
    pub tables_time: Duration,
}

/// Each object's level, by store slot; a resource of a world set up by [`install`], chosen each frame for the
/// objects the camera keeps ([`LodSelection::select`]). An object the camera did not keep keeps the level it
/// had.
#[derive(Resource, Clone, Debug, Default)]
pub struct LodSelection {
    /// Per slot, the object's chain ([`MeshRef`]), or [`NO_CHAIN`].
    pub(super) chain: Vec<u32>,
    /// Per slot (padded to whole words), the largest axis scale of the object's transform: what turns the
    /// mesh's error into the world's.
    pub(super) scale: Vec<f32>,
    /// Per slot (padded to whole words), the level, or [`UNCHOSEN`].
    pub(super) level: Vec<u8>,
    /// The store's layout and generation the per-slot tables were last brought up to date with.
    synced: Option<(u64, u64)>,
    /// Slots whose scale may be out of date (the object moved while the camera did not keep it).
    stale: VisibleSet,
    /// Objects dropped this frame to keep the budget.
    pub(super) dropped: VisibleSet,
    /// Slots whose level changed in the last selection.
    pub(super) changed: Vec<u32>,
    pub(super) stats: LodStats,
    /// The last selection chose anything but full detail.
    active: bool,
    /// Time the last [`sync_objects`] took, counted in the next selection's.
    sync_time: Duration,
}

impl LodSelection {
    /// The level of the object in `slot` (0 is full detail), or `None` for an object without levels or never
    /// chosen for.
    pub fn level(&self, slot: usize) -> Option<u8> {
        self.level.get(slot).copied().filter(|&l| l != UNCHOSEN && self.chain.get(slot) != Some(&NO_CHAIN))
    }

    /// The mesh, in [`LodLibrary::meshes`], that the object in `slot` draws: `None` for an object without
    /// levels or dropped by the budget. An object not chosen for yet draws full detail.
    pub fn mesh_of(&self, slot: usize, library: &LodLibrary) -> Option<u32> {
        let chain = *self.chain.get(slot)?;
        if chain == NO_CHAIN || self.dropped.contains(slot) {
            return None;
        }
        library.mesh_of(chain, self.level(slot).unwrap_or(0))
    }

    /// Slots whose drawn mesh changed in the last selection, increasing: their level, or whether the budget
    /// dropped them. What a GPU copy of the instances must rewrite.
    pub fn changed(&self) -> &[u32] {
        &self.changed
    }

    /// Objects the budget dropped this frame: kept by culling, not to be drawn.
    pub fn dropped(&self) -> &VisibleSet {
        &self.dropped
    }

    /// What the last selection chose.
    pub fn stats(&self) -> LodStats {
        self.stats
    }

    /// Sets the object in `slot` to draw `chain` (a [`MeshRef`]; `None` for none) under a transform whose
    /// largest axis scale is `scale`. Grows the tables to hold `slot`.
    pub fn set_object(&mut self, slot: usize, chain: Option<u32>, scale: f32) {
        self.resize(slot + 1);
        self.chain[slot] = chain.unwrap_or(NO_CHAIN);
        self.scale[slot] = scale;
    }

    /// Sizes the tables for `len` slots; new slots have no levels until set.
    fn resize(&mut self, len: usize) {
        if len > self.chain.len() {
            self.chain.resize(len, NO_CHAIN);
        }
        let padded = len.div_ceil(64) * 64;
        if padded > self.level.len() {
            self.level.resize(padded, UNCHOSEN);
        }
        if padded > self.scale.len() {
            self.scale.resize(padded, 1.0);
        }
    }

    /// Chooses a level for every object of `visible` (store slots of `store`) seen from `camera`, as
    /// `settings` ask: under [`LodSettings::max_error_pixels`], then within [`LodSettings::triangle_budget`].
    /// With `settings` off, every object goes back to full detail, and a frame after that costs nothing.
    pub fn select(
        &mut self,
        library: &LodLibrary,
        store: &BoundsStore,
        camera: &Camera,
        visible: &VisibleSet,
        settings: &LodSettings,
    ) {
        let tables_time = std::mem::take(&mut self.sync_time);
        let start = Instant::now() - tables_time;
        let _stage = Stage::Lod.enter();
        self.changed.clear();
        self.resize(store.len());
        let was_dropped = std::mem::take(&mut self.dropped);
        self.dropped.reset(store.len());
        if !settings.enabled() {
            if self.active {
                self.reset_to_full_detail();
            }
            self.note_dropped_changes(&was_dropped);
            self.stats = LodStats { time: start.elapsed(), tables_time, ..LodStats::default() };
            return;
        }
        self.active = true;
        let previous = settings.triangle_budget.map(|_| self.level.clone());
        let frame = SelectionFrame { library, store, camera, visible, settings, focal: settings.focal_pixels(camera) };
        self.choose_within_threshold(&frame);
        if let (Some(budget), Some(previous)) = (settings.triangle_budget, previous)
            && self.stats.triangles > budget
        {
            self.fit_budget(&frame, budget, &previous);
        }
        self.note_dropped_changes(&was_dropped);
        (self.stats.time, self.stats.tables_time) = (start.elapsed(), tables_time);
    }

    /// Adds to the changed slots those the budget dropped, or drew again, since `was_dropped` (the last
    /// selection's): their drawn mesh changed with the same level.
    fn note_dropped_changes(&mut self, was_dropped: &VisibleSet) {
        let (now, before) = (self.dropped.words(), was_dropped.words());
        let word = |words: &[u64], i: usize| words.get(i).copied().unwrap_or(0);
        let flips: Vec<u64> = (0..now.len().max(before.len())).map(|i| word(now, i) ^ word(before, i)).collect();
        let len = self.dropped.len();
        let flipped: Vec<u32> = set_slots(0, &flips).filter(|&slot| slot < len).map(|slot| slot as u32).collect();
        if !flipped.is_empty() {
            self.changed.extend(flipped);
            self.changed.sort_unstable();
            self.changed.dedup();
        }
    }

    /// Every object back at full detail (LOD switched off).
    fn reset_to_full_detail(&mut self) {
        self.active = false;
        for (slot, level) in self.level.iter_mut().enumerate() {
            if *level != UNCHOSEN && *level != 0 {
                *level = 0;
                self.changed.push(slot as u32);
            }
        }
    }

    /// The threshold's choice with hysteresis, in parallel over runs of words; fills the stats and the
    /// changed slots.
    fn choose_within_threshold(&mut self, frame: &SelectionFrame<'_>) {
        let SelectionFrame { library, store, camera, visible, settings, focal } = *frame;
        let soa = store.soa();
        let (chains, scales) = (&self.chain, &self.scale);
        let (eye, threshold) = (camera.position, settings.max_error_pixels.max(0.0));
        let keep_below = 1.0 - settings.hysteresis.clamp(0.0, 0.99);
        let len = store.len();
        let tasks: Vec<Choice> = parallel::region(|region| {
            visible
                .words()
                .par_chunks(WORDS_PER_TASK)
                .zip(self.level.par_chunks_mut(WORDS_PER_TASK * 64))
                .enumerate()
                .map(|(task, (words, levels))| {
                    region.task(|| {
                        let mut choice = Choice::default();
                        let mut allowed = [0.0f32; 64];
                        // The error in the mesh's units that projects to `threshold` pixels at the object's
                        // nearest distance from the eye (0 where the eye is inside its sphere).
                        let allowed_at = |slot: usize| {
                            let (dx, dy, dz) =
                                (soa.center_x[slot] - eye.x, soa.center_y[slot] - eye.y, soa.center_z[slot] - eye.z);
                            let nearest = ((dx * dx + dy * dy + dz * dz).sqrt() - soa.radius[slot]).max(0.0);
                            threshold * nearest / (focal * scales[slot])
                        };
                        for (w, &word) in words.iter().enumerate() {
                            if word == 0 {
                                continue;
                            }
                            let base = (task * WORDS_PER_TASK + w) * 64;
                            // A set longer than the store (not the pipeline's) holds no object there.
                            if base >= len {
                                break;
                            }
                            // A dense word is computed whole, straight-line over the SoA bounds so that it
                            // vectorizes; a sparse one object by object.
                            let dense = word.count_ones() >= DENSE_WORD;
                            if dense {
                                // Fixed 64-lane runs of the SoA bounds and scales (both padded to whole words).
                                let lanes = base..base + 64;
                                let (xs, ys, zs) = (
                                    &soa.center_x[lanes.clone()],
                                    &soa.center_y[lanes.clone()],
                                    &soa.center_z[lanes.clone()],
                                );
                                let (radii, word_scales) = (&soa.radius[lanes.clone()], &scales[lanes]);
                                for lane in 0..64 {
                                    let (dx, dy, dz) = (xs[lane] - eye.x, ys[lane] - eye.y, zs[lane] - eye.z);
                                    let nearest = ((dx * dx + dy * dy + dz * dz).sqrt() - radii[lane]).max(0.0);
                                    allowed[lane] = threshold * nearest / (focal * word_scales[lane]);
                                }
                            }
                            let mut bits = word;
                            while bits != 0 {
                                let i = bits.trailing_zeros() as usize;
                                bits &= bits - 1;
                                let slot = base + i;
                                // A set longer than the store (not the pipeline's) holds no object there.
                                if slot >= len {
                                    break;
                                }
                                let Some(table) = chains.get(slot).and_then(|&c| library.chains.get(c as usize)) else {
                                    continue;
                                };
                                let allowed = if dense { allowed[i] } else { allowed_at(slot) };
                                // Not finite (a zero or broken scale): full detail.
                                let within = if allowed.is_finite() { allowed } else { 0.0 };
                                let level = &mut levels[slot - task * WORDS_PER_TASK * 64];
                                let chosen = hysteresis(table, *level, within, within * keep_below);
                                choice.add(table, slot, *level, chosen);
                                *level = chosen;
                            }
                        }
                        choice
                    })
                })
                .collect()
        });
        let mut stats = LodStats::default();
        for task in tasks {
            stats.objects += task.objects;
            stats.triangles_full += task.triangles_full;
            stats.triangles += task.triangles;
            stats.switches += task.switches;
            self.changed.extend(task.changed);
        }
        self.stats = stats;
    }
}

/// What one selection reads.
#[derive(Clone, Copy)]
pub(super) struct SelectionFrame<'a> {
    pub library: &'a LodLibrary,
    pub store: &'a BoundsStore,
    pub camera: &'a Camera,
    /// The objects to choose for (store slots).
    pub visible: &'a VisibleSet,
    pub settings: &'a LodSettings,
    /// The camera's focal length in pixels ([`LodSettings::focal_pixels`]).
    pub focal: f32,
}

/// The level an object at `previous` goes to: finer at once where `previous` is coarser than the coarsest
/// level within `allowed`; coarser only to the coarsest within `relaxed` (below `allowed`).
#[inline]
fn hysteresis(table: &ChainTable, previous: u8, allowed: f32, relaxed: f32) -> u8 {
    let target = table.coarsest_within(allowed);
    if previous == UNCHOSEN || previous >= table.levels || previous > target {
        return target;
    }
    previous.max(table.coarsest_within(relaxed))
}

/// One task's share of a selection.
#[derive(Default)]
struct Choice {
    objects: usize,
    triangles_full: u64,
    triangles: u64,
    switches: usize,
    changed: Vec<u32>,
}

impl Choice {
    fn add(&mut self, table: &ChainTable, slot: usize, previous: u8, chosen: u8) {
        self.objects += 1;
        self.triangles_full += table.triangles[0] as u64;
        self.triangles += table.triangles[chosen as usize] as u64;
        if previous != chosen {
            self.changed.push(slot as u32);
            self.switches += (previous != UNCHOSEN) as usize;
        }
    }
}

/// Installs level selection into a world set up by [`crate::install`]: `library` (the levels of the meshes
/// that [`MeshRef`]s name), `settings` and the [`LodSelection`] as resources, and the [`CullStage::Lod`]
/// systems in `schedule`, after the occlusion stage: each run chooses a level for every object the camera
/// keeps.
pub fn install(world: &mut World, schedule: &mut Schedule, library: LodLibrary, settings: LodSettings) {
    world.insert_resource(library);
    world.insert_resource(settings);
    world.init_resource::<LodSelection>();
    world.init_resource::<LodRemeshed>();
    world.add_observer(on_mesh_inserted);
    schedule.configure_sets(CullStage::Lod.after(CullStage::Occlusion));
    schedule.add_systems((sync_objects, select_levels).chain().in_set(CullStage::Lod));
}

/// Keeps [`LodSelection`]'s per-slot chain and scale in step with the entities, at a cost that follows what
/// changed and what the camera keeps: every slot after the store's layout changed (objects added, removed or
/// moved between slots, or a [`MeshRef`] inserted); else the slots whose bounds changed in place this frame
/// ([`BoundsStore::last_moves`]: transforms mutated or inserted) are marked stale, and only the stale slots the
/// camera keeps are read from their entities (the others when it keeps them). An object's mesh is changed by
/// inserting a new [`MeshRef`] (an insert, not a mutation).
fn sync_objects(
    store: Res<BoundsStore>,
    culler: Res<CameraCuller>,
    mut selection: ResMut<LodSelection>,
    mut remeshed: ResMut<LodRemeshed>,
    objects: Query<(Option<&MeshRef>, Option<&ObjectTransform>)>,
) {
    let start = Instant::now();
    let _stage = Stage::Lod.enter();
    let object_in = |slot: u32| {
        let entity = store.entities()[slot as usize];
        objects.get(entity).map_or((None, 1.0), |(mesh, transform)| {
            (mesh.map(|m| m.0), transform.map_or(1.0, |t| largest_axis_scale(&t.0)))
        })
    };
    let incremental = store
        .last_moves()
        .filter(|moves| selection.synced == Some((store.layout_generation(), moves.from)) && !remeshed.0)
        .filter(|moves| moves.to == store.generation());
    let selection = &mut *selection;
    let slots: Vec<u32> = match incremental {
        Some(moves) => {
            for &slot in &moves.slots {
                selection.stale.set(slot as usize, true);
            }
            // Stale and kept: a word-wise AND, then only those objects' entities are read.
            let (stale, kept) = (selection.stale.words_mut(), culler.visible().words());
            let mut slots = Vec::new();
            for (w, (stale, &kept)) in stale.iter_mut().zip(kept).enumerate() {
                let refresh = *stale & kept;
                // Most words hold nothing to refresh: no iterator built for them.
                if refresh != 0 {
                    *stale &= !refresh;
                    slots.extend(crate::visible::set_slots(w, &[refresh]).map(|slot| slot as u32));
                }
            }
            slots
        }
        None => {
            selection.chain.clear();
            selection.scale.clear();
            selection.level.clear();
            selection.resize(store.len());
            selection.stale.reset(store.len());
            (0..store.len() as u32).collect()
        }
    };
    let objects: Vec<(Option<u32>, f32)> = parallel::map_range(slots.len(), 512, |i| object_in(slots[i]));
    for (&slot, (chain, scale)) in slots.iter().zip(objects) {
        selection.set_object(slot as usize, chain, scale);
    }
    selection.synced = Some((store.layout_generation(), store.generation()));
    remeshed.0 = false;
    selection.sync_time = start.elapsed();
}

/// Set when a [`MeshRef`] was inserted since the last [`sync_objects`]: its tables are then filled again.
#[derive(Resource, Default)]
struct LodRemeshed(bool);

/// Observer: an object's mesh changed.
fn on_mesh_inserted(_event: On<Insert<MeshRef>>, mut remeshed: ResMut<LodRemeshed>) {
    remeshed.0 = true;
}

/// Chooses the levels of the camera's kept objects ([`LodSelection::select`]).
fn select_levels(
    library: Res<LodLibrary>,
    store: Res<BoundsStore>,
    camera: Option<Res<Camera>>,
    culler: Res<CameraCuller>,
    settings: Res<LodSettings>,
    mut selection: ResMut<LodSelection>,
) {
    if let Some(camera) = camera {
        selection.select(&library, &store, &camera, culler.visible(), &settings);
    }
}
