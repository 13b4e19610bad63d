//! # Cullet ground truth
//!
//! The judge the culling engine is measured against; shared by the tests, the benchmarks and the game's
//! validate mode. It is deliberately simple and slow next to the engine: every object's real triangles are
//! rasterized at full resolution in f64 and nothing is approximated.
//!
//! - [`render`]: the exact visible set. Each object's triangles go into an object-ID (and triangle-ID)
//!   buffer at full resolution (1920x1080 by default), with exact edge functions, the top-left fill rule and
//!   f64 `1/w` depth. An object, or a triangle, is visible when it owns at least one pixel.
//! - [`occluders`]: the ideal the low-resolution occlusion buffer is compared with: the same occluders in an
//!   exact full-resolution depth buffer, and the same box test against it.
//! - [`metrics`]: false negatives (with the stage that culled them), false positives, culling efficiency per
//!   stage, occlusion efficiency against the ideal, and image error; per frame and over a camera path.
//! - [`lod`]: the image error of levels of detail: each object at its chosen level against full detail.
//! - [`judge`]: all of the above for a `bevy_ecs` world that has just run the culling schedule.
//! - [`half_spaces`]: a view's frustum as exact f64 half-spaces, which the other modules test against.
//! - [`shadows`]: which shadow casters a light view needs, decided exactly: their shadows can reach the
//!   camera's view, and the light sees them ([`render::render_light_view`], the exact rendering from the light
//!   at the shadow map's texel centres).
//! - [`stress`]: scenes and cameras at the edges of the numeric range, judged on the CPU and GPU paths.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod half_spaces;
pub mod judge;
pub mod lod;
pub mod metrics;
pub mod occluders;
pub mod render;
pub mod shadows;
pub mod stress;
mod triangle;

pub use judge::{JudgeSettings, judge_culled, judge_culler, judge_frame};
pub use metrics::{FrameMetrics, PathMetrics};
pub use render::{ExactVisibility, IdBuffer, ReferenceObject, ReferenceSettings, render_ids};
