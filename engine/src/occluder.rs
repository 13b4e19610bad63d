//! Stage 3a, occluder selection: which artist occluders to rasterize this frame.
//!
//! 1. Frustum: an occluder lies inside its object's bounds, so one whose object the frustum stage culled is
//!    skipped.
//! 2. Inside: an occluder whose object's box contains the camera is skipped. From inside an object its
//!    surface hides nothing (a renderer culls the back faces the camera sees), even if the camera is outside
//!    the occluder.
//! 3. Rank: by the solid-angle estimate of Coorg and Teller (seed 002), `area / distance^2`, taken for the
//!    object's bounding sphere as `radius^2 / distance^2` (distance to the box centre).
//! 4. Budget: occluders are taken best-first while their triangles fit in the budget; one that does not fit
//!    is skipped and smaller ones after it may still fill the budget (see [`select_occluders`]).

use crate::bounds::BoundsStore;
use crate::raster::OccluderInstance;
use crate::visible::VisibleSet;
use glam::Vec3;

/// Candidates ordered per round of selection: enough to fill most budgets in one round.
const ROUND: usize = 1024;

/// Picks the occluders to rasterize: among store slots marked as occluders ([`BoundsStore::occluders`])
/// that the frustum kept and whose box does not contain the camera, best-first while their triangles fit in
/// `triangle_budget`. `occluder_of` gives a slot's occluder mesh and transform. Returns the chosen slots with
/// their occluders, best first.
///
/// Candidates are found with a bitwise AND and ranked from the store's arrays; only the best are ordered, a
/// round of [`ROUND`] at a time, until the budget is full or a whole round fits nothing more.
pub fn select_occluders<'a>(
    store: &BoundsStore,
    frustum_visible: &VisibleSet,
    camera_position: Vec3,
    triangle_budget: usize,
    occluder_of: impl Fn(usize) -> Option<OccluderInstance<'a>>,
) -> Vec<(u32, OccluderInstance<'a>)> {
    let mut ranked: Vec<(f32, u32)> = Vec::new();
    for (word_index, (&visible, &occluders)) in
        frustum_visible.words().iter().zip(store.occluders().words()).enumerate()
    {
        let mut bits = visible & occluders;
        while bits != 0 {
            let slot = word_index * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let offset = Vec3::new(store.center_x[slot], store.center_y[slot], store.center_z[slot]) - camera_position;
            let extent = Vec3::new(store.extent_x[slot], store.extent_y[slot], store.extent_z[slot]);
            let distance_squared = offset.length_squared();
            if offset.abs().cmple(extent).all() || distance_squared <= 0.0 {
                continue; // The camera is inside the object.
            }
            ranked.push((store.radius[slot] * store.radius[slot] / distance_squared, slot as u32));
        }
    }
    let best_first = |a: &(f32, u32), b: &(f32, u32)| b.0.total_cmp(&a.0);
    let mut remaining = triangle_budget;
    let mut chosen = Vec::new();
    let mut rest = &mut ranked[..];
    while remaining > 0 && !rest.is_empty() {
        let round = ROUND.min(rest.len());
        if round < rest.len() {
            rest.select_nth_unstable_by(round, best_first);
        }
        let (head, tail) = rest.split_at_mut(round);
        head.sort_unstable_by(best_first);
        let before = chosen.len();
        for &(_, slot) in head.iter() {
            let Some(instance) = occluder_of(slot as usize) else { continue };
            let triangles = instance.occluder.triangle_count();
            if triangles <= remaining {
                remaining -= triangles;
                chosen.push((slot, instance));
                if remaining == 0 {
                    break;
                }
            }
        }
        if chosen.len() == before {
            break; // A whole round fitted nothing: the budget is as full as it gets.
        }
        rest = tail;
    }
    chosen
}
