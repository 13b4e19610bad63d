//! Bevy's visibility systems against the plugin's, in the same headless app, over the built-in city's
//! fly-through.
//!
//! For 1e4, 1e5 and 1e6 objects, three apps with Bevy's real transform and visibility plugins fly the same
//! 20-second path in 120 frames: Bevy's own `check_visibility_cpu_culling`, the plugin with frustum culling
//! only, and the plugin with occlusion (its defaults). Timer systems in `PostUpdate` measure, per frame:
//! - **check**: the system that decides what each camera sees: Bevy's `check_visibility_cpu_culling`, or the
//!   plugin's `CulletSystems::Cull` (frustum, occluders, occlusion, writing `ViewVisibility` and
//!   `VisibleEntities`);
//! - **visibility**: everything from the end of transform propagation to the end of Bevy's visibility
//!   systems: visibility propagation, Bevy's `reset_view_visibility` and `mark_newly_hidden_entities_invisible`
//!   (both kept by the plugin), the plugin's mirroring of moved bounds, and the check;
//! - **frame**: the whole `App::update`.
//!
//! With `--still-camera` the camera stays at the path's start while the city's moving cars (2% of the cars)
//! drive, 1/30 s a frame: the case where the plugin re-tests only what moved.
//!
//! The first 10 frames (spawning, the plugin's first mirroring of every object) are not counted. Wall times
//! on the machine's threads; the main thread is one of rayon's (see the plugin's "Threads"). Writes
//! `target/bevy_visibility/visibility.csv` (`visibility_still.csv` with a still camera).
//!
//! `cargo bench -p bevy_cullet --bench visibility [-- --objects N] [--still-camera]`

#[path = "../tests/support/mod.rs"]
mod support;

use bevy_app::{App, PostUpdate};
use bevy_camera::visibility::VisibilitySystems;
use bevy_cullet::{CulletSettings, CulletSystems, CulletView, spawn_scene};
use bevy_ecs::prelude::*;
use bevy_transform::TransformSystems;
use clap::Parser;
use cullet::culler::OcclusionSettings;
use cullet::scene::city::{CityParams, CityScene};
use std::fmt::Write as _;
use std::time::{Duration, Instant};
use support::timing::{Marks, mark, mean_ms, median_ms};
use support::{app, drawn, set_camera, spawn_camera};

const FRAMES: usize = 120;
const WARM_UP: usize = 10;
const FAR: f32 = 1e5;

#[derive(Parser)]
struct Args {
    /// Object counts to run (default 1e4, 1e5 and 1e6).
    #[arg(long, num_args = 1..)]
    objects: Vec<usize>,
    /// Keep the camera still at the path's start and drive the city's moving cars (2%) instead, at 30 frames
    /// a second.
    #[arg(long)]
    still_camera: bool,
    #[arg(long, hide = true)]
    bench: bool,
}

/// Adds the timer systems around the visibility systems and the check.
fn add_timers(app: &mut App) {
    use VisibilitySystems::*;
    app.init_resource::<Marks<4>>().add_systems(
        PostUpdate,
        (
            mark::<4, 0>
                .after(TransformSystems::Propagate)
                .after(CalculateBounds)
                .after(UpdateFrusta)
                .before(VisibilityPropagate)
                .before(CulletSystems::Mirror),
            mark::<4, 1>.after(VisibilityPropagate).after(CulletSystems::Mirror).before(CheckVisibility),
            mark::<4, 2>.after(CheckVisibility).before(MarkNewlyHiddenEntitiesInvisible),
            mark::<4, 3>.after(MarkNewlyHiddenEntitiesInvisible),
        ),
    );
}

/// Per-frame times of one configuration: check, visibility, frame; and the mean objects kept.
struct Run {
    check: Vec<Duration>,
    visibility: Vec<Duration>,
    frame: Vec<Duration>,
    kept: f64,
    /// The plugin's stage times, summed: frustum, raster, occlusion, write.
    stages: [Duration; 4],
}

fn fly(city: &CityScene, settings: Option<CulletSettings>, still_camera: bool) -> Run {
    let mut app = app(settings);
    add_timers(&mut app);
    let path = city.flythrough();
    let world = app.world_mut();
    let entities = spawn_scene(world, &city.scene, |_, entity| {
        entity.insert(drawn());
    });
    let cars: Vec<(Entity, glam::Vec3)> = (entities.iter().zip(&city.scene.objects))
        .filter_map(|(&entity, object)| Some((entity, object.velocity?)))
        .filter(|_| still_camera)
        .collect();
    let camera = spawn_camera(world, &path.camera_at(0.0, 16.0 / 9.0), FAR);
    let mut run =
        Run { check: Vec::new(), visibility: Vec::new(), frame: Vec::new(), kept: 0.0, stages: [Duration::ZERO; 4] };
    for frame in 0..FRAMES + WARM_UP {
        let t = if still_camera { 0.0 } else { path.duration() * frame.saturating_sub(WARM_UP) as f32 / FRAMES as f32 };
        set_camera(app.world_mut(), camera, &path.camera_at(t, 16.0 / 9.0), FAR);
        for &(car, velocity) in &cars {
            let step = bevy_math::Vec3::from_array((velocity / 30.0).to_array());
            app.world_mut().get_mut::<bevy_transform::components::Transform>(car).unwrap().translation += step;
        }
        let start = Instant::now();
        app.update();
        let elapsed = start.elapsed();
        if frame < WARM_UP {
            continue;
        }
        let marks = app.world().resource::<Marks<4>>().all();
        run.check.push(marks[2] - marks[1]);
        run.visibility.push(marks[3] - marks[0]);
        run.frame.push(elapsed);
        let world = app.world_mut();
        run.kept += match world.get::<CulletView>(camera) {
            Some(view) => {
                let stats = view.stats();
                let times = [stats.frustum_time, stats.raster_time, stats.occlusion_time, stats.write_time];
                run.stages.iter_mut().zip(times).for_each(|(sum, time)| *sum += time);
                stats.after_occlusion as f64
            }
            None => {
                let mut visible = world.query::<&bevy_camera::visibility::ViewVisibility>();
                visible.iter(world).filter(|v| v.get()).count() as f64
            }
        } / FRAMES as f64;
    }
    run
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    // As the plugin's docs advise: the main thread, which runs the plugin's culling, is one of rayon's.
    rayon::ThreadPoolBuilder::new().use_current_thread().build_global()?;
    let counts = if args.objects.is_empty() { vec![10_000, 100_000, 1_000_000] } else { args.objects };
    let configurations: [(&str, Option<CulletSettings>); 3] = [
        ("bevy", None),
        (
            "cullet_frustum",
            Some(CulletSettings {
                occlusion: OcclusionSettings { enabled: false, ..Default::default() },
                ..Default::default()
            }),
        ),
        ("cullet_occlusion", Some(CulletSettings::default())),
    ];
    let path = if args.still_camera { "a still camera over the city's moving cars" } else { "the city fly-through" };
    println!(
        "{} threads; ms per frame, mean (median) of {FRAMES} frames of {path}",
        std::thread::available_parallelism()?
    );
    println!(
        "{:>9} {:<17} {:>17} {:>17} {:>17} {:>10} {:>12}",
        "objects", "configuration", "check", "visibility", "frame", "kept", "check / bevy"
    );
    let mut csv = String::from("objects,configuration,check_ms,visibility_ms,frame_ms,check_median_ms,kept\n");
    for &objects in &counts {
        let city = CityScene::generate(CityParams::with_objects(objects));
        let mut bevy_check = None;
        for (name, settings) in &configurations {
            let run = fly(&city, *settings, args.still_camera);
            let check = mean_ms(&run.check);
            let bevy = *bevy_check.get_or_insert(check);
            println!(
                "{objects:>9} {name:<17} {:>8.3} ({:>6.3}) {:>8.3} ({:>6.3}) {:>8.3} ({:>6.3}) {:>10.0} {:>11.1}%",
                check,
                median_ms(&run.check),
                mean_ms(&run.visibility),
                median_ms(&run.visibility),
                mean_ms(&run.frame),
                median_ms(&run.frame),
                run.kept,
                100.0 * check / bevy,
            );
            if settings.is_some() {
                let [frustum, raster, occlusion, write] = run.stages.map(|t| t.as_secs_f64() * 1e3 / FRAMES as f64);
                println!(
                    "{:>27} frustum {frustum:.3}, raster {raster:.3}, occlusion {occlusion:.3}, write {write:.3}",
                    "stages:"
                );
            }
            writeln!(
                csv,
                "{objects},{name},{check:.4},{:.4},{:.4},{:.4},{:.0}",
                mean_ms(&run.visibility),
                mean_ms(&run.frame),
                median_ms(&run.check),
                run.kept
            )?;
        }
    }
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/bevy_visibility");
    std::fs::create_dir_all(&out)?;
    std::fs::write(out.join(if args.still_camera { "visibility_still.csv" } else { "visibility.csv" }), csv)?;
    Ok(())
}
