//! The bounding volume hierarchy against the linear arrays: the pipeline's stages (`StageCuller`, the SoA
//! arrays with their group hierarchy) and `HierarchyCuller`, both with the default occlusion settings, over
//! the city's fly-through at several sizes, on one thread and on all, in three stores: the city at rest, the
//! city with its cars moving (the tree refitted each frame, the arrays updated in place), and the city at
//! rest spawned in a shuffled order (store slots with no spatial order, which the arrays' groups rely on).
//! Time is the mean per frame of the frustum, raster and occlusion stages (the tree's refit in its frustum
//! time), fastest of three passes.
//!
//! `cargo bench -p cullet-benches --bench hierarchy`; `CULLET_HIERARCHY_SIZES` (comma-separated, default
//! `10000,100000,1000000`) and `CULLET_HIERARCHY_FRAMES` (default 30). Writes
//! `target/hierarchy/hierarchy.csv`.

use cullet::culler::{Culler, HierarchyCuller, StageCuller, ViewSettings};
use cullet::scene::Scene;
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use std::fmt::Write as _;
use std::path::PathBuf;

/// Makes a fresh culler for a pass.
type MakeCuller = dyn Fn() -> Box<dyn Culler> + Sync;

/// Passes over the path per configuration; the fastest is kept.
const PASSES: usize = 3;

/// `objects` in a deterministic shuffled order (Fisher-Yates with SplitMix64).
fn shuffled(scene: &Scene) -> Scene {
    let mut objects = scene.objects.clone();
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    for i in (1..objects.len()).rev() {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        objects.swap(i, ((z ^ (z >> 31)) % (i as u64 + 1)) as usize);
    }
    Scene::new(scene.meshes.clone(), objects)
}

/// Mean milliseconds a frame of `culler` over `frames` frames of `scene`'s `path`, fastest of [`PASSES`],
/// and the objects it kept a frame on average.
fn time(scene: &Scene, path: &cullet::CameraPath, frames: u32, make: &MakeCuller) -> (f64, f64) {
    let mut best = (f64::INFINITY, 0.0);
    for _ in 0..PASSES {
        let mut flight = Flight::for_cullers(path.clone(), 16.0 / 9.0, frames, |world| {
            scene.spawn(world);
        });
        let mut culler = make();
        let (mut total, mut kept) = (0.0, 0usize);
        for frame in 0..frames {
            let stats = flight.cull_frame(frame, culler.as_mut()).1.stats;
            total += (stats.frustum_time + stats.raster_time + stats.occlusion_time).as_secs_f64();
            kept += stats.after_occlusion;
        }
        let mean = total / f64::from(frames) * 1e3;
        if mean < best.0 {
            best = (mean, kept as f64 / f64::from(frames));
        }
    }
    best
}

fn main() {
    if std::env::args().skip(1).any(|a| !a.starts_with('-') && !"hierarchy".contains(a.as_str())) {
        return;
    }
    let sizes: Vec<usize> = std::env::var("CULLET_HIERARCHY_SIZES")
        .unwrap_or_else(|_| "10000,100000,1000000".into())
        .split(',')
        .map(|s| s.trim().parse().expect("a size"))
        .collect();
    let frames: u32 = std::env::var("CULLET_HIERARCHY_FRAMES").ok().and_then(|f| f.parse().ok()).unwrap_or(30);
    let all = rayon::current_num_threads();
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let mut csv = String::from("objects,store,threads,culler,ms_per_frame,kept_per_frame\n");
    println!("{all} threads; {frames} frames of the fly-through, fastest of {PASSES} passes, ms a frame");
    for &objects in &sizes {
        let moving = CityScene::generate(CityParams::with_objects(objects));
        let resting = CityScene::generate(CityParams { moving_fraction: 0.0, ..CityParams::with_objects(objects) });
        let path = moving.flythrough();
        let stores =
            [("at rest", resting.scene.clone()), ("moving", moving.scene), ("shuffled", shuffled(&resting.scene))];
        for (store, scene) in &stores {
            for threads in [1, all] {
                let cullers: [(&str, &MakeCuller); 2] = [
                    ("arrays", &|| Box::new(StageCuller::new("arrays", ViewSettings::default()))),
                    ("hierarchy", &|| Box::new(HierarchyCuller::default())),
                ];
                let mut line = format!("{objects:>8} {store:<8} {threads:>2} threads:");
                for (name, make) in cullers {
                    let run = || time(scene, &path, frames, make);
                    let (ms, kept) = if threads == 1 { one.install(run) } else { run() };
                    write!(line, "  {name} {ms:7.3} ms ({kept:.0} kept)").unwrap();
                    writeln!(csv, "{objects},{store},{threads},{name},{ms:.4},{kept:.1}").unwrap();
                }
                println!("{line}");
            }
        }
    }
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/hierarchy");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("hierarchy.csv"), csv).unwrap();
    println!("wrote {}", dir.join("hierarchy.csv").display());
}
