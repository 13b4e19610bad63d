//! `cullet-game`: flies a camera through a scene and culls it every frame, in a window (free flight, stage
//! toggles, frozen culling, debug views) or headless along a camera path, showing its progress and printing
//! summary statistics of each stage (per-frame lines with `--verbose`, a CSV row per frame with `--stats`).

#![forbid(unsafe_code)]

mod headless;
pub mod hud;
mod present;
mod report;
mod validation;
mod window;

use clap::Parser;
use cullet::CameraPath;
use cullet::detail::DetailSettings;
use cullet::frustum::LightSource;
use cullet::gpu::{GpuError, GpuGating};
use cullet::lod::{ChainSettings, LodLibrary, LodSettings};
use cullet::pipeline::LightViews;

use cullet::culler::{AdaptiveSettings, OcclusionSettings};
use cullet::raster::RasterMode;
use cullet::scene::Scene;
use cullet::scene::auto_occluders::{AutoOccluderSettings, add_auto_occluders};
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use cullet::scene::gltf_import::load_gltf;
use std::process::ExitCode;
use std::time::Instant;

/// Fly through a scene and cull it every frame.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Scene to load: a built-in one, `city[:N]` (dense, occluded; 100 000 objects by default), `field[:N]`
    /// (open, no occluders), `cad[:N]` (everything on screen; 20 000 by default), `building[:N]` (floors of
    /// rooms with cells and portals, walked through; 1 500 by default), or a glTF file (`.gltf` or
    /// `.glb`).
    #[arg(long, default_value = "city:100000")]
    scene: String,
    /// Give large meshes without an artist occluder one made of their own largest triangles (conservative:
    /// those triangles are the drawn surface).
    #[arg(long)]
    auto_occluders: bool,
    /// Move the scene and the camera path together by `X,Y,Z` world units (precision test: the world is
    /// stored in f32 that far from its origin).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    world_offset: Option<String>,
    /// Keep the camera at the start of its path (a static-camera run: nothing changes, so the stages reuse
    /// their last result).
    #[arg(long)]
    static_camera: bool,
    /// Run every stage every frame: no reuse of unchanged frames, no skipping of stages that removed little,
    /// no temporal coherence (the fixed pipeline, for comparison).
    #[arg(long)]
    fixed_pipeline: bool,
    /// Number of frames: headless, spread along the camera path (default 300); in a window, close after this
    /// many (default: run until closed).
    #[arg(long)]
    frames: Option<u32>,
    /// Viewport size, `WIDTHxHEIGHT` (sets the aspect ratio of the camera).
    #[arg(long, default_value = "1920x1080")]
    resolution: String,
    /// Headless, print only the summary: no progress bar (shown by default on a terminal, on stderr) and no
    /// line per frame.
    #[arg(long, conflicts_with = "verbose")]
    quiet: bool,
    /// Headless, print one line per frame instead of the progress bar: the camera, each stage's counts and
    /// times, the GPU passes' counts, and with --validate the frame's accuracy. The summary follows as without.
    #[arg(long)]
    verbose: bool,
    /// Size of the software occlusion depth buffer, `WIDTHxHEIGHT`, sampled by whole-texel coverage (the
    /// engine's default without a frame, 256x144), at texel centres with `--fast-occlusion`, or with
    /// `--pixel-centres` or `--masked` at most the frame's size, each sample standing for the frame's pixel
    /// centres in its square. Without it (and without `--pixel-centres` or `--masked`) the buffer is masked,
    /// standing for the frame's pixels, at the frame's size up to 960x540 samples and at a whole divisor of it
    /// beyond (half of 1920x1080: `OcclusionSettings::for_frame`).
    #[arg(long)]
    occlusion_resolution: Option<String>,
    /// Sample the occlusion buffer at texel centres (not conservative) instead of whole-texel coverage.
    #[arg(long, conflicts_with_all = ["pixel_centres", "masked"])]
    fast_occlusion: bool,
    /// Make the occlusion buffer as large as the viewport (`--resolution`; or `--occlusion-resolution`, standing
    /// for the viewport's pixels) and sample it at pixel centres: conservative for the frame drawn.
    #[arg(long, conflicts_with = "masked")]
    pixel_centres: bool,
    /// Like `--pixel-centres`, with the covered pixels kept as coverage masks and one depth per 4x4 block
    /// (Masked Occlusion Culling's layout): conservative for the frame drawn, and cheaper.
    #[arg(long)]
    masked: bool,
    /// Turn the software occlusion stage off.
    #[arg(long)]
    no_occlusion: bool,
    /// Cull light views with the camera, in the same pass: a sun's four shadow cascades (to 400 m) and the
    /// six cube faces of a lamp 6 m above the camera path's start (60 m range), each keeping only the shadow
    /// casters whose shadows can reach the camera's view. Their counts are printed and shown in the HUD, and
    /// --validate judges them exactly.
    #[arg(long)]
    light_views: bool,
    /// Detail culling (lossy): drop the objects whose bounding sphere projects under this many pixels of the
    /// --resolution frame. --validate counts what it costs and does not fail on it.
    #[arg(long, value_name = "PIXELS")]
    detail_pixels: Option<f32>,
    /// Levels of detail (lossy): each object the camera keeps draws the coarsest level of its mesh (made by
    /// meshoptimizer's simplifier at load) whose error projects under this many pixels of the --resolution
    /// frame.
    #[arg(long, value_name = "PIXELS")]
    lod_pixels: Option<f32>,
    /// Levels of detail under a budget (lossy): at most this many triangles a frame over the objects the
    /// camera keeps, levels chosen best-first by error removed per triangle, the smallest objects dropped
    /// where even the coarsest levels do not fit. With --lod-pixels, never finer than its levels.
    #[arg(long, value_name = "TRIANGLES")]
    triangle_budget: Option<u64>,
    /// Most occluder triangles rasterized per frame (default: 5120 for the buffer standing for the frame's
    /// pixels, 4096 for the others).
    #[arg(long)]
    occluder_budget: Option<usize>,
    /// Judge every frame against the exact ground truth (every object's triangles rasterized at the viewport
    /// resolution): report false negatives, false positives and image error, and fail if a conservative
    /// configuration culled anything visible. In a window the HUD shows them live, for every setting changed.
    #[arg(long)]
    validate: bool,
    /// Run only the CPU stages (bounds, frustum, occlusion), without a GPU adapter: cluster and triangle
    /// culling and the draw are skipped.
    #[arg(long)]
    cpu_only: bool,
    /// Camera path to fly instead of the scene's built-in one (JSON, see the README).
    #[arg(long, value_name = "FILE.json")]
    camera_path: Option<std::path::PathBuf>,
    /// Write one CSV row per frame: counts and each stage's time in microseconds (plus accuracy with
    /// --validate, and with --light-views each light view's kept and occluded casters: `sun_cascade_1_kept`,
    /// `sun_cascade_1_occluded`, ..., `lamp_plus_x_kept`, ...; empty where a frame lacks that view).
    #[arg(long, value_name = "FILE.csv")]
    stats: Option<std::path::PathBuf>,
    /// Save the drawn frame as PNG into this folder every --every frames (needs a GPU adapter). In a window,
    /// the frame the player sees, HUD included.
    #[arg(long, value_name = "DIR")]
    screenshots: Option<std::path::PathBuf>,
    /// Frames between screenshots.
    #[arg(long, default_value_t = 30)]
    every: u32,
    /// Two-phase GPU occlusion: draw first what was visible last frame, then cull the rest against that depth
    /// merged with the software occlusion buffer (conservative). The GPU summary and the HUD show each phase.
    /// Also the HUD's checkbox and key 5.
    #[arg(long)]
    two_phase: bool,
    /// Read each frame's GPU counters back at the next frame, so that no frame waits for its own GPU work: the
    /// CPU stages of a frame run while the GPU works on the one before (headless). The GPU columns of --stats
    /// and the GPU summary are then each the previous frame's, and pass times are not read.
    #[arg(long)]
    late_readback: bool,
    /// Run without a window along the camera path (the default where no display exists).
    #[arg(long)]
    headless: bool,
    /// Start with the heads-up display hidden (H shows it).
    #[arg(long)]
    no_hud: bool,
    /// What the window shows at first (V cycles through them).
    #[arg(long, value_enum, default_value = "shaded")]
    view: hud::controls::View,
    /// Which culler removes what is hidden after the frustum: the pipeline's occlusion stage (`stages`),
    /// the occluders' shadow frusta (`shadow-frusta`; `--occluder-budget` is its budget) or GPU occlusion
    /// queries over a uniform grid (`query-grid`, lossy: what comes into view is drawn a frame late; needs a
    /// GPU). Headless only. The frustum stage, the light views and the GPU passes run as with the stages,
    /// and --validate judges the culler chosen.
    #[arg(long, value_enum, default_value = "stages")]
    culler: CullerChoice,
    /// The query grid's cell side in world units (default: from the scene's object sizes).
    #[arg(long)]
    cell_size: Option<f32>,
    /// The query grid's most queries a frame (default 4000, the thesis's; 0 for no cap).
    #[arg(long)]
    query_cap: Option<u32>,
}

/// The culler `--culler` chooses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum CullerChoice {
    /// The pipeline's stages (`cullet::culler::ViewCuller`).
    #[default]
    Stages,
    /// The occluders' shadow frusta (`cullet::culler::ShadowFrustaCuller`).
    ShadowFrusta,
    /// GPU occlusion queries over a uniform grid (`cullet::gpu::QueryGridCuller`).
    QueryGrid,
}

impl Args {
    /// Frames of a headless run.
    fn headless_frames(&self) -> u32 {
        self.frames.unwrap_or(300)
    }
}

/// A loaded scene and the camera path it is flown along without `--camera-path`.
struct LoadedScene {
    scene: Scene,
    path: CameraPath,
    description: String,
}

/// The scene `--scene` names: the built-in city, or a glTF file (warnings printed, errors returned).
fn load_scene(args: &Args) -> Result<LoadedScene, String> {
    let (name, count) = match args.scene.split_once(':') {
        Some((name, count)) => (name, Some(count)),
        None => (args.scene.as_str(), None),
    };
    let builtin = ["city", "field", "cad", "building"].contains(&name).then(|| match count {
        None => Ok(match name {
            "city" => 100_000,
            "building" => 1_500,
            _ => 20_000,
        }),
        Some(count) => count.parse::<usize>().map_err(|_| format!("bad object count in --scene {}", args.scene)),
    });
    let mut loaded = match builtin {
        Some(objects) => {
            let objects = objects?;
            let (scene, path) = match name {
                "city" => {
                    let city = CityScene::generate(CityParams::with_objects(objects));
                    let path = city.flythrough();
                    (city.scene, path)
                }
                "field" => cullet::scene::field::field(objects),
                "building" => (cullet::scene::building::building(objects), cullet::scene::building::walk()),
                _ => cullet::scene::cad::cad(objects),
            };
            LoadedScene { description: format!("{name} of {} objects", scene.objects.len()), scene, path }
        }
        None => {
            let file = std::path::Path::new(&args.scene);
            let extension = file.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
            if !matches!(extension.as_deref(), Some("gltf" | "glb")) {
                return Err(format!(
                    "unknown scene '{}': expected city[:N], field[:N], cad[:N], building[:N] or a .gltf/.glb file",
                    args.scene
                ));
            }
            let gltf = load_gltf(file).map_err(|e| e.to_string())?;
            for warning in &gltf.warnings {
                eprintln!("warning: {}: {warning}", args.scene);
            }
            let path = gltf.scene.orbit_path();
            LoadedScene {
                description: format!(
                    "{}: {} objects, {} triangles, {} artist occluder nodes",
                    args.scene,
                    gltf.scene.objects.len(),
                    gltf.scene.triangle_count(),
                    gltf.occluder_nodes
                ),
                scene: gltf.scene,
                path,
            }
        }
    };
    if args.auto_occluders {
        let added = add_auto_occluders(&mut loaded.scene, &AutoOccluderSettings::default());
        loaded.description.push_str(&format!(", {added} automatic occluders"));
    }
    Ok(loaded)
}

fn parse_offset(offset: &str) -> Result<glam::Vec3, String> {
    let parts: Vec<Option<f32>> = offset.split(',').map(|p| p.trim().parse().ok()).collect();
    match parts[..] {
        [Some(x), Some(y), Some(z)] if x.is_finite() && y.is_finite() && z.is_finite() => Ok(glam::Vec3::new(x, y, z)),
        _ => Err(format!("bad --world-offset '{offset}', expected X,Y,Z")),
    }
}

fn parse_resolution(resolution: &str) -> Result<(u32, u32), String> {
    let parsed = resolution.split_once('x').and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)));
    match parsed {
        Some((w, h)) if w > 0 && h > 0 => Ok((w, h)),
        _ => Err(format!("bad --resolution '{resolution}', expected WIDTHxHEIGHT")),
    }
}

/// How to get a GPU adapter where none was found (see `gpu_error_message`), indented under the error.
const NO_ADAPTER_ADVICE: &str = concat!(
    "  To get one on a machine without a GPU, install Mesa's software Vulkan driver, lavapipe:\n",
    "    sudo apt-get install mesa-vulkan-drivers    (Debian, Ubuntu; Fedora: sudo dnf install mesa-vulkan-drivers)\n",
    "  With a GPU, install its Vulkan, Metal or DirectX 12 driver. Or run with --cpu-only, which needs no adapter\n",
    "  (headless, the CPU stages only).",
);

/// `error` as the game reports it: for a missing adapter, how to get one; for one the pipeline cannot use, how
/// to run without it.
pub(crate) fn gpu_error_message(error: &GpuError) -> String {
    match error {
        GpuError::NoAdapter(_) => format!("{error}\n{NO_ADAPTER_ADVICE}"),
        GpuError::Unsupported { .. } => {
            format!("{error}\n  run with --cpu-only to do without it (headless, the CPU stages only)")
        }
        _ => error.to_string(),
    }
}

/// Runs in a window where a display exists and `--headless` is not given; otherwise headless.
fn run(args: &Args, prepared: Prepared) -> Result<(), String> {
    if args.headless || args.cpu_only || args.culler != CullerChoice::Stages {
        // The CPU-only run, and another culler's, are measurements along the camera path: no window.
        return headless::run(args, prepared);
    }
    match window::open_event_loop() {
        Ok(event_loop) => window::run(args, prepared, event_loop),
        Err(why) => {
            println!("no window ({why}): running headless");
            headless::run(args, prepared)
        }
    }
}

/// Runs the game with the command line's arguments: what `cullet-game` does.
pub fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()))
        .init();
    let args = Args::parse();
    // The main thread runs the pipeline: as one of rayon's threads it starts each stage's parallel work itself,
    // where from outside the pool it would wait for a pool thread to wake, and that one for the next (a wake
    // can take longer than the stage: docs/performance.md measures it).
    if let Err(error) = rayon::ThreadPoolBuilder::new().use_current_thread().build_global() {
        // Only where the pool was built before in this process: that pool stays.
        tracing::debug!("rayon's global pool as it was: {error}");
    }
    match prepare(&args).and_then(|prepared| run(&args, prepared)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("cullet-game: {message}");
            ExitCode::FAILURE
        }
    }
}

/// Everything a run needs, built from the command line.
pub struct Prepared {
    /// The scene's meshes (for the GPU and the ground truth).
    pub scene: Scene,
    /// The world with the scene spawned, its schedule and camera path.
    pub flight: Flight,
    /// Viewport width and height.
    pub resolution: (u32, u32),
}

/// Loads the scene and camera path and sets up the world.
fn prepare(args: &Args) -> Result<Prepared, String> {
    let (width, height) = parse_resolution(&args.resolution)?;
    let aspect = width as f32 / height as f32;
    let chosen = if args.fast_occlusion || args.pixel_centres || args.masked || args.occlusion_resolution.is_some() {
        let mode = match (args.fast_occlusion, args.pixel_centres, args.masked) {
            (true, _, _) => RasterMode::Fast,
            (_, true, _) => RasterMode::PixelCentres,
            (_, _, true) => RasterMode::Masked,
            _ => RasterMode::Conservative,
        };
        let mut chosen = OcclusionSettings { mode, ..OcclusionSettings::default() };
        if let Some(resolution) = &args.occlusion_resolution {
            (chosen.width, chosen.height) = parse_resolution(resolution)?;
            if mode.samples_pixel_centres() && (chosen.width > width || chosen.height > height) {
                return Err(format!(
                    "--occlusion-resolution {resolution}: a pixel-centre or masked buffer stands for the frame's \
                     pixels, so it is no larger than --resolution {width}x{height}"
                ));
            }
        } else if mode.samples_pixel_centres() {
            (chosen.width, chosen.height) = (width, height);
        }
        chosen
    } else {
        OcclusionSettings::for_frame(width, height)
    };
    let occlusion = OcclusionSettings {
        // Another culler replaces the occlusion stage.
        enabled: !args.no_occlusion && args.culler == CullerChoice::Stages,
        triangle_budget: args.occluder_budget.unwrap_or(chosen.triangle_budget),
        frame: Some((width, height)),
        ..chosen
    };
    occlusion
        .validate()
        .map_err(|error| format!("the occlusion buffer {}x{}: {error}", occlusion.width, occlusion.height))?;

    let start = Instant::now();
    let LoadedScene { mut scene, path, mut description } = load_scene(args)?;
    let mut path = match &args.camera_path {
        Some(file) => {
            let json = std::fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))?;
            CameraPath::from_json(&json).map_err(|e| format!("{}: {e}", file.display()))?
        }
        None => path,
    };
    if args.static_camera {
        path.keys.truncate(1);
    }
    if let Some(offset) = &args.world_offset {
        let offset = parse_offset(offset)?;
        scene.translate(offset);
        path = path.translated(offset);
        description.push_str(&format!(", moved by {offset}"));
    }
    let mut flight = Flight::new(path, aspect, args.headless_frames(), occlusion, |world| {
        scene.spawn(world);
    });
    if args.light_views {
        let lamp =
            flight.path.keys.first().map_or(glam::Vec3::ZERO, |key| key.position) + glam::Vec3::new(0.0, 6.0, 0.0);
        flight.world.insert_resource(LightViews(vec![
            LightSource::Sun {
                direction: glam::Vec3::new(0.35, -1.0, 0.25),
                splits: vec![0.1, 12.0, 40.0, 120.0, 400.0],
            },
            LightSource::Lamp { position: lamp, near: 0.05, range: Some(60.0) },
        ]));
    }
    if let Some(min_pixels) = args.detail_pixels {
        flight.world.insert_resource(DetailSettings { min_pixels, viewport_height: height });
    }
    // Levels of detail for every mesh, made at load where asked for, and in a window, where the HUD switches
    // them on (off until then). A headless run without them neither simplifies nor clusters the levels.
    if !args.headless || args.lod_pixels.is_some() || args.triangle_budget.is_some() {
        let library = LodLibrary::for_scene(&scene, &ChainSettings::default());
        for (mesh, error) in library.errors() {
            println!("mesh {mesh} has fewer levels: {error}");
        }
        let lod = LodSettings {
            max_error_pixels: args.lod_pixels.unwrap_or(0.0),
            viewport_height: height,
            triangle_budget: args.triangle_budget,
            ..LodSettings::default()
        };
        cullet::lod::install(&mut flight.world, &mut flight.schedule, library, lod);
    }
    if args.fixed_pipeline {
        flight.world.insert_resource(AdaptiveSettings::fixed());
        flight.world.insert_resource(GpuGating::fixed());
    }
    println!(
        "{description}; loaded and spawned in {:.0} ms; camera path of {:.0} s",
        start.elapsed().as_secs_f64() * 1e3,
        flight.path.duration()
    );
    Ok(Prepared { scene, flight, resolution: (width, height) })
}

#[cfg(test)]
mod tests {
    use super::gpu_error_message;
    use cullet::gpu::GpuError;

    #[test]
    fn a_missing_adapter_says_how_to_get_one() {
        let message = gpu_error_message(&GpuError::NoAdapter("no Vulkan driver".into()));
        assert!(message.starts_with("no GPU adapter found: no Vulkan driver"), "{message}");
        for advice in ["apt-get install mesa-vulkan-drivers", "lavapipe", "--cpu-only"] {
            assert!(message.contains(advice), "'{advice}' missing from: {message}");
        }
        let unsupported =
            gpu_error_message(&GpuError::Unsupported { adapter: "old".into(), missing: "a feature".into() });
        assert!(unsupported.contains("lacks a feature") && unsupported.contains("--cpu-only"), "{unsupported}");
        let lost = gpu_error_message(&GpuError::Lost("gone".into()));
        assert!(!lost.contains("--cpu-only"), "{lost}");
    }
}
