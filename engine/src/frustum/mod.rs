//! Stage 2, frustum: planes extracted from a view-projection matrix, and the SoA box-versus-frustum test run
//! in parallel over blocks of the [`BoundsStore`], 8 objects a SIMD step; many views in one pass over the
//! bounds, light views keeping only shadow casters ([`cull_views`], module `views`).
//!
//! Each group of 64 consecutive objects, and each supergroup of 64 groups, has a box ([`GroupBounds`]) tested
//! first (a hierarchy, as in the hierarchical culling of seed 000 section 19.4): a group outside or inside the
//! frustum is decided without touching its objects. Between the two, a supergroup that crosses the frustum
//! has its blocks of 8 groups boxed on the fly and tested in one 8-lane step, so a block outside skips its 8
//! group tests. Scenes stored in spatial order (the city is) decide most groups this way; in a shuffled store
//! every group crosses and every object is tested. The per-object kernel runs all six planes, fully unrolled:
//! branch-free, it is faster than skipping the planes a group lies inside. One branch it does take is temporal
//! coherence (Assarsson and Möller, seed 000 section 19.4): [`PlaneCoherence`] remembers, per block of 8
//! objects, the plane that rejected the whole block last frame, and tests it alone first.
//!
//! # Conventions
//! - A plane is `(normal, d)` with `normal` of unit length pointing *into* the frustum: a point `p` is inside
//!   when `normal · p + d >= 0`.
//! - Planes are camera-relative: they are extracted from `clip_from_relative`, the projection times the view
//!   with the camera at the origin, and each object's centre has the camera position subtracted before the
//!   test. This keeps plane distances small and exact far from the world origin.
//! - Clip-space depth follows [`DepthConvention`]. A plane with a zero normal (the far plane of an infinite
//!   projection) is dropped: it never rejects anything.
//!
//! # Conservative by construction
//! An object is culled only if its box lies entirely on the outer side of one plane, by more than a slack that
//! bounds the `f32` rounding error of the test (relative `2^-20` of the magnitudes involved). The f64 property
//! tests check that nothing an exact test keeps is ever culled.

use crate::bounds::{BoundsStore, GROUPS_PER_SUPERGROUP, GroupBounds, SIMD_LANES, SoaSlices, WorldBounds};
use crate::camera::{Camera, DepthConvention};
use crate::parallel;
use crate::visible::VisibleSet;
use glam::{DMat4, DVec4, Mat4, Vec3};
use rayon::prelude::*;
use thiserror::Error;

mod views;
pub use views::{
    Light, LightSource, LightView, View, ViewError, cascade_clip_from_relative, cascade_frustum, cube_face_cameras,
    cull_views, cull_views_with,
};

/// Relative slack of the plane test, a bound on the rounding error of the camera-relative `f32` arithmetic
/// (about 16 units in the last place) so that the fast test never culls what the exact test keeps.
pub const PLANE_TEST_TOLERANCE: f32 = 1.0 / (1 << 20) as f32;

/// Bitset words handed to one rayon task: one supergroup.
const WORDS_PER_TASK: usize = GROUPS_PER_SUPERGROUP;

/// SIMD blocks of objects per bitset word.
const BLOCKS_PER_WORD: usize = 64 / SIMD_LANES;

/// No plane rejected the whole block last frame.
const NO_PLANE: u8 = u8::MAX;

/// Temporal coherence of the frustum test: for each block of 8 consecutive store slots, the plane that rejected
/// all 8 objects in the last frame culled with it, tested alone first in the next (seed 000 section 19.4,
/// after Assarsson and Möller). Objects move little between frames, so an object outside one plane usually
/// stays outside that plane. Results are the same bits as without it: a block is skipped only when that plane
/// rejects every object in it, which the full test would do too.
#[derive(bevy_ecs::resource::Resource, Clone, Debug, Default, PartialEq, Eq)]
pub struct PlaneCoherence {
    /// Plane index per block, or `NO_PLANE`.
    planes: Vec<u8>,
}

impl PlaneCoherence {
    /// Blocks whose last frame found a plane rejecting all of their objects.
    pub fn blocks_with_plane(&self) -> usize {
        self.planes.iter().filter(|&&p| p != NO_PLANE).count()
    }
}

/// A plane `normal · p + d = 0`, `normal` of unit length pointing into the frustum.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal pointing inside.
    pub normal: Vec3,
    /// Offset: signed distance of the origin from the plane.
    pub d: f32,
}

impl Plane {
    /// Signed distance of `point` from the plane, positive inside.
    pub fn distance(&self, point: Vec3) -> f32 {
        self.normal.dot(point) + self.d
    }
}

/// Why a frustum could not be built.
#[derive(Error, Clone, Copy, Debug, PartialEq)]
pub enum FrustumError {
    /// The camera is outside its documented ranges ([`crate::Camera::validate`] says which).
    #[error("invalid camera: {0}")]
    InvalidCamera(&'static str),
    /// The matrix or the camera origin has a NaN or infinite entry.
    #[error("view-projection matrix or camera origin is not finite")]
    NonFinite,
    /// A plane has a zero normal and excludes everything: the projection is degenerate.
    #[error("view-projection matrix is degenerate: plane {0} excludes all space")]
    Degenerate(usize),
}

impl Camera {
    /// The camera-relative culling frustum, its planes extracted from the f64 matrices.
    ///
    /// # Errors
    /// [`FrustumError::InvalidCamera`] for a camera outside its documented ranges ([`Camera::validate`]), and
    /// [`FrustumError`]'s other variants for matrices that are not finite or degenerate (`up` along `forward`);
    /// every stage then keeps every object, and the pipeline reports why.
    pub fn frustum(&self) -> Result<Frustum, FrustumError> {
        self.validate().map_err(FrustumError::InvalidCamera)?;
        Frustum::from_clip_from_relative_f64(self.position, self.clip_from_relative_f64(), self.depth)
    }
}

/// Offset of the stand-in for a plane at infinity: never rejects, and any sphere is inside it.
const PLANE_AT_INFINITY_D: f32 = f32::MAX / 4.0;

/// Where a group of objects lies relative to the frustum.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GroupClass {
    /// Entirely outside one plane: every member is culled.
    Outside,
    /// Inside every plane: every member is visible.
    Inside,
    /// Crossing at least one plane: members are tested one by one.
    Crossing,
}

/// Which instruction set runs the culling kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum SimdBackend {
    /// AVX2 where the processor has it, scalar elsewhere.
    #[default]
    Auto,
    /// One object at a time; the reference the SIMD paths match bit for bit.
    Scalar,
    /// 8 objects a step with AVX2. Falls back to scalar where AVX2 is missing.
    Avx2,
}

impl SimdBackend {
    /// The backend that will actually run on this processor.
    pub fn resolve(self) -> Self {
        match self {
            Self::Scalar => Self::Scalar,
            Self::Auto | Self::Avx2 if avx2_available() => Self::Avx2,
            Self::Auto | Self::Avx2 => Self::Scalar,
        }
    }
}

fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The planes of a view frustum and the camera position they are relative to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frustum {
    planes: [Plane; 6],
    /// Per plane, `PLANE_TEST_TOLERANCE * |d|`, the part of the slack that does not depend on the object.
    slack_d: [f32; 6],
    plane_count: usize,
    origin: Vec3,
}

impl Frustum {
    /// Extracts the planes of `clip_from_relative`, a projection times a view whose eye is at the origin, for a
    /// camera at world position `origin`. The extraction runs in f64 and rounds once to f32.
    ///
    /// An f32 matrix cannot place the far plane of a standard-depth projection whose far/near ratio exceeds
    /// about 1e6 (the depth terms round to -1): use [`Frustum::from_clip_from_relative_f64`] there, as
    /// [`crate::Camera::frustum`] does.
    pub fn from_clip_from_relative(
        origin: Vec3,
        clip_from_relative: Mat4,
        depth: DepthConvention,
    ) -> Result<Self, FrustumError> {
        Self::from_clip_from_relative_f64(origin, clip_from_relative.as_dmat4(), depth)
    }

    /// [`Frustum::from_clip_from_relative`] from an f64 matrix: the planes are exact to f32 rounding whatever
    /// the near and far distances.
    pub fn from_clip_from_relative_f64(
        origin: Vec3,
        clip_from_relative: DMat4,
        depth: DepthConvention,
    ) -> Result<Self, FrustumError> {
        if !origin.is_finite() || !clip_from_relative.is_finite() {
            return Err(FrustumError::NonFinite);
        }
        let m = clip_from_relative.transpose();
        let (r0, r1, r2, r3) = (m.x_axis, m.y_axis, m.z_axis, m.w_axis);
        let (near, far) = match depth {
            DepthConvention::Standard => (r2, r3 - r2),
            DepthConvention::Reversed => (r3 - r2, r2),
            DepthConvention::NegativeOneToOne => (r3 + r2, r3 - r2),
        };
        // Near first: it rejects everything behind the camera, half of all objects in an open world.
        let raw = [near, r3 + r0, r3 - r0, r3 + r1, r3 - r1, far];
        let mut frustum = Self {
            planes: [Plane { normal: Vec3::ZERO, d: PLANE_AT_INFINITY_D }; 6],
            slack_d: [0.0; 6],
            plane_count: 0,
            origin,
        };
        for (index, plane) in raw.into_iter().enumerate() {
            if let Some(plane) = normalize_plane(plane, index)? {
                frustum.slack_d[frustum.plane_count] = PLANE_TEST_TOLERANCE * plane.d.abs();
                frustum.planes[frustum.plane_count] = plane;
                frustum.plane_count += 1;
            }
        }
        Ok(frustum)
    }

    /// Planes of a plain `clip_from_world` matrix, camera-relative at the world origin. Prefer
    /// [`Frustum::from_clip_from_relative`] far from the origin.
    pub fn from_clip_from_world(clip_from_world: Mat4, depth: DepthConvention) -> Result<Self, FrustumError> {
        Self::from_clip_from_relative(Vec3::ZERO, clip_from_world, depth)
    }

    /// The active planes, camera-relative (near first; an infinite far plane is absent).
    pub fn planes(&self) -> &[Plane] {
        &self.planes[..self.plane_count]
    }

    /// The camera position the planes are relative to.
    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    /// Whether a box may be visible: the arithmetic of the batch kernels, for a single object, all planes.
    pub fn intersects(&self, bounds: &WorldBounds) -> bool {
        let c = bounds.center;
        let e = bounds.half_extent;
        self.test_lane(c.x, c.y, c.z, e.x, e.y, e.z, bounds.radius)
    }

    /// Where a group box lies: entirely outside one plane, inside all, or crossing.
    pub fn classify_group(&self, group: &GroupBounds) -> GroupClass {
        let (outside, inside) = self.classify_groups(std::slice::from_ref(group));
        if outside & 1 != 0 {
            GroupClass::Outside
        } else if inside & 1 != 0 {
            GroupClass::Inside
        } else {
            GroupClass::Crossing
        }
    }

    /// Classifies up to 8 groups at once, one per lane: returns the bits of those outside and of those inside.
    /// Written lane-parallel so the compiler vectorizes it (8 lanes where built with AVX2).
    #[inline(always)]
    fn classify_groups(&self, groups: &[GroupBounds]) -> (u8, u8) {
        let GroupLanes { center, extent, empty, valid } = GroupLanes::of(groups, self.origin);
        let magnitude = lane_magnitudes(&center, &extent);
        let mut outside = [false; SIMD_LANES];
        let mut crossing = [false; SIMD_LANES];
        for (plane, slack_d) in self.planes.iter().zip(self.slack_d) {
            let (n, abs_n) = (plane.normal, plane.normal.abs());
            for lane in 0..SIMD_LANES {
                let dist = n.x * center[0][lane] + n.y * center[1][lane] + n.z * center[2][lane] + plane.d;
                let reach = abs_n.x * extent[0][lane] + abs_n.y * extent[1][lane] + abs_n.z * extent[2][lane];
                let slack = PLANE_TEST_TOLERANCE * magnitude[lane] + slack_d;
                outside[lane] |= dist + reach + slack < 0.0;
                crossing[lane] |= dist - reach - slack < 0.0;
            }
        }
        let bits = |flags: [bool; SIMD_LANES]| flags.iter().enumerate().fold(0u8, |b, (i, &f)| b | (f as u8) << i);
        let outside = (bits(outside) | empty) & valid;
        (outside, !bits(crossing) & !outside & valid)
    }

    /// [`Frustum::intersects`] of up to 8 stored objects at once, bit `i` for the object in store slot
    /// `slots[i]` (a slot past the store's end counts as visible, as `intersects` of no bounds would): the same
    /// operations lane by lane, so that the lanes run in SIMD where the slots are scattered through the store.
    pub(crate) fn intersects_slots(&self, store: &BoundsStore, slots: &[u32]) -> u8 {
        let soa = store.soa();
        let (mut rel, mut extent, mut radius) =
            ([[0.0f32; SIMD_LANES]; 3], [[0.0f32; SIMD_LANES]; 3], [0.0; SIMD_LANES]);
        let mut stored = 0u8;
        for (lane, &slot) in slots.iter().take(SIMD_LANES).enumerate() {
            let i = slot as usize;
            if i >= store.len() {
                continue;
            }
            stored |= 1 << lane;
            rel[0][lane] = soa.center_x[i] - self.origin.x;
            rel[1][lane] = soa.center_y[i] - self.origin.y;
            rel[2][lane] = soa.center_z[i] - self.origin.z;
            (extent[0][lane], extent[1][lane], extent[2][lane]) = (soa.extent_x[i], soa.extent_y[i], soa.extent_z[i]);
            radius[lane] = soa.radius[i];
        }
        let magnitude: [f32; SIMD_LANES] =
            std::array::from_fn(|l| rel[0][l].abs() + rel[1][l].abs() + rel[2][l].abs() + radius[l]);
        let (mut sphere_out, mut sphere_in, mut box_out) =
            ([false; SIMD_LANES], [true; SIMD_LANES], [false; SIMD_LANES]);
        for (plane, slack_d) in self.planes.iter().zip(self.slack_d).take(self.plane_count) {
            let (n, abs_n) = (plane.normal, plane.normal.abs());
            for l in 0..SIMD_LANES {
                let dist = n.x * rel[0][l] + n.y * rel[1][l] + n.z * rel[2][l] + plane.d;
                let slack = PLANE_TEST_TOLERANCE * magnitude[l] + slack_d;
                sphere_out[l] |= dist + radius[l] + slack < 0.0;
                sphere_in[l] &= dist - radius[l] - slack >= 0.0;
                let projected_extent = abs_n.x * extent[0][l] + abs_n.y * extent[1][l] + abs_n.z * extent[2][l];
                box_out[l] |= dist + projected_extent + slack < 0.0;
            }
        }
        let lanes = (1u16 << slots.len().min(SIMD_LANES)) - 1;
        let visible =
            (0..SIMD_LANES).fold(0u8, |bits, l| bits | u8::from(sphere_in[l] || !(sphere_out[l] || box_out[l])) << l);
        (visible | !stored) & lanes as u8
    }

    /// The per-object test every backend computes, operation for operation, over all six plane slots (absent
    /// planes are stand-ins that never reject).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn test_lane(&self, cx: f32, cy: f32, cz: f32, ex: f32, ey: f32, ez: f32, r: f32) -> bool {
        let (rx, ry, rz) = (cx - self.origin.x, cy - self.origin.y, cz - self.origin.z);
        let magnitude = rx.abs() + ry.abs() + rz.abs() + r;
        let mut sphere_out = false;
        let mut sphere_in = true;
        let mut box_out = false;
        for (plane, slack_d) in self.planes.iter().zip(self.slack_d) {
            let n = plane.normal;
            let dist = n.x * rx + n.y * ry + n.z * rz + plane.d;
            let slack = PLANE_TEST_TOLERANCE * magnitude + slack_d;
            sphere_out |= dist + r + slack < 0.0;
            sphere_in &= dist - r - slack >= 0.0;
            let projected_extent = n.x.abs() * ex + n.y.abs() * ey + n.z.abs() * ez;
            box_out |= dist + projected_extent + slack < 0.0;
        }
        sphere_in || !(sphere_out || box_out)
    }

    fn cull_word_scalar(&self, store: &BoundsStore, base: usize) -> u64 {
        let soa = store.soa();
        let mut word = 0;
        for lane in 0..64 {
            let i = base + lane;
            let visible = self.test_lane(
                soa.center_x[i],
                soa.center_y[i],
                soa.center_z[i],
                soa.extent_x[i],
                soa.extent_y[i],
                soa.extent_z[i],
                soa.radius[i],
            );
            word |= (visible as u64) << lane;
        }
        word
    }
}

/// Up to 8 group boxes in SIMD lanes, as every view's group test takes them.
struct GroupLanes {
    /// Centres relative to the view's origin, per axis and lane.
    center: [[f32; SIMD_LANES]; 3],
    /// Half extents, per axis and lane.
    extent: [[f32; SIMD_LANES]; 3],
    /// Lanes holding an empty group (no member).
    empty: u8,
    /// Lanes holding a group at all.
    valid: u8,
}

impl GroupLanes {
    /// The first 8 of `groups`, relative to `origin`. Centre and extent are rounded outward: their f32 error is
    /// below an ulp of the corners' magnitude.
    #[inline(always)]
    fn of(groups: &[GroupBounds], origin: Vec3) -> Self {
        let mut lanes = Self { center: [[0.0; SIMD_LANES]; 3], extent: [[0.0; SIMD_LANES]; 3], empty: 0, valid: 0 };
        for (lane, group) in groups.iter().enumerate().take(SIMD_LANES) {
            let corner_magnitude = group.min.abs().max(group.max.abs());
            let c = (group.min + group.max) * 0.5 - origin;
            let e = (group.max - group.min) * 0.5 + corner_magnitude * f32::EPSILON;
            for axis in 0..3 {
                (lanes.center[axis][lane], lanes.extent[axis][lane]) = (c[axis], e[axis]);
            }
            lanes.empty |= (!group.min.cmple(group.max).all() as u8) << lane;
            lanes.valid |= 1 << lane;
        }
        lanes
    }
}

/// Per lane, the sum of a box's centre and extent magnitudes, `|cx| + |cy| + |cz| + ex + ey + ez` summed left to
/// right: what the plane tests' rounding slack scales with.
#[inline(always)]
fn lane_magnitudes(center: &[[f32; SIMD_LANES]; 3], extent: &[[f32; SIMD_LANES]; 3]) -> [f32; SIMD_LANES] {
    std::array::from_fn(|lane| {
        center[0][lane].abs()
            + center[1][lane].abs()
            + center[2][lane].abs()
            + extent[0][lane]
            + extent[1][lane]
            + extent[2][lane]
    })
}

fn normalize_plane(plane: DVec4, index: usize) -> Result<Option<Plane>, FrustumError> {
    let length = plane.truncate().length();
    // A normal this small relative to d puts the plane beyond any f32 distance: treat it as at infinity.
    if length <= plane.w.abs() * 1e-12 || length == 0.0 {
        return if plane.w > 0.0 { Ok(None) } else { Err(FrustumError::Degenerate(index)) };
    }
    let plane = plane / length;
    Ok(Some(Plane { normal: plane.truncate().as_vec3(), d: plane.w as f32 }))
}

/// How [`cull_frustum`] runs. The default: every object, the fastest backend of this processor, no plane
/// coherence.
#[derive(Debug, Default)]
pub struct FrustumOptions<'a> {
    /// Which instruction set runs the kernel; every backend gives the same bits.
    pub backend: SimdBackend,
    /// Plane coherence: for each block of 8 objects, the plane that rejected the whole block last call is tried
    /// first, and this call's is remembered for the next. The same bits as without it.
    pub coherence: Option<&'a mut PlaneCoherence>,
    /// Only these store slots, one by one, each getting the bit the whole pass would give it; `visible`'s other
    /// slots keep their bits (for a frame where only they moved since `visible` was culled with the same
    /// frustum). A slot the store does not hold is set visible.
    pub only: Option<&'a [u32]>,
}

/// Frustum-culls the objects of `store` into `visible` (resized to the store), in parallel over blocks of
/// 4096 objects, as `options` say. Returns the number of visible objects.
///
/// # Panics
/// Where a slot of `options.only` is past `visible`'s words.
pub fn cull_frustum(
    store: &BoundsStore,
    frustum: &Frustum,
    options: FrustumOptions,
    visible: &mut VisibleSet,
) -> usize {
    if let Some(slots) = options.only {
        for &slot in slots {
            let visible_now = store.get(slot as usize).is_none_or(|bounds| frustum.intersects(&bounds));
            visible.set(slot as usize, visible_now);
        }
        return visible.count();
    }
    cull(store, frustum, options.backend, visible, options.coherence)
}

/// [`cull_frustum`] over every object, with coherence or without.
fn cull(
    store: &BoundsStore,
    frustum: &Frustum,
    backend: SimdBackend,
    visible: &mut VisibleSet,
    coherence: Option<&mut PlaneCoherence>,
) -> usize {
    let view = View::new(*frustum);
    cull_pass(store, std::slice::from_ref(&view), backend, vec![(visible, coherence)])[0]
}

/// Most views one pass tests; [`cull_views`] runs more in several passes. Each task keeps its per-view state
/// in arrays of this size on its stack.
const MAX_VIEWS_PER_PASS: usize = 32;

/// The one pass over the store behind every frustum entry point: each task takes one supergroup (64 bitset
/// words), and each word of 64 objects is tested against every view in turn while its bounds are in cache.
/// Each view runs its own group hierarchy. Returns each view's visible count.
///
/// # Panics
/// If `views` has more than [`MAX_VIEWS_PER_PASS`] views, or a different number from `outputs`.
fn cull_pass(
    store: &BoundsStore,
    views: &[View],
    backend: SimdBackend,
    mut outputs: Vec<(&mut VisibleSet, Option<&mut PlaneCoherence>)>,
) -> Vec<usize> {
    assert!(views.len() <= MAX_VIEWS_PER_PASS && views.len() == outputs.len());
    let len = store.len();
    let words = len.div_ceil(64);
    let tasks = words.div_ceil(WORDS_PER_TASK);
    let backend = backend.resolve();
    if let [(visible, coherence)] = &mut outputs[..] {
        // One view: its words straight from its set, with nothing allocated per task (each task clears its own).
        visible.resize_for_overwrite(len);
        let planes = task_planes(coherence.take(), words);
        let count = parallel::region(|region| {
            visible
                .words_mut()
                .par_chunks_mut(WORDS_PER_TASK)
                .zip(planes)
                .enumerate()
                .map(|(task, (words, planes))| {
                    region.task(|| cull_task::<1>(store, views, backend, task, &mut [(words, planes)])[0])
                })
                .sum()
        });
        return vec![count];
    }
    // Per task, per view: its bitset words and, with coherence, their blocks' planes.
    let mut task_outputs: Vec<Vec<TaskOutput<'_>>> = (0..tasks).map(|_| Vec::with_capacity(views.len())).collect();
    for (visible, coherence) in outputs {
        visible.resize_for_overwrite(len);
        let chunks = visible.words_mut().chunks_mut(WORDS_PER_TASK);
        for ((task, chunk), planes) in chunks.enumerate().zip(task_planes(coherence, words)) {
            task_outputs[task].push((chunk, planes));
        }
    }
    let counts = parallel::region(|region| {
        task_outputs
            .into_par_iter()
            .enumerate()
            .map(|(task, mut outputs)| {
                region.task(|| cull_task::<MAX_VIEWS_PER_PASS>(store, views, backend, task, &mut outputs))
            })
            .reduce(
                || [0; MAX_VIEWS_PER_PASS],
                |mut total, counts| {
                    total.iter_mut().zip(counts).for_each(|(total, count)| *total += count);
                    total
                },
            )
    });
    counts[..views.len()].to_vec()
}

/// One view's part of one task: its bitset words, and their blocks' coherence planes where it keeps them.
type TaskOutput<'a> = (&'a mut [u64], Option<&'a mut [u8]>);

/// Each task's slice of `coherence`'s planes (resized to `words` bitset words), or none for each task.
fn task_planes(coherence: Option<&mut PlaneCoherence>, words: usize) -> Vec<Option<&mut [u8]>> {
    match coherence {
        Some(coherence) => {
            coherence.planes.resize(words * BLOCKS_PER_WORD, NO_PLANE);
            coherence.planes.chunks_mut(WORDS_PER_TASK * BLOCKS_PER_WORD).map(Some).collect()
        }
        None => (0..words.div_ceil(WORDS_PER_TASK)).map(|_| None).collect(),
    }
}

/// One task of [`cull_pass`]: the words of supergroup `task` for every view, written to `outputs` (per view,
/// its words of this task, cleared here first, and their coherence planes). Returns the visible counts, per view.
///
/// Views take turns per block of 8 words (512 objects, whose bounds stay in the L1 cache between views), and
/// a view skips the words of a supergroup it has wholly outside (they stay clear).
fn cull_task<const VIEWS: usize>(
    store: &BoundsStore,
    views: &[View],
    backend: SimdBackend,
    task: usize,
    outputs: &mut [TaskOutput<'_>],
) -> [usize; VIEWS] {
    let len = store.len();
    // The sets were resized without clearing: words outside the views stay as cleared here.
    for (words, _) in outputs.iter_mut() {
        words.fill(0);
    }
    let mut counts = [0; VIEWS];
    // Per view: the supergroup's class, then the bits of its blocks of 8 groups outside and inside.
    let mut blocks_outside = [u8::MAX; VIEWS];
    let mut blocks_inside = [0u8; VIEWS];
    let groups = store.groups();
    let task_groups = &groups[task * WORDS_PER_TASK..((task + 1) * WORDS_PER_TASK).min(groups.len())];
    // The boxes of the blocks of 8 groups, a level between the supergroup and its groups, computed only where
    // a view crosses the supergroup, and once for every view.
    let mut blocks: Option<[GroupBounds; SIMD_LANES]> = None;
    for (v, view) in views.iter().enumerate() {
        match view.classify_group(&store.supergroups()[task], backend) {
            GroupClass::Outside => {}
            GroupClass::Inside => (blocks_outside[v], blocks_inside[v]) = (0, u8::MAX),
            GroupClass::Crossing => {
                let blocks = blocks.get_or_insert_with(|| {
                    let mut blocks = [GroupBounds::EMPTY; SIMD_LANES];
                    for (block, groups) in blocks.iter_mut().zip(task_groups.chunks(SIMD_LANES)) {
                        *block = groups.iter().fold(GroupBounds::EMPTY, |block, group| block.union(group));
                    }
                    blocks
                });
                (blocks_outside[v], blocks_inside[v]) = view.classify_groups(blocks, backend);
            }
        }
    }
    let task_words = outputs.first().map_or(0, |(words, _)| words.len());
    for (block, groups) in task_groups.chunks(SIMD_LANES).enumerate() {
        let first_word = block * SIMD_LANES;
        let first_group = task * WORDS_PER_TASK + first_word;
        for (v, (view, (words, planes))) in views.iter().zip(outputs.iter_mut()).enumerate() {
            let (outside, inside) = if blocks_outside[v] >> block & 1 != 0 {
                continue; // Its words stay clear.
            } else if blocks_inside[v] >> block & 1 != 0 {
                (0, u8::MAX)
            } else {
                view.classify_groups(groups, backend)
            };
            for (lane, offset) in (first_word..(first_word + SIMD_LANES).min(task_words)).enumerate() {
                let base = (first_group + lane) * 64;
                let mut word = if outside >> lane & 1 != 0 {
                    0
                } else if inside >> lane & 1 != 0 {
                    u64::MAX
                } else {
                    let planes = planes
                        .as_deref_mut()
                        .map(|planes| &mut planes[offset * BLOCKS_PER_WORD..(offset + 1) * BLOCKS_PER_WORD]);
                    view.cull_word(store, base, backend, planes)
                };
                if len - base < 64 {
                    // Padding slots hold zero-size boxes at the origin, which may test visible.
                    word &= (1u64 << (len - base)) - 1;
                }
                words[offset] = word;
                counts[v] += word.count_ones() as usize;
            }
        }
    }
    counts
}

impl Frustum {
    /// Classifies up to 8 groups with `backend` (already resolved): the bits of those outside and inside.
    #[inline]
    fn classify_groups_with(&self, groups: &[GroupBounds], backend: SimdBackend) -> (u8, u8) {
        match backend {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `resolve` picks Avx2 only where the processor reports AVX2; the function reads `groups`
            // through safe indexing only.
            SimdBackend::Avx2 => unsafe { avx2::classify_groups(self, groups) },
            _ => self.classify_groups(groups),
        }
    }

    /// The visibility bits of the 64 objects from `base`, with `backend` (already resolved) and, where given,
    /// the coherence planes of their 8 blocks.
    ///
    /// # Panics
    /// If `base + 64` exceeds the store's padded length.
    #[inline]
    fn cull_word_with(&self, store: &BoundsStore, base: usize, backend: SimdBackend, planes: Option<&mut [u8]>) -> u64 {
        assert!(base + 64 <= store.padded_len(), "word past the store's padded arrays");
        match backend {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `resolve` picks Avx2 only where the processor reports AVX2 (the target feature), and
            // `base + 64 <= store.padded_len()` was asserted above; the store's SoA layout invariant
            // (`BoundsStore`, established and checked in `insert` and `remove`) makes every array that long.
            SimdBackend::Avx2 => unsafe {
                let mut none = [NO_PLANE; BLOCKS_PER_WORD];
                avx2::cull_word(self, store, base, planes.unwrap_or(&mut none))
            },
            _ => self.cull_word_scalar(store, base),
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! The 8-lane kernel: the same operations as `Frustum::test_lane`, in the same order, so results are
    //! identical to the scalar path (no fused multiply-add anywhere).
    use super::*;
    use std::arch::x86_64::*;

    /// [`Frustum::classify_groups`] compiled for AVX2.
    ///
    /// # Safety
    /// The processor must support AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn classify_groups(frustum: &Frustum, groups: &[GroupBounds]) -> (u8, u8) {
        frustum.classify_groups(groups)
    }

    /// Culls the 64 objects from `base`, returning their visibility bits; `planes` holds the coherence plane
    /// of each of its 8 blocks (see [`PlaneCoherence`]), read and updated.
    ///
    /// # Safety
    /// The processor must support AVX2, and `base + 64 <= store.padded_len()` (the length of every SoA array,
    /// by the store's layout invariant).
    #[target_feature(enable = "avx2")]
    pub unsafe fn cull_word(frustum: &Frustum, store: &BoundsStore, base: usize, planes: &mut [u8]) -> u64 {
        debug_assert!(base + 64 <= store.padded_len());
        let soa = store.soa();
        let mut word = 0u64;
        for (block, plane) in planes.iter_mut().enumerate().take(BLOCKS_PER_WORD) {
            let i = base + block * SIMD_LANES;
            // SAFETY: AVX2 is available (this function's own contract), and `i + 8 <= base + 64 <= padded_len`,
            // the length of every array of `soa` (the caller's contract).
            let bits = unsafe { cull_block(frustum, &soa, i, plane) };
            word |= (bits as u64) << (block * SIMD_LANES);
        }
        word
    }

    /// The 8 values of `array` from `i`.
    ///
    /// # Safety
    /// The processor must support AVX2, and `i + 8 <= array.len()`.
    #[target_feature(enable = "avx2")]
    unsafe fn load(array: &[f32], i: usize) -> __m256 {
        debug_assert!(i + SIMD_LANES <= array.len());
        // SAFETY: `i + 8 <= array.len()` (this function's contract): the unaligned load reads inside `array`.
        unsafe { _mm256_loadu_ps(array.as_ptr().add(i)) }
    }

    #[target_feature(enable = "avx2")]
    fn abs(v: __m256) -> __m256 {
        _mm256_andnot_ps(_mm256_set1_ps(-0.0), v)
    }

    /// The visibility bits of the 8 objects from slot `i`; `coherent_plane` as in [`cull_word`].
    ///
    /// # Safety
    /// The processor must support AVX2, and `i + 8 <=` the length of every array of `soa`.
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn cull_block(frustum: &Frustum, soa: &SoaSlices<'_>, i: usize, coherent_plane: &mut u8) -> u8 {
        let zero = _mm256_setzero_ps();
        let tolerance = _mm256_set1_ps(PLANE_TEST_TOLERANCE);
        // SAFETY: `i + 8` is within every array of `soa` (this function's contract).
        let (cx, cy, cz, r) =
            unsafe { (load(soa.center_x, i), load(soa.center_y, i), load(soa.center_z, i), load(soa.radius, i)) };
        let rx = _mm256_sub_ps(cx, _mm256_set1_ps(frustum.origin.x));
        let ry = _mm256_sub_ps(cy, _mm256_set1_ps(frustum.origin.y));
        let rz = _mm256_sub_ps(cz, _mm256_set1_ps(frustum.origin.z));
        let magnitude = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(abs(rx), abs(ry)), abs(rz)), r);
        let base_slack = _mm256_mul_ps(tolerance, magnitude);
        // The sphere test of plane `p`, as in the loop below: its distances, slacks and the lanes it rejects.
        let plane_test = |p: usize| {
            let n = frustum.planes[p].normal;
            let d = _mm256_add_ps(
                _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(n.x), rx), _mm256_mul_ps(_mm256_set1_ps(n.y), ry)),
                    _mm256_mul_ps(_mm256_set1_ps(n.z), rz),
                ),
                _mm256_set1_ps(frustum.planes[p].d),
            );
            let s = _mm256_add_ps(base_slack, _mm256_set1_ps(frustum.slack_d[p]));
            let out = _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_add_ps(_mm256_add_ps(d, r), s), zero);
            (d, s, out)
        };
        let last = usize::from(*coherent_plane);
        if last < frustum.planes.len() && _mm256_movemask_ps(plane_test(last).2) == 0xFF {
            // Last frame's plane rejects the whole block again: so would the full test.
            return 0;
        }
        *coherent_plane = NO_PLANE;

        let mut dist = [zero; 6];
        let mut slack = [zero; 6];
        let mut sphere_out = zero;
        let mut sphere_in = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
        let mut outs = [zero; 6];
        for p in 0..frustum.planes.len() {
            let (d, s, out) = plane_test(p);
            outs[p] = out;
            let inside = _mm256_cmp_ps::<_CMP_GE_OQ>(_mm256_sub_ps(_mm256_sub_ps(d, r), s), zero);
            sphere_out = _mm256_or_ps(sphere_out, out);
            sphere_in = _mm256_and_ps(sphere_in, inside);
            dist[p] = d;
            slack[p] = s;
        }
        if _mm256_movemask_ps(sphere_out) == 0xFF {
            // Remember a plane rejecting the whole block, if one does, for the next frame.
            let whole = (0..frustum.planes.len()).find(|&p| _mm256_movemask_ps(outs[p]) == 0xFF);
            *coherent_plane = whole.map_or(NO_PLANE, |p| p as u8);
        }
        let sphere_in_bits = _mm256_movemask_ps(sphere_in) as u8;
        let decided = _mm256_movemask_ps(_mm256_or_ps(sphere_in, sphere_out)) as u8;
        if decided == 0xFF {
            // Early out: every sphere is fully inside or outside, the boxes cannot change the answer.
            return sphere_in_bits;
        }
        // SAFETY: as for the centres above.
        let (ex, ey, ez) = unsafe { (load(soa.extent_x, i), load(soa.extent_y, i), load(soa.extent_z, i)) };
        let mut box_out = zero;
        for (p, plane) in frustum.planes.iter().enumerate() {
            let n = plane.normal.abs();
            let projected = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(n.x), ex), _mm256_mul_ps(_mm256_set1_ps(n.y), ey)),
                _mm256_mul_ps(_mm256_set1_ps(n.z), ez),
            );
            let out = _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_add_ps(_mm256_add_ps(dist[p], projected), slack[p]), zero);
            box_out = _mm256_or_ps(box_out, out);
        }
        let rejected = _mm256_movemask_ps(_mm256_or_ps(sphere_out, box_out)) as u8;
        sphere_in_bits | !rejected
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bounds::LocalBounds;
    use bevy_ecs::entity::Entity;
    use glam::Affine3A;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// Eight objects at a time, gathered from scattered slots, get the bits of one [`Frustum::intersects`]
        /// each; a slot past the store counts as visible.
        #[test]
        fn slots_at_once_test_as_one_by_one(
            boxes in prop::collection::vec((-60.0f32..60.0, -20.0f32..20.0, -80.0f32..40.0, 0.01f32..9.0), 1..40),
            picks in prop::collection::vec(0u32..48, 0..=8),
            turn in -1.0f32..1.0,
        ) {
            let mut store = BoundsStore::default();
            for (i, &(x, y, z, size)) in boxes.iter().enumerate() {
                let entity = Entity::from_raw_u32(i as u32 + 1).unwrap();
                let local = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::new(size, size * 0.5, size * 2.0) };
                let bounds = WorldBounds::from_local(entity, &local, &Affine3A::from_translation(Vec3::new(x, y, z)));
                store.insert(entity, &bounds.unwrap()).unwrap();
            }
            let camera = Camera::looking_at(Vec3::new(1.0, 2.0, 3.0), Vec3::new(turn * 10.0, 0.0, -10.0));
            let frustum = camera.frustum().unwrap();
            let one_by_one = picks.iter().enumerate().fold(0u8, |bits, (lane, &slot)| {
                let visible = store.get(slot as usize).is_none_or(|bounds| frustum.intersects(&bounds));
                bits | u8::from(visible) << lane
            });
            prop_assert_eq!(frustum.intersects_slots(&store, &picks), one_by_one);
        }
    }
}
