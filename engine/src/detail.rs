//! Detail culling (seed 000 section 19.6): the frustum's survivors whose projected size is under a threshold
//! in pixels are dropped. Lossy by design and off by default: an object that small may still cover pixels,
//! and the judge measures what dropping it costs in image error.

use crate::bounds::BoundsStore;
use crate::camera::Camera;
use crate::parallel;
use crate::visible::VisibleSet;
use bevy_ecs::prelude::Resource;
use rayon::prelude::*;

/// Bitset words (of 64 objects) one task of [`cull_small`] looks at.
const WORDS_PER_TASK: usize = 128;

/// When objects are too small to draw; a resource of a world set up by [`crate::install`] (off there until
/// changed).
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct DetailSettings {
    /// Objects whose bounding sphere projects to a diameter under this many pixels are dropped; 0 (the
    /// default), or anything not above 0, drops nothing.
    pub min_pixels: f32,
    /// The height of the frame in pixels, which sizes a pixel.
    pub viewport_height: u32,
}

impl Default for DetailSettings {
    /// Off.
    fn default() -> Self {
        Self { min_pixels: 0.0, viewport_height: 1080 }
    }
}

impl DetailSettings {
    /// Whether it drops anything.
    pub fn enabled(&self) -> bool {
        self.min_pixels > 0.0 && self.viewport_height > 0
    }
}

/// The diameter in pixels that a sphere of `radius` at `distance` from `camera`'s eye projects to, seen
/// straight ahead in a frame `viewport_height` pixels tall: `2 f tan(asin(radius / distance))`, with `f` the
/// focal length in pixels. Infinite for an eye inside the sphere. Off the view axis a sphere projects larger,
/// never smaller.
pub fn projected_diameter(camera: &Camera, viewport_height: u32, radius: f32, distance: f32) -> f32 {
    let focal = 0.5 * viewport_height as f32 / (0.5 * camera.fov_y).tan();
    let beyond = distance * distance - radius * radius;
    if beyond <= 0.0 { f32::INFINITY } else { 2.0 * focal * radius / beyond.sqrt() }
}

/// Clears in `visible` (a set of `store`'s slots) every object whose bounding sphere projects under
/// `settings.min_pixels` across, seen from `camera`; in parallel over words. Returns the objects cleared.
pub fn cull_small(store: &BoundsStore, camera: &Camera, settings: &DetailSettings, visible: &mut VisibleSet) -> usize {
    if !settings.enabled() {
        return 0;
    }
    let soa = store.soa();
    let eye = camera.position;
    // Under the threshold: 2 f r / sqrt(d^2 - r^2) < min, squared as 4 f^2 r^2 < min^2 (d^2 - r^2) with
    // d^2 > r^2, with no root or division per object.
    let focal = 0.5 * settings.viewport_height as f32 / (0.5 * camera.fov_y).tan();
    let (four_focal_squared, min_squared) = (4.0 * focal * focal, settings.min_pixels * settings.min_pixels);
    parallel::region(|region| {
        visible
            .words_mut()
            .par_chunks_mut(WORDS_PER_TASK)
            .enumerate()
            .map(|(chunk, words)| {
                region.task(|| {
                    let mut cleared = 0;
                    for (i, word) in words.iter_mut().enumerate() {
                        if *word == 0 {
                            continue;
                        }
                        let base = (chunk * WORDS_PER_TASK + i) * 64;
                        // The whole word at once, over fixed 64-lane runs of the SoA bounds (padded to whole
                        // words) so that it vectorizes; then packed, bit `i` set where object `base + i` is
                        // under the threshold.
                        let lanes = base..base + 64;
                        let (xs, ys, zs, radii) = (
                            &soa.center_x[lanes.clone()],
                            &soa.center_y[lanes.clone()],
                            &soa.center_z[lanes.clone()],
                            &soa.radius[lanes],
                        );
                        let mut under = [false; 64];
                        for lane in 0..64 {
                            let (dx, dy, dz) = (xs[lane] - eye.x, ys[lane] - eye.y, zs[lane] - eye.z);
                            let radius_squared = radii[lane] * radii[lane];
                            let beyond = dx * dx + dy * dy + dz * dz - radius_squared;
                            under[lane] = beyond > 0.0 && four_focal_squared * radius_squared < min_squared * beyond;
                        }
                        let small = under.iter().rev().fold(0u64, |bits, &u| bits << 1 | u as u64);
                        cleared += (*word & small).count_ones() as usize;
                        *word &= !small;
                    }
                    cleared
                })
            })
            .sum()
    })
}
