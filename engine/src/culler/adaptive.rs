//! What a view's culler remembers to skip work that cannot pay off: the benefit gate that skips a stage
//! removing too little, and the choice between re-testing moved objects alone or in a full pass.

use super::AdaptiveSettings;
use crate::bounds::BoundsStore;
use crate::frustum::{Frustum, FrustumOptions, PlaneCoherence, cull_frustum};
use crate::visible::VisibleSet;
use std::time::{Duration, Instant};

/// Skips a stage that keeps removing too little: after `low_benefit_frames` frames in a row under the benefit
/// threshold, the stage is skipped for `reprobe_every` frames, then runs again to re-probe.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BenefitGate {
    /// Consecutive frames the stage removed less than the threshold.
    low_frames: u32,
    /// Frames left to skip the stage before re-probing it.
    skip_left: u32,
}

impl BenefitGate {
    /// Whether the stage is skipped this frame; call once a frame.
    pub fn skip_this_frame(&mut self) -> bool {
        let skip = self.skip_left > 0;
        self.skip_left = self.skip_left.saturating_sub(1);
        skip
    }

    /// Runs the stage again from the next frame on, forgetting what it removed lately: for a view that
    /// changed too much for that to say anything.
    pub fn reopen(&mut self) {
        *self = Self::default();
    }

    /// Records a frame the stage ran, removing `removed` of the `tested` items, against `min_benefit` (a
    /// fraction): after `low_benefit_frames` such frames in a row the stage is skipped for `reprobe_every`
    /// frames. A frame with nothing tested says nothing and is not counted.
    pub fn record(
        &mut self,
        removed: usize,
        tested: usize,
        min_benefit: f32,
        low_benefit_frames: u32,
        reprobe_every: u32,
    ) {
        if tested == 0 {
            return;
        }
        if (removed as f32) < min_benefit * tested as f32 {
            self.low_frames += 1;
            if self.low_frames >= low_benefit_frames {
                self.low_frames = 0;
                self.skip_left = reprobe_every;
            }
        } else {
            self.low_frames = 0;
        }
    }

    /// Records a frame an occlusion stage ran, removing `removed` of the `tested` objects that reached it,
    /// against `adaptive`'s [`AdaptiveSettings::min_occlusion_benefit`], frames and re-probes.
    pub fn record_occlusion(&mut self, removed: usize, tested: usize, adaptive: &AdaptiveSettings) {
        let (frames, reprobe) = (adaptive.low_benefit_frames, adaptive.reprobe_every);
        self.record(removed, tested, adaptive.min_occlusion_benefit, frames, reprobe);
    }
}

/// How the frustum stage re-tests a frame where only some objects moved: each moved object alone
/// ([`crate::frustum::FrustumOptions::only`]), or the full pass over the store, which gives the others their results
/// again. Each costs what it last cost. One by one, a moved object's bounds come from scattered slots, which costs more
/// per object once the store outgrows the caches; the full pass reads the store in order and skips whole
/// groups outside the view. Neither wins at every store size (docs/performance.md), so each is timed as it runs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RetestCost {
    /// What re-testing one by one costs, per moved object.
    alone: WayCost,
    /// What the full pass costs, per stored object.
    full: WayCost,
    /// Choices made so far.
    choices: u32,
}

/// What one way of re-testing costs per object, in seconds, smoothed; none before two measurements.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct WayCost {
    per_object: Option<f64>,
    measured: u32,
}

impl WayCost {
    /// Folds `time` over `count` objects in, half and half, so that one disturbed frame moves the choice less.
    /// The first measurement is dropped: it runs on cold caches (at 1e6 objects the first full pass took
    /// several times the next ones).
    fn record(&mut self, time: Duration, count: usize) {
        if count == 0 {
            return;
        }
        self.measured += 1;
        if self.measured > 1 {
            let sample = time.as_secs_f64() / count as f64;
            self.per_object = Some(self.per_object.map_or(sample, |cost| (cost + sample) * 0.5));
        }
    }
}

/// Every this many choices [`RetestCost`] takes the way that costs more, to keep its cost current: one
/// measured for another view would otherwise keep the choice wrong.
const RETEST_PROBE_EVERY: u32 = 32;

impl RetestCost {
    /// Chooses, for a frame that re-tests `moved` of `objects` objects, between testing them one by one (`true`)
    /// and the full pass. Until each way has a cost, the one without (one by one first); then the way that cost
    /// less, except every 32nd call, which takes the other. Call once a frame that re-tests, then record what
    /// the way taken cost.
    pub fn choose_alone(&mut self, moved: usize, objects: usize) -> bool {
        self.choices = self.choices.wrapping_add(1);
        match (self.alone.per_object, self.full.per_object) {
            (None, _) => true,
            (_, None) => false,
            (Some(alone), Some(full)) => {
                let cheaper = moved as f64 * alone <= objects as f64 * full;
                cheaper != self.choices.is_multiple_of(RETEST_PROBE_EVERY)
            }
        }
    }

    /// Records a re-test of `moved` objects one by one that took `time`.
    pub fn record_alone(&mut self, time: Duration, moved: usize) {
        self.alone.record(time, moved);
    }

    /// Records a full pass over `objects` that took `time`.
    pub fn record_full(&mut self, time: Duration, objects: usize) {
        self.full.record(time, objects);
    }

    /// Re-tests the store slots `moved` against `frustum` into `visible`, which holds the result of the same
    /// frustum before they moved: one by one or in a full pass (with `coherence` where given), as
    /// [`RetestCost::choose_alone`] chooses, recording what it cost. Both give the same bits.
    pub fn retest_frustum(
        &mut self,
        store: &BoundsStore,
        frustum: &Frustum,
        moved: &[u32],
        coherence: Option<&mut PlaneCoherence>,
        visible: &mut VisibleSet,
    ) {
        let start = Instant::now();
        if self.choose_alone(moved.len(), store.len()) {
            cull_frustum(store, frustum, FrustumOptions { only: Some(moved), ..Default::default() }, visible);
            self.record_alone(start.elapsed(), moved.len());
        } else {
            cull_frustum(store, frustum, FrustumOptions { coherence, ..Default::default() }, visible);
            self.record_full(start.elapsed(), store.len());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each way is measured (its first, cold measurement dropped) before they are compared; then the one that
    /// costs less for this many moved objects, a disturbed measurement moving the estimate halfway, and every
    /// 32nd choice the other way.
    #[test]
    fn moved_objects_are_re_tested_the_way_that_last_cost_less() {
        let mut cost = RetestCost::default();
        // Asks `cost` for `moved` of 1000 objects, past any probe, and says whether one by one was chosen.
        let choose = |cost: &mut RetestCost, moved: usize| {
            if (cost.choices + 1).is_multiple_of(RETEST_PROBE_EVERY) {
                cost.choose_alone(moved, 1000);
            }
            cost.choose_alone(moved, 1000)
        };
        cost.record_full(Duration::from_millis(1), 1000); // cold: dropped
        cost.record_full(Duration::from_micros(1), 1000); // 1 ns an object
        assert!(choose(&mut cost, 1_000_000), "one by one is not measured yet");
        cost.record_alone(Duration::from_micros(50), 50); // cold: dropped
        assert!(choose(&mut cost, 1_000_000), "nor yet");
        cost.record_alone(Duration::from_nanos(400), 50); // 8 ns a moved object
        assert!(choose(&mut cost, 100) && !choose(&mut cost, 150));
        cost.record_full(Duration::from_micros(5), 1000); // 5 ns once: 3 ns smoothed
        assert!(choose(&mut cost, 350) && !choose(&mut cost, 400));
        cost.record_alone(Duration::ZERO, 0); // nothing moved: nothing learnt
        assert!(choose(&mut cost, 350) && !choose(&mut cost, 400));
        // The probes: every 32nd choice goes the other way.
        let picks: Vec<bool> = (0..64).map(|_| cost.choose_alone(100, 1000)).collect();
        assert_eq!(picks.iter().filter(|&&alone| !alone).count(), 2);
        // The full pass is measured first where one by one already is.
        let mut fresh = RetestCost::default();
        fresh.record_alone(Duration::from_nanos(400), 50);
        fresh.record_alone(Duration::from_nanos(400), 50);
        assert!(!fresh.choose_alone(1, 1000));
    }
}
