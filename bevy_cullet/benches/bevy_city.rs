//! Bevy's camera and light visibility against the plugin's, on a headless stand-in for Bevy's own `bevy_city`
//! example (`tests/support/bevy_city.rs` says what it keeps of the example and what differs): about 50,000
//! mesh entities, a tenth of them cars driving every frame, one sun with Bevy's four default cascades.
//!
//! Two apps with Bevy's real transform, camera and light plugins run the same 120 frames (after 10 not
//! counted), cars driving 1/60 s a frame: Bevy's own systems, and the plugin with its defaults. The camera
//! stays at the example's start view (`--orbit`: circles the city once at the same height instead). Timer
//! systems in `PostUpdate` measure, per frame:
//! - **check**: what decides what the camera sees: Bevy's `check_visibility_cpu_culling`, or the plugin's
//!   `CulletSystems::Cull` (the camera's and its light views' frustum pass, occlusion, the camera's write);
//! - **lights**: Bevy's `SimulationLightSystems::CheckLightVisibility` set: its
//!   `check_dir_light_mesh_visibility` and `check_point_light_mesh_visibility`, or the plugin's
//!   `CulletSystems::Lights` (the light views' write);
//! - **mirror**: from the end of transform propagation to the camera check: Bevy's visibility propagation,
//!   and with the plugin its mirroring of the moved bounds, which Bevy's checks do not need;
//! - **frame**: the whole `App::update`.
//!
//! Writes `target/bevy_visibility/bevy_city.csv` (`bevy_city_orbit.csv` with `--orbit`).
//!
//! `cargo bench -p bevy_cullet --bench bevy_city [-- --orbit]`

#[path = "../tests/support/mod.rs"]
mod support;

use bevy_app::{App, PostUpdate};
use bevy_camera::Camera3d;
use bevy_camera::visibility::{CascadesVisibleEntities, ViewVisibility, VisibilitySystems};
use bevy_cullet::{CulletSettings, CulletSystems};
use bevy_ecs::prelude::*;
use bevy_light::SimulationLightSystems;
use bevy_transform::TransformSystems;
use bevy_transform::prelude::*;
use clap::Parser;
use std::fmt::Write as _;
use std::time::{Duration, Instant};
use support::app_with_lights;
use support::bevy_city::{drive, example_camera, spawn_bevy_city};
use support::timing::{Marks, mark, mean_ms, median_ms};

const FRAMES: usize = 120;
const WARM_UP: usize = 10;

#[derive(Parser)]
struct Args {
    /// Circle the city once instead of keeping the example's start view.
    #[arg(long)]
    orbit: bool,
    /// Run only this configuration (`bevy` or `cullet`), for a profiler.
    #[arg(long)]
    only: Option<String>,
    #[arg(long, hide = true)]
    bench: bool,
}

/// Adds the timer systems around the mirroring, the camera check and the light checks.
fn add_timers(app: &mut App) {
    use SimulationLightSystems::*;
    use VisibilitySystems::*;
    app.init_resource::<Marks<5>>().add_systems(
        PostUpdate,
        (
            mark::<5, 0>
                .after(TransformSystems::Propagate)
                .after(CalculateBounds)
                .after(UpdateFrusta)
                .before(VisibilityPropagate)
                .before(CulletSystems::Mirror),
            mark::<5, 1>.after(VisibilityPropagate).after(CulletSystems::Mirror).before(CheckVisibility),
            mark::<5, 2>.after(CheckVisibility).before(UpdateLightFrusta).before(AssignLightsToClusters),
            mark::<5, 3>
                .after(CheckVisibility)
                .after(UpdateLightFrusta)
                .after(AssignLightsToClusters)
                .after(UpdateDirectionalLightCascades)
                .before(CheckLightVisibility),
            mark::<5, 4>.after(CheckLightVisibility).before(MarkNewlyHiddenEntitiesInvisible),
        ),
    );
}

/// Per-frame times of one configuration, and mean counts.
#[derive(Default)]
struct Run {
    check: Vec<Duration>,
    lights: Vec<Duration>,
    mirror: Vec<Duration>,
    frame: Vec<Duration>,
    visible: f64,
    casters: f64,
    /// The plugin's stage times, summed: frustum (camera and light views), occlusion (raster and test), light
    /// views' occlusion, the camera's write, the lights' write.
    stages: [Duration; 5],
}

fn fly(settings: Option<CulletSettings>, orbit: bool) -> (Run, usize, usize) {
    let mut app = app_with_lights(settings);
    add_timers(&mut app);
    let world = app.world_mut();
    let mut city = spawn_bevy_city(world, 30, 0.4, 42);
    let camera = world.spawn((Camera3d::default(), example_camera())).id();
    let mut run = Run::default();
    for frame in 0..FRAMES + WARM_UP {
        if orbit {
            let angle = std::f32::consts::TAU * frame.saturating_sub(WARM_UP) as f32 / FRAMES as f32;
            let at = bevy_math::Vec3::new(25.0 * angle.cos(), 10.0, 25.0 * angle.sin());
            *app.world_mut().get_mut::<Transform>(camera).unwrap() =
                Transform::from_translation(at).looking_at(bevy_math::Vec3::ZERO, bevy_math::Vec3::Y);
        }
        drive(app.world_mut(), &mut city.cars, 1.0 / 60.0);
        let start = Instant::now();
        app.update();
        let elapsed = start.elapsed();
        if frame < WARM_UP {
            continue;
        }
        let marks = app.world().resource::<Marks<5>>().all();
        run.mirror.push(marks[1] - marks[0]);
        run.check.push(marks[2] - marks[1]);
        run.lights.push(marks[4] - marks[3]);
        run.frame.push(elapsed);
        let world = app.world_mut();
        let visible = world.query::<&ViewVisibility>().iter(world).filter(|v| v.get()).count();
        let cascades = world.get::<CascadesVisibleEntities>(city.sun).unwrap();
        let casters: usize = cascades.entities.values().flatten().map(|list| list.entities.len()).sum();
        if let Some(view) = world.get::<bevy_cullet::CulletView>(camera) {
            let stats = view.stats();
            let light_write = world.resource::<bevy_cullet::CulletLightStats>().write_time;
            let times = [
                stats.frustum_time,
                stats.raster_time + stats.occlusion_time,
                stats.light_occlusion_time,
                stats.write_time,
                light_write,
            ];
            run.stages.iter_mut().zip(times).for_each(|(sum, time)| *sum += time);
        }
        run.visible += visible as f64 / FRAMES as f64;
        run.casters += casters as f64 / FRAMES as f64;
    }
    (run, city.meshes.len(), city.cars.len())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    // As the plugin's docs advise: the main thread, which runs the plugin's culling, is one of rayon's.
    rayon::ThreadPoolBuilder::new().use_current_thread().build_global()?;
    let configurations: [(&str, Option<CulletSettings>); 2] =
        [("bevy", None), ("cullet", Some(CulletSettings::default()))];
    let view = if args.orbit { "orbiting the city" } else { "at the example's start view" };
    println!(
        "{} threads; ms per frame, mean (median) of {FRAMES} frames, camera {view}",
        std::thread::available_parallelism()?
    );
    println!(
        "{:<8} {:>17} {:>17} {:>17} {:>17} {:>17} {:>9} {:>9}",
        "", "check", "lights", "check + lights", "mirror", "frame", "visible", "casters"
    );
    let mut csv = String::from(
        "configuration,check_ms,lights_ms,mirror_ms,frame_ms,check_median_ms,lights_median_ms,visible,casters\n",
    );
    let mut bevy_total = None;
    for (name, settings) in &configurations {
        if args.only.as_ref().is_some_and(|only| only != name) {
            continue;
        }
        let (run, meshes, cars) = fly(*settings, args.orbit);
        if bevy_total.is_none() {
            println!("{meshes} mesh entities, {cars} of them cars");
        }
        let both: Vec<Duration> = run.check.iter().zip(&run.lights).map(|(a, b)| *a + *b).collect();
        let total = mean_ms(&both);
        let bevy = *bevy_total.get_or_insert(total);
        println!(
            "{name:<8} {:>8.3} ({:>6.3}) {:>8.3} ({:>6.3}) {:>8.3} ({:>6.3}) {:>8.3} ({:>6.3}) {:>8.3} ({:>6.3}) {:>9.0} {:>9.0}  {:.1}% of bevy's check + lights",
            mean_ms(&run.check),
            median_ms(&run.check),
            mean_ms(&run.lights),
            median_ms(&run.lights),
            total,
            median_ms(&both),
            mean_ms(&run.mirror),
            median_ms(&run.mirror),
            mean_ms(&run.frame),
            median_ms(&run.frame),
            run.visible,
            run.casters,
            100.0 * total / bevy,
        );
        if settings.is_some() {
            let [frustum, occlusion, light_occlusion, write, light_write] =
                run.stages.map(|t| t.as_secs_f64() * 1e3 / FRAMES as f64);
            println!(
                "{:>8} frustum {frustum:.3}, occlusion {occlusion:.3}, light occlusion {light_occlusion:.3}, write \
                 {write:.3}, light write {light_write:.3}",
                "stages:"
            );
        }
        writeln!(
            csv,
            "{name},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.0},{:.0}",
            mean_ms(&run.check),
            mean_ms(&run.lights),
            mean_ms(&run.mirror),
            mean_ms(&run.frame),
            median_ms(&run.check),
            median_ms(&run.lights),
            run.visible,
            run.casters
        )?;
    }
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/bevy_visibility");
    std::fs::create_dir_all(&out)?;
    std::fs::write(out.join(if args.orbit { "bevy_city_orbit.csv" } else { "bevy_city.csv" }), csv)?;
    Ok(())
}
