//! Drawing the HUD into the window's frame: egui's input from winit (`egui-winit`) and its triangles drawn
//! over the frame with wgpu (`egui-wgpu`), in the same command encoder as the frame.

use cpu_time::ThreadTime;
use cullet::gpu::GpuContext;
use std::time::{Duration, Instant};
use winit::event::WindowEvent;
use winit::window::Window;

/// egui's context, its winit input state and its wgpu renderer for one window.
///
/// A new build of the HUD is spread over frames, so that no frame pays for much of it: one begins egui's pass
/// (taking its input), then one builds each part of the HUD (its widgets and their layout; the last ends the
/// pass), one tessellates the pass's shapes and one uploads them. Every frame draws the last build uploaded;
/// the new one shows from its upload on. A build that answers input runs its pass whole in one frame, so that
/// a click shows three frames later. A first build, or one for a new window size, is done whole in one frame,
/// as there is nothing to draw until it is.
pub struct HudPainter {
    context: egui::Context,
    input: egui_winit::State,
    renderer: egui_wgpu::Renderer,
    /// The parts a build is made of, each built in a frame of its own.
    parts: usize,
    /// The last build, uploaded: drawn every frame until the next replaces it.
    built: Option<Built>,
    /// The build under way, if any: a step of it a frame.
    building: Building,
    /// A build was asked for (its content changed, there was input the HUD can react to, egui asked to run
    /// again) and not yet begun.
    wanted: bool,
    /// The build asked for answers input (or egui asking to run again): its pass runs whole in one frame, so
    /// that the HUD answers a click three frames later rather than one a part later.
    answering: bool,
    /// egui asked to be run again at once (an animation, a widget settling, a pass to discard).
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

/// A build under way, at the step the next frame takes.
enum Building {
    /// None: the next build begins egui's pass.
    Idle,
    /// egui's pass is under way for a `size`-pixel frame: the parts before `next` are built and cover
    /// `covered` (points); the next frame builds part `next`.
    Open { next: usize, covered: Vec<egui::Rect>, size: (u32, u32) },
    /// The pass ended: its output, to tessellate.
    Ended(Pending),
    /// Its shapes tessellated (the pass's texture changes still in its output): to upload.
    Tessellated { primitives: Vec<egui::ClippedPrimitive>, built: Pending },
}

/// One pass of egui, not yet uploaded: its output (its shapes taken once tessellated), for what frame size,
/// and the areas it covers in points.
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
    /// Began egui's pass for a new build, taking its input.
    Begin,
    /// Ran egui's pass for a new build whole, answering input.
    Pass,
    /// Built this part of the HUD in egui's pass; the last part also ends the pass.
    Part(usize),
    /// Tessellated the shapes of the pass.
    Tessellate,
    /// Uploaded the tessellated build and its texture changes: drawn from this frame on.
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
    /// A painter for `window`, drawing into targets of `format` a HUD built in `parts` parts (at least one),
    /// each in a frame of its own (see [`HudPainter::paint`]).
    pub fn new(window: &Window, gpu: &GpuContext, format: wgpu::TextureFormat, parts: usize) -> Self {
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
            parts: parts.max(1),
            built: None,
            building: Building::Idle,
            wanted: true,
            answering: false,
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
    /// is begun only when `changed` says its content did, when there is input the HUD can react to (the
    /// pointer over it, keys while one of its widgets has the focus) or egui asked to be run again, or when
    /// the size changed; `build(ctx, part)` builds each part of it in egui's pass (returning the areas it
    /// covers, in points), a frame each (see [`HudPainter`]). Otherwise the last build's triangles are drawn
    /// again, which costs next to nothing.
    #[allow(clippy::too_many_arguments)]
    pub fn paint(
        &mut self,
        window: &Window,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        size: (u32, u32),
        changed: bool,
        mut build: impl FnMut(&egui::Context, usize) -> Vec<egui::Rect>,
    ) -> Painted {
        let thread_start = ThreadTime::now();
        let resized = self.built.as_ref().is_none_or(|built| built.size != size);
        if resized {
            // A build laid out for another size is of no use, but its texture changes are: later passes build
            // on them (the font atlas grows).
            self.abandon(gpu);
        }
        // Input the HUD cannot react to (the pointer moving over the scene, keys flying the camera) starts no
        // build, and egui never sees it.
        let covered = match (&self.building, &self.built) {
            (Building::Ended(pending) | Building::Tessellated { built: pending, .. }, _) => &pending.covered[..],
            (_, Some(built)) => &built.covered[..],
            (_, None) => &[],
        };
        let input = keep_hud_input(
            &mut self.input.egui_input_mut().events,
            covered,
            &mut self.hovering,
            self.context.egui_is_using_pointer(),
            self.context.egui_wants_keyboard_input(),
        );
        self.wanted |= changed || self.run_again || resized || input;
        self.answering |= self.run_again || input;
        let mut wall_times = [Duration::ZERO; 3];
        let work = if resized {
            (self.wanted, self.answering) = (false, false);
            self.build_pass(window, size, &mut build, &mut wall_times);
            if self.run_again {
                // A window showing for the first time is only sized in its first pass, unpainted, and egui asks
                // to run again at once: with nothing to show until then, it runs again in this frame.
                self.abandon(gpu);
                self.build_pass(window, size, &mut build, &mut wall_times);
            }
            self.tessellate(&mut wall_times);
            self.upload(gpu, encoder, &mut wall_times);
            Work::Whole
        } else {
            match &self.building {
                Building::Idle if std::mem::take(&mut self.wanted) => {
                    if std::mem::take(&mut self.answering) {
                        self.build_pass(window, size, &mut build, &mut wall_times);
                        Work::Pass
                    } else {
                        self.begin(window, size, &mut wall_times);
                        Work::Begin
                    }
                }
                Building::Idle => Work::Drawn,
                Building::Open { .. } => Work::Part(self.build_part(window, &mut build, &mut wall_times)),
                Building::Ended(_) => {
                    self.tessellate(&mut wall_times);
                    Work::Tessellate
                }
                Building::Tessellated { .. } => {
                    self.upload(gpu, encoder, &mut wall_times);
                    Work::Upload
                }
            }
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

    /// Drops the build under way, applying the texture changes of its pass where it has ended or ends it now.
    fn abandon(&mut self, gpu: &GpuContext) {
        let mut textures = match std::mem::replace(&mut self.building, Building::Idle) {
            Building::Idle => return,
            Building::Open { .. } => self.context.end_pass().textures_delta,
            Building::Ended(pending) | Building::Tessellated { built: pending, .. } => pending.output.textures_delta,
        };
        self.update_textures(gpu, &mut textures);
    }

    /// Begins egui's pass for a `size`-pixel frame, with the input since the last.
    fn begin(&mut self, window: &Window, size: (u32, u32), wall_times: &mut [Duration; 3]) {
        let start = Instant::now();
        let raw_input = self.take_input(window, size);
        self.context.begin_pass(raw_input);
        self.building = Building::Open { next: 0, covered: Vec::new(), size };
        wall_times[0] += start.elapsed();
    }

    /// Runs a whole pass of egui for a `size`-pixel frame, every part of the HUD in it.
    fn build_pass(
        &mut self,
        window: &Window,
        size: (u32, u32),
        build: &mut impl FnMut(&egui::Context, usize) -> Vec<egui::Rect>,
        wall_times: &mut [Duration; 3],
    ) {
        self.begin(window, size, wall_times);
        while matches!(self.building, Building::Open { .. }) {
            self.build_part(window, build, wall_times);
        }
    }

    /// Builds the next part of the HUD in the pass under way, and ends the pass after the last. Returns the
    /// part built.
    fn build_part(
        &mut self,
        window: &Window,
        build: &mut impl FnMut(&egui::Context, usize) -> Vec<egui::Rect>,
        wall_times: &mut [Duration; 3],
    ) -> usize {
        let start = Instant::now();
        let Building::Open { next, covered, size } = &mut self.building else {
            unreachable!("called only while a pass is under way")
        };
        let (part, size) = (*next, *size);
        covered.extend(build(&self.context, part));
        *next += 1;
        if *next == self.parts {
            let mut covered = std::mem::take(covered);
            let mut output = self.context.end_pass();
            if output.platform_output.requested_discard() {
                // egui asked to discard the pass (a window sizing itself on its first showing, unpainted): it
                // runs again at once and whole, as `Context::run_pass` runs it, after the texture changes of
                // the first.
                output.platform_output.request_discard_reasons.clear();
                let raw_input = self.take_input(window, size);
                self.context.begin_pass(raw_input);
                covered = (0..self.parts).flat_map(|part| build(&self.context, part)).collect();
                output.append(self.context.end_pass());
            }
            let repaint_now = output
                .viewport_output
                .get(&egui::ViewportId::ROOT)
                .is_some_and(|viewport| viewport.repaint_delay.is_zero());
            self.run_again = repaint_now || output.platform_output.requested_discard();
            self.input.handle_platform_output(window, std::mem::take(&mut output.platform_output));
            self.building = Building::Ended(Pending { output, covered, size });
        }
        wall_times[0] += start.elapsed();
        part
    }

    /// Tessellates the ended pass's shapes.
    fn tessellate(&mut self, wall_times: &mut [Duration; 3]) {
        let start = Instant::now();
        let Building::Ended(mut pending) = std::mem::replace(&mut self.building, Building::Idle) else {
            unreachable!("called only once a pass has ended")
        };
        let shapes = std::mem::take(&mut pending.output.shapes);
        let primitives = self.context.tessellate(shapes, pending.output.pixels_per_point);
        self.building = Building::Tessellated { primitives, built: pending };
        wall_times[1] += start.elapsed();
    }

    /// Uploads the tessellated build and its texture changes: the build drawn from now on.
    fn upload(&mut self, gpu: &GpuContext, encoder: &mut wgpu::CommandEncoder, wall_times: &mut [Duration; 3]) {
        let start = Instant::now();
        let Building::Tessellated { primitives, built } = std::mem::replace(&mut self.building, Building::Idle) else {
            unreachable!("called only once a pass is tessellated")
        };
        let Pending { mut output, covered, size } = built;
        let screen =
            egui_wgpu::ScreenDescriptor { size_in_pixels: [size.0, size.1], pixels_per_point: output.pixels_per_point };
        self.update_textures(gpu, &mut output.textures_delta);
        let extra = self.renderer.update_buffers(&gpu.device, &gpu.queue, encoder, &primitives, &screen);
        if !extra.is_empty() {
            // Only paint callbacks return command buffers; the HUD has none, so there is nothing to order.
            gpu.queue.submit(extra);
        }
        wall_times[2] += start.elapsed();
        self.built = Some(Built { primitives, screen, covered, size });
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

impl Drop for HudPainter {
    /// A build under way when the window closes has texture changes no renderer will apply.
    fn drop(&mut self) {
        match &mut self.building {
            Building::Idle | Building::Open { .. } => {}
            Building::Ended(pending) | Building::Tessellated { built: pending, .. } => {
                pending.output.textures_delta.clear()
            }
        }
    }
}

/// Points around the HUD's windows within which the pointer still counts as over them: egui's interaction
/// reaches a little past a window's frame.
const HOVER_MARGIN: f32 = 8.0;

/// Keeps of `events` those the HUD can react to, and returns whether any are left:
/// - pointer events over `areas` (points) or within [`HOVER_MARGIN`] of them, or while the pointer was over
///   them (so that egui sees it leave), or
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
