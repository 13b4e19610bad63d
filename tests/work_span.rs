//! The work and span accounting of `cullet::parallel`: a stage of known work and span is measured as such, a
//! nested region is part of its task, nothing is recorded while recording is off, and the pipeline's stages
//! record their regions under their own names, inside their own times.
//!
//! Recording is global: the tests take a lock so that they never record at once.

use bevy_ecs::schedule::SingleThreadedExecutor;
use cullet::culler::{AdaptiveSettings, OcclusionSettings};
use cullet::parallel::{self, Recorded, Stage};
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use rayon::prelude::*;
use std::sync::Mutex;
use std::time::{Duration, Instant};

static RECORDING: Mutex<()> = Mutex::new(());

/// Keeps the thread busy for `time` (wall time: the accounting measures wall time).
fn spin(time: Duration) {
    let start = Instant::now();
    while start.elapsed() < time {
        std::hint::spin_loop();
    }
}

/// Runs `f` on a pool of `threads` threads with recording on; what it recorded and its wall time.
fn record_on(threads: usize, f: impl FnOnce() + Send) -> (Recorded, Duration) {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
    parallel::take_recorded();
    parallel::set_recording(true);
    let start = Instant::now();
    pool.install(f);
    let wall = start.elapsed();
    parallel::set_recording(false);
    (parallel::take_recorded(), wall)
}

/// A stage of a 4 ms serial section, a region of six tasks of 1 to 6 ms, and a 2 ms serial section: work
/// 27 ms, span 12 ms (the serial 6 ms and the slowest task).
fn known_stage() {
    let _stage = Stage::Frustum.enter();
    spin(Duration::from_millis(4));
    parallel::region(|region| {
        (1..=6u64).into_par_iter().for_each(|ms| region.task(|| spin(Duration::from_millis(ms))));
    });
    spin(Duration::from_millis(2));
}

#[test]
fn a_stage_of_known_work_and_span_measures_as_such() {
    let _lock = RECORDING.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    let ms = |ms: u64| Duration::from_millis(ms);
    // On one thread, the stage's wall time is its work.
    let (recorded, work) = record_on(1, known_stage);
    let times = recorded.stage(Stage::Frustum);
    assert_eq!(times.regions, 1);
    assert_eq!(recorded.total(), times, "only the frustum stage recorded");
    // Every task and section spins at least its time; a preempted one takes longer, never shorter.
    assert!(times.tasks >= ms(21) && times.slowest >= ms(6) && times.wall >= times.tasks, "{times:?}");
    let span = times.span(work);
    assert!(work >= ms(27) && span >= ms(12) && span < work, "work {work:?}, span {span:?}");
    let parallelism = times.parallelism(work);
    assert!((parallelism - 2.25).abs() < 0.5, "parallelism {parallelism}, expected 27/12 but for preemption");
    // On two threads the tasks are timed the same, though the span no longer follows from the wall time.
    let (recorded, _) = record_on(2, known_stage);
    let times = recorded.stage(Stage::Frustum);
    assert_eq!(times.regions, 1);
    assert!(times.tasks >= ms(21) && times.slowest >= ms(6), "{times:?}");
}

#[test]
fn a_region_nested_in_a_task_is_part_of_that_task() {
    let _lock = RECORDING.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    // One thread, as the accounting assumes: on two, a thread done with its own outer task may steal the other's
    // inner tasks, whose time then falls outside every outer task on that thread.
    let (recorded, wall) = record_on(1, || {
        let _stage = Stage::Raster.enter();
        parallel::region(|outer| {
            (0..2).into_par_iter().for_each(|_| {
                outer.task(|| {
                    parallel::region(|inner| {
                        (0..3).into_par_iter().for_each(|_| inner.task(|| spin(Duration::from_millis(2))))
                    })
                })
            })
        });
    });
    let times = recorded.stage(Stage::Raster);
    assert_eq!(times.regions, 1, "the nested regions are not recorded on their own");
    assert!(times.tasks >= Duration::from_millis(12) && times.slowest >= Duration::from_millis(6), "{times:?}");
    assert!(times.wall <= wall);
}

#[test]
fn nothing_is_recorded_while_recording_is_off() {
    let _lock = RECORDING.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    parallel::take_recorded();
    let sum: u64 = parallel::region(|region| (0..64u64).into_par_iter().map(|i| region.task(|| i)).sum());
    assert_eq!(sum, 64 * 63 / 2);
    assert_eq!(parallel::take_recorded(), Recorded::default());
}

#[test]
fn the_pipeline_records_each_stage_inside_its_time() {
    let _lock = RECORDING.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    let city = CityScene::generate(CityParams::with_objects(20_000));
    let frames = 4;
    let mut flight = Flight::new(city.flythrough(), 16.0 / 9.0, frames, OcclusionSettings::default(), |world| {
        city.spawn(world);
    });
    flight.world.insert_resource(AdaptiveSettings::fixed());
    // The schedule on the recording pool's one thread, as the scaling bench runs it.
    flight.schedule.set_executor(SingleThreadedExecutor::new());
    for frame in 0..frames {
        let (recorded, wall) = record_on(1, || {
            flight.run_frame(frame);
        });
        let stats = flight.world.resource::<cullet::pipeline::CullStats>();
        let stages = [
            (Stage::Bounds, stats.bounds_time),
            (Stage::Frustum, stats.frustum_time),
            (Stage::Raster, stats.raster_time),
            (Stage::Occlusion, stats.occlusion_time),
        ];
        for (stage, time) in stages {
            let times = recorded.stage(stage);
            // The cars move every frame, and every stage runs on every frame.
            assert!(times.regions >= 1, "frame {frame}: {stage:?} recorded no region");
            assert!(times.tasks <= times.wall, "frame {frame}: {stage:?}'s tasks {times:?} outside their regions");
            assert!(times.wall <= time, "frame {frame}: {stage:?}'s regions {times:?} outside its time {time:?}");
            assert!(times.span(time) <= time, "frame {frame}: {stage:?} {times:?}");
        }
        let total = recorded.total();
        assert!(total.wall <= wall && total.span(wall) <= wall, "frame {frame}: {total:?}");
    }
}

/// The hierarchy records its tree's traversals (and its build) under the frustum and occlusion stages, and the
/// portals their member tests under the frustum stage, each inside the stage's time.
#[test]
fn the_structures_record_their_stages_inside_their_times() {
    use cullet::culler::{Culler, HierarchyCuller, HierarchySettings, PortalCuller, PortalSettings};
    let _lock = RECORDING.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    let city = CityScene::generate(CityParams::with_objects(20_000));
    let building = cullet::scene::building::building(12_000);
    let adaptive = AdaptiveSettings::fixed();
    let cases: [(&cullet::scene::Scene, cullet::CameraPath, Box<dyn Culler + Send>); 2] = [
        (
            &city.scene,
            city.flythrough(),
            Box::new(HierarchyCuller::new(HierarchySettings { adaptive, ..Default::default() })),
        ),
        (
            &building,
            cullet::scene::building::walk(),
            Box::new(PortalCuller::new(PortalSettings { adaptive, ..Default::default() })),
        ),
    ];
    for (scene, path, mut culler) in cases {
        let frames = 4;
        let mut flight = Flight::for_cullers(path, 16.0 / 9.0, frames, |world| {
            scene.spawn(world);
        });
        flight.schedule.set_executor(SingleThreadedExecutor::new());
        let mut frames_occluded = 0;
        for frame in 0..frames {
            let mut stats = None;
            let (recorded, _) = record_on(1, || stats = Some(flight.cull_frame(frame, culler.as_mut()).1.stats));
            let stats = stats.unwrap();
            let stages = [
                (Stage::Frustum, stats.frustum_time),
                (Stage::Raster, stats.raster_time),
                (Stage::Occlusion, stats.occlusion_time),
            ];
            // The portals skip the occlusion stage where nothing is seen through them from inside the cells.
            let occlusion_ran = stats.occluders > 0;
            frames_occluded += usize::from(occlusion_ran);
            for (stage, time) in stages {
                let times = recorded.stage(stage);
                if stage == Stage::Frustum || occlusion_ran {
                    assert!(times.regions >= 1, "{}, frame {frame}: {stage:?} recorded no region", culler.name());
                }
                assert!(
                    times.tasks <= times.wall && times.wall <= time,
                    "{}, frame {frame}: {stage:?} {times:?} in {time:?}",
                    culler.name()
                );
            }
        }
        assert!(frames_occluded > 0, "{}: occlusion never ran", culler.name());
    }
}
