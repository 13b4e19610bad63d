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
//!    is skipped and smaller ones after it may still fill the budget.

use crate::bounds::{BoundsStore, Occluder};
use crate::visible::VisibleSet;
use bevy_ecs::entity::Entity;
use glam::{Affine3A, Vec3};

/// An occluder as the selection sees it: its object's store slot, its triangles and transform.
#[derive(Clone, Debug)]
pub struct OccluderEntry<'a> {
    /// The owning entity.
    pub entity: Entity,
    /// Store slot of the owning object.
    pub slot: usize,
    /// The occluder's local triangles.
    pub occluder: &'a Occluder,
    /// Local-to-world transform.
    pub transform: Affine3A,
}

/// Orders `candidates` best-first and keeps those that pass the frustum and inside tests and fit in
/// `triangle_budget` triangles. Returns indices into `candidates`.
pub fn select_occluders(
    candidates: &[OccluderEntry<'_>],
    store: &BoundsStore,
    frustum_visible: &VisibleSet,
    camera_position: Vec3,
    triangle_budget: usize,
) -> Vec<usize> {
    let mut ranked: Vec<(f32, usize)> = candidates
        .iter()
        .enumerate()
        .filter(|(_, entry)| frustum_visible.contains(entry.slot))
        .filter_map(|(index, entry)| {
            let bounds = store.get(entry.slot);
            let offset = bounds.center - camera_position;
            let inside = offset.abs().cmple(bounds.half_extent).all();
            let distance_squared = offset.length_squared();
            (!inside && distance_squared > 0.0).then(|| (bounds.radius * bounds.radius / distance_squared, index))
        })
        .collect();
    let best_first = |a: &(f32, usize), b: &(f32, usize)| b.0.total_cmp(&a.0);
    // Only the best few can fit the budget: order just enough of them (at least one triangle each), and the
    // rest only if the budget is still not full.
    let smallest = ranked.iter().map(|&(_, i)| candidates[i].occluder.triangle_count()).min().unwrap_or(1).max(1);
    let head = (triangle_budget / smallest + 1).min(ranked.len());
    if head < ranked.len() {
        ranked.select_nth_unstable_by(head, best_first);
    }
    ranked[..head].sort_unstable_by(best_first);
    let mut remaining = triangle_budget;
    let mut chosen = Vec::new();
    let mut take = |ranked: &[(f32, usize)], remaining: &mut usize| {
        for &(_, index) in ranked {
            let triangles = candidates[index].occluder.triangle_count();
            if triangles <= *remaining {
                *remaining -= triangles;
                chosen.push(index);
            }
            if *remaining == 0 {
                return;
            }
        }
    };
    take(&ranked[..head], &mut remaining);
    if remaining > 0 && head < ranked.len() {
        ranked[head..].sort_unstable_by(best_first);
        take(&ranked[head..], &mut remaining);
    }
    chosen
}
