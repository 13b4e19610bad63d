//! Run time against error: sweeps the software occlusion buffer's resolution, its mode and the occluder
//! budget over the city's fly-through (and the pixel-centre mode at the viewport's resolution, 1920x1080),
//! each configuration a culler run through the engine's culler interface (`cullet::culler::Culler`, here the
//! pipeline's stages, `StageCuller`, with those settings; another culler is another series), judging every
//! frame against the exact ground truth, and writes `target/tradeoff/tradeoff.csv` and
//! `target/tradeoff/tradeoff.png` (the Pareto front). Intel's Masked Occlusion Culling is a series of its own
//! where it is built (see `build.rs`): at each resolution and the viewport's, given each frame the frustum
//! survivors and occluders of Cullet's default configuration. The occluders' shadow frusta (`ShadowFrustaCuller`)
//! are a series at each budget, on the same occluders as the depth buffer at that budget. Last, the default and the settings for the
//! 1920x1080 frame (`OcclusionSettings::for_frame`) are timed against each other in alternating passes, on
//! rayon's threads and on one (CPU time), into `target/tradeoff/paired.csv`; in the building, the portals before
//! the default buffer against the default buffer alone the same way, into `target/tradeoff/building-paired.csv`.
//!
//! truck_town and zdm2, nobody here's scenes (with automatic occluders, around their orbits), are judged the same way with
//! fewer configurations (frustum only, the default buffer at each budget, the masked buffers for the frame,
//! the shadow frusta at each budget, MOC); their rows are in the same CSV (column `scene`), and no plot.
//!
//! Detail culling (`cullet::detail`, lossy) before the default buffer is a series at 1, 2 and 4 pixels.
//!
//! Where a GPU is found (lavapipe will do), hardware occlusion queries over a uniform grid
//! (`cullet::gpu::QueryGridCuller`, lossy: a cell coming into view is drawn a frame late) are a series on
//! every scene: the thesis's cap of 4000 queries a frame, no cap, a cap of 500, no cap and no spreading
//! (visible results lasting one frame), and the thesis's own settings.
//! Its time is the CPU's (binning, traversal, recording); the GPU's depth pass and queries are not counted.
//!
//! The bounding volume hierarchy (`HierarchyCuller`) and cells and portals (`PortalCuller`), each before the
//! default buffer, are a series on every scene; the generated building (`cullet::scene::building`, its walk) is
//! one more scene, judged like the shared ones.
//!
//! `cargo bench -p cullet-benches --bench tradeoff`; `CULLET_TRADEOFF_ONLY` (series names as in the CSV's
//! `peer` column, comma-separated) runs only those with the default and frustum only; `CULLET_TRADEOFF_OBJECTS` (default 100000) and
//! `CULLET_TRADEOFF_FRAMES` (default 200) size the city's run, `CULLET_TRADEOFF_SCENE_FRAMES` (default 60)
//! each shared scene's, and `CULLET_TRADEOFF_SCENES` (default `city,truck_town,zdm2,building`; `CULLET_TRADEOFF_BUILDING_OBJECTS`, default 1500, sizes the
//! building) chooses the scenes.

#[path = "moc/mod.rs"]
mod moc;

use cullet::camera::CameraPath;
use cullet::culler::{
    Culled, Culler, HierarchyCuller, HierarchySettings, OcclusionSettings, PortalCuller, PortalSettings,
    ShadowFrustaCuller, ShadowFrustaSettings, StageCuller, ViewSettings,
};
use cullet::detail::DetailSettings;
use cullet::gpu::{GpuContext, QueryGridCuller, QueryGridSettings};
use cullet::raster::RasterMode;
use cullet::scene::Scene;
use cullet::scene::auto_occluders::{AutoOccluderSettings, add_auto_occluders};
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use cullet::scene::gltf_import::load_gltf;
use cullet_truth::FrameMetrics;
use cullet_truth::judge::{occlusion_ideal_of, render_world};
use cullet_truth::metrics::OcclusionIdeal;
use cullet_truth::{ExactVisibility, PathMetrics, ReferenceSettings};
use moc::{Moc, Occludees};
use plotters::prelude::*;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::{Duration, Instant};

const RESOLUTIONS: [(u32, u32); 5] = [(64, 36), (128, 72), (256, 144), (512, 288), (1024, 576)];
const BUDGETS: [usize; 4] = [1024, 4096, 8192, 16_384];
/// The masked buffer's budgets: also 2048 and 3072, between which it crosses 97% culled.
const MASKED_BUDGETS: [usize; 6] = [1024, 2048, 3072, 4096, 8192, 16_384];
/// Masked buffers below the 1920x1080 frame's resolution, standing for its pixels: half of it (two thirds is
/// no better than a third, see `ScreenView::for_frame`).
const MASKED_BELOW_FRAME: [(u32, u32); 1] = [(960, 540)];
/// Their budgets.
const MASKED_BELOW_FRAME_BUDGETS: [usize; 5] = [2048, 4096, 5120, 6144, 8192];
/// Detail culling's thresholds: objects projecting under this many pixels of the frame are dropped.
const DETAIL_PIXELS: [u32; 3] = [1, 2, 4];
/// Timed passes per configuration, after the judged one; the fastest is kept (the machine is noisy, the work is
/// deterministic). Each round times every configuration once, so that a slow stretch of the machine slows one
/// pass of each rather than every pass of a few.
const TIMED_ROUNDS: usize = 3;
/// Alternating passes of each of the two configurations [`paired_for_frame`] compares.
const PAIRED_PASSES: usize = 8;
/// Alternating passes of the default and the portals in the building: a pass is a fiftieth of the city's, and
/// the difference a few percent.
const BUILDING_PAIRED_PASSES: usize = 64;

/// Which culler a row is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Series {
    /// The pipeline's stages with the row's settings (`StageCuller`).
    Stages,
    /// Intel MOC at the row's resolution and budget, given the default's survivors and occluders.
    Moc,
    /// The occluders' shadow frusta at the row's budget (`ShadowFrustaCuller`).
    ShadowFrusta,
    /// The pipeline's stages with the row's settings, dropping the frustum's survivors that project under
    /// this many pixels of the frame judged (`cullet::detail`, lossy).
    Detail(u32),
    /// Hardware occlusion queries over a uniform grid (`cullet::gpu::QueryGridCuller`, lossy), on the GPU the
    /// bench finds, with the given query cap (`None`: none), or as the thesis has it.
    QueryGrid(QueryGridVariant),
    /// A bounding volume hierarchy, then the occlusion stage with the row's settings (`HierarchyCuller`).
    Hierarchy,
    /// Cells and portals, then the occlusion stage with the row's settings (`PortalCuller`); without cells,
    /// the frustum alone before it.
    Portals,
}

/// Which query grid a row is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum QueryGridVariant {
    /// The engine's settings with this query cap (`None`: no cap).
    Capped(Option<u32>),
    /// No cap and no spreading: visible cells queried again every frame, as hidden ones are.
    Unspread,
    /// `QueryGridSettings::thesis()`: hidden results last 2 frames and are trusted however old.
    Thesis,
}

impl QueryGridVariant {
    const ALL: [Self; 5] =
        [Self::Capped(Some(4000)), Self::Capped(None), Self::Capped(Some(500)), Self::Unspread, Self::Thesis];

    /// Its settings; the judged pass waits for each frame's results, as a GPU that keeps up delivers them.
    fn settings(self) -> QueryGridSettings {
        let settings = match self {
            Self::Capped(query_cap) => QueryGridSettings { query_cap, ..QueryGridSettings::default() },
            Self::Unspread => {
                QueryGridSettings { query_cap: None, visible_lifetime: 1, ..QueryGridSettings::default() }
            }
            Self::Thesis => QueryGridSettings::thesis(),
        };
        QueryGridSettings { wait_for_results: true, ..settings }
    }

    fn label(self) -> String {
        match self {
            Self::Capped(Some(cap)) => format!("query grid cap {cap}"),
            Self::Capped(None) => "query grid no cap".into(),
            Self::Unspread => "query grid no cap no spreading".into(),
            Self::Thesis => "query grid as the thesis".into(),
        }
    }
}

/// The GPU the query grid runs on, opened once; `None` (and no query grid rows) without one.
fn gpu() -> Option<&'static GpuContext> {
    static CONTEXT: std::sync::OnceLock<Option<GpuContext>> = std::sync::OnceLock::new();
    CONTEXT.get_or_init(|| GpuContext::new().map_err(|error| println!("SKIPPED the query grid: {error}")).ok()).as_ref()
}

impl Series {
    fn name(self) -> &'static str {
        match self {
            Self::Stages => "cullet",
            Self::Moc => "moc",
            Self::ShadowFrusta => "cullet-shadow-frusta",
            Self::Detail(_) => "cullet-detail",
            Self::QueryGrid(_) => "cullet-query-grid",
            Self::Hierarchy => "cullet-hierarchy",
            Self::Portals => "cullet-portals",
        }
    }
}

/// The culler of a Cullet row, for `flight`'s world of `scene`.
fn culler_for(series: Series, settings: OcclusionSettings, flight: &Flight, scene: &Scene) -> Box<dyn Culler> {
    match series {
        Series::QueryGrid(variant) => {
            let context = gpu().expect("query grid rows only where a GPU was found");
            let viewport = settings.frame.unwrap_or((1920, 1080));
            Box::new(QueryGridCuller::new(context, &flight.world, &scene.meshes, viewport, variant.settings()))
        }
        Series::Hierarchy => {
            Box::new(HierarchyCuller::new(HierarchySettings { occlusion: settings, ..Default::default() }))
        }
        Series::Portals => Box::new(PortalCuller::new(PortalSettings { occlusion: settings, ..Default::default() })),
        Series::ShadowFrusta => {
            let triangle_budget = settings.triangle_budget;
            Box::new(ShadowFrustaCuller::new(ShadowFrustaSettings { triangle_budget, ..Default::default() }))
        }
        Series::Stages | Series::Moc | Series::Detail(_) => {
            let min_pixels = if let Series::Detail(pixels) = series { pixels as f32 } else { 0.0 };
            let viewport_height = settings.frame.map_or(1080, |(_, height)| height);
            let detail = DetailSettings { min_pixels, viewport_height };
            let settings = ViewSettings { occlusion: settings, detail, ..ViewSettings::default() };
            Box::new(StageCuller::new(format!("{settings:?}"), settings))
        }
    }
}

/// One configuration's results over a scene's path.
struct Row {
    /// The scene judged.
    scene: &'static str,
    series: Series,
    /// The occlusion buffer's settings (a shadow frusta row: its budget).
    settings: OcclusionSettings,
    /// Mean per-frame times of the fastest pass, microseconds: bounds and frustum, raster, occlusion test.
    frustum_us: f64,
    raster_us: f64,
    occlusion_us: f64,
    accuracy: PathMetrics,
    on_front: bool,
}

impl Row {
    /// A row not timed yet: its time infinite until a pass is timed.
    fn untimed(scene: &'static str, series: Series, settings: OcclusionSettings, accuracy: PathMetrics) -> Self {
        let (frustum_us, raster_us, occlusion_us) = (f64::INFINITY, 0.0, 0.0);
        Self { scene, series, settings, frustum_us, raster_us, occlusion_us, accuracy, on_front: false }
    }

    /// Whether it never hides what a rendering of `viewport` shows.
    fn is_conservative_for(&self, viewport: (u32, u32)) -> bool {
        match self.series {
            Series::Stages | Series::Hierarchy | Series::Portals => self.settings.is_conservative_for(viewport),
            Series::ShadowFrusta => true,
            Series::Moc | Series::Detail(_) | Series::QueryGrid(_) => false,
        }
    }

    /// Mean per-frame time of all culling stages, fastest pass, microseconds.
    fn cull_us(&self) -> f64 {
        self.frustum_us + self.raster_us + self.occlusion_us
    }

    fn label(&self) -> String {
        match self.series {
            Series::Moc => {
                let s = &self.settings;
                return format!("MOC {}x{} {}", s.width, s.height, s.triangle_budget);
            }
            Series::ShadowFrusta => return format!("shadow frusta {}", self.settings.triangle_budget),
            Series::QueryGrid(variant) => return variant.label(),
            Series::Hierarchy => return "hierarchy + default".into(),
            Series::Portals => return "portals + default".into(),
            Series::Detail(pixels) => {
                let s = &self.settings;
                return format!(
                    "{}x{} {} {} + detail {pixels} px",
                    s.width,
                    s.height,
                    s.mode.name(),
                    s.triangle_budget
                );
            }
            Series::Stages => {}
        }
        if !self.settings.enabled {
            return "frustum only".into();
        }
        let s = &self.settings;
        format!("{}x{} {} {}", s.width, s.height, s.mode.name(), s.triangle_budget)
    }

    fn is_default(&self) -> bool {
        self.series == Series::Stages
            && self.settings == OcclusionSettings { frame: self.settings.frame, ..OcclusionSettings::default() }
    }

    fn efficiency(&self) -> f64 {
        self.accuracy.final_efficiency()
    }

    fn false_negatives_per_frame(&self) -> f64 {
        self.accuracy.false_negatives as f64 / self.accuracy.frames as f64
    }

    fn image_error_per_frame(&self) -> f64 {
        self.accuracy.image_error_pixels as f64 / self.accuracy.frames as f64
    }
}

fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// A scene flown along a camera path, every frame judged against the exact ground truth.
struct JudgedScene<'a> {
    name: &'static str,
    scene: &'a Scene,
    path: CameraPath,
    frames: u32,
}

impl JudgedScene<'_> {
    /// The scene flown with the pipeline's stages installed, with `settings`.
    fn flight(&self, settings: OcclusionSettings) -> Flight {
        Flight::new(self.path.clone(), 16.0 / 9.0, self.frames, settings, |world| {
            self.scene.spawn(world);
        })
    }

    /// The scene flown for a culler of its own (`Flight::cull_frame`): the same path, frames and moving objects.
    fn culler_flight(&self) -> Flight {
        Flight::for_cullers(self.path.clone(), 16.0 / 9.0, self.frames, |world| {
            self.scene.spawn(world);
        })
    }
}

fn main() {
    // `cargo bench` passes `--bench`; a filter argument from `cargo bench -- x` that is not ours skips the run.
    if std::env::args().skip(1).any(|a| !a.starts_with('-') && !"tradeoff".contains(a.as_str())) {
        return;
    }
    let objects = env_or("CULLET_TRADEOFF_OBJECTS", 100_000);
    let frames = env_or("CULLET_TRADEOFF_FRAMES", 200) as u32;
    let chosen = std::env::var("CULLET_TRADEOFF_SCENES").unwrap_or_else(|_| "city,truck_town,zdm2,building".into());
    let chosen: Vec<&str> = chosen.split(',').map(str::trim).collect();
    let reference = ReferenceSettings::default();
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/tradeoff");
    std::fs::create_dir_all(&dir).unwrap();
    let mut rows = Vec::new();

    if chosen.contains(&"city") {
        let city = CityScene::generate(CityParams::with_objects(objects));
        let judged = JudgedScene { name: "city", scene: &city.scene, path: city.flythrough(), frames };
        let mut city_rows = sweep(&judged, city_configs(&reference), &reference);
        mark_pareto_front(&mut city_rows, (reference.width, reference.height));
        let default = city_rows.iter().find(|r| r.is_default()).unwrap();
        println!("default {} is {}on the Pareto front", default.label(), if default.on_front { "" } else { "NOT " });
        plot(&city_rows, &dir.join("tradeoff.png"), objects, frames).unwrap();
        rows.extend(city_rows);

        let mut paired_csv = String::from("threads,passes,default_us,for_frame_us,median_ratio\n");
        let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        for threads in [rayon::current_num_threads(), 1] {
            let pool = if threads == 1 { Some(&one_thread) } else { None };
            let (default, for_frame, ratio) = paired_for_frame(&|settings| judged.flight(settings), frames, pool);
            println!(
                "default against for_frame(1920, 1080), {threads} thread(s), {PAIRED_PASSES} alternating passes: \
                 fastest {default:.1} and {for_frame:.1} us/frame, median ratio {ratio:.3}"
            );
            writeln!(paired_csv, "{threads},{PAIRED_PASSES},{default:.1},{for_frame:.1},{ratio:.4}").unwrap();
        }
        std::fs::write(dir.join("paired.csv"), paired_csv).unwrap();
    }

    if chosen.contains(&"building") {
        let building = cullet::scene::building::building(env_or("CULLET_TRADEOFF_BUILDING_OBJECTS", 1500));
        let frames = env_or("CULLET_TRADEOFF_SCENE_FRAMES", 60) as u32;
        let path = cullet::scene::building::walk();
        let judged = JudgedScene { name: "building", scene: &building, path, frames };
        let mut scene_rows = sweep(&judged, scene_configs(&reference), &reference);
        mark_pareto_front(&mut scene_rows, (reference.width, reference.height));
        rows.extend(scene_rows);

        let frame = Some((reference.width, reference.height));
        let default = (Series::Stages, OcclusionSettings { frame, ..OcclusionSettings::default() });
        let portals = (Series::Portals, default.1);
        let passes = BUILDING_PAIRED_PASSES;
        let (default_us, portals_us, ratio) = paired_cullers(&judged, passes, default, portals);
        println!(
            "building: the default against portals + default, {passes} alternating passes: fastest \
             {default_us:.1} and {portals_us:.1} us/frame, median ratio {ratio:.3}"
        );
        let csv =
            format!("passes,default_us,portals_us,median_ratio\n{passes},{default_us:.1},{portals_us:.1},{ratio:.4}\n");
        std::fs::write(dir.join("building-paired.csv"), csv).unwrap();
    }

    // Nobody here's scenes: truck_town and zdm2 with automatic occluders (they have no artist ones), around
    // their orbits.
    for (name, file) in [("truck_town", "truck_town/town_model.gltf"), ("zdm2", "zdm2/zdm2.glb")] {
        if !chosen.contains(&name) {
            continue;
        }
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes").join(file);
        match load_gltf(&path) {
            Ok(mut loaded) => {
                add_auto_occluders(&mut loaded.scene, &AutoOccluderSettings::default());
                let frames = env_or("CULLET_TRADEOFF_SCENE_FRAMES", 60) as u32;
                let path = loaded.scene.orbit_path();
                let judged = JudgedScene { name, scene: &loaded.scene, path, frames };
                let mut scene_rows = sweep(&judged, scene_configs(&reference), &reference);
                mark_pareto_front(&mut scene_rows, (reference.width, reference.height));
                rows.extend(scene_rows);
            }
            Err(error) => println!("SKIPPED {name}: {error}"),
        }
    }

    std::fs::write(dir.join("tradeoff.csv"), csv(&rows)).unwrap();
    println!("wrote {}", dir.canonicalize().unwrap().display());
}

/// The city's configurations: every resolution, mode and budget of the sweep, and the shadow frusta at each
/// budget.
fn city_configs(reference: &ReferenceSettings) -> Vec<(Series, OcclusionSettings)> {
    let frame = Some((reference.width, reference.height));
    let mut configs = vec![OcclusionSettings { enabled: false, ..OcclusionSettings::default() }];
    for (width, height) in RESOLUTIONS {
        for mode in [RasterMode::Conservative, RasterMode::Fast] {
            for triangle_budget in BUDGETS {
                configs.push(OcclusionSettings { enabled: true, width, height, mode, triangle_budget, frame });
            }
        }
    }
    // Pixel centres, per pixel or masked per block, are conservative at the resolution of the rendering
    // judged, the viewport's.
    for (mode, budgets) in [(RasterMode::PixelCentres, &BUDGETS[..]), (RasterMode::Masked, &MASKED_BUDGETS[..])] {
        for &triangle_budget in budgets {
            let (width, height) = (reference.width, reference.height);
            configs.push(OcclusionSettings { enabled: true, width, height, mode, triangle_budget, frame });
        }
    }
    // The masked buffer below the frame's resolution, each sample standing for the frame's pixel centres in
    // its square (`OcclusionSettings::frame`): conservative for the frame too.
    for (width, height) in MASKED_BELOW_FRAME {
        for triangle_budget in MASKED_BELOW_FRAME_BUDGETS {
            let mode = RasterMode::Masked;
            configs.push(OcclusionSettings { enabled: true, width, height, mode, triangle_budget, frame });
        }
    }
    let mut configs: Vec<(Series, OcclusionSettings)> =
        configs.into_iter().map(|settings| (Series::Stages, settings)).collect();
    // The shadow frusta at each budget: the depth buffer's occluders at that budget, without the buffer.
    for triangle_budget in BUDGETS {
        configs.push((Series::ShadowFrusta, OcclusionSettings { triangle_budget, ..OcclusionSettings::default() }));
    }
    // Detail culling (lossy) before the default buffer.
    for pixels in DETAIL_PIXELS {
        configs.push((Series::Detail(pixels), OcclusionSettings { frame, ..OcclusionSettings::default() }));
    }
    configs.extend(query_grid_configs(reference));
    configs.extend(structure_configs(reference));
    configs
}

/// The hierarchy's and the portals' rows, each before the default buffer.
fn structure_configs(reference: &ReferenceSettings) -> Vec<(Series, OcclusionSettings)> {
    let frame = Some((reference.width, reference.height));
    let default = OcclusionSettings { frame, ..OcclusionSettings::default() };
    vec![(Series::Hierarchy, default), (Series::Portals, default)]
}

/// The query grid's rows, where a GPU is found: its cap at the thesis's 4000, none and 500, and as the thesis.
fn query_grid_configs(reference: &ReferenceSettings) -> Vec<(Series, OcclusionSettings)> {
    let frame = Some((reference.width, reference.height));
    let variants = if gpu().is_some() { &QueryGridVariant::ALL[..] } else { &[] };
    variants
        .iter()
        .map(|&v| (Series::QueryGrid(v), OcclusionSettings { frame, ..OcclusionSettings::default() }))
        .collect()
}

/// A shared scene's configurations, fewer than the city's: frustum only, the default buffer at each budget,
/// the masked buffers for the viewport's frame at the default budget, and the shadow frusta at each budget.
fn scene_configs(reference: &ReferenceSettings) -> Vec<(Series, OcclusionSettings)> {
    let frame = Some((reference.width, reference.height));
    let default = OcclusionSettings { frame, ..OcclusionSettings::default() };
    let mut configs = vec![(Series::Stages, OcclusionSettings { enabled: false, ..default })];
    for triangle_budget in BUDGETS {
        configs.push((Series::Stages, OcclusionSettings { triangle_budget, ..default }));
    }
    let masked = OcclusionSettings { mode: RasterMode::Masked, ..default };
    let (width, height) = (reference.width, reference.height);
    configs.push((Series::Stages, OcclusionSettings { width, height, ..masked }));
    for (width, height) in MASKED_BELOW_FRAME {
        configs.push((Series::Stages, OcclusionSettings { width, height, triangle_budget: 5120, ..masked }));
    }
    for triangle_budget in BUDGETS {
        configs.push((Series::ShadowFrusta, OcclusionSettings { triangle_budget, ..OcclusionSettings::default() }));
    }
    configs.extend(query_grid_configs(reference));
    configs.extend(structure_configs(reference));
    configs
}

/// Judges every configuration of `configs` over `judged`'s path against the exact rendering, times each in
/// [`TIMED_ROUNDS`] rounds, and adds Intel MOC's rows where it is built. The rows, untouched by the Pareto
/// front.
fn sweep(judged: &JudgedScene, configs: Vec<(Series, OcclusionSettings)>, reference: &ReferenceSettings) -> Vec<Row> {
    let frames = judged.frames;
    // `CULLET_TRADEOFF_ONLY` (series names, comma-separated) keeps those series, the default and frustum only.
    let only = std::env::var("CULLET_TRADEOFF_ONLY").ok();
    let wanted =
        |series: Series| only.as_ref().is_none_or(|only| only.split(',').any(|name| name.trim() == series.name()));
    let configs: Vec<(Series, OcclusionSettings)> = configs
        .into_iter()
        .filter(|&(series, settings)| {
            let default = OcclusionSettings { frame: settings.frame, ..OcclusionSettings::default() };
            wanted(series) || (series == Series::Stages && (settings == default || !settings.enabled))
        })
        .collect();
    let start = Instant::now();
    let mut truth_flight = judged.flight(OcclusionSettings::default());
    let truth: Vec<ExactVisibility> = (0..frames)
        .map(|frame| {
            truth_flight.run_frame(frame);
            render_world(&truth_flight.world, &judged.scene.meshes, reference).visibility()
        })
        .collect();
    println!(
        "{}: exact visibility of {frames} frames of {} objects in {:.1} s",
        judged.name,
        judged.scene.objects.len(),
        start.elapsed().as_secs_f64()
    );
    // Frustum survivors an exact 1920x1080 buffer of the same occluders culls, per budget and frame.
    let mut ideal: HashMap<usize, Vec<usize>> = HashMap::new();
    let mut rows = Vec::new();
    for (series, settings) in configs {
        let start = Instant::now();
        let mut accuracy = PathMetrics::default();
        let run = &mut judged.culler_flight();
        let mut stages_culler = StageCuller::new("", ViewSettings { occlusion: settings, ..ViewSettings::default() });
        let mut other = culler_for(series, settings, run, judged.scene);
        let budget_ideal = settings.enabled.then(|| ideal.contains_key(&settings.triangle_budget));
        let mut ideal_this_budget = Vec::new();
        for frame in 0..frames {
            let culler: &mut dyn Culler = if series == Series::Stages { &mut stages_culler } else { other.as_mut() };
            let Culled { stages, .. } = run.cull_frame(frame, culler).1;
            let mut metrics = FrameMetrics::new(&truth[frame as usize], &stages);
            if settings.enabled {
                let culled = metrics.stages[0].kept - metrics.stages[1].kept;
                let ideal_culled = match budget_ideal {
                    Some(true) => ideal[&settings.triangle_budget][frame as usize],
                    // Only the pipeline's stages run before the other series, so they measure the ideals.
                    _ if stages_culler.view().occluder_slots().is_empty() => 0,
                    _ => {
                        let camera = run.world.resource::<cullet::Camera>();
                        occlusion_ideal_of(&run.world, camera, stages_culler.view(), reference).ideal_culled
                    }
                };
                ideal_this_budget.push(ideal_culled);
                metrics.occlusion_ideal = Some(OcclusionIdeal { culled, ideal_culled });
            }
            accuracy.add(&metrics);
        }
        if budget_ideal == Some(false) {
            ideal.insert(settings.triangle_budget, ideal_this_budget);
        }
        let row = Row::untimed(judged.name, series, settings, accuracy);
        println!("{:<28} judged in {:.1} s", row.label(), start.elapsed().as_secs_f64());
        rows.push(row);
    }
    let mut moc = match wanted(Series::Moc) {
        true => MocSeries::new(judged.flight(OcclusionSettings::default()), &truth, judged.name),
        false => None,
    };
    let start = Instant::now();
    for round in 0..TIMED_ROUNDS {
        for row in rows.iter_mut() {
            let run = judged.culler_flight();
            let mut culler = culler_for(row.series, row.settings, &run, judged.scene);
            let mut run = run;
            let pass: Vec<[Duration; 3]> = (0..frames)
                .map(|frame| {
                    let (bounds_time, Culled { stats, .. }) = run.cull_frame(frame, culler.as_mut());
                    [bounds_time + stats.frustum_time, stats.raster_time, stats.occlusion_time]
                })
                .collect();
            let mean = |part: usize| pass.iter().map(|s| s[part].as_secs_f64()).sum::<f64>() / pass.len() as f64 * 1e6;
            let (frustum, raster, occlusion) = (mean(0), mean(1), mean(2));
            if frustum + raster + occlusion < row.cull_us() {
                (row.frustum_us, row.raster_us, row.occlusion_us) = (frustum, raster, occlusion);
            }
        }
        if let Some(moc) = &mut moc {
            moc.time_pass(judged.flight(OcclusionSettings::default()));
        }
        println!("timed round {} of {TIMED_ROUNDS} in {:.1} s", round + 1, start.elapsed().as_secs_f64());
    }
    for row in &rows {
        print_row(row);
    }
    let default = rows.iter().find(|r| r.is_default()).unwrap();
    let frustum_us = default.frustum_us;
    if let Some(moc) = moc {
        rows.extend(moc.rows(frustum_us));
    }
    rows
}

/// The default settings against those for the 1920x1080 frame (`OcclusionSettings::for_frame`), the new
/// default wherever the frame is known: their mean time a frame (bounds, frustum, raster and occlusion test)
/// over the path, in [`paired`] passes, on `pool` where given, else on rayon's global one.
fn paired_for_frame(
    flight: &(impl Fn(OcclusionSettings) -> Flight + Sync),
    frames: u32,
    pool: Option<&rayon::ThreadPool>,
) -> (f64, f64, f64) {
    let pass_us = |settings: OcclusionSettings| {
        let run = || {
            let mut run = flight(settings);
            let total = (0..frames).map(|frame| {
                let stats = run.run_frame(frame);
                (stats.bounds_time + stats.frustum_time + stats.raster_time + stats.occlusion_time).as_secs_f64()
            });
            total.sum::<f64>() / frames.max(1) as f64 * 1e6
        };
        pool.map_or_else(run, |pool| pool.install(run))
    };
    let (default, for_frame) = (OcclusionSettings::default(), OcclusionSettings::for_frame(1920, 1080));
    paired(PAIRED_PASSES, || pass_us(default), || pass_us(for_frame))
}

/// Two cullers' mean time a frame over `judged`'s path, each a fresh culler on a flight of its own (the
/// culler's bounds, frustum, raster and occlusion time, as the sweep counts it), in `passes` [`paired`] passes.
fn paired_cullers(
    judged: &JudgedScene,
    passes: usize,
    a: (Series, OcclusionSettings),
    b: (Series, OcclusionSettings),
) -> (f64, f64, f64) {
    let pass_us = |(series, settings): (Series, OcclusionSettings)| {
        let mut run = judged.culler_flight();
        let mut culler = culler_for(series, settings, &run, judged.scene);
        let total = (0..judged.frames).map(|frame| {
            let (bounds_time, Culled { stats, .. }) = run.cull_frame(frame, culler.as_mut());
            (bounds_time + stats.frustum_time + stats.raster_time + stats.occlusion_time).as_secs_f64()
        });
        total.sum::<f64>() / judged.frames.max(1) as f64 * 1e6
    };
    paired(passes, || pass_us(a), || pass_us(b))
}

/// Times two passes, `a` and `b` (each returning its time), against each other in `passes` passes each,
/// alternating which goes first, so that a slow stretch of the machine slows both. Returns each one's fastest
/// pass and the median of the passes' ratios (`b`'s time over `a`'s).
fn paired(passes: usize, mut a: impl FnMut() -> f64, mut b: impl FnMut() -> f64) -> (f64, f64, f64) {
    let (mut fastest, mut ratios) = ((f64::INFINITY, f64::INFINITY), Vec::new());
    for pass in 0..passes.max(1) {
        let (a, b) = if pass % 2 == 0 {
            let a = a();
            (a, b())
        } else {
            let b = b();
            (a(), b)
        };
        fastest = (fastest.0.min(a), fastest.1.min(b));
        ratios.push(b / a);
    }
    ratios.sort_by(f64::total_cmp);
    (fastest.0, fastest.1, ratios[ratios.len() / 2])
}

fn print_row(row: &Row) {
    println!(
        "{:<28} {:8.1} us/frame  efficiency {:5.1}%  vs ideal {:5.1}%  false negatives {:7.2}/frame  \
         image error {:8.1} px/frame",
        row.label(),
        row.cull_us(),
        100.0 * row.efficiency(),
        100.0 * row.accuracy.occlusion_efficiency().unwrap_or(f64::NAN),
        row.false_negatives_per_frame(),
        row.image_error_per_frame(),
    );
}

/// Intel MOC at each resolution of the sweep and the viewport's (1920x1080), with the default triangle
/// budget, given each frame the frustum survivors and selected occluders of Cullet's default configuration.
/// MOC rasterizes on its own 2-thread pool and tests on rayon's. Its time per frame is its raster and
/// `TestRect` plus the default's bounds and frustum time: projecting the boxes, which MOC leaves to its caller,
/// is not counted (Cullet's time counts its own, and choosing the occluders).
struct MocSeries {
    sizes: Vec<(u32, u32)>,
    peers: Vec<Moc>,
    accuracy: Vec<PathMetrics>,
    /// Per size: the fastest pass's summed raster and `TestRect` seconds, and its summed projection seconds.
    fastest: Vec<(f64, f64, f64)>,
    frames: u32,
    scratch: Occludees,
    scene: &'static str,
}

impl MocSeries {
    /// Builds MOC at each size and judges it over the path `run` flies against `truth`. None, with a message,
    /// where MOC is not built.
    fn new(mut run: Flight, truth: &[ExactVisibility], scene: &'static str) -> Option<Self> {
        let start = Instant::now();
        let sizes: Vec<(u32, u32)> = RESOLUTIONS.iter().copied().chain([(1920, 1080)]).collect();
        let near = run.path.camera_at(0.0, run.aspect).near;
        let mut peers = match sizes.iter().map(|&(w, h)| Moc::new(w, h, near, 2)).collect::<Result<Vec<_>, _>>() {
            Ok(peers) => peers,
            Err(why) => {
                println!("SKIPPED the Intel MOC series: {why}");
                return None;
            }
        };
        println!("Intel MOC, {} back end, given the default's survivors and occluders", peers[0].implementation());
        let mut accuracy = vec![PathMetrics::default(); sizes.len()];
        let mut scratch = Occludees::default();
        for (frame, exact) in truth.iter().enumerate() {
            run.run_frame(frame as u32);
            for (peer, accuracy) in peers.iter_mut().zip(&mut accuracy) {
                accuracy.add(&moc::cull_world(peer, &run.world, 2, &mut scratch).judge(&run.world, exact));
            }
        }
        println!("MOC judged in {:.1} s", start.elapsed().as_secs_f64());
        let fastest = vec![(f64::INFINITY, 0.0, 0.0); sizes.len()];
        Some(Self { sizes, peers, accuracy, fastest, frames: truth.len() as u32, scratch, scene })
    }

    /// Times one pass of every size over the path `run` flies, keeping each size's fastest.
    fn time_pass(&mut self, mut run: Flight) {
        let mut pass = vec![(0.0, 0.0, 0.0); self.sizes.len()];
        for frame in 0..self.frames {
            run.run_frame(frame);
            for (peer, time) in self.peers.iter_mut().zip(&mut pass) {
                let culled = moc::cull_world(peer, &run.world, 2, &mut self.scratch);
                time.0 += culled.raster.as_secs_f64();
                time.1 += culled.test.as_secs_f64();
                time.2 += culled.project.as_secs_f64();
            }
        }
        for (fastest, time) in self.fastest.iter_mut().zip(pass) {
            if time.0 + time.1 < fastest.0 + fastest.1 {
                *fastest = time;
            }
        }
    }

    /// The series' rows, `frustum_us` (the default's bounds and frustum time) added to each.
    fn rows(self, frustum_us: f64) -> Vec<Row> {
        let frames = self.frames.max(1) as f64;
        self.sizes
            .into_iter()
            .zip(self.accuracy.into_iter().zip(self.fastest))
            .map(|((width, height), (accuracy, (raster, test, project)))| {
                let settings = OcclusionSettings { width, height, ..OcclusionSettings::default() };
                let mut row = Row::untimed(self.scene, Series::Moc, settings, accuracy);
                (row.frustum_us, row.raster_us, row.occlusion_us) =
                    (frustum_us, raster / frames * 1e6, test / frames * 1e6);
                print_row(&row);
                println!("    (MOC's box projection, not counted above: {:.1} us/frame)", project / frames * 1e6);
                row
            })
            .collect()
    }
}

/// Marks the conservative configurations (occlusion off, or on in a mode conservative for the `viewport` judged:
/// never a false negative by construction, and none measured) that no other conservative one dominates: none
/// is both at least as fast and at least as efficient, and better in one. Fast mode is left out even where this
/// path happened to show no false negative: it guarantees none.
fn mark_pareto_front(rows: &mut [Row], viewport: (u32, u32)) {
    let conservative = |r: &Row| r.accuracy.false_negatives == 0 && r.is_conservative_for(viewport);
    let exact: Vec<(f64, f64)> =
        rows.iter().filter(|r| conservative(r)).map(|r| (r.cull_us(), r.efficiency())).collect();
    for row in rows.iter_mut().filter(|r| conservative(r)) {
        let (time, efficiency) = (row.cull_us(), row.efficiency());
        row.on_front = !exact.iter().any(|&(t, e)| t <= time && e >= efficiency && (t < time || e > efficiency));
    }
}

fn csv(rows: &[Row]) -> String {
    let mut out = String::from(
        "scene,config,peer,occlusion,width,height,mode,triangle_budget,frames,mean_cull_us,mean_raster_us,mean_occlusion_us,\
         frustum_efficiency,culling_efficiency,occlusion_efficiency_vs_ideal,false_negatives,\
         frames_with_false_negatives,image_error_pixels_per_frame,worst_image_error_pixels,pareto_front\n",
    );
    for r in rows {
        let s = &r.settings;
        writeln!(
            out,
            "{},{},{},{},{},{},{:?},{},{},{:.1},{:.1},{:.1},{:.4},{:.4},{},{},{},{:.1},{},{}",
            r.scene,
            r.label(),
            r.series.name(),
            s.enabled,
            s.width,
            s.height,
            s.mode,
            s.triangle_budget,
            r.accuracy.frames,
            r.cull_us(),
            r.raster_us,
            r.occlusion_us,
            r.accuracy.efficiency(0),
            r.efficiency(),
            r.accuracy.occlusion_efficiency().map_or(String::new(), |e| format!("{e:.4}")),
            r.accuracy.false_negatives,
            r.accuracy.frames_with_false_negatives,
            r.image_error_per_frame(),
            r.accuracy.worst_image_error_pixels,
            r.on_front,
        )
        .unwrap();
    }
    out
}

/// A panel's y-axis title and the value it plots.
type Panel = (&'static str, fn(&Row) -> f64);

/// Three panels against cull time: culling efficiency (with the Pareto front of exact configurations),
/// false negatives per frame, and image error per frame.
fn plot(rows: &[Row], path: &std::path::Path, objects: usize, frames: u32) -> Result<(), Box<dyn std::error::Error>> {
    let root = BitMapBackend::new(path, (2100, 760)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(
        &format!("Cullet occlusion: run time against error, {objects}-object city, {frames}-frame fly-through"),
        ("sans-serif", 26),
    )?;
    let panels = root.split_evenly((1, 3));
    let max_time = rows.iter().map(|r| r.cull_us() / 1e3).fold(0.0, f64::max) * 1.1;
    let mode_color = |mode| match mode {
        RasterMode::Conservative => BLUE,
        RasterMode::PixelCentres => CYAN,
        RasterMode::Masked => RGBColor(230, 120, 0),
        RasterMode::Fast => RED,
    };
    let color = |r: &Row| if r.settings.enabled { mode_color(r.settings.mode) } else { BLACK };
    let panel_specs: [Panel; 3] = [
        ("culling efficiency (%)", |r| 100.0 * r.efficiency()),
        ("false negatives per frame (objects)", |r| r.false_negatives_per_frame()),
        ("image error per frame (pixels of 1920x1080)", |r| r.image_error_per_frame()),
    ];
    for (panel, (y_desc, value)) in panels.iter().zip(panel_specs) {
        let efficiency_panel = y_desc.starts_with("culling");
        let (min_y, max_y) = if efficiency_panel {
            (rows.iter().map(value).fold(100.0, f64::min) - 5.0, 100.0)
        } else {
            (0.0, rows.iter().map(value).fold(0.0, f64::max).max(1.0) * 1.1)
        };
        let mut chart = ChartBuilder::on(panel)
            .margin(20)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..max_time, min_y..max_y)?;
        chart.configure_mesh().x_desc("cull time per frame (ms), all CPU stages").y_desc(y_desc).draw()?;
        if efficiency_panel {
            let mut front: Vec<(f64, f64)> =
                rows.iter().filter(|r| r.on_front).map(|r| (r.cull_us() / 1e3, value(r))).collect();
            front.sort_by(|a, b| a.0.total_cmp(&b.0));
            chart
                .draw_series(LineSeries::new(front, BLUE.stroke_width(2)))?
                .label("Pareto front of the conservative configurations")
                .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        }
        let modes = [
            ("conservative", RasterMode::Conservative),
            ("pixel centres at 1920x1080", RasterMode::PixelCentres),
            ("masked at 1920x1080", RasterMode::Masked),
            ("fast", RasterMode::Fast),
        ];
        for (name, mode) in modes {
            let series =
                rows.iter().filter(|r| r.series == Series::Stages && r.settings.enabled && r.settings.mode == mode);
            let c = mode_color(mode);
            chart
                .draw_series(series.map(|r| Circle::new((r.cull_us() / 1e3, value(r)), 5, color(r).filled())))?
                .label(name)
                .legend(move |(x, y)| Circle::new((x + 10, y), 5, c.filled()));
        }
        chart
            .draw_series(
                rows.iter()
                    .filter(|r| r.series == Series::Moc)
                    .map(|r| TriangleMarker::new((r.cull_us() / 1e3, value(r)), 7, MAGENTA.filled())),
            )?
            .label("Intel MOC")
            .legend(|(x, y)| TriangleMarker::new((x + 10, y), 7, MAGENTA.filled()));
        let frusta_color = RGBColor(0, 140, 70);
        chart
            .draw_series(
                rows.iter()
                    .filter(|r| r.series == Series::ShadowFrusta)
                    .map(|r| Cross::new((r.cull_us() / 1e3, value(r)), 7, frusta_color.stroke_width(3))),
            )?
            .label("occluder shadow frusta")
            .legend(move |(x, y)| Cross::new((x + 10, y), 7, frusta_color.stroke_width(3)));
        let grid_color = RGBColor(140, 80, 20);
        // A square marker, sized in pixels around the point.
        let square =
            |point: (f64, f64)| EmptyElement::at(point) + Rectangle::new([(-5, -5), (5, 5)], grid_color.filled());
        chart
            .draw_series(
                rows.iter()
                    .filter(|r| matches!(r.series, Series::QueryGrid(_)))
                    .map(|r| square((r.cull_us() / 1e3, value(r)))),
            )?
            .label("GPU query grid (lossy, CPU time only)")
            .legend(move |(x, y)| Rectangle::new([(x + 5, y - 5), (x + 15, y + 5)], grid_color.filled()));
        for (series, name, color) in [
            (Series::Hierarchy, "hierarchy + default buffer", RGBColor(90, 40, 160)),
            (Series::Portals, "cells and portals + default buffer", RGBColor(200, 120, 0)),
        ] {
            chart
                .draw_series(
                    rows.iter()
                        .filter(|r| r.series == series)
                        .map(|r| TriangleMarker::new((r.cull_us() / 1e3, value(r)), 7, color.filled())),
                )?
                .label(name)
                .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 7, color.filled()));
        }
        chart.draw_series(
            rows.iter()
                .filter(|r| !r.settings.enabled)
                .map(|r| Circle::new((r.cull_us() / 1e3, value(r)), 5, BLACK.filled())),
        )?;
        chart.draw_series(
            rows.iter()
                .filter(|r| r.is_default())
                .map(|r| Circle::new((r.cull_us() / 1e3, value(r)), 10, ShapeStyle::from(&GREEN).stroke_width(3))),
        )?;
        let labelled = |r: &&Row| {
            r.is_default() || (efficiency_panel && (r.on_front || r.series != Series::Stages || !r.settings.enabled))
        };
        chart.draw_series(rows.iter().filter(labelled).map(|r| {
            let label = if r.is_default() { format!("{} (default)", r.label()) } else { r.label() };
            Text::new(label, (r.cull_us() / 1e3, value(r)), ("sans-serif", 13))
        }))?;
        chart.configure_series_labels().position(SeriesLabelPosition::LowerRight).border_style(BLACK).draw()?;
    }
    root.present()?;
    Ok(())
}
