//! Drawing the HUD into the window's frame: egui's input from winit (`egui-winit`) and its triangles drawn
//! over the frame with wgpu (`egui-wgpu`), in the same command encoder as the frame.

use cullet::gpu::GpuContext;
use std::time::{Duration, Instant};
use winit::event::WindowEvent;
use winit::window::Window;

/// egui's context, its winit input state and its wgpu renderer for one window.
pub struct HudPainter {
    context: egui::Context,
    input: egui_winit::State,
    renderer: egui_wgpu::Renderer,
}

/// What painting the HUD recorded.
pub struct Painted {
    /// The screen areas the HUD covers, in pixels (`[x0, y0, x1, y1]`, exclusive ends).
    pub regions: Vec<[u32; 4]>,
    /// CPU time spent: building the UI, tessellating it, uploading its buffers and recording its pass.
    pub cpu_time: Duration,
}

impl HudPainter {
    /// A painter for `window`, drawing into targets of `format`.
    pub fn new(window: &Window, gpu: &GpuContext, format: wgpu::TextureFormat) -> Self {
        let context = egui::Context::default();
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
        Self { context, input, renderer }
    }

    /// Passes a window event to egui. Returns whether egui used it (a click on the HUD, a drag of one of its
    /// sliders), in which case the game should not act on it too.
    pub fn on_window_event(&mut self, window: &Window, event: &WindowEvent) -> bool {
        self.input.on_window_event(window, event).consumed
    }

    /// Builds the UI with `build` (which returns the areas it covers, in points) and records drawing it over
    /// `target`, a view of the `size`-pixel frame, into `encoder`.
    pub fn paint(
        &mut self,
        window: &Window,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        size: (u32, u32),
        mut build: impl FnMut(&egui::Context) -> Vec<egui::Rect>,
    ) -> Painted {
        let start = Instant::now();
        let raw_input = self.input.take_egui_input(window);
        let mut covered = Vec::new();
        let mut output = self.context.run_pass(raw_input, |ctx| covered = build(ctx));
        self.input.handle_platform_output(window, output.platform_output);
        let pixels_per_point = output.pixels_per_point;
        let primitives = self.context.tessellate(output.shapes, pixels_per_point);
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
            self.renderer.render(&mut pass.forget_lifetime(), &primitives, &screen);
        }
        for id in output.textures_delta.free.drain() {
            self.renderer.free_texture(&id);
        }
        let regions = covered.into_iter().map(|rect| pixel_region(rect, pixels_per_point, size)).collect();
        Painted { regions, cpu_time: start.elapsed() }
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
