//! Detail culling (seed 000 section 19.6): the frustum's survivors whose projected size is under a threshold
//! in pixels are dropped. Lossy by design and off by default: an object that small may still cover pixels,
//! and the judge measures what dropping it costs in image error.

use crate::bounds::{BoundsStore, GroupBounds};
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
    let groups = store.groups();
    let eye = camera.position;
    // Under the threshold: 2 f r / sqrt(d^2 - r^2) < min, which is r^2 (4 f^2 + min^2) < min^2 d^2, or
    // r^2 < k^2 d^2: one compare, no root or division per object.
    let focal = 0.5 * settings.viewport_height as f32 / (0.5 * camera.fov_y).tan();
    let min_squared = settings.min_pixels * settings.min_pixels;
    let k_squared = min_squared / (4.0 * focal * focal + min_squared);
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
                        // A word is a group of the store: every member's centre lies in the group's box, so
                        // between its nearest and farthest distances from the eye. Objects whose radius alone
                        // decides against those bounds need no centre read; only where one lies between are
                        // the distances computed.
                        let group = chunk * WORDS_PER_TASK + i;
                        // A set longer than the store (not the pipeline's) holds no object there.
                        if group >= groups.len() {
                            break;
                        }
                        let lanes = group * 64..group * 64 + 64;
                        let (nearest, farthest) = distance_range(&groups[group], eye);
                        let (surely_small, surely_big) =
                            (k_squared * nearest * nearest, k_squared * farthest * farthest);
                        let radii = &soa.radius[lanes.clone()];
                        // Fixed 64-lane loops over the SoA bounds (padded to whole words), so that they vectorize.
                        let (mut under, mut undecided) = ([false; 64], [false; 64]);
                        for lane in 0..64 {
                            let radius_squared = radii[lane] * radii[lane];
                            under[lane] = radius_squared < surely_small;
                            undecided[lane] = !under[lane] && radius_squared < surely_big;
                        }
                        if (*word & pack(&undecided)) != 0 {
                            let (xs, ys, zs) =
                                (&soa.center_x[lanes.clone()], &soa.center_y[lanes.clone()], &soa.center_z[lanes]);
                            for lane in 0..64 {
                                let (dx, dy, dz) = (xs[lane] - eye.x, ys[lane] - eye.y, zs[lane] - eye.z);
                                under[lane] = radii[lane] * radii[lane] < k_squared * (dx * dx + dy * dy + dz * dz);
                            }
                        }
                        let small = pack(&under);
                        cleared += (*word & small).count_ones() as usize;
                        *word &= !small;
                    }
                    cleared
                })
            })
            .sum()
    })
}

/// The bits of `lanes`, lane `i` in bit `i`.
#[inline(always)]
fn pack(lanes: &[bool; 64]) -> u64 {
    lanes.iter().rev().fold(0u64, |bits, &lane| bits << 1 | lane as u64)
}

/// The nearest and farthest distances from `eye` of the points of `group`'s box (0 nearest for an eye inside).
fn distance_range(group: &GroupBounds, eye: glam::Vec3) -> (f32, f32) {
    let nearest = (group.min - eye).max(eye - group.max).max(glam::Vec3::ZERO);
    let farthest = (eye - group.min).abs().max((group.max - eye).abs());
    (nearest.length(), farthest.length())
}
