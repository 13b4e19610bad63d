//! The heads-up display drawn into the game's frame: objects and time per stage, the GPU passes, what the
//! adaptive pipeline skipped, live plots of the last seconds, the debug views' legends, the key bindings and
//! the controls a player changes most. [`Hud::ui`] builds it with egui from one frame's figures; the
//! [`painter`] draws it into the window's frame.

pub mod controls;
mod labels;
pub mod painter;

use crate::validation::{Validation, frame_efficiency};
use controls::{Controls, View};
use cullet::culler::OcclusionSettings;
use cullet::draw_cost::DrawSavings;
use cullet::gpu::{GpuCounters, GpuFrameOutput, GpuPassTimes};
use cullet::pipeline::CullStats;
use cullet::raster::RasterMode;
use egui::{Color32, RichText};
use labels::{Labels, TableRow};
use std::collections::VecDeque;
use std::time::Duration;

/// The key bindings, printed when the window opens and shown by the help key.
pub const HELP: &str = "\
right mouse button held + move   look around
W A S D   move          Q / E   down / up          Shift   5x faster
P   follow the camera path / fly freely (moving also leaves the path)
F   freeze culling at the current camera: fly around to see what was culled
1   frustum culling on/off          2   occlusion culling on/off
3   GPU cluster culling (normal cones, HZB) on/off
4   GPU triangle culling on/off
5   two-phase GPU occlusion (last frame's visible first, the rest against their depth) on/off
V   cycle the view: shaded / tinted by the stage that culled each object / occlusion buffer / its pyramid
[ ] pyramid level down / up
H   heads-up display on/off         F1  this help          Esc  quit";

/// Tint of objects the frustum stage culled, in the tinted view (and its colour in the HUD).
pub const FRUSTUM_TINT: [u8; 4] = [235, 50, 210, 255];
/// Tint of objects the occlusion stage culled (and its colour in the HUD).
pub const OCCLUSION_TINT: [u8; 4] = [40, 120, 255, 255];

const fn colour(rgba: [u8; 4]) -> Color32 {
    Color32::from_rgb(rgba[0], rgba[1], rgba[2])
}

const BOUNDS_COLOUR: Color32 = Color32::from_rgb(150, 150, 150);
const FRUSTUM_COLOUR: Color32 = colour(FRUSTUM_TINT);
const RASTER_COLOUR: Color32 = Color32::from_rgb(130, 200, 255);
const OCCLUSION_COLOUR: Color32 = colour(OCCLUSION_TINT);
const HZB_COLOUR: Color32 = Color32::from_rgb(170, 120, 255);
const DRAW_COLOUR: Color32 = Color32::from_rgb(230, 230, 120);
const CLUSTERS_COLOUR: Color32 = Color32::from_rgb(255, 170, 40);
const TRIANGLES_COLOUR: Color32 = Color32::from_rgb(110, 210, 90);
const WARNING_COLOUR: Color32 = Color32::from_rgb(255, 90, 80);
const NOTE_COLOUR: Color32 = Color32::from_rgb(240, 210, 100);

/// The CPU time plot's series, in the order of [`Sample::cpu_ms`].
const CPU_SERIES: [(&str, Color32); 4] = [
    ("bounds", BOUNDS_COLOUR),
    ("frustum", FRUSTUM_COLOUR),
    ("occluder raster", RASTER_COLOUR),
    ("occlusion test", OCCLUSION_COLOUR),
];
/// The GPU time plot's series, in the order of [`Sample::gpu_ms`].
const GPU_SERIES: [(&str, Color32); 4] =
    [("HZB", HZB_COLOUR), ("clusters", CLUSTERS_COLOUR), ("triangles", TRIANGLES_COLOUR), ("draw", DRAW_COLOUR)];
/// The removed-share plots' series, in the order of [`Sample::removed`].
const REMOVED_SERIES: [(&str, Color32); 4] = [
    ("frustum", FRUSTUM_COLOUR),
    ("occlusion", OCCLUSION_COLOUR),
    ("GPU clusters", CLUSTERS_COLOUR),
    ("GPU triangles", TRIANGLES_COLOUR),
];

/// Seconds of history the plots show.
const HISTORY_SECONDS: f64 = 5.0;
/// Most plot points a second of history gets.
const PLOT_POINTS_PER_SECOND: f64 = 30.0;
/// Seconds between refreshes of the figures and plots shown: readable, and the UI is built again only then
/// (or on input).
pub const REFRESH_SECONDS: f64 = 0.1;
/// Frames between refreshes, at least: below 40 frames a second they come every this many frames rather than
/// every [`REFRESH_SECONDS`], so that the HUD's cost per frame stays low at any frame rate (a build is spread
/// over five frames, so it comes every fifth frame at most: see [`painter::HudPainter`]). The plots still get
/// every frame.
pub const REFRESH_FRAMES: u32 = 4;

/// The egui context the HUD is built in, with its style.
pub fn context() -> egui::Context {
    let context = egui::Context::default();
    context.global_style_mut(|style| {
        // No shadows: the HUD covers exactly its windows' rectangles.
        style.visuals.window_shadow = egui::Shadow::NONE;
        style.visuals.popup_shadow = egui::Shadow::NONE;
        // Text selection is egui's plugin, which a pass begun and ended by hand (spread over frames, see
        // `painter::HudPainter`) does not run; the HUD's figures need none.
        style.interaction.selectable_labels = false;
    });
    context
}

/// One frame's figures, as the HUD shows them.
#[derive(Clone, Debug)]
pub struct HudFrame {
    /// The CPU stages.
    pub stats: CullStats,
    /// The GPU passes, when they ran this frame.
    pub gpu: Option<GpuFrameOutput>,
    /// Triangles each stage kept from the draw.
    pub savings: DrawSavings,
    /// Frames per second, smoothed.
    pub fps: f32,
    /// The most CPU time the HUD took in one of the last frames.
    pub hud_time: Duration,
    /// The camera follows its path (not free flight).
    pub following_path: bool,
    /// Size of the occlusion buffer, in texels.
    pub buffer: (u32, u32),
    /// Size of each level of its pyramid, in texels (empty when none was built).
    pub pyramid: Vec<(u32, u32)>,
    /// The window's size in pixels (the "viewport" occlusion resolution).
    pub viewport: (u32, u32),
    /// Each light view's name and the casters it kept (empty without light views).
    pub light_views: Vec<(String, usize)>,
}

/// One frame in the plots' history.
struct Sample {
    /// Seconds since the HUD started, at the sample's first frame.
    seconds: f64,
    /// Frames averaged into this sample.
    frames: u32,
    /// Milliseconds of each CPU stage, as in [`CPU_SERIES`].
    cpu_ms: [f64; 4],
    /// Milliseconds of each GPU pass, as in [`GPU_SERIES`], where the GPU has timestamps.
    gpu_ms: Option<[f64; 4]>,
    /// Percent of all objects each CPU stage removed, then 0 for the GPU stages.
    objects_removed: [f64; 4],
    /// Percent of all triangles each stage kept from being drawn, as in [`REMOVED_SERIES`].
    triangles_removed: [f64; 4],
}

impl Sample {
    /// Averages `next`, a later frame's sample, into this one.
    fn merge(&mut self, next: &Sample) {
        let weight = 1.0 / f64::from(self.frames + 1);
        let mean = |mine: &mut [f64], theirs: &[f64]| {
            for (a, b) in mine.iter_mut().zip(theirs) {
                *a += (b - *a) * weight;
            }
        };
        mean(&mut self.cpu_ms, &next.cpu_ms);
        match (&mut self.gpu_ms, &next.gpu_ms) {
            (Some(mine), Some(theirs)) => mean(mine, theirs),
            (mine, theirs) => *mine = *theirs,
        }
        mean(&mut self.objects_removed, &next.objects_removed);
        mean(&mut self.triangles_removed, &next.triangles_removed);
        self.frames += 1;
    }
}

/// The heads-up display's state: shown or not, the help, the figures shown and the plots' history.
pub struct Hud {
    /// The HUD is drawn.
    pub visible: bool,
    /// The key bindings are shown.
    pub help: bool,
    /// The figures shown, refreshed every [`REFRESH_SECONDS`] and [`REFRESH_FRAMES`], whichever is longer.
    shown: Option<HudFrame>,
    /// When `shown` was refreshed, in seconds since the HUD started.
    shown_at: f64,
    /// Frames recorded since `shown` was refreshed.
    frames_since_shown: u32,
    history: VecDeque<Sample>,
    seconds: f64,
}

impl Hud {
    /// A HUD, shown or hidden.
    pub fn new(visible: bool) -> Self {
        Self {
            visible,
            help: false,
            shown: None,
            shown_at: 0.0,
            frames_since_shown: 0,
            history: VecDeque::new(),
            seconds: 0.0,
        }
    }

    /// Adds a frame `delta` seconds after the last to the plots' history (kept while hidden, so the plots
    /// are full when it is shown again), and shows its figures when the last shown are old enough: at least
    /// [`REFRESH_SECONDS`] and [`REFRESH_FRAMES`] old. Returns whether they were: the HUD's content changed.
    pub fn record(&mut self, frame: HudFrame, delta: f32) -> bool {
        self.seconds += f64::from(delta);
        let stats = &frame.stats;
        let ms = |duration: Duration| duration.as_secs_f64() * 1e3;
        let objects = stats.objects.max(1) as f64;
        let savings = &frame.savings;
        let total = savings.total.max(1) as f64;
        let sample = Sample {
            seconds: self.seconds,
            frames: 1,
            cpu_ms: [ms(stats.bounds_time), ms(stats.frustum_time), ms(stats.raster_time), ms(stats.occlusion_time)],
            gpu_ms: frame
                .gpu
                .as_ref()
                .and_then(|gpu| gpu.pass_times)
                .map(|t| [ms(t.hzb), ms(t.clusters), ms(t.triangles), ms(t.draw)]),
            objects_removed: [
                100.0 * stats.frustum_removed() as f64 / objects,
                100.0 * stats.occlusion_removed() as f64 / objects,
                0.0,
                0.0,
            ],
            triangles_removed: savings.by_stage().map(|(_, removed)| 100.0 * removed as f64 / total),
        };
        // Frames closer together than a plot point are averaged into one: the plots' cost stays the same at
        // any frame rate.
        match self.history.back_mut() {
            Some(last) if self.seconds - last.seconds < 1.0 / PLOT_POINTS_PER_SECOND => last.merge(&sample),
            _ => self.history.push_back(sample),
        }
        while self.history.front().is_some_and(|oldest| self.seconds - oldest.seconds > HISTORY_SECONDS) {
            self.history.pop_front();
        }
        self.frames_since_shown += 1;
        let refresh = self.shown.is_none()
            || (self.seconds - self.shown_at >= REFRESH_SECONDS && self.frames_since_shown >= REFRESH_FRAMES);
        if refresh {
            self.shown = Some(frame);
            self.shown_at = self.seconds;
            self.frames_since_shown = 0;
        }
        refresh
    }

    /// The parts [`Hud::ui_part`] builds the HUD in: its figures window, then its plots and help windows.
    pub const PARTS: usize = 2;

    /// Builds the HUD from the figures recorded last, with `validation`'s live figures, and widgets editing
    /// `controls`: every part of [`Hud::ui_part`] in turn. Returns the screen areas its windows cover, in
    /// points (egui's logical pixels); none when it is hidden or nothing was recorded yet.
    pub fn ui(&self, ctx: &egui::Context, validation: Option<&Validation>, controls: &mut Controls) -> Vec<egui::Rect> {
        (0..Self::PARTS).flat_map(|part| self.ui_part(ctx, part, validation, controls)).collect()
    }

    /// Builds part `part` (below [`Hud::PARTS`]) of the HUD in egui's pass under way: 0 is the figures window
    /// (with `validation`'s live figures and widgets editing `controls`), 1 the plots window and the key
    /// bindings. The painter spreads the parts of a pass over frames of their own. Returns the screen areas the
    /// part's windows cover, in points; none when the HUD is hidden, nothing was recorded yet, or `part` is
    /// past the last.
    pub fn ui_part(
        &self,
        ctx: &egui::Context,
        part: usize,
        validation: Option<&Validation>,
        controls: &mut Controls,
    ) -> Vec<egui::Rect> {
        let Some(frame) = self.shown.as_ref().filter(|_| self.visible) else {
            return Vec::new();
        };
        let labels = Labels::new(ctx);
        match part {
            0 => {
                let table = panel(
                    ctx,
                    "cullet",
                    true,
                    |window| window.default_pos([8.0, 8.0]),
                    |ui| {
                        stage_table(ui, &labels, frame);
                        adaptive_flags(ui, &labels, frame, controls);
                        if let Some(validation) = validation {
                            validation_lines(ui, &labels, validation);
                        }
                        view_help(ui, &labels, frame, controls);
                        egui::CollapsingHeader::new("settings")
                            .default_open(false)
                            .show(ui, |ui| settings(ui, frame, controls));
                        ui.label(RichText::new("H hides the HUD, F1 shows the keys").weak());
                    },
                );
                table.into_iter().collect()
            }
            1 => {
                // In a small window the plots would cover the figures: they start folded there.
                let plots = panel(
                    ctx,
                    "last 5 seconds",
                    frame.viewport.0 >= 900,
                    |window| window.anchor(egui::Align2::RIGHT_TOP, [-8.0, 8.0]).default_width(260.0),
                    |ui| self.plots(ui, &labels),
                );
                let help = self.help.then(|| {
                    egui::Window::new("keys")
                        .anchor(egui::Align2::CENTER_BOTTOM, [0.0, -8.0])
                        .resizable(false)
                        .collapsible(false)
                        .show(ctx, |ui| ui.label(RichText::new(HELP).monospace()))
                });
                plots.into_iter().chain(help.flatten().map(|shown| shown.response.rect)).collect()
            }
            _ => Vec::new(),
        }
    }

    /// The plots, each stacked by stage: CPU time, GPU time (where timestamps exist), and the share of objects
    /// and of triangles each stage removed.
    fn plots(&self, ui: &mut egui::Ui, labels: &Labels) {
        let xs: Vec<f64> = self.history.iter().map(|s| s.seconds - self.seconds).collect();
        // The titles' figures are those of the frame shown, so they change (and are laid out) only when the
        // figures are refreshed.
        let shown = self.history.iter().rev().find(|s| s.seconds <= self.shown_at);
        // One plot: its title with the shown frame's total (`decimals` places, then `unit`), the series'
        // legend, and the series stacked.
        let stacked = |ui: &mut egui::Ui,
                       name: &str,
                       unit: &str,
                       decimals: usize,
                       series: &[(&str, Color32)],
                       value: &dyn Fn(&Sample, usize) -> f64| {
            let total: f64 = shown.map_or(0.0, |s| (0..series.len()).map(|i| value(s, i)).sum());
            labels.text(ui, &format!("{name}: {total:.decimals$}{unit}"));
            labels.legend(ui, series);
            let values: Vec<[f64; 4]> = self.history.iter().map(|s| std::array::from_fn(|i| value(s, i))).collect();
            stacked_bands(ui, &xs, &values, series);
        };
        stacked(ui, "CPU time per stage", " ms", 2, &CPU_SERIES, &|s, i| s.cpu_ms[i]);
        if self.history.iter().any(|s| s.gpu_ms.is_some()) {
            stacked(ui, "GPU time per pass", " ms", 2, &GPU_SERIES, &|s, i| s.gpu_ms.map_or(0.0, |ms| ms[i]));
        }
        stacked(ui, "objects culled", "% of all", 0, &REMOVED_SERIES[..2], &|s, i| s.objects_removed[i]);
        stacked(ui, "triangles not drawn", "% of all", 0, &REMOVED_SERIES, &|s, i| s.triangles_removed[i]);
    }
}

/// A window of the HUD, placed by `place`, whose content folds under a header named `title`, open at first
/// when `open`. Returns the area it covers, in points; none when egui did not show it.
///
/// A collapsing header in a window without egui's title bar: the title bar took a tenth of the pass's perf
/// samples in the game, and with headers in its place the pass costs 4-5% less (the README's HUD cost).
fn panel(
    ctx: &egui::Context,
    title: &str,
    open: bool,
    place: impl FnOnce(egui::Window<'_>) -> egui::Window<'_>,
    contents: impl FnOnce(&mut egui::Ui),
) -> Option<egui::Rect> {
    let window = place(egui::Window::new(title)).resizable(false).title_bar(false);
    let shown = window.show(ctx, |ui| {
        egui::CollapsingHeader::new(title).default_open(open).show_unindented(ui, contents);
    });
    shown.map(|shown| shown.response.rect)
}

/// Height of each plot, in points.
const PLOT_HEIGHT: f32 = 56.0;

/// Paints one plot of the last [`HISTORY_SECONDS`]: at each time in `xs` (seconds before now, negative), the
/// values of `series` stacked from 0 as filled bands, scaled so that the highest stack fills the plot.
///
/// One mesh of two triangles per band and sample, which egui passes to the GPU as it is: a plot widget's
/// polygons, axes and interaction cost more CPU than the rest of the HUD together (`benches/hud.rs`).
fn stacked_bands(ui: &mut egui::Ui, xs: &[f64], values: &[[f64; 4]], series: &[(&str, Color32)]) {
    let size = egui::vec2(ui.available_width(), PLOT_HEIGHT);
    let (rect, _) = ui.allocate_exact_size(size, egui::Sense::hover());
    let visuals = ui.visuals();
    let painter = ui.painter();
    painter.rect_filled(rect, 2.0, visuals.extreme_bg_color);
    let stacks = values.iter().map(|v| v.iter().take(series.len()).sum::<f64>());
    let top = stacks.fold(0.0, f64::max);
    if top > 0.0 && top.is_finite() {
        let inner = rect.shrink(2.0);
        let x = |seconds: f64| inner.left() + inner.width() * (1.0 + seconds / HISTORY_SECONDS).clamp(0.0, 1.0) as f32;
        let y = |value: f64| inner.bottom() - inner.height() * (value / top).clamp(0.0, 1.0) as f32;
        let mut mesh = egui::Mesh::default();
        mesh.reserve_vertices(2 * xs.len() * series.len());
        mesh.reserve_triangles(2 * xs.len() * series.len());
        let mut lower = vec![0.0; xs.len()];
        for (index, &(_, colour)) in series.iter().enumerate() {
            let first = mesh.vertices.len() as u32;
            for ((&seconds, below), value) in xs.iter().zip(&mut lower).zip(values) {
                let above = *below + value[index];
                mesh.colored_vertex(egui::pos2(x(seconds), y(*below)), colour);
                mesh.colored_vertex(egui::pos2(x(seconds), y(above)), colour);
                *below = above;
            }
            // Vertices 2j and 2j + 1 are sample j's bottom and top: one quad between each sample and the next.
            for j in 1..xs.len() as u32 {
                let (bottom, top) = (first + 2 * j, first + 2 * j + 1);
                mesh.add_triangle(bottom - 2, top - 2, top);
                mesh.add_triangle(bottom - 2, top, bottom);
            }
        }
        painter.add(mesh);
    }
    painter.rect_stroke(rect, 2.0, visuals.widgets.noninteractive.bg_stroke, egui::StrokeKind::Inside);
}

/// One row of the stage table: the stage's colour and name, what it kept, its time.
fn stage_row(colour: Color32, stage: &str, kept: String, time: String) -> TableRow<3> {
    TableRow { swatch: Some(colour), cells: [stage.into(), kept, time] }
}

/// A row of the stage table without a stage's colour.
fn plain_row(cells: [String; 3]) -> TableRow<3> {
    TableRow { swatch: None, cells }
}

/// Objects (or clusters and triangles) after each stage and each stage's time.
fn stage_table(ui: &mut egui::Ui, labels: &Labels, frame: &HudFrame) {
    let stats = &frame.stats;
    let us = |duration: Duration| format!("{:.0} µs", duration.as_secs_f64() * 1e6);
    let mut rows = vec![plain_row(["stage".into(), "kept".into(), "time".into()])];
    let updated = format!("{} of {} updated", stats.bounds_recomputed, stats.objects);
    rows.push(stage_row(BOUNDS_COLOUR, "bounds", updated, us(stats.bounds_time)));
    let kept = format!("{} of {}", stats.after_frustum, stats.objects);
    rows.push(stage_row(FRUSTUM_COLOUR, "frustum", kept, us(stats.frustum_time)));
    if stats.detail_culled > 0 {
        let dropped = format!("{} too small (lossy)", stats.detail_culled);
        rows.push(stage_row(FRUSTUM_COLOUR, "detail", dropped, "in the frustum's".into()));
    }
    if stats.light_views > 0 {
        // Before their occlusion, which has its own row.
        let casters = stats.light_view_casters + stats.light_view_occluded;
        let casters = format!("{casters} casters in {} views", stats.light_views);
        rows.push(stage_row(FRUSTUM_COLOUR, "light views", casters, "in the frustum's".into()));
        for (name, kept) in &frame.light_views {
            rows.push(plain_row([format!("   {name}"), format!("{kept} casters"), String::new()]));
        }
    }
    let occluders =
        format!("{} occluders ({} hidden), {} tris", stats.occluders, stats.occluders_hidden, stats.occluder_triangles);
    rows.push(stage_row(RASTER_COLOUR, "occluder raster", occluders, us(stats.raster_time)));
    let kept = format!("{} of {}", stats.after_occlusion, stats.after_frustum);
    rows.push(stage_row(OCCLUSION_COLOUR, "occlusion test", kept, us(stats.occlusion_time)));
    if stats.light_views > 0 {
        let (hidden, gated) = (stats.light_view_occluded, stats.light_occlusion_gated);
        let hidden = format!("{hidden} casters hidden, {gated} of {} views gated", stats.light_views);
        rows.push(stage_row(OCCLUSION_COLOUR, "light views' occlusion", hidden, us(stats.light_occlusion_time)));
    }
    if let Some(gpu) = &frame.gpu {
        let counters = gpu.counters;
        let times = gpu.pass_times;
        let pass = |time: fn(&GpuPassTimes) -> Duration| times.as_ref().map_or(String::from("-"), |t| us(time(t)));
        rows.push(stage_row(HZB_COLOUR, "GPU HZB", "from the occlusion buffer".into(), pass(|t| t.hzb)));
        let clusters = format!("{} of {}", counters.clusters_out, counters.clusters_in);
        rows.push(stage_row(CLUSTERS_COLOUR, "GPU clusters", clusters, pass(|t| t.clusters)));
        let triangles = format!("{} of {}", counters.triangles_out, counters.triangles_in);
        rows.push(stage_row(TRIANGLES_COLOUR, "GPU triangles", triangles, pass(|t| t.triangles)));
        rows.push(stage_row(DRAW_COLOUR, "draw", format!("{} draws", counters.draws), pass(|t| t.draw)));
        if let Some(phases) = gpu.phases {
            let late = phases.late;
            let split = format!(
                "{} tris early, {} late; merged HZB hid {} of {} clusters",
                phases.early.triangles_out, late.triangles_out, late.clusters_hzb, late.clusters_in
            );
            let late_time =
                pass(|t| t.merge + t.late_clusters + t.late_triangles + t.late_draw + t.final_merge + t.final_marks);
            rows.push(stage_row(HZB_COLOUR, "two phases", split, late_time));
        }
        if !gpu.light_views.is_empty() {
            let sum = |f: fn(&GpuCounters) -> u32| gpu.light_views.iter().map(f).sum::<u32>();
            let shadows = format!(
                "{} cascades: {} of {} tris",
                gpu.light_views.len(),
                sum(|c| c.triangles_out),
                sum(|c| c.triangles_in)
            );
            rows.push(stage_row(DRAW_COLOUR, "shadow maps", shadows, "in the frame's".into()));
        }
        let source = if times.is_some() { "submit to read-back" } else { "no timestamps on this GPU" };
        let wall = format!("{:.2} ms", gpu.wall_time.as_secs_f64() * 1e3);
        rows.push(plain_row(["GPU wall".into(), source.into(), wall]));
    }
    labels.table(ui, &rows);
    labels.text(
        ui,
        &format!("{:.0} fps    HUD at most {:.2} ms CPU a frame", frame.fps, frame.hud_time.as_secs_f64() * 1e3),
    );
}

/// What the adaptive pipeline skipped or reused this frame, and what is off or frozen.
fn adaptive_flags(ui: &mut egui::Ui, labels: &Labels, frame: &HudFrame, controls: &Controls) {
    let stats = &frame.stats;
    let gpu = frame.gpu.as_ref();
    let mut notes: Vec<String> = Vec::new();
    if stats.reused {
        notes.push("reused last frame's result (nothing changed)".into());
    }
    if stats.retested > 0 {
        notes.push(format!("re-tested only the {} objects that moved", stats.retested));
    }
    if stats.occlusion_gated {
        notes.push("occlusion skipped: it removed too little lately, or the frame's own depth hides as much".into());
    }
    if gpu.is_some_and(|o| o.cluster_pass_skipped) {
        notes.push("cluster pass skipped: too few clusters, or it removed too little lately".into());
    }
    if gpu.is_some_and(|o| o.triangle_pass_skipped) {
        notes.push("triangle pass skipped: it removed too little lately".into());
    }
    if let Some(error) = &stats.frustum_error {
        notes.push(format!("no frustum ({error}): everything kept"));
    }
    for note in notes {
        labels.coloured(ui, NOTE_COLOUR, &note);
    }
    let mut off: Vec<&str> = Vec::new();
    for (is_off, name) in [
        (!controls.frustum.enabled, "frustum"),
        (!controls.occlusion.enabled, "occlusion"),
        (!controls.clusters_on(), "GPU clusters"),
        (!controls.triangles_on(), "GPU triangles"),
    ] {
        if is_off {
            off.push(name);
        }
    }
    if !off.is_empty() {
        ui.colored_label(WARNING_COLOUR, format!("switched off: {}", off.join(", ")));
    }
    if controls.frozen {
        ui.colored_label(WARNING_COLOUR, "culling FROZEN at an earlier camera (F)");
    }
    let occlusion = &controls.occlusion;
    if !occlusion.is_conservative_for(frame.viewport) {
        let why = if occlusion.mode.samples_pixel_centres() {
            "pixel centres below the viewport's size"
        } else {
            "fast occlusion"
        };
        ui.colored_label(WARNING_COLOUR, format!("{why}: lossy, may cull visible objects"));
    }
    ui.label(if frame.following_path { "camera: following its path (P)" } else { "camera: free flight (P)" });
}

/// The live judge's figures: this frame's false negatives and culling efficiency, and the run's.
fn validation_lines(ui: &mut egui::Ui, labels: &Labels, validation: &Validation) {
    let Some(last) = &validation.last else { return };
    let missed = last.false_negatives.len();
    let text = format!(
        "judged: {missed} false negatives, efficiency frustum {:.1}%, + occlusion {:.1}%, image error {} px",
        100.0 * frame_efficiency(last, 0),
        100.0 * frame_efficiency(last, 1),
        last.image_error_pixels
    );
    labels.coloured(ui, if missed > 0 { WARNING_COLOUR } else { TRIANGLES_COLOUR }, &text);
    let total = &validation.total;
    labels.text(
        ui,
        &format!(
            "over {} frames: {} false negatives, efficiency {:.1}%",
            total.frames,
            total.false_negatives,
            100.0 * total.efficiency(1)
        ),
    );
}

/// The levels view's colours, finest first (a coarser level than these takes the last).
pub const LEVEL_COLOURS: [[u8; 4]; 6] = [
    [235, 235, 235, 255],
    [90, 170, 255, 255],
    [80, 200, 120, 255],
    [250, 210, 60, 255],
    [250, 130, 40, 255],
    [220, 50, 50, 255],
];

/// The legend of the tinted view, or the buffer and level the depth views show.
fn view_help(ui: &mut egui::Ui, labels: &Labels, frame: &HudFrame, controls: &Controls) {
    ui.separator();
    ui.label(format!("view (V): {}", controls.view.label()));
    match controls.view {
        View::Shaded => {}
        View::Tinted => {
            labels.swatch(ui, FRUSTUM_COLOUR, "culled by the frustum stage");
            labels.swatch(ui, OCCLUSION_COLOUR, "culled by the occlusion stage");
            labels.swatch(ui, Color32::from_gray(200), "own colour: kept (drawn)");
        }
        View::OcclusionBuffer => {
            let (width, height) = frame.buffer;
            ui.label(format!("occlusion buffer: {width}x{height} texels"));
            ui.label("brighter is nearer; black is empty (nothing rasterized)");
        }
        View::Levels => {
            for (level, colour) in LEVEL_COLOURS.iter().enumerate() {
                let [r, g, b, _] = *colour;
                let name = if level == 0 { "level 0: full detail".to_string() } else { format!("level {level}") };
                labels.swatch(ui, Color32::from_rgb(r, g, b), &name);
            }
            labels.swatch(ui, Color32::from_gray(200), "own colour: no levels (or levels of detail off)");
        }
        View::Pyramid => {
            let levels = frame.pyramid.len();
            let level = controls.pyramid_level.min(levels.saturating_sub(1));
            match frame.pyramid.get(level) {
                Some((width, height)) => ui.label(format!(
                    "pyramid level {level} of 0-{} ([ ]): {width}x{height} texels, each the farthest depth of \
                     the level below",
                    levels - 1
                )),
                None => ui.label("no pyramid this frame: the occlusion buffer is shown"),
            };
            ui.label("brighter is nearer; black is empty (nothing rasterized)");
        }
    }
}

/// Buffer sizes offered for the occlusion stage: width and height, and the viewport's own.
const BUFFER_SIZES: [(u32, u32); 4] = [(128, 72), (256, 144), (512, 288), (1024, 576)];

/// The controls: each stage on or off, the occlusion buffer, its mode and budget, freezing and the view.
fn settings(ui: &mut egui::Ui, frame: &HudFrame, controls: &mut Controls) {
    // Two switches a row, so that the settings fit under the figures in a 960x540 window.
    ui.horizontal(|ui| {
        ui.checkbox(&mut controls.frustum.enabled, "frustum culling (1)");
        ui.checkbox(&mut controls.occlusion.enabled, "occlusion culling (2)");
    });
    ui.horizontal(|ui| {
        let mut clusters = controls.clusters_on();
        if ui.checkbox(&mut clusters, "GPU cluster culling (3)").changed() {
            controls.set_clusters(clusters);
        }
        let mut triangles = controls.triangles_on();
        if ui.checkbox(&mut triangles, "GPU triangle culling (4)").changed() {
            controls.set_triangles(triangles);
        }
        ui.checkbox(&mut controls.gpu.two_phase, "two-phase occlusion (5)");
    });
    if let Some(lod) = &mut controls.lod {
        ui.horizontal(|ui| {
            let mut on = lod.max_error_pixels > 0.0;
            if ui.checkbox(&mut on, "levels of detail (lossy)").changed() {
                lod.max_error_pixels = if on { 1.0 } else { 0.0 };
            }
            // Pixels of the frame the player sees.
            lod.viewport_height = frame.viewport.1;
            if on {
                ui.add(egui::Slider::new(&mut lod.max_error_pixels, 0.25..=8.0).logarithmic(true).suffix(" px"));
            }
        });
        ui.horizontal(|ui| {
            let mut on = lod.triangle_budget.is_some();
            if ui.checkbox(&mut on, "triangle budget (lossy)").changed() {
                lod.triangle_budget = on.then_some(100_000);
            }
            if let Some(budget) = &mut lod.triangle_budget {
                ui.add(egui::Slider::new(budget, 1_000..=10_000_000).logarithmic(true));
            }
        });
    }
    ui.horizontal(|ui| {
        ui.checkbox(&mut controls.frozen, "freeze culling (F)");
        let detail = &mut controls.detail;
        let mut on = detail.enabled();
        if ui.checkbox(&mut on, "detail culling (lossy)").changed() {
            detail.min_pixels = if on { 1.0 } else { 0.0 };
        }
        if on {
            // Pixels of the frame the player sees.
            detail.viewport_height = frame.viewport.1;
            ui.add(egui::Slider::new(&mut detail.min_pixels, 0.25..=8.0).logarithmic(true).suffix(" px"));
        }
    });
    let occlusion = &mut controls.occlusion;
    let current = (occlusion.width, occlusion.height);
    egui::ComboBox::from_label("occlusion buffer").selected_text(format!("{}x{}", current.0, current.1)).show_ui(
        ui,
        |ui| {
            let (w, h) = frame.viewport;
            // Only sizes within the engine's bounds (a very large window's own size may not be).
            let fits = |(width, height)| OcclusionSettings { width, height, ..*occlusion }.validate().is_ok();
            for size in BUFFER_SIZES.into_iter().chain([(w, h)]).filter(|&size| fits(size)) {
                let name = if size == frame.viewport {
                    format!("{w}x{h} (viewport)")
                } else {
                    format!("{}x{}", size.0, size.1)
                };
                if ui.selectable_label(current == size, name).clicked() {
                    (occlusion.width, occlusion.height) = size;
                }
            }
        },
    );
    if let Err(error) = occlusion.validate() {
        ui.colored_label(Color32::LIGHT_RED, format!("occlusion skipped: {error}"));
    }
    // A list rather than a row of radio buttons, which made the window as wide as two thirds of a 960-pixel one.
    let modes = [
        (RasterMode::Conservative, "conservative"),
        (RasterMode::PixelCentres, "pixel centres (at the viewport's size)"),
        (RasterMode::Masked, "masked (at the viewport's size)"),
        (RasterMode::Fast, "fast (lossy)"),
    ];
    let shown = modes.iter().find(|(mode, _)| *mode == occlusion.mode).map_or("", |&(_, name)| name);
    egui::ComboBox::from_label("occlusion mode").selected_text(shown).show_ui(ui, |ui| {
        for (mode, name) in modes {
            ui.selectable_value(&mut occlusion.mode, mode, name);
        }
    });
    ui.add(egui::Slider::new(&mut occlusion.triangle_budget, 64..=65536).logarithmic(true).text("occluder triangles"));
    egui::ComboBox::from_label("view (V)").selected_text(controls.view.label()).show_ui(ui, |ui| {
        for view in View::ALL {
            ui.selectable_value(&mut controls.view, view, view.label());
        }
    });
    if controls.view == View::Pyramid && frame.pyramid.len() > 1 {
        let top = frame.pyramid.len() - 1;
        ui.add(egui::Slider::new(&mut controls.pyramid_level, 0..=top).text("pyramid level ([ ])"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The frames, of `frames` at `fps` a second, that refresh the figures shown.
    fn refreshes(fps: f32, frames: usize) -> Vec<usize> {
        let frame = HudFrame {
            stats: CullStats::default(),
            gpu: None,
            savings: DrawSavings::default(),
            fps,
            hud_time: Duration::ZERO,
            following_path: true,
            buffer: (256, 144),
            pyramid: Vec::new(),
            viewport: (1280, 720),
            light_views: Vec::new(),
        };
        let mut hud = Hud::new(true);
        (0..frames).filter(|_| hud.record(frame.clone(), 1.0 / fps)).collect()
    }

    #[test]
    fn figures_refresh_every_tenth_of_a_second_and_no_more_often_than_every_fourth_frame() {
        for (fps, gaps) in [(200.0, 20..=21), (60.0, 6..=7), (20.0, 4..=4), (8.0, 4..=4)] {
            let shown = refreshes(fps, 400);
            assert_eq!(shown[0], 0, "the first frame is shown");
            for pair in shown.windows(2) {
                // A tenth of a second, one frame more where the sum of frame times falls just short of it; below
                // 40 frames a second, every fourth frame.
                assert!(gaps.contains(&(pair[1] - pair[0])), "at {fps} frames a second: {shown:?}");
            }
            assert!(400 - shown.last().unwrap() <= *gaps.end(), "at {fps} frames a second: {shown:?}");
        }
    }
}
