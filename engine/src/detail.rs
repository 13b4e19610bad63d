//! Detail culling (seed 000 section 19.6): the frustum's survivors whose projected size is under a threshold
//! in pixels are dropped. Lossy by design and off by default: an object that small may still cover pixels,
//! and the judge measures what dropping it costs in image error.

use crate::bounds::{BoundsStore, GroupBounds, SoaSlices};
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
    let focal = camera.focal_pixels(viewport_height);
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
    let focal = camera.focal_pixels(settings.viewport_height);
    let min_squared = settings.min_pixels * settings.min_pixels;
    let k_squared = min_squared / (4.0 * focal * focal + min_squared);
    let test = WordTest { soa, eye, k_squared };
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
                        let (nearest, farthest) = distance_range(&groups[group], eye);
                        let (surely_small, surely_big) =
                            (k_squared * nearest * nearest, k_squared * farthest * farthest);
                        let small = test.small(group * 64, *word, surely_small, surely_big);
                        cleared += (*word & small).count_ones() as usize;
                        *word &= !small;
                    }
                    cleared
                })
            })
            .sum()
    })
}

/// Detail culling's test of one word of the store.
struct WordTest<'a> {
    soa: SoaSlices<'a>,
    eye: glam::Vec3,
    /// An object is small where its radius squared is under this times its distance squared.
    k_squared: f32,
}

impl WordTest<'_> {
    /// The bits of the objects in the word of slots from `first` that are small, of those set in `word`
    /// (others may be set too), given that every member's distance squared times `k_squared` lies between
    /// `surely_small` and `surely_big`. Objects the radius alone decides need no centre read.
    #[inline(always)]
    fn small(&self, first: usize, word: u64, surely_small: f32, surely_big: f32) -> u64 {
        let lanes = first..first + 64;
        let radii = &self.soa.radius[lanes.clone()];
        // Fixed 64-lane loops over the SoA bounds (padded to whole words), so that they vectorize.
        let radius_squared = |lane: usize| radii[lane] * radii[lane];
        let under = mask(|lane| radius_squared(lane) < surely_small);
        let undecided = mask(|lane| radius_squared(lane) < surely_big) & !under;
        if word & undecided == 0 {
            return under;
        }
        let (xs, ys, zs) =
            (&self.soa.center_x[lanes.clone()], &self.soa.center_y[lanes.clone()], &self.soa.center_z[lanes]);
        let eye = self.eye;
        mask(|lane| {
            let (dx, dy, dz) = (xs[lane] - eye.x, ys[lane] - eye.y, zs[lane] - eye.z);
            radius_squared(lane) < self.k_squared * (dx * dx + dy * dy + dz * dz)
        })
    }
}

/// The bits of `condition` over the 64 lanes of a word, lane `i` in bit `i`: eight lanes a byte, which
/// compiles to vector compares and byte masks.
#[inline(always)]
fn mask(condition: impl Fn(usize) -> bool) -> u64 {
    let mut bits = 0u64;
    for byte in 0..8 {
        let mut packed = 0u8;
        for bit in 0..8 {
            packed |= (condition(byte * 8 + bit) as u8) << bit;
        }
        bits |= (packed as u64) << (byte * 8);
    }
    bits
}

/// The nearest and farthest distances from `eye` of the points of `group`'s box (0 nearest for an eye inside).
fn distance_range(group: &GroupBounds, eye: glam::Vec3) -> (f32, f32) {
    let nearest = (group.min - eye).max(eye - group.max).max(glam::Vec3::ZERO);
    let farthest = (eye - group.min).abs().max((group.max - eye).abs());
    (nearest.length(), farthest.length())
}
