//! The sample game end to end, as a user runs it: headless runs of the built-in city, of the shipped glTF
//! test scene and of a third-party scene with `--validate` report zero false negatives and write a stats CSV
//! with every column; bad scene files fail with a message naming the file. With `CULLET_REQUIRE_GPU` set (as
//! CI sets it) the GPU passes must have run too.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The columns the stats CSV must have (the sample-game issue's list, accuracy, then gating and savings).
const COLUMNS: [&str; 26] = [
    "frame",
    "objects",
    "after_frustum",
    "after_occlusion",
    "clusters_in",
    "clusters_out",
    "triangles_in",
    "triangles_out",
    "draws",
    "bounds_us",
    "frustum_us",
    "raster_us",
    "occlusion_us",
    "gpu_us",
    "false_negatives",
    "false_positives",
    "image_error_pixels",
    "reused",
    "retested",
    "occlusion_gated",
    "cluster_pass_skipped",
    "triangle_pass_skipped",
    "saved_triangles_frustum",
    "saved_triangles_occlusion",
    "saved_triangles_clusters",
    "saved_triangles_triangles",
];

fn workspace_file(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(relative)
}

/// Runs the game headless with `args` plus validation and a stats file; returns its output and the CSV rows
/// as maps from column to value.
fn run_validated(name: &str, args: &[&str], frames: u32) -> (String, Vec<std::collections::HashMap<String, String>>) {
    let stats = std::env::temp_dir().join(format!("cullet-e2e-{name}-{}.csv", std::process::id()));
    let output = Command::new(env!("CARGO_BIN_EXE_cullet-game"))
        .args(args)
        .args(["--headless", "--validate", "--quiet", "--resolution", "640x360", "--frames"])
        .arg(frames.to_string())
        .arg("--stats")
        .arg(&stats)
        .output()
        .expect("the game runs");
    let text = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "{name}: the game failed:\n{text}");
    let csv = std::fs::read_to_string(&stats).expect("stats written");
    let _ = std::fs::remove_file(&stats);
    let mut lines = csv.lines();
    let header: Vec<String> = lines.next().expect("a header").split(',').map(String::from).collect();
    for column in COLUMNS {
        assert!(header.iter().any(|h| h == column), "{name}: stats lack column {column}: {header:?}");
    }
    let rows: Vec<_> =
        lines.map(|line| header.iter().cloned().zip(line.split(',').map(String::from)).collect()).collect();
    assert_eq!(rows.len(), frames as usize, "{name}: one row a frame");
    (text, rows)
}

/// Checks zero false negatives on every row, and GPU work where a GPU is required.
fn check(name: &str, text: &str, rows: &[std::collections::HashMap<String, String>]) {
    for row in rows {
        assert_eq!(row["false_negatives"], "0", "{name}: frame {} has false negatives", row["frame"]);
        assert_eq!(row["image_error_pixels"], "0", "{name}: frame {} has image error", row["frame"]);
    }
    let gpu_ran = rows.iter().any(|row| row["clusters_in"] != "0");
    if std::env::var_os("CULLET_REQUIRE_GPU").is_some() {
        assert!(
            text.contains("GPU: ") && gpu_ran,
            "{name}: CULLET_REQUIRE_GPU is set but the GPU passes did not run:\n{text}"
        );
    } else if !gpu_ran {
        eprintln!("SKIPPED: {name}: no GPU adapter, only the CPU stages were checked");
    }
    assert!(text.contains("0 false negatives"), "{name}: no validation summary:\n{text}");
}

#[test]
fn built_in_city_validates_with_zero_false_negatives() {
    let (text, rows) = run_validated("city", &["--scene", "city:3000"], 24);
    check("city", &text, &rows);
    // Not vacuous: the stages cull.
    let culled =
        rows.iter().any(|r| r["after_occlusion"].parse::<u32>().unwrap() < r["after_frustum"].parse().unwrap());
    assert!(culled, "occlusion never culled anything");
}

/// `--culler shadow-frusta`: the occluders' shadow frusta replace the occlusion stage, the GPU passes draw
/// what they keep, and the judge finds nothing visible culled, far from the origin too.
#[test]
fn the_shadow_frusta_culler_validates_with_zero_false_negatives() {
    for (name, offset) in [("shadow frusta", "0,0,0"), ("shadow frusta far away", "1e7,0,-1e7")] {
        let args = ["--scene", "city:3000", "--culler", "shadow-frusta", "--world-offset", offset];
        let (text, rows) = run_validated(name, &args, 16);
        check(name, &text, &rows);
        assert!(text.contains("culler: shadow frusta 4096"), "{text}");
        let culled =
            rows.iter().any(|r| r["after_occlusion"].parse::<u32>().unwrap() < r["after_frustum"].parse().unwrap());
        assert!(culled, "{name}: the shadow frusta never culled anything");
    }
}

/// The query grid runs in the game and is judged as the lossy culler it is: it culls behind the buildings,
/// its false negatives are counted without failing the run, and the summary says what it queried.
#[test]
fn the_query_grid_culler_runs_and_is_judged_as_lossy() {
    let gpu_required = std::env::var_os("CULLET_REQUIRE_GPU").is_some();
    let probe = Command::new(env!("CARGO_BIN_EXE_cullet-game"))
        .args(["--scene", "city:300", "--culler", "query-grid", "--headless", "--quiet", "--frames", "1"])
        .output()
        .expect("the game runs");
    if !probe.status.success() && !gpu_required {
        eprintln!("SKIPPED: the query grid needs a GPU adapter: {}", String::from_utf8_lossy(&probe.stdout));
        return;
    }
    let args = ["--scene", "city:3000", "--culler", "query-grid"];
    let (text, rows) = run_validated("query grid", &args, 24);
    assert!(text.contains("culler: query grid") && text.contains("query grid: "), "{text}");
    let culled =
        rows.iter().any(|r| r["after_occlusion"].parse::<u32>().unwrap() < r["after_frustum"].parse().unwrap());
    assert!(culled, "the query grid never culled anything:\n{text}");
    assert!(text.contains("validation over 24 frames"), "{text}");
}

#[test]
fn city_far_from_the_origin_validates_with_zero_false_negatives() {
    let args = ["--scene", "city:2000", "--world-offset", "1e7,0,-1e7", "--light-views"];
    let (text, rows) = run_validated("offset", &args, 12);
    check("offset", &text, &rows);
    assert!(text.contains("moved by"), "{text}");
    // The light views ran with the camera and lost no shadow caster.
    assert!(text.contains("(10 light views, culled in the frustum's pass)"), "{text}");
    assert!(text.contains("light views: 0 shadow casters culled that were needed"), "{text}");
}

#[test]
fn field_cad_tiny_and_static_camera_runs_validate_with_zero_false_negatives() {
    for (name, args) in [
        ("field", &["--scene", "field:3000"][..]),
        ("cad", &["--scene", "cad:2000"][..]),
        ("static", &["--scene", "cad:1000", "--static-camera"][..]),
        ("tiny", &["--scene", "city:30"][..]),
        ("city static", &["--scene", "city:3000", "--static-camera"][..]),
        ("masked at half", &["--scene", "city:3000", "--masked", "--occlusion-resolution", "320x180"][..]),
        ("256x144", &["--scene", "city:3000", "--occlusion-resolution", "256x144"][..]),
    ] {
        let (text, rows) = run_validated(name, args, 12);
        check(name, &text, &rows);
        assert!(text.contains("estimated draw cost saved per frame"), "{name}: no savings summary:\n{text}");
        if name == "static" {
            // Nothing moves and the camera stays: every frame after the first reuses the first's result.
            assert!(rows[1..].iter().all(|r| r["reused"] == "1"), "{name}: frames not reused");
        }
        if name == "city static" {
            // The camera stays while the cars move: after the first frame, only the cars are re-tested.
            assert!(rows[1..].iter().all(|r| r["retested"] != "0" && r["reused"] == "0"), "{name}: not re-tested");
        }
        let gpu_ran = rows.iter().any(|row| row["clusters_in"] != "0");
        if name == "tiny" && gpu_ran {
            // A few dozen objects: the GPU cluster pass cannot pay, and is skipped on every frame.
            assert!(rows.iter().all(|r| r["cluster_pass_skipped"] == "1"), "{name}: cluster pass ran");
        }
        if name == "cad" {
            // Everything on screen: the frustum saves nothing, occlusion does.
            assert!(rows.iter().all(|r| r["saved_triangles_frustum"] == "0"));
            assert!(rows.iter().any(|r| r["saved_triangles_occlusion"] != "0"));
        }
    }
}

#[test]
fn shipped_gltf_scene_validates_with_zero_false_negatives() {
    let scene = workspace_file("tests/scenes/city_small.gltf");
    let (text, rows) = run_validated("gltf", &["--scene", scene.to_str().unwrap()], 24);
    check("gltf", &text, &rows);
    assert!(text.contains("79 artist occluder nodes"), "{text}");
}

#[test]
fn third_party_scene_with_automatic_occluders_validates() {
    let scene = workspace_file("../shared/scenes/truck_town/town_model.gltf");
    if !scene.exists() {
        eprintln!("SKIPPED: {} not found (the shared scenes sit beside the repository)", scene.display());
        return;
    }
    let (text, rows) = run_validated("truck_town", &["--scene", scene.to_str().unwrap(), "--auto-occluders"], 12);
    check("truck_town", &text, &rows);
    assert!(text.contains("automatic occluders"), "{text}");
}

#[test]
fn bad_scene_files_fail_with_a_message_naming_them() {
    let broken = std::env::temp_dir().join(format!("cullet-e2e-broken-{}.gltf", std::process::id()));
    std::fs::write(&broken, r#"{"asset": {"version": "2.0"}, "buffers": [{"byteLength": 12, "uri": "gone.bin"}]}"#)
        .unwrap();
    for (scene, expected) in [
        (broken.to_str().unwrap(), "gone.bin"),
        ("no/such/scene.glb", "no/such/scene.glb"),
        ("city:lots", "bad object count"),
        ("scene.obj", "unknown scene"),
    ] {
        let output = Command::new(env!("CARGO_BIN_EXE_cullet-game"))
            .args(["--headless", "--frames", "1", "--scene", scene])
            .output()
            .expect("the game runs");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{scene}: should fail");
        assert!(stderr.contains(expected), "{scene}: expected '{expected}' in: {stderr}");
    }
    let _ = std::fs::remove_file(&broken);
}

#[test]
fn cpu_only_says_what_it_skips() {
    let output = Command::new(env!("CARGO_BIN_EXE_cullet-game"))
        .args(["--cpu-only", "--frames", "2", "--scene", "city:500", "--quiet"])
        .output()
        .expect("the game runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success());
    assert!(stdout.contains("--cpu-only: GPU cluster culling, triangle culling and the draw are skipped"), "{stdout}");
}

/// Runs the game with `args` and `envs`; returns whether it succeeded, and its stdout and stderr.
fn run_game(args: &[&str], envs: &[(&str, &str)]) -> (bool, String, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_cullet-game"))
        .args(args)
        .envs(envs.iter().copied())
        .output()
        .expect("the game runs");
    let (stdout, stderr) = (String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    (output.status.success(), stdout.into_owned(), stderr.into_owned())
}

/// A first run reads well: a headless run prints the summary, not a line per frame; `--verbose` prints one
/// line per frame (and per frame judged with `--validate`) before the same summary. Neither writes the
/// progress bar's frames where stderr is not a terminal (here a pipe).
#[test]
fn headless_run_prints_the_summary_and_frame_lines_only_with_verbose() {
    let frame_lines = |text: &str| text.lines().filter(|line| line.starts_with("frame ")).count();
    let base = ["--cpu-only", "--frames", "3", "--scene", "city:500", "--resolution", "640x360"];
    let (ok, stdout, stderr) = run_game(&base, &[]);
    assert!(ok, "the game failed:\n{stdout}{stderr}");
    assert!(stdout.contains("summary over 3 frames, 500 objects"), "no summary:\n{stdout}");
    assert_eq!(frame_lines(&stdout), 0, "per-frame lines without --verbose:\n{stdout}");
    assert!(!stderr.contains("frames,"), "a progress bar on a pipe:\n{stderr}");

    let (ok, stdout, stderr) = run_game(&[&base[..], &["--verbose"]].concat(), &[]);
    assert!(ok, "the game failed with --verbose:\n{stdout}{stderr}");
    assert_eq!(frame_lines(&stdout), 3, "one line a frame with --verbose:\n{stdout}");
    assert!(stdout.contains("frame    2  camera ("), "{stdout}");
    assert!(stdout.contains("summary over 3 frames, 500 objects"), "no summary with --verbose:\n{stdout}");

    let (ok, stdout, stderr) = run_game(&[&base[..], &["--verbose", "--validate"]].concat(), &[]);
    assert!(ok, "the game failed with --verbose --validate:\n{stdout}{stderr}");
    assert_eq!(frame_lines(&stdout), 6, "a stages line and an accuracy line a frame:\n{stdout}");

    let (ok, _, stderr) = run_game(&[&base[..], &["--verbose", "--quiet"]].concat(), &[]);
    assert!(!ok && stderr.contains("cannot be used with"), "--verbose with --quiet should be refused:\n{stderr}");
}

/// Without a GPU adapter (here none of wgpu's backends asked for has one) the game says how to get one and
/// runs the CPU stages.
#[test]
fn a_missing_gpu_adapter_says_how_to_get_one() {
    let args = ["--headless", "--frames", "2", "--scene", "city:300", "--resolution", "640x360"];
    let (ok, stdout, stderr) = run_game(&args, &[("WGPU_BACKEND", "noop")]);
    assert!(ok, "the game failed:\n{stdout}{stderr}");
    if stdout.contains("GPU: ") {
        eprintln!("SKIPPED: WGPU_BACKEND=noop found an adapter, so the message without one was not checked");
        return;
    }
    assert!(stdout.contains("no GPU adapter found"), "{stdout}");
    for advice in ["mesa-vulkan-drivers", "lavapipe", "--cpu-only"] {
        assert!(stdout.contains(advice), "'{advice}' missing from:\n{stdout}");
    }
    assert!(stdout.contains("running the CPU stages only"), "{stdout}");
    assert!(stdout.contains("summary over 2 frames"), "{stdout}");
}

/// With `--light-views` the stats CSV has each light view's kept and occluded casters, a number in every row
/// of a run whose views are all built, and their means are the summary's casters per light view.
#[test]
fn light_views_have_per_frame_columns_in_the_stats() {
    let stats = std::env::temp_dir().join(format!("cullet-e2e-light-views-{}.csv", std::process::id()));
    let frames = 6;
    let args = ["--cpu-only", "--light-views", "--scene", "city:2000", "--resolution", "640x360", "--frames", "6"];
    let (ok, stdout, stderr) = run_game(&[&args[..], &["--stats", stats.to_str().unwrap()]].concat(), &[]);
    assert!(ok, "the game failed:\n{stdout}{stderr}");
    let csv = std::fs::read_to_string(&stats).expect("stats written");
    let _ = std::fs::remove_file(&stats);
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    for column in COLUMNS {
        assert!(header.contains(&column), "stats lack column {column}: {header:?}");
    }
    let cascades = (1..=4).map(|n| format!("sun cascade {n}"));
    let faces = ["+x", "-x", "+y", "-y", "+z", "-z"].map(|face| format!("lamp {face}"));
    let views: Vec<String> = cascades.chain(faces).collect();
    let column = |view: &str, count: &str| {
        let name = format!("{}_{count}", view.replace('+', "plus_").replace('-', "minus_").replace(' ', "_"));
        header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("stats lack column {name}: {header:?}"))
    };
    let rows: Vec<Vec<&str>> = lines.map(|line| line.split(',').collect()).collect();
    assert_eq!(rows.len(), frames, "one row a frame");
    let mut summary = Vec::new();
    for view in &views {
        let (kept, occluded) = (column(view, "kept"), column(view, "occluded"));
        let mut total = 0;
        for row in &rows {
            assert_eq!(row.len(), header.len(), "a row as long as the header: {row:?}");
            let number = |i: usize| row[i].parse::<usize>().unwrap_or_else(|_| panic!("{view}: not a count: {row:?}"));
            total += number(kept);
            number(occluded);
        }
        summary.push(format!("{view} {:.0}", total as f64 / frames as f64));
    }
    let expected = format!("casters per light view (mean a frame): {}", summary.join(", "));
    assert!(stdout.contains(&expected), "the CSV's means, {expected}, are not the summary's:\n{stdout}");
    // Not vacuous: the views keep casters, and their occlusion hides some.
    let sum = |suffix: &str| -> usize {
        let columns: Vec<usize> = views.iter().map(|view| column(view, suffix)).collect();
        rows.iter().flat_map(|row| columns.iter().map(|&i| row[i].parse::<usize>().unwrap())).sum()
    };
    assert!(sum("kept") > 0, "no light view kept a caster");
    assert!(sum("occluded") > 0, "no light view's occlusion hid a caster");
}

/// The window mode on a virtual X display (Xvfb): it opens, culls and draws frames, closes after `--frames`
/// and prints the summary. Needs `xvfb-run`; CI installs it and sets `CULLET_REQUIRE_WINDOW`.
#[test]
fn window_opens_draws_and_closes_after_its_frames() {
    if !xvfb_available("the window test") {
        return;
    }
    let output = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 1280x720x24", env!("CARGO_BIN_EXE_cullet-game")])
        .args(["--scene", "city:2000", "--frames", "12", "--resolution", "640x360"])
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .expect("xvfb-run runs");
    let text = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "the windowed game failed:\n{text}");
    assert!(text.contains("window opened: 640x360"), "no window:\n{text}");
    assert!(text.contains("summary over 12 frames"), "no summary:\n{text}");
    assert!(text.contains("clusters"), "the GPU passes did not run in the window:\n{text}");
    // The HUD's builds after the first are spread over frames (begun, or run whole when answering input, then
    // tessellated and uploaded in frames of their own); the last may still be under way.
    assert!(text.contains("HUD CPU time per frame over 11 frames after the first"), "no HUD summary:\n{text}");
    assert!(!text.contains("whole builds"), "a HUD build after the first was done in one frame:\n{text}");
    let frames_doing = |work: &str| {
        text.lines()
            .find_map(|line| line.trim().strip_prefix(work)?.split_whitespace().next()?.parse::<usize>().ok())
            .unwrap_or(0)
    };
    let begun = frames_doing("beginning egui's pass:") + frames_doing("egui's pass whole, answering input:");
    let (tessellated, uploads) = (frames_doing("tessellating:"), frames_doing("uploading:"));
    assert!(uploads > 0, "no HUD build after the first was uploaded:\n{text}");
    assert!(begun == uploads || begun == uploads + 1, "{begun} builds begun, {uploads} uploaded:\n{text}");
    assert!(tessellated == uploads || tessellated == uploads + 1, "{tessellated} tessellated:\n{text}");
}

/// Whether window tests can run: `xvfb-run` exists, or the test must fail because CI requires it.
fn xvfb_available(test: &str) -> bool {
    if Command::new("xvfb-run").arg("--help").output().is_ok() {
        return true;
    }
    assert!(
        std::env::var_os("CULLET_REQUIRE_WINDOW").is_none(),
        "CULLET_REQUIRE_WINDOW is set but xvfb-run is missing"
    );
    eprintln!("SKIPPED: {test} needs xvfb-run (Debian package xvfb)");
    false
}

/// Runs the windowed game under Xvfb on a still scene and camera up to frame `frame`, saving the frame the
/// player sees there. Returns the screenshot, the HUD's rectangles the game reported for it (`[x0, y0, x1,
/// y1]`) and what the game printed.
fn window_screenshot(name: &str, frame: u32, extra: &[&str]) -> (image::RgbaImage, Vec<[u32; 4]>, String) {
    let dir = std::env::temp_dir().join(format!("cullet-e2e-{name}-{}", std::process::id()));
    let output = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 1280x720x24", env!("CARGO_BIN_EXE_cullet-game")])
        .args(["--scene", "cad:800", "--static-camera", "--resolution", "960x540", "--screenshots"])
        .arg(&dir)
        .args(["--frames", &(frame + 1).to_string(), "--every", &frame.to_string()])
        .args(extra)
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .expect("xvfb-run runs");
    let text = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "{name}: the windowed game failed:\n{text}");
    let file = format!("frame_{frame:05}.png");
    let line = text
        .lines()
        .find(|line| line.contains(&format!("{file}: HUD over pixels")))
        .unwrap_or_else(|| panic!("{name}: no screenshot of frame {frame}:\n{text}"));
    let inside = &line[line.find('[').expect("a list") + 1..line.rfind(']').expect("a list")];
    let regions = inside
        .split_whitespace()
        .map(|rect| {
            let v: Vec<u32> = rect.split(',').map(|n| n.parse().expect("a pixel coordinate")).collect();
            [v[0], v[1], v[2], v[3]]
        })
        .collect();
    let image = image::open(dir.join(file)).expect("the screenshot").to_rgba8();
    let _ = std::fs::remove_dir_all(&dir);
    (image, regions, text)
}

/// The HUD is drawn into the frame: a screenshot with it differs from one without it inside the rectangles
/// the HUD reports, substantially, and nowhere else. Both at frame 2, drawn from the first build (made whole),
/// and at frame 30, drawn from a build spread over frames.
#[test]
fn hud_changes_the_frame_inside_its_region_and_nowhere_else() {
    if !xvfb_available("the HUD test") {
        return;
    }
    for frame in [2, 30] {
        let (with_hud, regions, text) = window_screenshot("hud", frame, &[]);
        let (without, none, _) = window_screenshot("no-hud", frame, &["--no-hud"]);
        assert!(none.is_empty(), "--no-hud drew a HUD: {none:?}");
        assert_eq!(regions.len(), 2, "the figures and the plots windows: {regions:?}");
        assert_eq!(with_hud.dimensions(), (960, 540));
        assert_eq!(with_hud.dimensions(), without.dimensions());
        if frame == 30 {
            for step in ["beginning egui's pass: ", "the plots window, ending the pass: ", "uploading: "] {
                assert!(text.contains(step), "no build spread over frames by frame {frame} ({step}):\n{text}");
            }
        }
        let in_hud =
            |x: u32, y: u32| regions.iter().any(|&[x0, y0, x1, y1]| (x0..x1).contains(&x) && (y0..y1).contains(&y));
        let (mut changed_inside, mut area) = (0usize, 0usize);
        for (x, y, pixel) in with_hud.enumerate_pixels() {
            let changed = pixel != without.get_pixel(x, y);
            if in_hud(x, y) {
                area += 1;
                changed_inside += usize::from(changed);
            } else {
                assert!(!changed, "frame {frame}: pixel ({x}, {y}) outside the HUD's region {regions:?} changed");
            }
        }
        assert!(changed_inside * 2 > area, "frame {frame}: the HUD changed only {changed_inside} of its {area} pixels");
    }
}

/// An occlusion buffer past the engine's bounds is refused before anything runs, with the bound in the
/// message, instead of aborting on the allocation.
#[test]
fn an_oversized_occlusion_buffer_is_refused_with_a_clear_error() {
    let args = ["--cpu-only", "--frames", "1", "--scene", "city:200", "--occlusion-resolution", "100000x100000"];
    let (ok, stdout, stderr) = run_game(&args, &[]);
    assert!(!ok, "an oversized buffer should be refused:\n{stdout}");
    assert!(stderr.contains("100000x100000") && stderr.contains("too large"), "{stderr}");
}

/// Detail culling is lossy: --validate measures its false negatives and image error and still passes; it
/// drops objects the frustum kept.
#[test]
fn detail_culling_is_judged_as_lossy() {
    let args = ["--scene", "city:3000", "--detail-pixels", "4", "--cpu-only"];
    let (text, rows) = run_validated("detail", &args, 8);
    assert!(text.contains("detail culling (lossy):"), "{text}");
    assert!(text.contains("validation over 8 frames"), "{text}");
    let image_error: u64 = rows.iter().map(|r| r["image_error_pixels"].parse::<u64>().unwrap()).sum();
    println!("detail culling at 4 px: {image_error} pixels of image error over 8 frames");
}
