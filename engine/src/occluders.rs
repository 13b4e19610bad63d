//! Stage 3, occluders: the [`Occluder`] component an artist gives an object, the [`OccluderInstance`] the
//! raster stage draws, and the selection of which occluders to rasterize this frame:
//!
//! 1. Frustum: an occluder lies inside its object's bounds, so one whose object the frustum stage culled is
//!    skipped.
//! 2. Inside: an occluder whose object's box contains the camera is skipped. From inside an object its
//!    surface hides nothing (a renderer culls the back faces the camera sees), even if the camera is outside
//!    the occluder.
//! 3. Rank: by the solid-angle estimate of Coorg and Teller (seed 002), `area / distance^2`, taken for the
//!    object's bounding sphere as `radius^2 / distance^2` (distance to the box centre). In an orthographic
//!    view (a sun's cascade, [`select_occluders_for_view`]) every occluder is seen from one direction, so the
//!    rank is `radius^2` and nothing contains the eye.
//!    Only the groups of 64 slots whose bound (their largest occluder radius over the distance to their box)
//!    ranks best have their candidates ranked first; at 1e6 objects that is about 2,400 of 46,500.
//! 4. Budget: occluders are taken best-first while their triangles fit in the budget; one that does not fit
//!    is skipped and smaller ones after it may still fill the budget, until less room is left than the
//!    smallest occluder taken (see [`select_occluders`]).

use crate::bounds::{BoundsStore, GroupBounds};
use crate::depth::ScreenView;
use crate::parallel;
use crate::visible::VisibleSet;
use bevy_ecs::prelude::*;
use glam::Vec3;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;

/// Marks an edge of an [`Occluder`] triangle without a neighbouring triangle.
pub const NO_NEIGHBOUR: u32 = u32::MAX;

/// An artist occluder: triangles in the entity's local space, meant to lie inside the rendered geometry, that
/// the software occlusion stage rasterizes to hide what is behind them. Triangles are counter-clockwise seen
/// from outside; closed meshes occlude best, since the raster covers the union of their front faces.
///
/// Immutable as a component: change an entity's occluder by inserting another, so that the pipeline learns of
/// it through its observers rather than by scanning every occluder each frame.
#[derive(Component, Clone, Debug, PartialEq)]
#[component(immutable)]
pub struct Occluder {
    /// Triangle list: every three vertices form one triangle, in the entity's local space. Shared, since many
    /// objects of one shape carry the same occluder.
    triangles: Arc<[Vec3]>,
    /// For edge `e` of triangle `t` (from vertex `e` to vertex `e + 1`), at `3 * t + e`: the triangle sharing
    /// that edge in the opposite direction, or [`NO_NEIGHBOUR`].
    neighbours: Arc<[u32]>,
    /// The distinct positions of `triangles`, which the raster transforms and projects once each.
    vertices: Arc<[Vec3]>,
    /// For each entry of `triangles`, the index of its position in `vertices`.
    corners: Arc<[u32]>,
    /// The least and greatest of `vertices`, per axis (`[+inf, -inf]` for no triangle): the raster bounds the
    /// occluder on screen from this box's corners before it sets up any triangle.
    local_box: [Vec3; 2],
}

impl Occluder {
    /// An occluder from a triangle list (a trailing partial triangle is ignored). Edges are matched by exact
    /// vertex positions; an edge shared by more than two triangles counts as having no neighbour.
    pub fn new(triangles: impl Into<Arc<[Vec3]>>) -> Self {
        let triangles: Arc<[Vec3]> = triangles.into();
        let count = triangles.len() / 3;
        let triangles: Arc<[Vec3]> =
            if triangles.len() == 3 * count { triangles } else { Arc::from(&triangles[..3 * count]) };
        // Positions are matched by their exact bits: each distinct one becomes a vertex, and edges are matched
        // by the vertices at their ends.
        let (mut vertices, mut index_of) = (Vec::new(), HashMap::new());
        let corners: Vec<u32> = triangles
            .iter()
            .map(|&p| {
                *index_of.entry(p.to_array().map(f32::to_bits)).or_insert_with(|| {
                    vertices.push(p);
                    vertices.len() as u32 - 1
                })
            })
            .collect();
        let edge = |t: usize, e: usize| (corners[3 * t + e], corners[3 * t + (e + 1) % 3]);
        let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
        for t in 0..count {
            for e in 0..3 {
                edges.entry(edge(t, e)).or_default().push(t as u32);
            }
        }
        let mut neighbours = vec![NO_NEIGHBOUR; 3 * count];
        for t in 0..count {
            for e in 0..3 {
                let (a, b) = edge(t, e);
                let forward = edges.get(&(a, b)).map_or(0, Vec::len);
                if let Some([other]) = edges.get(&(b, a)).map(Vec::as_slice)
                    && forward == 1
                {
                    neighbours[3 * t + e] = *other;
                }
            }
        }
        let local_box =
            vertices.iter().fold([Vec3::INFINITY, Vec3::NEG_INFINITY], |[min, max], &v| [min.min(v), max.max(v)]);
        Self { triangles, neighbours: neighbours.into(), vertices: vertices.into(), corners: corners.into(), local_box }
    }

    /// The triangle list: every three vertices form one triangle, in the entity's local space, counter-clockwise
    /// seen from outside. Occluders cloned from one another share it.
    pub fn triangles(&self) -> &[Vec3] {
        &self.triangles
    }

    /// For edge `e` of triangle `t` (from vertex `e` to vertex `e + 1`), at `3 * t + e`: the triangle sharing
    /// that edge in the opposite direction, or [`NO_NEIGHBOUR`].
    pub fn neighbours(&self) -> &[u32] {
        &self.neighbours
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len() / 3
    }

    /// The distinct vertex positions, and for each corner of [`Occluder::triangles`] its index among them.
    pub(crate) fn indexed(&self) -> (&[Vec3], &[u32]) {
        (&self.vertices, &self.corners)
    }

    /// The least and greatest vertex position per axis, in local space; `[+inf, -inf]` without triangles.
    pub(crate) fn local_box(&self) -> [Vec3; 2] {
        self.local_box
    }
}

/// One occluder to rasterize: its mesh and its world transform.
#[derive(Clone, Copy, Debug)]
pub struct OccluderInstance<'a> {
    /// The occluder mesh, with its edge adjacency.
    pub occluder: &'a Occluder,
    /// Local-to-world transform.
    pub transform: glam::Affine3A,
}

/// Candidates ordered per round of selection: enough to fill most budgets in one round.
const ROUND: usize = 1024;
/// Ranked candidates whose occluders are fetched at once, then looked at in order: more than one task's, and
/// not many more than a budget takes.
const FETCH_BATCH: usize = 256;
/// Candidates one task sorts when a round is ordered ([`sort_best_first`]).
const SORT_PER_TASK: usize = 128;
/// Occluders one task fetches.
const FETCH_PER_TASK: usize = 32;
/// Relative room for f32 rounding when telling whether the eye may be inside an occluder's sphere: the squared
/// distance and radius are each within a few ulps of their exact values.
const INSIDE_SPHERE_SLACK: f32 = 1.0 + 1e-4;
/// Bitset words (of 64 slots) one thread ranks at a time.
const RANK_WORDS_PER_TASK: usize = 256;
/// Bitset words above which ranking runs in parallel (about 260,000 objects): below, waking the pool costs
/// more than it saves (docs/performance.md).
const RANK_IN_PARALLEL_ABOVE: usize = 4096;

/// One chunk's groups with candidates, each `(bound, group)` in order, and their candidates per binary exponent
/// of the bound.
type BoundedGroups = (Vec<(f32, u32)>, [u32; 256]);

/// Bitset words whose groups one task bounds when choosing which groups to rank: each task's counts per
/// exponent are summed on one thread afterwards, so tasks are fewer than when ranking.
const BOUND_WORDS_PER_TASK: usize = 1024;
/// Groups with candidates whose best candidates one task ranks, at most, when ranking the best groups.
const RANK_GROUPS_PER_TASK: usize = 64;
/// Candidates ranked first, from the groups that can rank best (see [`select_occluders`]): two rounds.
const FIRST_CANDIDATES: usize = 2 * ROUND;
/// Relative room for f32 rounding in a group's bound on its occluders' ranks: each of the distances and the
/// radius is within a few ulps of its exact value.
const BOUND_SLACK: f32 = 1.0 + 1e-5;

/// Picks the occluders to rasterize: among store slots marked as occluders ([`BoundsStore::occluders`])
/// that the frustum kept and whose box does not contain the camera, best-first while their triangles fit in
/// `triangle_budget`. `occluder_of` gives a slot's occluder mesh and transform; it is called from rayon's
/// threads, for a batch of the best candidates at a time, and for some that are not chosen. Returns the chosen
/// slots with their occluders, best first.
///
/// Candidates are found with a bitwise AND and ranked from the store's arrays, first only those of the groups
/// whose bounds rank best (the others are ranked only where those cannot settle the choice, which is the same
/// either way; equal ranks go in slot order). Only the best are ordered, a round of `ROUND` (1024) at a time,
/// until the budget is full, it has less room left than the smallest occluder chosen, a whole round fits
/// nothing more, or a round leaves less room than the smallest occluder it met (so at most that many triangles
/// of the budget go unused).
pub fn select_occluders<'a>(
    store: &BoundsStore,
    frustum_visible: &VisibleSet,
    camera_position: Vec3,
    triangle_budget: usize,
    occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>> + Sync,
) -> Vec<(u32, OccluderInstance<'a>)> {
    select_ranked(store, frustum_visible, Viewpoint::Position(camera_position), triangle_budget, occluder_of)
}

/// [`select_occluders`] for any view: for a perspective one, from its eye ([`ScreenView::origin`]); for an
/// orthographic one (a sun's cascade), where every occluder is seen from the same direction, ranked by the
/// size alone (`radius^2`) and none skipped as containing the eye.
pub fn select_occluders_for_view<'a>(
    store: &BoundsStore,
    visible: &VisibleSet,
    view: &ScreenView,
    triangle_budget: usize,
    occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>> + Sync,
) -> Vec<(u32, OccluderInstance<'a>)> {
    let viewpoint = if view.is_orthographic() { Viewpoint::Direction } else { Viewpoint::Position(view.origin) };
    select_ranked(store, visible, viewpoint, triangle_budget, occluder_of)
}

/// Where occluders are seen from, for ranking.
#[derive(Clone, Copy)]
enum Viewpoint {
    /// An eye at this world position.
    Position(Vec3),
    /// A light at infinity.
    Direction,
}

/// [`select_occluders`] with occluders ranked as seen from `viewpoint`.
///
/// A budget takes a few hundred of tens of thousands of candidates, and ranking them all streams much of the
/// store. So the groups' bounds ([`group_bound`]) are ranked first, and only the candidates of the best groups
/// (at least [`FIRST_CANDIDATES`], or a quarter of the budget's triangles) are ranked and chosen from. Every
/// candidate left out ranks below the threshold those groups reach; a choice that looked at none below it is the
/// one all candidates give. Otherwise every candidate is ranked and the choice made again.
fn select_ranked<'a>(
    store: &BoundsStore,
    visible: &VisibleSet,
    viewpoint: Viewpoint,
    triangle_budget: usize,
    occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>> + Sync,
) -> Vec<(u32, OccluderInstance<'a>)> {
    let wanted = FIRST_CANDIDATES.max(triangle_budget / 4);
    let (mut best, threshold) = rank_best_groups(store, visible, viewpoint, wanted);
    if let Some(chosen) = choose(&mut best, threshold, triangle_budget, &occluder_of) {
        return chosen;
    }
    let mut ranked = rank_all(store, visible, viewpoint);
    choose(&mut ranked, None, triangle_budget, &occluder_of).expect("a choice from every candidate always stands")
}

/// Every candidate (an occluder set in `visible`) with its rank, in slot order.
fn rank_all(store: &BoundsStore, visible: &VisibleSet, viewpoint: Viewpoint) -> Vec<(f32, u32)> {
    // Ranking reads the bounds of every candidate: at 1e6 objects that streams much of the store, which two
    // threads do faster than one; below, waking the pool costs more than it saves. Chunks are joined in order,
    // so ties fall as they would in one pass.
    let rank_chunk = |(chunk, (visible, occluders)): (usize, (&[u64], &[u64]))| {
        // Sized once, and the chunks joined with one copy: growing each list and flattening them cost twice as
        // much (docs/performance.md).
        let candidates = visible.iter().zip(occluders).map(|(&v, &o)| (v & o).count_ones() as usize).sum();
        let mut ranked = Vec::with_capacity(candidates);
        for (i, (&visible, &occluders)) in visible.iter().zip(occluders).enumerate() {
            rank_word(store, (chunk * RANK_WORDS_PER_TASK + i) * 64, visible & occluders, viewpoint, &mut ranked);
        }
        ranked
    };
    let (visible, occluders) = (visible.words(), store.occluders().words());
    if visible.len() < RANK_IN_PARALLEL_ABOVE {
        rank_chunk((0, (visible, occluders)))
    } else {
        let chunks = visible.par_chunks(RANK_WORDS_PER_TASK).zip(occluders.par_chunks(RANK_WORDS_PER_TASK));
        let ranked: Vec<_> =
            parallel::region(|region| chunks.enumerate().map(|chunk| region.task(|| rank_chunk(chunk))).collect());
        ranked.concat()
    }
}

/// The candidates of the groups with the best bounds, ranked, in slot order: whole groups, best bound first,
/// until they hold at least `wanted` candidates. Also the threshold that every candidate left out ranks below;
/// `None` where none was left out.
///
/// Groups are taken by the binary exponent of their bound (a histogram, not a sort), so those taken reach up
/// to twice the bound needed.
fn rank_best_groups(
    store: &BoundsStore,
    visible: &VisibleSet,
    viewpoint: Viewpoint,
    wanted: usize,
) -> (Vec<(f32, u32)>, Option<f32>) {
    let (visible, occluders) = (visible.words(), store.occluders().words());
    // Bounds are never negative, so their bits order as they do, and bits >> 23 is the exponent.
    let exponent = |bound: f32| (bound.to_bits() >> 23) as usize;
    // Per chunk of groups, in order: each group's bound, and the candidates per exponent of the bound.
    let bound_chunk = |chunk: usize| {
        let words = chunk * BOUND_WORDS_PER_TASK..((chunk + 1) * BOUND_WORDS_PER_TASK).min(visible.len());
        let mut by_exponent = [0u32; 256];
        let groups: Vec<(f32, u32)> = words
            .filter(|&group| visible[group] & occluders[group] != 0)
            .map(|group| {
                let bound = group_bound(store, group, viewpoint);
                by_exponent[exponent(bound)] += (visible[group] & occluders[group]).count_ones();
                (bound, group as u32)
            })
            .collect();
        (groups, by_exponent)
    };
    let chunks = visible.len().div_ceil(BOUND_WORDS_PER_TASK);
    let bounded: Vec<BoundedGroups> = if visible.len() < RANK_IN_PARALLEL_ABOVE {
        (0..chunks).map(bound_chunk).collect()
    } else {
        parallel::region(|region| (0..chunks).into_par_iter().map(|chunk| region.task(|| bound_chunk(chunk))).collect())
    };
    let mut candidates_by_exponent = [0usize; 256];
    for (_, by_exponent) in &bounded {
        candidates_by_exponent.iter_mut().zip(by_exponent).for_each(|(total, &n)| *total += n as usize);
    }
    let mut taken = 0;
    let lowest = (0..256).rev().find(|&e| {
        taken += candidates_by_exponent[e];
        taken >= wanted
    });
    // Below the lowest exponent taken, every bound (and so every rank) is under its least value.
    let threshold = lowest.filter(|&e| e > 0 && candidates_by_exponent[..e].iter().any(|&n| n > 0));
    let least_taken = threshold.unwrap_or(0);
    let rank_chunk = |groups: &[(f32, u32)]| {
        let mut ranked = Vec::new();
        for &(_, group) in groups.iter().filter(|(bound, _)| exponent(*bound) >= least_taken) {
            let group = group as usize;
            rank_word(store, group * 64, visible[group] & occluders[group], viewpoint, &mut ranked);
        }
        ranked
    };
    let ranked = if visible.len() < RANK_IN_PARALLEL_ABOVE {
        bounded.iter().flat_map(|(groups, _)| rank_chunk(groups)).collect()
    } else {
        // The best groups crowd the chunks nearest the eye: ranked in pieces of a chunk, so that no task ranks
        // a large share of them.
        let pieces: Vec<&[(f32, u32)]> =
            bounded.iter().flat_map(|(groups, _)| groups.chunks(RANK_GROUPS_PER_TASK)).collect();
        let ranked: Vec<Vec<(f32, u32)>> = parallel::region(|region| {
            pieces.into_par_iter().map(|groups| region.task(|| rank_chunk(groups))).collect()
        });
        ranked.concat()
    };
    (ranked, threshold.map(|e| f32::from_bits((e as u32) << 23)))
}

/// A rank no occluder of `group` (the slots of one bitset word) can exceed, seen from `viewpoint`: the largest
/// occluder radius of the group squared, over the squared distance from the eye to the group's box (which holds
/// every member's centre), widened for rounding. Infinite for an eye inside the box.
fn group_bound(store: &BoundsStore, group: usize, viewpoint: Viewpoint) -> f32 {
    let radius = store.occluder_radii()[group];
    let Viewpoint::Position(eye) = viewpoint else { return radius * radius * BOUND_SLACK };
    let GroupBounds { min, max } = store.groups()[group];
    let distance_squared = (min - eye).max(eye - max).max(Vec3::ZERO).length_squared();
    if distance_squared > 0.0 { radius * radius / distance_squared * BOUND_SLACK } else { f32::INFINITY }
}

/// Chooses from `ranked` (reordered in place) as [`select_occluders`] documents. Where `threshold` says that
/// candidates ranked below it were left out, gives up (`None`) as soon as the choice would look at a candidate
/// below it, or would look past the last: the candidates left out might have changed the choice there.
fn choose<'a>(
    ranked: &mut [(f32, u32)],
    threshold: Option<f32>,
    triangle_budget: usize,
    occluder_of: &(impl Fn(usize) -> Option<OccluderInstance<'a>> + Sync),
) -> Option<Vec<(u32, OccluderInstance<'a>)>> {
    // Equal ranks in slot order, so that the choice does not depend on which candidates were ranked.
    let best_first = |a: &(f32, u32), b: &(f32, u32)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
    let mut remaining = triangle_budget;
    let mut chosen = Vec::new();
    let mut smallest_chosen = usize::MAX;
    let mut rest = ranked;
    while remaining > 0 {
        if rest.is_empty() {
            return threshold.is_none().then_some(chosen);
        }
        let round = ROUND.min(rest.len());
        if round < rest.len() {
            rest.select_nth_unstable_by(round, best_first);
        }
        let (head, tail) = rest.split_at_mut(round);
        sort_best_first(head, best_first);
        let before = chosen.len();
        let mut smallest = usize::MAX;
        'round: for batch in head.chunks(FETCH_BATCH) {
            for (&(rank, slot), instance) in batch.iter().zip(fetch_occluders(batch, occluder_of)) {
                if threshold.is_some_and(|threshold| rank < threshold) {
                    return None;
                }
                let Some(instance) = instance else { continue };
                let triangles = instance.occluder.triangle_count();
                smallest = smallest.min(triangles);
                if triangles <= remaining {
                    remaining -= triangles;
                    smallest_chosen = smallest_chosen.min(triangles);
                    chosen.push((slot, instance));
                    // With less room than the smallest occluder chosen, looking on (each look fetches an
                    // occluder, a cache miss in a large world) could fill at most that little.
                    if remaining == 0 || remaining < smallest_chosen {
                        break 'round;
                    }
                }
            }
        }
        // A round that fitted nothing, or left less room than the smallest occluder it met, ends the selection:
        // another round would rank every remaining candidate again to fill at most that little room.
        if chosen.len() == before || remaining < smallest {
            break;
        }
        rest = tail;
    }
    Some(chosen)
}

/// Sorts `ranked` by `best_first`: above [`SORT_PER_TASK`] candidates, its pieces are sorted in parallel and
/// then merged.
fn sort_best_first(
    ranked: &mut [(f32, u32)],
    best_first: impl Fn(&(f32, u32), &(f32, u32)) -> std::cmp::Ordering + Sync,
) {
    if ranked.len() <= SORT_PER_TASK {
        ranked.sort_unstable_by(best_first);
        return;
    }
    parallel::region(|region| {
        ranked.par_chunks_mut(SORT_PER_TASK).for_each(|piece| region.task(|| piece.sort_unstable_by(&best_first)));
    });
    let merged: Vec<(f32, u32)> =
        itertools::kmerge_by(ranked.chunks(SORT_PER_TASK), |a: &&(f32, u32), b: &&(f32, u32)| best_first(a, b).is_lt())
            .copied()
            .collect();
    ranked.copy_from_slice(&merged);
}

/// The occluder of each of `ranked`'s slots, in order. Each fetch is a few cache misses in a large world, and
/// a selection looks at hundreds: more than [`FETCH_PER_TASK`] are fetched in parallel.
fn fetch_occluders<'a>(
    ranked: &[(f32, u32)],
    occluder_of: &(impl Fn(usize) -> Option<OccluderInstance<'a>> + Sync),
) -> Vec<Option<OccluderInstance<'a>>> {
    let fetch = |index: usize| occluder_of(ranked[index].1 as usize);
    if ranked.len() <= FETCH_PER_TASK {
        (0..ranked.len()).map(fetch).collect()
    } else {
        parallel::map_range(ranked.len(), FETCH_PER_TASK, fetch)
    }
}

/// Appends the rank (larger is better) of each occluder candidate set in `bits` (slots from `base`) to `ranked`,
/// as seen from `viewpoint`: `radius^2 / distance^2` from an eye, leaving out occluders whose box contains it,
/// or `radius^2` from a direction.
fn rank_word(store: &BoundsStore, base: usize, mut bits: u64, viewpoint: Viewpoint, ranked: &mut Vec<(f32, u32)>) {
    let soa = store.soa();
    while bits != 0 {
        let slot = base + bits.trailing_zeros() as usize;
        bits &= bits - 1;
        let radius_squared = soa.radius[slot] * soa.radius[slot];
        let Viewpoint::Position(eye) = viewpoint else {
            ranked.push((radius_squared, slot as u32));
            continue;
        };
        let offset = Vec3::new(soa.center_x[slot], soa.center_y[slot], soa.center_z[slot]) - eye;
        let distance_squared = offset.length_squared();
        // A box holding the eye lies within its sphere (the store's radius is at least the box's circumradius),
        // so only an eye inside the sphere, with room for rounding, needs the extents: the other three arrays
        // stay unread for nearly every candidate.
        if distance_squared <= radius_squared * INSIDE_SPHERE_SLACK {
            let extent = Vec3::new(soa.extent_x[slot], soa.extent_y[slot], soa.extent_z[slot]);
            if offset.abs().cmple(extent).all() || distance_squared <= 0.0 {
                continue; // The camera is inside the object.
            }
        }
        ranked.push((radius_squared / distance_squared, slot as u32));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Mesh;

    #[test]
    fn a_cube_has_eight_distinct_vertices_and_every_edge_a_neighbour() {
        let occluder = Occluder::new(Mesh::unit_cube(1).triangle_soup());
        let (vertices, corners) = occluder.indexed();
        assert_eq!((occluder.triangle_count(), vertices.len()), (12, 8));
        let rebuilt: Vec<Vec3> = corners.iter().map(|&c| vertices[c as usize]).collect();
        assert_eq!(rebuilt, occluder.triangles());
        assert!(occluder.neighbours().iter().all(|&n| n != NO_NEIGHBOUR));
    }

    /// A store of boxes at `centres` (half extent `half`), every one an occluder.
    fn occluder_store(centres: &[Vec3], half: Vec3) -> BoundsStore {
        let mut store = BoundsStore::default();
        for (i, &centre) in centres.iter().enumerate() {
            let entity = Entity::from_raw_u32(i as u32 + 1).unwrap();
            let slot = store.insert(entity, &crate::WorldBounds::new(entity, centre, half).unwrap()).unwrap();
            store.set_occluder(slot, true).unwrap();
        }
        store
    }

    /// Selects among every slot of `store`, each occluder a cube of 12 triangles.
    fn select(store: &BoundsStore, eye: Vec3, budget: usize) -> Vec<u32> {
        let cube = Occluder::new(Mesh::unit_cube(1).triangle_soup());
        let instance = OccluderInstance { occluder: &cube, transform: glam::Affine3A::IDENTITY };
        let visible = VisibleSet::all(store.len());
        select_occluders(store, &visible, eye, budget, |_| Some(instance)).into_iter().map(|(slot, _)| slot).collect()
    }

    /// Nearest (largest on screen) first, as many as the budget holds; an occluder whose box holds the eye is
    /// left out, and one whose sphere holds the eye but whose box does not is still chosen.
    #[test]
    fn occluders_are_chosen_largest_on_screen_first_and_never_around_the_eye() {
        let half = Vec3::new(1.0, 1.0, 0.1);
        // Slot 0 holds the eye; slot 1 has the eye inside its sphere, just off its thin box; then farther ones.
        let centres = [Vec3::ZERO, Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.0, 0.0, 30.0), Vec3::new(0.0, 0.0, 9.0)];
        let store = occluder_store(&centres, half);
        assert!(store.soa().radius[1] > 0.5, "the eye must lie inside slot 1's sphere");
        assert_eq!(select(&store, Vec3::ZERO, 36), [1, 3, 2]);
        assert_eq!(select(&store, Vec3::ZERO, 24), [1, 3]);
        assert_eq!(select(&store, Vec3::ZERO, 11), [] as [u32; 0]);
    }

    /// An occluder too large for the budget is passed over; once less room is left than the smallest occluder
    /// chosen, the search stops, leaving fewer triangles than that unused.
    #[test]
    fn selection_passes_over_what_does_not_fit_and_stops_when_little_room_is_left() {
        let centres: Vec<Vec3> = (2..7).map(|d| Vec3::new(0.0, 0.0, d as f32)).collect();
        let store = occluder_store(&centres, Vec3::splat(0.5));
        let meshes: Vec<Occluder> = [100, 12, 12, 2, 12].map(|n| Occluder::new(vec![Vec3::ZERO; 3 * n])).into();
        let visible = VisibleSet::all(store.len());
        let occluder_of =
            |slot: usize| Some(OccluderInstance { occluder: &meshes[slot], transform: Default::default() });
        let chosen: Vec<u32> =
            select_occluders(&store, &visible, Vec3::ZERO, 30, occluder_of).into_iter().map(|(s, _)| s).collect();
        // 6 triangles left after slots 1 and 2, less than the 12 of the smallest chosen: slot 3's 2 are not sought.
        assert_eq!(chosen, [1, 2]);
    }

    /// Above `RANK_IN_PARALLEL_ABOVE` words the ranking runs in parallel, and 2000 chosen take eight batches of
    /// fetched occluders: the choice is still the best ranked occluders, as a sort of every candidate gives them.
    #[test]
    fn a_store_ranked_in_parallel_chooses_as_a_full_sort_does() {
        let count = RANK_IN_PARALLEL_ABOVE * 64 + 1000;
        // Distinct distances along a scrambled order, so that no two ranks tie.
        let centres: Vec<Vec3> =
            (0..count).map(|i| Vec3::new(((i * 7919) % count) as f32 * 0.5 + 10.0, 0.0, 0.0)).collect();
        let store = occluder_store(&centres, Vec3::splat(0.5));
        let mut nearest: Vec<u32> = (0..count as u32).collect();
        nearest.sort_by(|&a, &b| centres[a as usize].x.total_cmp(&centres[b as usize].x));
        assert_eq!(select(&store, Vec3::ZERO, 12 * 2000), nearest[..2000]);
    }

    /// Choosing from the candidates of the groups that can rank best gives what ranking every candidate gives:
    /// from an eye far off, one among the objects, and a direction; for budgets that take a few occluders, and
    /// nearly all (where the first candidates cannot do, and every candidate is ranked).
    #[test]
    fn choosing_from_the_best_groups_chooses_as_ranking_every_candidate_does() {
        // 20,000 boxes of scattered places and sizes, three in four of them occluders, of 12 or 2 triangles.
        // Each run of 64 slots lies in its own cell of a grid, as spawning a world place by place leaves it.
        let mut store = BoundsStore::default();
        let scatter = |i: usize, salt: usize| ((i * 7919 + salt * 104_729) % 10_007) as f32 / 10_007.0;
        for i in 0..20_000 {
            let entity = Entity::from_raw_u32(i as u32 + 1).unwrap();
            let cell = Vec3::new((i / 64 % 18) as f32, 0.0, (i / 64 / 18) as f32) * 100.0;
            let centre = cell + Vec3::new(scatter(i, 1), scatter(i, 2) * 0.5, scatter(i, 3)) * 10.0;
            // Sizes vary more from group to group than within one, so bounds are nearly reached.
            let half = Vec3::splat(1.0 + scatter(i / 64, 4) * 20.0) + Vec3::splat(scatter(i, 5));
            let slot = store.insert(entity, &crate::WorldBounds::new(entity, centre, half).unwrap()).unwrap();
            store.set_occluder(slot, i % 4 != 0).unwrap();
        }
        let visible = VisibleSet::all(store.len());
        let meshes = [12, 2].map(|n| Occluder::new(vec![Vec3::ZERO; 3 * n]));
        let occluder_of = |slot: usize| {
            let occluder = &meshes[slot.is_multiple_of(3) as usize];
            Some(OccluderInstance { occluder, transform: Default::default() })
        };
        let among_objects = store.get(5).unwrap().center + Vec3::new(0.0, 0.0, 1.0);
        let viewpoints = [
            Viewpoint::Position(Vec3::new(-300.0, 10.0, -100.0)),
            Viewpoint::Position(among_objects),
            Viewpoint::Direction,
        ];
        for (v, viewpoint) in viewpoints.into_iter().enumerate() {
            for budget in [600, 4096, 200_000] {
                let slots = |chosen: Vec<(u32, OccluderInstance)>| chosen.into_iter().map(|(s, _)| s).collect();
                let mut ranked = rank_all(&store, &visible, viewpoint);
                for &(rank, slot) in &ranked {
                    let bound = group_bound(&store, slot as usize / 64, viewpoint);
                    assert!(rank <= bound, "viewpoint {v}: slot {slot} ranks {rank}, above its group's {bound}");
                }
                let all: Vec<u32> = slots(choose(&mut ranked, None, budget, &occluder_of).unwrap());
                // A budget for nearly all: the first candidates, here the fewest, cannot do.
                let wanted = if budget < 200_000 { FIRST_CANDIDATES.max(budget / 4) } else { 64 };
                let (mut best, threshold) = rank_best_groups(&store, &visible, viewpoint, wanted);
                assert!(threshold.is_some() && best.len() < 15_000 / 2, "viewpoint {v}: {} ranked first", best.len());
                let from_best = choose(&mut best, threshold, budget, &occluder_of).map(slots);
                let stands = budget < 200_000;
                assert_eq!(from_best.as_ref(), stands.then_some(&all), "viewpoint {v}, budget {budget}");
                let selected: Vec<u32> = slots(select_ranked(&store, &visible, viewpoint, budget, occluder_of));
                assert_eq!(selected, all, "viewpoint {v}, budget {budget}");
            }
        }
    }

    #[test]
    fn a_trailing_partial_triangle_is_dropped_everywhere() {
        let soup = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z, Vec3::ONE];
        let occluder = Occluder::new(soup);
        let (vertices, corners) = occluder.indexed();
        assert_eq!(occluder.triangles(), &[Vec3::ZERO, Vec3::X, Vec3::Y]);
        assert_eq!((occluder.neighbours().len(), corners.len(), vertices.len()), (3, 3, 3));
        assert!(occluder.neighbours().iter().all(|&n| n == NO_NEIGHBOUR));
    }
}
