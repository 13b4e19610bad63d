//! Accuracy of the culling stages against the exact visible set, per frame and over a camera path.
//!
//! Stages are given in pipeline order, each with the set of objects still kept after it (so each set is a
//! subset of the one before). For each:
//! - **false negatives**: visible objects it culled (0 in conservative modes), each listed with the first
//!   stage that culled it;
//! - **false positives**: objects it kept that are not visible;
//! - **culling efficiency**: objects culled up to and including it over the objects that could be culled,
//!   `culled / (objects - visible)` (1 when nothing is cullable).
//!
//! Besides: **image error**, the pixels that change when only the kept objects are drawn, and **occlusion
//! efficiency**, objects the occlusion stage culled over objects an exact full-resolution buffer of the same
//! occluders culls ([`crate::occluders`]).

use crate::render::ExactVisibility;
use cullet::VisibleSet;

/// One stage's result, cumulative over the stages up to it.
#[derive(Clone, Debug, PartialEq)]
pub struct StageMetrics {
    /// Stage name.
    pub name: &'static str,
    /// Objects kept after it.
    pub kept: usize,
    /// Kept objects that are not visible.
    pub false_positives: usize,
    /// Visible objects culled by it or an earlier stage.
    pub false_negatives: usize,
    /// `culled / (objects - visible)`.
    pub efficiency: f64,
}

/// A visible object that a stage culled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FalseNegative {
    /// The object's index (a store slot when judged by [`crate::judge_frame`]).
    pub object: usize,
    /// The first stage that culled it.
    pub stage: &'static str,
}

/// How the occlusion stage compares with an exact full-resolution buffer of the same occluders.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OcclusionIdeal {
    /// Frustum survivors the occlusion stage culled.
    pub culled: usize,
    /// Frustum survivors the exact buffer culls.
    pub ideal_culled: usize,
}

/// Accuracy of one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMetrics {
    /// Objects in the scene.
    pub objects: usize,
    /// Objects in the exact visible set.
    pub visible: usize,
    /// Per stage, in pipeline order.
    pub stages: Vec<StageMetrics>,
    /// Every visible object some stage culled.
    pub false_negatives: Vec<FalseNegative>,
    /// Pixels whose object changes when only the last stage's survivors are drawn.
    pub image_error_pixels: usize,
    /// Occlusion against its ideal, where measured.
    pub occlusion_ideal: Option<OcclusionIdeal>,
}

impl FrameMetrics {
    /// Judges `stages` (name and objects kept after it, in pipeline order) against the exact visibility
    /// `truth`.
    pub fn new(truth: &ExactVisibility, stages: &[(&'static str, &VisibleSet)]) -> Self {
        let visible = &truth.visible;
        let objects = visible.len();
        let visible_count = visible.count();
        let cullable = objects - visible_count;
        let mut false_negatives = Vec::new();
        let mut reported = VisibleSet::new(objects);
        let mut metrics = Vec::with_capacity(stages.len());
        for &(name, kept) in stages {
            let mut stage_false_negatives = 0;
            let mut false_positives = 0;
            for (word, (&truth_word, &kept_word)) in visible.words().iter().zip(kept.words()).enumerate() {
                false_positives += (kept_word & !truth_word).count_ones() as usize;
                let mut missed = truth_word & !kept_word;
                stage_false_negatives += missed.count_ones() as usize;
                while missed != 0 {
                    let object = word * 64 + missed.trailing_zeros() as usize;
                    missed &= missed - 1;
                    if !reported.contains(object) {
                        reported.set(object, true);
                        false_negatives.push(FalseNegative { object, stage: name });
                    }
                }
            }
            let kept_count = kept.count();
            let culled = objects - kept_count;
            let efficiency = if cullable == 0 { 1.0 } else { culled as f64 / cullable as f64 };
            metrics.push(StageMetrics {
                name,
                kept: kept_count,
                false_positives,
                false_negatives: stage_false_negatives,
                efficiency,
            });
        }
        let image_error_pixels = stages.last().map_or(0, |(_, kept)| truth.pixels_lost(kept));
        Self {
            objects,
            visible: visible_count,
            stages: metrics,
            false_negatives,
            image_error_pixels,
            occlusion_ideal: None,
        }
    }
}

/// Totals over the frames of a camera path; ratios are of sums, so busy frames weigh more.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PathMetrics {
    /// Frames added.
    pub frames: usize,
    /// Sum of objects over frames.
    pub objects: usize,
    /// Sum of visible objects over frames.
    pub visible: usize,
    /// Per stage: name, sum of objects culled, sum of false positives.
    pub stages: Vec<(&'static str, usize, usize)>,
    /// Sum of false negatives (of the last stage) over frames.
    pub false_negatives: usize,
    /// Frames with at least one false negative.
    pub frames_with_false_negatives: usize,
    /// Sum of image-error pixels.
    pub image_error_pixels: usize,
    /// Largest image error of one frame.
    pub worst_image_error_pixels: usize,
    /// Sums of occlusion against its ideal, over the frames where it was measured.
    pub occlusion_ideal: OcclusionIdeal,
}

impl PathMetrics {
    /// Adds one frame.
    pub fn add(&mut self, frame: &FrameMetrics) {
        self.frames += 1;
        self.objects += frame.objects;
        self.visible += frame.visible;
        self.stages.resize(frame.stages.len(), ("", 0, 0));
        for (total, stage) in self.stages.iter_mut().zip(&frame.stages) {
            *total = (stage.name, total.1 + frame.objects - stage.kept, total.2 + stage.false_positives);
        }
        self.false_negatives += frame.false_negatives.len();
        self.frames_with_false_negatives += usize::from(!frame.false_negatives.is_empty());
        self.image_error_pixels += frame.image_error_pixels;
        self.worst_image_error_pixels = self.worst_image_error_pixels.max(frame.image_error_pixels);
        if let Some(ideal) = frame.occlusion_ideal {
            self.occlusion_ideal.culled += ideal.culled;
            self.occlusion_ideal.ideal_culled += ideal.ideal_culled;
        }
    }

    /// Culling efficiency of stage `index` over the path: culled over cullable, summed over frames.
    pub fn efficiency(&self, index: usize) -> f64 {
        let cullable = self.objects - self.visible;
        if cullable == 0 { 1.0 } else { self.stages[index].1 as f64 / cullable as f64 }
    }

    /// Culling efficiency of the last stage over the path, the culler's result whatever its stages (a
    /// culler of one stage, such as frustum only, has one); 1 with no stage judged.
    pub fn final_efficiency(&self) -> f64 {
        self.stages.len().checked_sub(1).map_or(1.0, |last| self.efficiency(last))
    }

    /// Objects the occlusion stage culled over those an exact buffer of the same occluders culls, or `None`
    /// when the ideal culled nothing.
    pub fn occlusion_efficiency(&self) -> Option<f64> {
        let ideal = self.occlusion_ideal;
        (ideal.ideal_culled > 0).then(|| ideal.culled as f64 / ideal.ideal_culled as f64)
    }
}
