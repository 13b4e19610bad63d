//! Drawing the HUD into the window's frame: egui's input from winit (`egui-winit`) and its triangles drawn
//! over the frame with wgpu (`egui-wgpu`), in the same command encoder as the frame.

use cpu_time::ThreadTime;
use cullet::gpu::GpuContext;
use std::time::{Duration, Instant};
use winit::event::WindowEvent;
use winit::window::Window;

/// egui's context, its winit input state and its wgpu renderer for one window.
///
/// A new build of the HUD is spread over two frames, so that no frame pays for all of it: one runs egui's pass
/// (the widgets and their layout), the next tessellates its shapes and uploads them. Both frames draw the
/// build before; the new one shows a frame later. A first build, or one for a new window size, is done whole
/// in one frame, as there is nothing to draw until it is.
pub struct HudPainter {
    context: egui::Context,
    input: egui_winit::State,
    renderer: egui_wgpu::Renderer,
    /// The last build, uploaded: drawn every frame until the next replaces it.
    built: Option<Built>,
    /// The last pass's output, to tessellate and upload next frame.
    pending: Option<Pending>,
    /// A build was asked for (its content changed, there was input the HUD can react to, egui asked to run
    /// again) and not yet begun.
    wanted: bool,
    /// egui asked to be run again at once (an animation, a widget settling).
    run_again: bool,
    /// The pointer was over the HUD at its last event egui was given.
    hovering: bool,
    /// When the painter was made: egui's clock starts there.
    start: Instant,
}

/// One build of the HUD: its triangles (uploaded), for what screen, and the areas it covers in points.
struct Built {
    primitives: Vec<egui::ClippedPrimitive>,
    screen: egui_wgpu::ScreenDescriptor,
    covered: Vec<egui::Rect>,
    size: (u32, u32),
}

/// One pass of egui, not yet tessellated: its shapes and texture changes, for what frame size, and the areas
/// it covers in points.
struct Pending {
    output: egui::FullOutput,
    covered: Vec<egui::Rect>,
    size: (u32, u32),
}

/// What of the HUD's build a frame did, besides drawing the last one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Work {
    /// Nothing: the last build was drawn again.
    Drawn,
    /// egui's pass for a new build.
    Pass,
    /// Tessellating and uploading the pass of the frame before.
    Upload,
    /// A whole build at once: the first, or one for a new window size.
    Whole,
}

/// What painting the HUD recorded.
pub struct Painted {
    /// The screen areas the HUD covers, in pixels (`[x0, y0, x1, y1]`, exclusive ends).
    pub regions: Vec<[u32; 4]>,
    /// The part of a build done this frame.
    pub work: Work,
    /// Wall time spent in egui's pass, tessellating, and uploading its buffers and recording its pass (only
    /// the last when nothing was built).
    pub wall_times: [Duration; 3],
    /// CPU time this thread spent on the HUD this frame. Less than their wall time where other threads (a software
    /// GPU's, say) share the cores.
    pub cpu_time: Duration,
}

impl HudPainter {
    /// A painter for `window`, drawing into targets of `format`.
    pub fn new(window: &Window, gpu: &GpuContext, format: wgpu::TextureFormat) -> Self {
        let context = super::context();
        let max_texture_side = gpu.device.limits().max_texture_dimension_2d as usize;
        let input = egui_winit::State::new(
            context.clone(),
            egui::ViewportId::ROOT,
            window,
            Some(window.scale_factor() as f32),
            window.theme(),
            Some(max_texture_side),
        );
        let renderer = egui_wgpu::Renderer::new(&gpu.device, format, egui_wgpu::RendererOptions::default());
        Self {
            context,
            input,
            renderer,
            built: None,
            pending: None,
            wanted: true,
            run_again: false,
            hovering: false,
            start: Instant::now(),
        }
    }

    /// Passes a window event to egui. Returns whether egui used it (a click on the HUD, a drag of one of its
    /// sliders), in which case the game should not act on it too.
    pub fn on_window_event(&mut self, window: &Window, event: &WindowEvent) -> bool {
        self.input.on_window_event(window, event).consumed
    }

    /// Records drawing the HUD over `target`, a view of the `size`-pixel frame, into `encoder`. A new build
    /// is begun with `build` (which returns the areas it covers, in points) only when `changed` says its content
    /// did, when there is input the HUD can react to (the pointer over it, keys while one of its widgets has
    /// the focus) or egui asked to be run again, or when the size changed; it is spread over this frame and the
    /// next (see [`HudPainter`]). Otherwise the last build's triangles are drawn again, which costs next to
    /// nothing.
    #[allow(clippy::too_many_arguments)]
    pub fn paint(
        &mut self,
        window: &Window,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        size: (u32, u32),
        changed: bool,
        build: impl FnMut(&egui::Context) -> Vec<egui::Rect>,
    ) -> Painted {
        let thread_start = ThreadTime::now();
        let resized = self.built.as_ref().is_none_or(|built| built.size != size);
        if resized && let Some(mut pending) = self.pending.take() {
            // A pass laid out for another size is of no use, but its texture changes are: later passes build
            // on them (the font atlas grows).
            self.update_textures(gpu, &mut pending.output.textures_delta);
        }
        // Input the HUD cannot react to (the pointer moving over the scene, keys flying the camera) starts no
        // build, and egui never sees it.
        let covered = match (&self.pending, &self.built) {
            (Some(pending), _) => &pending.covered[..],
            (None, Some(built)) => &built.covered[..],
            (None, None) => &[],
        };
        let input = keep_hud_input(
            &mut self.input.egui_input_mut().events,
            covered,
            &mut self.hovering,
            self.context.egui_is_using_pointer(),
            self.context.egui_wants_keyboard_input(),
        );
        self.wanted |= changed || self.run_again || resized || input;
        let mut wall_times = [Duration::ZERO; 3];
        let work = if let Some(pending) = self.pending.take() {
            self.upload(gpu, encoder, pending, &mut wall_times);
            Work::Upload
        } else if std::mem::take(&mut self.wanted) {
            // Taken only for a build: taking it copies egui's per-viewport input, which other frames need not.
            let raw_input = self.take_input(window, size);
            let pending = self.run_pass(window, raw_input, size, build, &mut wall_times);
            if resized {
                self.upload(gpu, encoder, pending, &mut wall_times);
                Work::Whole
            } else {
                self.pending = Some(pending);
                Work::Pass
            }
        } else {
            Work::Drawn
        };
        let built = self.built.as_ref().expect("built whole above when missing or of another size");
        let recording = Instant::now();
        {
            let pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("hud"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: wgpu::LoadOp::Load, store: wgpu::StoreOp::Store },
                })],
                ..Default::default()
            });
            self.renderer.render(&mut pass.forget_lifetime(), &built.primitives, &built.screen);
        }
        wall_times[2] += recording.elapsed();
        let regions =
            built.covered.iter().map(|&rect| pixel_region(rect, built.screen.pixels_per_point, built.size)).collect();
        Painted { regions, work, wall_times, cpu_time: thread_start.elapsed() }
    }

    /// egui's input since the last build, for a `size`-pixel frame: `egui_winit::State::take_egui_input`, but
    /// with the size the game already knows, where that asks the window (on X11 a round trip to the server each
    /// frame, which blocked the HUD's thread).
    fn take_input(&mut self, window: &Window, size: (u32, u32)) -> egui::RawInput {
        let native_pixels_per_point = window.scale_factor() as f32;
        let points = egui::vec2(size.0 as f32, size.1 as f32) / (native_pixels_per_point * self.context.zoom_factor());
        let input = self.input.egui_input_mut();
        input.time = Some(self.start.elapsed().as_secs_f64());
        input.screen_rect =
            (points.x > 0.0 && points.y > 0.0).then(|| egui::Rect::from_min_size(egui::Pos2::ZERO, points));
        input.viewport_id = egui::ViewportId::ROOT;
        input.viewports.entry(egui::ViewportId::ROOT).or_default().native_pixels_per_point =
            Some(native_pixels_per_point);
        input.take()
    }

    /// Runs egui's pass with `build`, for a `size`-pixel frame.
    fn run_pass(
        &mut self,
        window: &Window,
        raw_input: egui::RawInput,
        size: (u32, u32),
        mut build: impl FnMut(&egui::Context) -> Vec<egui::Rect>,
        wall_times: &mut [Duration; 3],
    ) -> Pending {
        let start = Instant::now();
        let mut covered = Vec::new();
        let mut output = self.context.run_pass(raw_input, |ctx| covered = build(ctx));
        self.run_again = output
            .viewport_output
            .get(&egui::ViewportId::ROOT)
            .is_some_and(|viewport| viewport.repaint_delay.is_zero());
        self.input.handle_platform_output(window, std::mem::take(&mut output.platform_output));
        wall_times[0] = start.elapsed();
        Pending { output, covered, size }
    }

    /// Tessellates `pending`'s shapes and uploads them and its textures: the build drawn from now on.
    fn upload(
        &mut self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        pending: Pending,
        wall_times: &mut [Duration; 3],
    ) {
        let start = Instant::now();
        let Pending { mut output, covered, size } = pending;
        let pixels_per_point = output.pixels_per_point;
        let primitives = self.context.tessellate(std::mem::take(&mut output.shapes), pixels_per_point);
        let tessellated = Instant::now();
        let screen = egui_wgpu::ScreenDescriptor { size_in_pixels: [size.0, size.1], pixels_per_point };
        self.update_textures(gpu, &mut output.textures_delta);
        let extra = self.renderer.update_buffers(&gpu.device, &gpu.queue, encoder, &primitives, &screen);
        if !extra.is_empty() {
            // Only paint callbacks return command buffers; the HUD has none, so there is nothing to order.
            gpu.queue.submit(extra);
        }
        wall_times[1] = tessellated - start;
        wall_times[2] = tessellated.elapsed();
        self.built = Some(Built { primitives, screen, covered, size });
    }

    /// Applies a pass's texture changes, in the order of the passes. Only in a frame whose drawn build is
    /// replaced before it is drawn: a freed texture goes at once, and the build before may use it.
    fn update_textures(&mut self, gpu: &GpuContext, delta: &mut egui::TexturesDelta) {
        for (id, deltas) in delta.set.drain() {
            for delta in &deltas {
                self.renderer.update_texture(&gpu.device, &gpu.queue, id, delta);
            }
        }
        for id in delta.free.drain() {
            self.renderer.free_texture(&id);
        }
    }
}

/// Points around the HUD's windows within which the pointer still counts as over them: egui's interaction
/// reaches a little past a window's frame.
const HOVER_MARGIN: f32 = 8.0;

/// Keeps of `events` those the HUD can react to, and returns whether any are left:
/// - pointer events over `areas` (points) or within [`HOVER_MARGIN`] of them, or while the pointer was over them (so that egui sees it leave), or
///   while egui `using_pointer` (a drag begun on the HUD);
/// - keyboard events while egui has a widget `focused`;
/// - every other event (the window's focus, say).
///
/// `hovering`, whether the pointer was over `areas` at its last event kept, is updated.
fn keep_hud_input(
    events: &mut Vec<egui::Event>,
    areas: &[egui::Rect],
    hovering: &mut bool,
    using_pointer: bool,
    focused: bool,
) -> bool {
    use egui::Event;
    let over = |pos: egui::Pos2| areas.iter().any(|area| area.expand(HOVER_MARGIN).contains(pos));
    events.retain(|event| match event {
        Event::PointerMoved(pos) | Event::PointerButton { pos, .. } | Event::Touch { pos, .. } => {
            let was = std::mem::replace(hovering, over(*pos));
            was || *hovering || using_pointer
        }
        Event::PointerGone => std::mem::replace(hovering, false) || using_pointer,
        Event::MouseMoved(_) | Event::MouseWheel { .. } | Event::Zoom(_) | Event::Rotate(_) => {
            *hovering || using_pointer
        }
        Event::Key { .. }
        | Event::Text(_)
        | Event::Copy
        | Event::Cut
        | Event::Paste(_)
        | Event::PasteImage(_)
        | Event::MiddleClickPaste { .. }
        | Event::Ime(_)
        | Event::ModifiersChanged(_) => focused,
        _ => true,
    });
    !events.is_empty()
}

/// `rect` in points as whole pixels within a `size` frame, grown by one pixel for egui's anti-aliased edges.
fn pixel_region(rect: egui::Rect, pixels_per_point: f32, size: (u32, u32)) -> [u32; 4] {
    let pixels = |points: f32, limit: u32| (points * pixels_per_point).clamp(0.0, limit as f32);
    [
        (pixels(rect.min.x, size.0).floor() as u32).saturating_sub(1),
        (pixels(rect.min.y, size.1).floor() as u32).saturating_sub(1),
        (pixels(rect.max.x, size.0).ceil() as u32 + 1).min(size.0),
        (pixels(rect.max.y, size.1).ceil() as u32 + 1).min(size.1),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use egui::{Event, Key, Modifiers, PointerButton, Rect, pos2, vec2};

    fn pressed(key: Key) -> Event {
        Event::Key { key, physical_key: None, pressed: true, repeat: false, modifiers: Modifiers::NONE }
    }

    fn click(pos: egui::Pos2) -> Event {
        Event::PointerButton { pos, button: PointerButton::Primary, pressed: true, modifiers: Modifiers::NONE }
    }

    #[test]
    fn only_input_the_hud_can_react_to_starts_a_build() {
        let areas = [Rect::from_min_size(pos2(8.0, 8.0), vec2(300.0, 200.0))];
        let mut hovering = false;
        // The pointer moving over the scene and keys flying the camera: nothing kept, no build.
        let mut events = vec![Event::PointerMoved(pos2(500.0, 400.0)), pressed(Key::W), click(pos2(600.0, 300.0))];
        assert!(!keep_hud_input(&mut events, &areas, &mut hovering, false, false));
        assert!(events.is_empty() && !hovering);
        // The pointer entering the HUD and clicking it: kept.
        let mut events = vec![Event::PointerMoved(pos2(100.0, 100.0)), click(pos2(100.0, 100.0))];
        assert!(keep_hud_input(&mut events, &areas, &mut hovering, false, false));
        assert_eq!(events.len(), 2);
        assert!(hovering);
        // Leaving it: the first move outside is kept, so egui sees it go; the next are not.
        let mut events = vec![Event::PointerMoved(pos2(500.0, 100.0)), Event::PointerMoved(pos2(520.0, 100.0))];
        assert!(keep_hud_input(&mut events, &areas, &mut hovering, false, false));
        assert_eq!(events, [Event::PointerMoved(pos2(500.0, 100.0))]);
        assert!(!hovering);
        // A drag begun on the HUD (a slider) goes on outside it.
        let mut events = vec![Event::PointerMoved(pos2(700.0, 100.0))];
        assert!(keep_hud_input(&mut events, &areas, &mut hovering, true, false));
        // Keys reach egui only while one of its widgets has the focus.
        let mut events = vec![pressed(Key::ArrowRight)];
        assert!(keep_hud_input(&mut events, &areas, &mut hovering, false, true));
        // The window losing focus is kept.
        let mut events = vec![Event::WindowFocused(false)];
        assert!(keep_hud_input(&mut events, &areas, &mut hovering, false, false));
    }
}
