//! Drawing the HUD into the window's frame: egui's input from winit (`egui-winit`) and its triangles drawn
//! over the frame with wgpu (`egui-wgpu`), in the same command encoder as the frame.

use cpu_time::ThreadTime;
use cullet::gpu::GpuContext;
use std::time::{Duration, Instant};
use winit::event::WindowEvent;
use winit::window::Window;

/// egui's context, its winit input state and its wgpu renderer for one window.
pub struct HudPainter {
    context: egui::Context,
    input: egui_winit::State,
    renderer: egui_wgpu::Renderer,
    /// The last build, drawn again while nothing changes.
    built: Option<Built>,
    /// egui asked to be run again at once (an animation, a widget settling).
    run_again: bool,
    /// When the painter was made: egui's clock starts there.
    start: Instant,
}

/// One build of the HUD: its triangles (uploaded), for what screen, and the areas it covers.
struct Built {
    primitives: Vec<egui::ClippedPrimitive>,
    screen: egui_wgpu::ScreenDescriptor,
    regions: Vec<[u32; 4]>,
    size: (u32, u32),
}

/// What painting the HUD recorded.
pub struct Painted {
    /// The screen areas the HUD covers, in pixels (`[x0, y0, x1, y1]`, exclusive ends).
    pub regions: Vec<[u32; 4]>,
    /// The UI was built this frame (not drawn again from the last build).
    pub rebuilt: bool,
    /// Wall time spent building the UI, tessellating it, and uploading its buffers and recording its pass
    /// (only the last when it was not rebuilt).
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
        Self { context, input, renderer, built: None, run_again: false, start: Instant::now() }
    }

    /// Passes a window event to egui. Returns whether egui used it (a click on the HUD, a drag of one of its
    /// sliders), in which case the game should not act on it too.
    pub fn on_window_event(&mut self, window: &Window, event: &WindowEvent) -> bool {
        self.input.on_window_event(window, event).consumed
    }

    /// Records drawing the HUD over `target`, a view of the `size`-pixel frame, into `encoder`. The UI is
    /// built again with `build` (which returns the areas it covers, in points) only when `changed` says its
    /// content did, when egui has input to handle or asked to be run again, or when the size changed; otherwise
    /// last build's triangles are drawn again, which costs next to nothing.
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
        let rebuild = changed
            || self.run_again
            || !self.input.egui_input().events.is_empty()
            || self.built.as_ref().is_none_or(|built| built.size != size);
        let mut wall_times = [Duration::ZERO; 3];
        if rebuild {
            // Taken only for a build: taking it copies egui's per-viewport input, which other frames need not.
            let raw_input = self.take_input(window, size);
            self.build(window, gpu, encoder, raw_input, size, build, &mut wall_times);
        }
        let built = self.built.as_ref().expect("built above when missing");
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
        Painted { regions: built.regions.clone(), rebuilt: rebuild, wall_times, cpu_time: thread_start.elapsed() }
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

    /// Runs egui with `build` and uploads what it drew: textures and the triangles' buffers.
    #[allow(clippy::too_many_arguments)]
    fn build(
        &mut self,
        window: &Window,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        raw_input: egui::RawInput,
        size: (u32, u32),
        mut build: impl FnMut(&egui::Context) -> Vec<egui::Rect>,
        wall_times: &mut [Duration; 3],
    ) {
        let start = Instant::now();
        let mut covered = Vec::new();
        let mut output = self.context.run_pass(raw_input, |ctx| covered = build(ctx));
        self.run_again = output
            .viewport_output
            .get(&egui::ViewportId::ROOT)
            .is_some_and(|viewport| viewport.repaint_delay.is_zero());
        self.input.handle_platform_output(window, output.platform_output);
        let built = Instant::now();
        let pixels_per_point = output.pixels_per_point;
        let primitives = self.context.tessellate(output.shapes, pixels_per_point);
        let tessellated = Instant::now();
        let screen = egui_wgpu::ScreenDescriptor { size_in_pixels: [size.0, size.1], pixels_per_point };
        for (id, deltas) in output.textures_delta.set.drain() {
            for delta in &deltas {
                self.renderer.update_texture(&gpu.device, &gpu.queue, id, delta);
            }
        }
        let extra = self.renderer.update_buffers(&gpu.device, &gpu.queue, encoder, &primitives, &screen);
        if !extra.is_empty() {
            // Only paint callbacks return command buffers; the HUD has none, so there is nothing to order.
            gpu.queue.submit(extra);
        }
        // Freed textures are unused by the new triangles, so they can go before the pass that draws them.
        for id in output.textures_delta.free.drain() {
            self.renderer.free_texture(&id);
        }
        let regions = covered.into_iter().map(|rect| pixel_region(rect, pixels_per_point, size)).collect();
        *wall_times = [built - start, tessellated - built, tessellated.elapsed()];
        self.built = Some(Built { primitives, screen, regions, size });
    }
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
