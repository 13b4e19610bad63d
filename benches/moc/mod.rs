//! Intel's Masked Occlusion Culling (MOC), the peer the occlusion stage is measured against: a safe wrapper of
//! the C shim that `build.rs` compiles with MOC's sources, and the glue that gives MOC the occluders and
//! occludee boxes Cullet gets.
//!
//! MOC takes occluder triangles with a clip-from-object matrix (it transforms them itself, as Cullet does) and
//! occludees as screen rectangles with their nearest clip w. Its depth is 1/w, so the camera's depth
//! convention does not matter to it. Where MOC was not built, [`Moc::new`] says why.

use cullet::occluders::OccluderInstance;
use cullet::pipeline::CameraCuller;
use cullet::{BoundsStore, Camera, ObjectTransform, Occluder, VisibleSet};
use cullet_truth::judge::STAGES;
use cullet_truth::{ExactVisibility, FrameMetrics};
use glam::{DAffine3, DMat4, Mat4, Vec3, Vec4};
use rayon::prelude::*;
use std::marker::PhantomData;
use std::time::{Duration, Instant};

/// One occluder for MOC: its object-space triangle list and the matrix from object to clip space.
#[repr(C)]
pub struct Draw<'a> {
    vertices: *const f32,
    triangles: u32,
    clip_from_object: [f32; 16],
    /// The triangles `vertices` points into.
    _occluder: PhantomData<&'a [Vec3]>,
}

/// An occludee for MOC's `TestRect`: its screen rectangle in NDC, clamped to the screen, and the smallest clip
/// w of its box's corners.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct Rect {
    min: [f32; 2],
    max: [f32; 2],
    w_min: f32,
}

/// The frustum survivors as MOC sees them: the rectangles to test, the slot of each, and the slots kept
/// without a test (their boxes reach the near plane).
#[derive(Default)]
pub struct Occludees {
    pub rects: Vec<Rect>,
    pub slots: Vec<u32>,
    pub near_plane: Vec<u32>,
}

/// One frame of MOC: its timings and the objects it keeps.
pub struct MocFrame {
    /// Clear and rasterize the occluders.
    pub raster: Duration,
    /// Project the occludee boxes to rectangles (Rust, not MOC's code; MOC leaves this to its caller).
    pub project: Duration,
    /// `TestRect` on every rectangle.
    pub test: Duration,
    /// The frustum survivors MOC keeps, by store slot.
    pub visible: VisibleSet,
}

impl MocFrame {
    /// Judges this frame of `world` (the one MOC culled in [`cull_world`]) against the exact visibility
    /// `truth`: the frustum stage, then MOC in place of Cullet's occlusion stage.
    pub fn judge(&self, world: &bevy_ecs::world::World, truth: &ExactVisibility) -> FrameMetrics {
        let survivors = &world.resource::<CameraCuller>().frustum_visible();
        FrameMetrics::new(truth, &[(STAGES[0], survivors), (STAGES[1], &self.visible)])
    }
}

#[cfg(moc)]
mod ffi {
    use super::{Draw, Rect};
    use std::ffi::c_void;

    unsafe extern "C" {
        pub fn cullet_moc_new(width: u32, height: u32, near_distance: f32) -> *mut c_void;
        pub fn cullet_moc_free(moc: *mut c_void);
        pub fn cullet_moc_implementation(moc: *mut c_void) -> i32;
        pub fn cullet_moc_render(moc: *mut c_void, draws: *const Draw<'_>, count: u32, indices: *const u32);
        pub fn cullet_moc_test_rects(moc: *const c_void, rects: *const Rect, count: u32, visible: *mut u8) -> u32;
        pub fn cullet_moc_pool_new(moc: *mut c_void, threads: u32) -> *mut c_void;
        pub fn cullet_moc_pool_free(pool: *mut c_void);
        pub fn cullet_moc_pool_render(pool: *mut c_void, draws: *const Draw<'_>, count: u32);
    }
}

/// A MOC buffer of one resolution, rasterized on the calling thread or on MOC's own thread pool.
#[cfg(moc)]
pub struct Moc {
    raw: std::ptr::NonNull<std::ffi::c_void>,
    /// MOC's `CullingThreadpool` on `raw`, freed before it.
    pool: Option<std::ptr::NonNull<std::ffi::c_void>>,
    /// 0, 1, 2, ...: MOC takes indexed triangles, the occluders are triangle lists.
    indices: Vec<u32>,
}

/// MOC was not built (see `build.rs`): no value of this type exists.
#[cfg(not(moc))]
pub struct Moc {
    never: std::convert::Infallible,
}

// SAFETY: MOC's buffer is plain memory owned by this value; nothing in it is tied to the creating thread.
#[cfg(moc)]
unsafe impl Send for Moc {}
// SAFETY: the one method taking `&self` that reaches MOC, `test`, calls only `TestRect`, a const read of the
// buffer (MOC keeps no statistics unless built with ENABLE_STATS, which build.rs does not set).
#[cfg(moc)]
unsafe impl Sync for Moc {}

#[cfg(moc)]
impl Moc {
    /// A `width` x `height` buffer for a camera whose near plane is at `near` (clip w); `threads` above 1
    /// rasterizes on MOC's `CullingThreadpool` with that many workers.
    ///
    /// # Errors
    /// Where the shim refuses the size (MOC needs a width that is a multiple of 8 and a height that is a
    /// multiple of 4) or the threads (its pool needs a bin of at least one tile a thread).
    pub fn new(width: u32, height: u32, near: f32, threads: usize) -> Result<Self, &'static str> {
        // SAFETY: `cullet_moc_new` returns a new MOC object or null; a non-null one is owned here and freed
        // once in `drop`.
        let raw = unsafe { ffi::cullet_moc_new(width, height, near) };
        let raw = std::ptr::NonNull::new(raw)
            .ok_or("MOC needs a buffer width that is a multiple of 8 and a height that is a multiple of 4")?;
        let mut moc = Self { raw, pool: None, indices: Vec::new() };
        if threads > 1 {
            // SAFETY: `raw` is live; a non-null pool is freed in `drop` before it.
            let pool = unsafe { ffi::cullet_moc_pool_new(raw.as_ptr(), threads as u32) };
            moc.pool = Some(std::ptr::NonNull::new(pool).ok_or("MOC's pool needs a 32x16 bin a thread")?);
        }
        Ok(moc)
    }

    /// The SIMD back end MOC chose for this CPU.
    pub fn implementation(&mut self) -> &'static str {
        // SAFETY: `raw` is live.
        match unsafe { ffi::cullet_moc_implementation(self.raw.as_ptr()) } {
            0 => "SSE2",
            1 => "SSE4.1",
            2 => "AVX2",
            3 => "AVX-512",
            _ => "unknown",
        }
    }

    /// Clears the buffer and rasterizes `draws`.
    pub fn render(&mut self, draws: &[Draw<'_>]) {
        let most = draws.iter().map(|d| d.triangles as usize * 3).max().unwrap_or(0);
        if self.indices.len() < most {
            self.indices = (0..most as u32).collect();
        }
        // SAFETY: each draw's `vertices` points to `3 * triangles` vertices of 3 floats (built by `draws`,
        // borrowed for the draw's lifetime), and `indices` holds `0..3 * triangles` for the largest draw (the
        // pool keeps its own). `raw` and the pool are live, and the pool's render waits for its workers before
        // returning.
        unsafe {
            match self.pool {
                Some(pool) => ffi::cullet_moc_pool_render(pool.as_ptr(), draws.as_ptr(), draws.len() as u32),
                None => {
                    ffi::cullet_moc_render(self.raw.as_ptr(), draws.as_ptr(), draws.len() as u32, self.indices.as_ptr())
                }
            }
        }
    }

    /// `TestRect` on each rectangle: writes 1 to `visible` for those MOC keeps; returns how many. On
    /// `threads` threads of rayon's current pool.
    pub fn test(&self, rects: &[Rect], visible: &mut [u8], threads: usize) -> usize {
        assert_eq!(rects.len(), visible.len());
        let chunk = rects.len().div_ceil(threads.max(1)).max(1);
        rects
            .par_chunks(chunk)
            .zip(visible.par_chunks_mut(chunk))
            .map(|(rects, visible)| {
                // SAFETY: `rects` and `visible` have the same length (asserted above, chunked alike); `raw` is
                // live and `TestRect` only reads it (see `Sync`).
                unsafe {
                    ffi::cullet_moc_test_rects(
                        self.raw.as_ptr(),
                        rects.as_ptr(),
                        rects.len() as u32,
                        visible.as_mut_ptr(),
                    ) as usize
                }
            })
            .sum()
    }
}

#[cfg(moc)]
impl Drop for Moc {
    fn drop(&mut self) {
        // SAFETY: both were created in `new` and are freed once, the pool first since it refers to `raw`.
        unsafe {
            if let Some(pool) = self.pool {
                ffi::cullet_moc_pool_free(pool.as_ptr());
            }
            ffi::cullet_moc_free(self.raw.as_ptr());
        }
    }
}

#[cfg(not(moc))]
impl Moc {
    /// Always an error here: MOC was not built, and this says why.
    pub fn new(_width: u32, _height: u32, _near: f32, _threads: usize) -> Result<Self, &'static str> {
        Err(env!("CULLET_MOC_MISSING"))
    }

    pub fn implementation(&mut self) -> &'static str {
        match self.never {}
    }

    pub fn render(&mut self, _draws: &[Draw<'_>]) {
        match self.never {}
    }

    pub fn test(&self, _rects: &[Rect], _visible: &mut [u8], _threads: usize) -> usize {
        match self.never {}
    }
}

/// The occluders as MOC draws: each one's matrix is built in f64 from camera-relative coordinates, as
/// Cullet's rasterizer works, so both see the same triangles.
pub fn draws<'a>(camera: &Camera, occluders: &[OccluderInstance<'a>]) -> Vec<Draw<'a>> {
    let clip_from_relative: DMat4 = camera.clip_from_relative_f64();
    occluders
        .iter()
        .map(|instance| {
            let relative = DAffine3::from_mat3_translation(
                glam::Mat3::from(instance.transform.matrix3).as_dmat3(),
                Vec3::from(instance.transform.translation).as_dvec3() - camera.position.as_dvec3(),
            );
            let clip_from_object = (clip_from_relative * DMat4::from(relative)).as_mat4();
            let triangles: &'a [Vec3] = instance.occluder.triangles();
            Draw {
                vertices: triangles.as_ptr().cast(),
                triangles: (triangles.len() / 3) as u32,
                clip_from_object: clip_from_object.to_cols_array(),
                _occluder: PhantomData,
            }
        })
        .collect()
}

/// Projects every frustum survivor's box (8 corners) to MOC's rectangle, on rayon's current pool.
pub fn project(camera: &Camera, store: &BoundsStore, survivors: &VisibleSet, out: &mut Occludees) {
    let clip_from_relative: Mat4 = camera.clip_from_relative();
    let slots: Vec<u32> = survivors.iter().map(|slot| slot as u32).collect();
    let projected: Vec<Option<Rect>> = slots
        .par_iter()
        .map(|&slot| {
            let bounds = store.get(slot as usize).expect("a survivor's slot is in the store");
            // Corners as the centre's clip position plus or minus each axis's: 4 adds a corner, not a
            // matrix product.
            let centre = clip_from_relative * (bounds.center - camera.position).extend(1.0);
            let axes = [0, 1, 2].map(|i| clip_from_relative.col(i) * bounds.half_extent[i]);
            let (mut min, mut max, mut w_min) = ([f32::MAX; 2], [f32::MIN; 2], f32::MAX);
            for corner in 0..8 {
                let pick = |i: usize| if corner & (1 << i) == 0 { -axes[i] } else { axes[i] };
                let clip: Vec4 = centre + pick(0) + pick(1) + pick(2);
                if clip.w < camera.near {
                    return None;
                }
                let inv_w = 1.0 / clip.w;
                for axis in 0..2 {
                    min[axis] = min[axis].min(clip[axis] * inv_w);
                    max[axis] = max[axis].max(clip[axis] * inv_w);
                }
                w_min = w_min.min(clip.w);
            }
            Some(Rect { min: min.map(|v| v.max(-1.0)), max: max.map(|v| v.min(1.0)), w_min })
        })
        .collect();
    out.rects.clear();
    out.slots.clear();
    out.near_plane.clear();
    for (slot, rect) in slots.into_iter().zip(projected) {
        match rect {
            Some(rect) => {
                out.rects.push(rect);
                out.slots.push(slot);
            }
            None => out.near_plane.push(slot),
        }
    }
}

/// MOC's occlusion stage for one view: rasterize `occluders`, project the frustum survivors and test them,
/// on `threads` threads (rayon's current pool for the projection and test; MOC's pool, if `moc` has one,
/// for the raster). Returns the survivors MOC keeps and each step's time.
pub fn cull(
    moc: &mut Moc,
    camera: &Camera,
    store: &BoundsStore,
    survivors: &VisibleSet,
    occluders: &[OccluderInstance<'_>],
    threads: usize,
    scratch: &mut Occludees,
) -> MocFrame {
    let start = Instant::now();
    moc.render(&draws(camera, occluders));
    let raster = start.elapsed();
    let start = Instant::now();
    project(camera, store, survivors, scratch);
    let project = start.elapsed();
    let mut kept = vec![0u8; scratch.rects.len()];
    let start = Instant::now();
    moc.test(&scratch.rects, &mut kept, threads);
    let test = start.elapsed();
    let mut visible = VisibleSet::new(survivors.len());
    for &slot in &scratch.near_plane {
        visible.set(slot as usize, true);
    }
    for (&slot, _) in scratch.slots.iter().zip(&kept).filter(|(_, k)| **k != 0) {
        visible.set(slot as usize, true);
    }
    MocFrame { raster, project, test, visible }
}

/// The occluders Cullet's pipeline selected in `world`'s last frame, for MOC to rasterize the same ones.
pub fn world_occluders(world: &bevy_ecs::world::World) -> Vec<OccluderInstance<'_>> {
    let store = world.resource::<BoundsStore>();
    world
        .resource::<CameraCuller>()
        .occluder_slots()
        .iter()
        .filter_map(|&slot| {
            let entity = store.entities()[slot as usize];
            Some(OccluderInstance {
                occluder: world.get::<Occluder>(entity)?,
                transform: world.get::<ObjectTransform>(entity)?.0,
            })
        })
        .collect()
}

/// MOC's occlusion stage on `world`'s last frame: the same camera, frustum survivors and occluders as
/// Cullet's pipeline had.
pub fn cull_world(moc: &mut Moc, world: &bevy_ecs::world::World, threads: usize, scratch: &mut Occludees) -> MocFrame {
    let camera = world.resource::<Camera>();
    let store = world.resource::<BoundsStore>();
    let survivors = &world.resource::<CameraCuller>().frustum_visible();
    cull(moc, camera, store, survivors, &world_occluders(world), threads, scratch)
}
