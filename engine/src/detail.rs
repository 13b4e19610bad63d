//! Detail culling (seed 000 section 19.6): the frustum's survivors whose projected size is under a threshold
//! in pixels are dropped. Lossy by design and off by default: an object that small may still cover pixels,
//! and the judge measures what dropping it costs in image error.
//!
//! Where the occlusion stage runs, the test runs inside it ([`DetailTest`], passed to
//! [`crate::occlusion::test_occlusion`]): the groups the depth pyramid hides whole are never read, and the
//! others' bounds are read once for both tests. Elsewhere it is a pass of its own ([`cull_small`]).

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
///
/// The engine's occlusion stage runs the same test inside its own pass ([`DetailTest`]), where the bounds it
/// reads are already at hand; this pass is for a view without one.
pub fn cull_small(store: &BoundsStore, camera: &Camera, settings: &DetailSettings, visible: &mut VisibleSet) -> usize {
    DetailTest::new(camera, settings).map_or(0, |test| test.cull(store, visible))
}

/// Detail culling's test for one view: which objects' bounding spheres project under
/// [`DetailSettings::min_pixels`] across. Built once a frame ([`DetailTest::new`]), applied a word of 64 store
/// slots at a time, so that a pass that reads the objects' bounds anyway (the occlusion test) can drop the
/// small ones on the way.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DetailTest {
    eye: glam::Vec3,
    /// An object is small where its radius squared is under this times its distance squared.
    k_squared: f32,
}

impl DetailTest {
    /// The test of `settings` seen from `camera`; `None` where they drop nothing.
    pub fn new(camera: &Camera, settings: &DetailSettings) -> Option<Self> {
        if !settings.enabled() {
            return None;
        }
        // Under the threshold: 2 f r / sqrt(d^2 - r^2) < min, which is r^2 (4 f^2 + min^2) < min^2 d^2, or
        // r^2 < k^2 d^2: one compare, no root or division per object.
        let focal = camera.focal_pixels(settings.viewport_height);
        let min_squared = settings.min_pixels * settings.min_pixels;
        Some(Self { eye: camera.position, k_squared: min_squared / (4.0 * focal * focal + min_squared) })
    }

    /// The bits of `word` (objects of `store`'s group `group`, the slots `64 * group..`) whose objects are
    /// small. `group` must be below `store.groups().len()`.
    #[inline]
    pub fn small_in_word(&self, store: &BoundsStore, group: usize, word: u64) -> u64 {
        if word == 0 {
            return 0;
        }
        // A word is a group of the store: every member's centre lies in the group's box, so between its
        // nearest and farthest distances from the eye. Objects whose radius alone decides against those bounds
        // need no centre read; only where one lies between are the distances computed.
        let (nearest, farthest) = distance_range(&store.groups()[group], self.eye);
        let (surely_small, surely_big) = (self.k_squared * nearest * nearest, self.k_squared * farthest * farthest);
        word & self.small(store.soa(), group * 64, word, surely_small, surely_big)
    }

    /// Clears in `visible` (a set of `store`'s slots) every small object; in parallel over words. Returns the
    /// objects cleared.
    pub fn cull(&self, store: &BoundsStore, visible: &mut VisibleSet) -> usize {
        let groups = store.groups().len();
        parallel::region(|region| {
            visible
                .words_mut()
                .par_chunks_mut(WORDS_PER_TASK)
                .enumerate()
                .map(|(chunk, words)| {
                    region.task(|| {
                        let mut cleared = 0;
                        for (i, word) in words.iter_mut().enumerate() {
                            let group = chunk * WORDS_PER_TASK + i;
                            // A set longer than the store (not the pipeline's) holds no object there.
                            if group >= groups {
                                break;
                            }
                            let small = self.small_in_word(store, group, *word);
                            cleared += small.count_ones() as usize;
                            *word &= !small;
                        }
                        cleared
                    })
                })
                .sum()
        })
    }

    /// Whether the object in `slot` of `store` is small, as [`DetailTest::small_in_word`] finds it (the same
    /// decision, for one lane).
    pub fn is_small(&self, store: &BoundsStore, slot: usize) -> bool {
        let (soa, group) = (store.soa(), slot / 64);
        let (nearest, farthest) = distance_range(&store.groups()[group], self.eye);
        let radius_squared = soa.radius[slot] * soa.radius[slot];
        if radius_squared < self.k_squared * nearest * nearest {
            return true;
        }
        if radius_squared >= self.k_squared * farthest * farthest {
            return false;
        }
        let (dx, dy, dz) =
            (soa.center_x[slot] - self.eye.x, soa.center_y[slot] - self.eye.y, soa.center_z[slot] - self.eye.z);
        radius_squared < self.k_squared * (dx * dx + dy * dy + dz * dz)
    }

    /// The bits of the objects in the word of slots from `first` that are small, of those set in `word`
    /// (others may be set too), given that every member's distance squared times `k_squared` lies between
    /// `surely_small` and `surely_big`. Objects the radius alone decides need no centre read; each object's
    /// bit is the same whatever else `word` holds.
    #[inline(always)]
    fn small(&self, soa: SoaSlices<'_>, first: usize, word: u64, surely_small: f32, surely_big: f32) -> u64 {
        let lanes = first..first + 64;
        let radii = &soa.radius[lanes.clone()];
        // Fixed 64-lane loops over the SoA bounds (padded to whole words), so that they vectorize.
        let radius_squared = |lane: usize| radii[lane] * radii[lane];
        let under = mask(|lane| radius_squared(lane) < surely_small);
        let undecided = mask(|lane| radius_squared(lane) < surely_big) & !under;
        if word & undecided == 0 {
            return under;
        }
        let (xs, ys, zs) = (&soa.center_x[lanes.clone()], &soa.center_y[lanes.clone()], &soa.center_z[lanes]);
        let eye = self.eye;
        let near_enough = mask(|lane| {
            let (dx, dy, dz) = (xs[lane] - eye.x, ys[lane] - eye.y, zs[lane] - eye.z);
            radius_squared(lane) < self.k_squared * (dx * dx + dy * dy + dz * dz)
        });
        under | (undecided & near_enough)
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
