//! The stages' parallel regions, and their work and span: what bounds a stage's speed-up on any number of
//! cores, measured on one.
//!
//! A stage is serial sections and parallel [`region`]s, each region a set of [`Region::task`]s that may run
//! at once. Measured on a pool of one thread, where every task runs in turn, its **work** is its wall time,
//! and its **span** the time spent outside tasks (serial sections, and the splitting, joining and collecting
//! around the tasks, which is taken to be serial) plus each region's slowest task. No number of cores runs the
//! stage faster than its span, so work over span, the parallelism, bounds its speed-up (Brent's bound:
//! `T(p) <= work / p + span`).
//!
//! Recording is off by default; off, a region costs one relaxed atomic load and its tasks a branch. Switched
//! on ([`set_recording`]), each region adds its wall time, its tasks' summed time and its slowest task's time
//! to the totals of the [`Stage`] the thread is in ([`Stage::enter`]); [`take_recorded`] hands them over.
//! With a stage's wall time measured around it, [`RegionTimes::span`] and [`RegionTimes::parallelism`]
//! follow. On more threads the times are still recorded, but tasks overlap, and the span no longer follows.
//!
//! A region opened inside a task (nested parallelism) is not recorded on its own: its time is part of the
//! task's, as if it ran serially there. The totals are global: record while one stage at a time runs (one
//! schedule, one view), as the scaling bench does.
//!
//! # Example
//! ```
//! use cullet::parallel::{self, Stage};
//! use rayon::prelude::*;
//! use std::time::Instant;
//!
//! parallel::set_recording(true);
//! let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
//! let start = Instant::now();
//! let _stage = Stage::Other.enter();
//! let sums: Vec<u64> = pool.install(|| {
//!     parallel::region(|region| {
//!         (0..8u64).into_par_iter().map(|task| region.task(|| (0..1000 * task).sum::<u64>())).collect()
//!     })
//! });
//! let wall = start.elapsed();
//! parallel::set_recording(false);
//! let times = parallel::take_recorded().stage(Stage::Other);
//! assert_eq!((sums.len(), times.regions), (8, 1));
//! assert!(times.span(wall) <= wall && times.parallelism(wall) >= 1.0);
//! ```

use std::cell::Cell;
use std::marker::PhantomData;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// The stage a thread is in, under which its parallel regions are recorded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Stage {
    /// Bringing the bounds up to date (`pipeline::CullStats::bounds_time`).
    Bounds,
    /// The frustum stage, with the light views culled in its pass (`frustum_time`).
    Frustum,
    /// The occluder selection, raster and depth pyramid (`raster_time`).
    Raster,
    /// The occlusion test (`occlusion_time`).
    Occlusion,
    /// The light views' occlusion (`light_occlusion_time`).
    LightOcclusion,
    /// Choosing levels of detail (`lod::LodStats::time`).
    Lod,
    /// Outside every stage above: the thread's stage when none was entered.
    Other,
}

impl Stage {
    /// Every stage, in pipeline order; [`Recorded::stage`] is indexed by position in this array.
    pub const ALL: [Stage; 7] = [
        Stage::Bounds,
        Stage::Frustum,
        Stage::Raster,
        Stage::Occlusion,
        Stage::LightOcclusion,
        Stage::Lod,
        Stage::Other,
    ];

    /// Makes this the calling thread's stage until the returned scope is dropped (then the stage before it is
    /// the thread's again). Costs a thread-local write.
    #[must_use = "the stage lasts as long as the scope"]
    pub fn enter(self) -> StageScope {
        StageScope { previous: CURRENT_STAGE.replace(self), not_send: PhantomData }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// The calling thread's stage, from [`Stage::enter`] until dropped.
#[derive(Debug)]
pub struct StageScope {
    previous: Stage,
    // The stage is the thread's: the scope must end on the thread that entered it.
    not_send: PhantomData<*const ()>,
}

impl Drop for StageScope {
    fn drop(&mut self) {
        CURRENT_STAGE.set(self.previous);
    }
}

/// What the regions recorded under one stage took, summed over the regions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RegionTimes {
    /// Regions recorded.
    pub regions: usize,
    /// Their wall time, from opening each to its end (its results collected).
    pub wall: Duration,
    /// Their tasks' time, summed.
    pub tasks: Duration,
    /// Each region's slowest task, summed.
    pub slowest: Duration,
}

impl RegionTimes {
    /// The span of a stage that took `stage_wall` (wall time, measured around it) on a pool of one thread and
    /// opened these regions: its time outside their tasks plus each region's slowest task. Its work is
    /// `stage_wall` itself.
    pub fn span(&self, stage_wall: Duration) -> Duration {
        stage_wall.saturating_sub(self.tasks) + self.slowest
    }

    /// Work over span for that stage: the most it can gain from any number of threads. 1 for a serial stage
    /// (or one that took no time).
    pub fn parallelism(&self, stage_wall: Duration) -> f64 {
        let span = self.span(stage_wall).as_secs_f64();
        if span > 0.0 { stage_wall.as_secs_f64() / span } else { 1.0 }
    }
}

impl std::ops::Add for RegionTimes {
    type Output = RegionTimes;

    fn add(self, other: RegionTimes) -> RegionTimes {
        RegionTimes {
            regions: self.regions + other.regions,
            wall: self.wall + other.wall,
            tasks: self.tasks + other.tasks,
            slowest: self.slowest + other.slowest,
        }
    }
}

/// The regions recorded per stage since the last [`take_recorded`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Recorded([RegionTimes; Stage::ALL.len()]);

impl Recorded {
    /// The regions recorded under `stage`.
    pub fn stage(&self, stage: Stage) -> RegionTimes {
        self.0[stage.index()]
    }

    /// The regions recorded under every stage, summed: with a whole frame's wall time, the frame's work and span.
    pub fn total(&self) -> RegionTimes {
        self.0.iter().fold(RegionTimes::default(), |sum, &times| sum + times)
    }
}

/// Switches recording on or off for every thread (regions already open keep what they began with).
pub fn set_recording(on: bool) {
    RECORDING.store(on, Ordering::Relaxed);
}

/// The regions recorded since the last call, per stage; the totals start again from zero.
pub fn take_recorded() -> Recorded {
    let take = |counter: &AtomicU64| counter.swap(0, Ordering::Relaxed);
    Recorded(std::array::from_fn(|stage| {
        let [regions, wall, tasks, slowest] = &TOTALS[stage];
        RegionTimes {
            regions: take(regions) as usize,
            wall: Duration::from_nanos(take(wall)),
            tasks: Duration::from_nanos(take(tasks)),
            slowest: Duration::from_nanos(take(slowest)),
        }
    }))
}

/// Runs `body`, a parallel region whose tasks are the closures it passes to [`Region::task`], and records it
/// under the calling thread's [`Stage`] where recording is on and the thread is in no task.
pub fn region<R>(body: impl FnOnce(&Region) -> R) -> R {
    let watched = RECORDING.load(Ordering::Relaxed);
    let timed = watched && TASK_DEPTH.get() == 0;
    let region = Region { watched, timed, tasks: AtomicU64::new(0), slowest: AtomicU64::new(0) };
    let start = timed.then(Instant::now);
    let result = body(&region);
    if let Some(start) = start {
        let [regions, wall, tasks, slowest] = &TOTALS[CURRENT_STAGE.get().index()];
        regions.fetch_add(1, Ordering::Relaxed);
        wall.fetch_add(nanos(start.elapsed()), Ordering::Relaxed);
        tasks.fetch_add(region.tasks.into_inner(), Ordering::Relaxed);
        slowest.fetch_add(region.slowest.into_inner(), Ordering::Relaxed);
    }
    result
}

/// `f` of every index below `len`, in order, computed as one [`region`] whose tasks each take `per_task`
/// consecutive indices (at least one).
pub(crate) fn map_range<T: Send>(len: usize, per_task: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    use rayon::prelude::*;
    let per_task = per_task.max(1);
    region(|region| {
        (0..len.div_ceil(per_task))
            .into_par_iter()
            .flat_map_iter(|task| {
                let indices = task * per_task..((task + 1) * per_task).min(len);
                region.task(|| indices.map(&f).collect::<Vec<_>>())
            })
            .collect()
    })
}

/// A parallel region opened by [`region`]: the tasks it runs are timed where it is recorded.
#[derive(Debug)]
pub struct Region {
    /// Recording was on when it opened: its tasks mark their threads as in a task, so that regions nested in
    /// them are not recorded on their own.
    watched: bool,
    /// It is recorded: its tasks are timed.
    timed: bool,
    tasks: AtomicU64,
    slowest: AtomicU64,
}

impl Region {
    /// Runs `task`, one of the region's tasks (any thread may run it), timing it where the region is recorded.
    pub fn task<R>(&self, task: impl FnOnce() -> R) -> R {
        if !self.watched {
            return task();
        }
        let _in_task = InTask::enter();
        let start = self.timed.then(Instant::now);
        let result = task();
        if let Some(start) = start {
            let time = nanos(start.elapsed());
            self.tasks.fetch_add(time, Ordering::Relaxed);
            self.slowest.fetch_max(time, Ordering::Relaxed);
        }
        result
    }
}

/// The calling thread runs a task until dropped (also on unwinding).
struct InTask;

impl InTask {
    fn enter() -> InTask {
        TASK_DEPTH.set(TASK_DEPTH.get() + 1);
        InTask
    }
}

impl Drop for InTask {
    fn drop(&mut self) {
        TASK_DEPTH.set(TASK_DEPTH.get() - 1);
    }
}

fn nanos(time: Duration) -> u64 {
    u64::try_from(time.as_nanos()).unwrap_or(u64::MAX)
}

static RECORDING: AtomicBool = AtomicBool::new(false);

/// Per stage: regions, wall, tasks and slowest tasks (nanoseconds).
static TOTALS: [[AtomicU64; 4]; Stage::ALL.len()] = [const { [const { AtomicU64::new(0) }; 4] }; Stage::ALL.len()];

thread_local! {
    static CURRENT_STAGE: Cell<Stage> = const { Cell::new(Stage::Other) };
    static TASK_DEPTH: Cell<u32> = const { Cell::new(0) };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn span_from_a_stage_wall_time() {
        let times = RegionTimes {
            regions: 2,
            wall: Duration::from_millis(31),
            tasks: Duration::from_millis(30),
            slowest: Duration::from_millis(6),
        };
        let wall = Duration::from_millis(34);
        assert_eq!(times.span(wall), Duration::from_millis(10));
        assert!((times.parallelism(wall) - 3.4).abs() < 1e-9);
        assert_eq!(RegionTimes::default().parallelism(Duration::ZERO), 1.0);
    }
}
