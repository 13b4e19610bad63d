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
//! 4. Budget: occluders are taken best-first while their triangles fit in the budget; one that does not fit
//!    is skipped and smaller ones after it may still fill the budget, until less room is left than the
//!    smallest occluder taken (see [`select_occluders`]).

use crate::bounds::BoundsStore;
use crate::depth::ScreenView;
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
#[derive(Component, Clone, Debug, PartialEq)]
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
/// Relative room for f32 rounding when telling whether the eye may be inside an occluder's sphere: the squared
/// distance and radius are each within a few ulps of their exact values.
const INSIDE_SPHERE_SLACK: f32 = 1.0 + 1e-4;
/// Bitset words (of 64 slots) one thread ranks at a time.
const RANK_WORDS_PER_TASK: usize = 256;
/// Bitset words above which ranking runs in parallel (about 260,000 objects). Measured in one interleaved run
/// on the city's fly-through (`cullet-game --headless --cpu-only --fixed-pipeline`, 2 threads, median of 120
/// frames, three runs each): at 1e6 objects ranking took 0.44-0.47 ms in parallel against 0.51-0.58 ms in one
/// pass; at 1e5, 45-51 us against 22-45 us.
const RANK_IN_PARALLEL_ABOVE: usize = 4096;

/// Picks the occluders to rasterize: among store slots marked as occluders ([`BoundsStore::occluders`])
/// that the frustum kept and whose box does not contain the camera, best-first while their triangles fit in
/// `triangle_budget`. `occluder_of` gives a slot's occluder mesh and transform. Returns the chosen slots with
/// their occluders, best first.
///
/// Candidates are found with a bitwise AND and ranked from the store's arrays; only the best are ordered, a
/// round of `ROUND` (1024) at a time, until the budget is full, it has less room left than the smallest
/// occluder chosen, a whole round fits nothing more, or a round leaves less room than the smallest occluder it
/// met (so at most that many triangles of the budget go unused).
pub fn select_occluders<'a>(
    store: &BoundsStore,
    frustum_visible: &VisibleSet,
    camera_position: Vec3,
    triangle_budget: usize,
    occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>>,
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
    occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>>,
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
fn select_ranked<'a>(
    store: &BoundsStore,
    visible: &VisibleSet,
    viewpoint: Viewpoint,
    triangle_budget: usize,
    occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>>,
) -> Vec<(u32, OccluderInstance<'a>)> {
    // Ranking reads the bounds of every candidate: at 1e6 objects that streams much of the store, which two
    // threads do faster than one; below, waking the pool costs more than it saves. Chunks are joined in order,
    // so ties fall as they would in one pass.
    let rank_chunk = |(chunk, (visible, occluders)): (usize, (&[u64], &[u64]))| {
        // Sized once, and the chunks joined with one copy: growing each list and flattening them took 0.51-0.62
        // ms a frame for the 1e6 fly-through's 46,500 candidates, this 0.26 ms (Bevy plugin bench).
        let candidates = visible.iter().zip(occluders).map(|(&v, &o)| (v & o).count_ones() as usize).sum();
        let mut ranked = Vec::with_capacity(candidates);
        for (i, (&visible, &occluders)) in visible.iter().zip(occluders).enumerate() {
            rank_word(store, (chunk * RANK_WORDS_PER_TASK + i) * 64, visible & occluders, viewpoint, &mut ranked);
        }
        ranked
    };
    let (visible, occluders) = (visible.words(), store.occluders().words());
    let mut ranked: Vec<(f32, u32)> = if visible.len() < RANK_IN_PARALLEL_ABOVE {
        rank_chunk((0, (visible, occluders)))
    } else {
        let chunks = visible.par_chunks(RANK_WORDS_PER_TASK).zip(occluders.par_chunks(RANK_WORDS_PER_TASK));
        chunks.enumerate().map(rank_chunk).collect::<Vec<_>>().concat()
    };
    let best_first = |a: &(f32, u32), b: &(f32, u32)| b.0.total_cmp(&a.0);
    let mut remaining = triangle_budget;
    let mut chosen = Vec::new();
    let mut smallest_chosen = usize::MAX;
    let mut rest = &mut ranked[..];
    while remaining > 0 && !rest.is_empty() {
        let round = ROUND.min(rest.len());
        if round < rest.len() {
            rest.select_nth_unstable_by(round, best_first);
        }
        let (head, tail) = rest.split_at_mut(round);
        head.sort_unstable_by(best_first);
        let before = chosen.len();
        let mut smallest = usize::MAX;
        for &(_, slot) in head.iter() {
            let Some(instance) = occluder_of(slot as usize) else { continue };
            let triangles = instance.occluder.triangle_count();
            smallest = smallest.min(triangles);
            if triangles <= remaining {
                remaining -= triangles;
                smallest_chosen = smallest_chosen.min(triangles);
                chosen.push((slot, instance));
                // With less room than the smallest occluder chosen, looking on (each look fetches an occluder,
                // a cache miss in a large world) could fill at most that little.
                if remaining == 0 || remaining < smallest_chosen {
                    break;
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
    chosen
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

    /// Above `RANK_IN_PARALLEL_ABOVE` words the ranking runs in parallel: the choice is still the best ranked
    /// occluders, as a sort of every candidate gives them.
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
