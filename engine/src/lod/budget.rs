//! Time-critical rendering (Funkhouser and Sequin): where the threshold's levels come to more triangles than
//! the frame's budget, levels are chosen again best-first by benefit over cost, and the frame never goes over.
//!
//! Every kept object starts at its coarsest level. Where even that is over the budget, the objects smallest on
//! screen are dropped until it fits. Then, greedily, the refinement that removes the most projected error (in
//! pixels) per triangle added is taken while it fits, never finer than the threshold's level. A refinement
//! back towards the level an object had last frame counts for more (by the hysteresis), so that the choice
//! stays put while the view does.

use super::LodSelection;
use super::library::ChainTable;
use super::select::SelectionFrame;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// One kept object with levels, during the fit.
struct Candidate {
    slot: u32,
    /// Pixels a unit of the mesh's error projects to (infinite with the eye inside it).
    pixels_per_error: f32,
    /// Its projected diameter in pixels.
    size: f32,
    /// The threshold's level: the budget never refines past it.
    finest: u8,
}

/// A refinement of one object by one level, ordered by benefit over cost.
struct Refinement {
    priority: f32,
    candidate: usize,
}

impl PartialEq for Refinement {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Refinement {}
impl PartialOrd for Refinement {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Refinement {
    fn cmp(&self, other: &Self) -> Ordering {
        self.priority.total_cmp(&other.priority).then(other.candidate.cmp(&self.candidate))
    }
}

impl LodSelection {
    /// Rechooses the levels of `visible` so that their triangles come to at most `budget`; `previous` holds
    /// every slot's level before this frame's selection. Fills the stats and changed slots again.
    pub(super) fn fit_budget(&mut self, frame: &SelectionFrame<'_>, budget: u64, previous: &[u8]) {
        let SelectionFrame { library, store, camera, visible, settings, focal } = *frame;
        let soa = store.soa();
        let eye = camera.position;
        let boost = 1.0 / (1.0 - settings.hysteresis.clamp(0.0, 0.99));
        let table = |slot: usize| library.chains.get(*self.chain.get(slot)? as usize);
        let mut candidates: Vec<Candidate> = visible
            .iter()
            .filter(|&slot| slot < store.len() && table(slot).is_some())
            .map(|slot| {
                let centre = glam::Vec3::new(soa.center_x[slot], soa.center_y[slot], soa.center_z[slot]);
                let nearest = ((centre - eye).length() - soa.radius[slot]).max(0.0);
                let pixels_per_error = focal * self.scale[slot] / nearest;
                let size = 2.0 * focal * soa.radius[slot] / nearest;
                Candidate { slot: slot as u32, pixels_per_error, size, finest: self.level[slot] }
            })
            .collect();
        // Start from every object's coarsest level; drop the smallest on screen while even that is over.
        let coarsest = |c: &Candidate| {
            let t = table(c.slot as usize).expect("candidates have tables");
            (t, t.levels - 1)
        };
        let mut total: u64 = candidates.iter().map(|c| coarsest(c).0.triangles[coarsest(c).1 as usize] as u64).sum();
        candidates.sort_by(|a, b| b.size.total_cmp(&a.size).then(a.slot.cmp(&b.slot)));
        while total > budget {
            let Some(smallest) = candidates.pop() else { break };
            let (t, level) = coarsest(&smallest);
            total -= t.triangles[level as usize] as u64;
            self.dropped.set(smallest.slot as usize, true);
        }
        let mut levels: Vec<u8> = candidates.iter().map(|c| coarsest(c).1).collect();
        let priority = |c: &Candidate, t: &ChainTable, level: u8| {
            let gained = (t.error[level as usize] - t.error[level as usize - 1]) * c.pixels_per_error;
            let cost = t.triangles[level as usize - 1].saturating_sub(t.triangles[level as usize]).max(1) as f32;
            let back = previous[c.slot as usize] < level;
            let benefit = if gained.is_finite() { gained } else { f32::MAX };
            benefit / cost * if back { boost } else { 1.0 }
        };
        let mut heap: BinaryHeap<Refinement> = candidates
            .iter()
            .enumerate()
            .filter(|(i, c)| levels[*i] > c.finest)
            .map(|(i, c)| Refinement { priority: priority(c, coarsest(c).0, levels[i]), candidate: i })
            .collect();
        while let Some(Refinement { candidate, .. }) = heap.pop() {
            let c = &candidates[candidate];
            let t = coarsest(c).0;
            let level = levels[candidate];
            let added = t.triangles[level as usize - 1].saturating_sub(t.triangles[level as usize]) as u64;
            if total + added > budget {
                continue;
            }
            total += added;
            levels[candidate] = level - 1;
            if level - 1 > c.finest {
                heap.push(Refinement { priority: priority(c, t, level - 1), candidate });
            }
        }
        for (c, &level) in candidates.iter().zip(&levels) {
            self.level[c.slot as usize] = level;
        }
        // Stats and changes against the last frame, over every kept object (the dropped draw nothing).
        self.changed.clear();
        let (mut switches, mut triangles) = (0, 0);
        for slot in visible.iter().take_while(|&slot| slot < store.len()) {
            let Some(t) = table(slot) else { continue };
            if !self.dropped.contains(slot) {
                triangles += t.triangles[self.level[slot] as usize] as u64;
            }
            if self.level[slot] != previous[slot] {
                self.changed.push(slot as u32);
                switches += (previous[slot] != u8::MAX) as usize;
            }
        }
        self.stats.triangles = triangles;
        self.stats.switches = switches;
        self.stats.dropped = self.dropped.count();
        debug_assert!(triangles <= budget);
    }
}
