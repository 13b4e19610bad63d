//! The windowed game (winit): the scene culled and drawn every frame, following the camera path until the
//! player takes over with free flight. Each stage can be switched off, culling frozen at one camera while
//! the player flies around to see what was culled, and the window shows debug views: objects tinted by the
//! stage that culled them, the software occlusion buffer and each level of its pyramid. The title bar is the
//! overlay: per-stage counts and times, refreshed four times a second.

use crate::Prepared;
use crate::present::{PresentPass, Source};
use crate::report::{micros, print_gpu_summary, print_savings, print_summary};
use cullet::Camera;
use cullet::draw_cost::{DrawSavings, SlotTriangles};
use cullet::gpu::{GpuContext, GpuCullSettings, GpuCuller, GpuFrameOutput};
use cullet::pipeline::{CullStats, FrustumSettings, FrustumVisible, OcclusionSettings, OcclusionState};
use glam::Vec3;
use std::collections::HashSet;
use std::sync::Arc;
use std::time::{Duration, Instant};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{DeviceEvent, DeviceId, ElementState, KeyEvent, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{CursorGrabMode, Window, WindowId};

/// The controls, printed when the window opens.
const HELP: &str = "\
window controls:
  right mouse button held + move   look around       W A S D  move    Q / E  down / up    Shift  5x faster
  P   follow the camera path / fly freely (moving also leaves the path)
  F   freeze culling at the current camera: fly around to see what was culled
  1   frustum culling on/off        2   occlusion culling on/off
  3   GPU cluster culling (normal cones, HZB) on/off        4   GPU triangle culling on/off
  V   cycle the view: shaded / tinted by the stage that culled each object / occlusion buffer / its pyramid
  [ ] pyramid level down / up       Esc  quit";

/// Tint of objects the frustum stage culled, in the tinted view.
const FRUSTUM_TINT: [u8; 4] = [235, 50, 210, 255];
/// Tint of objects the occlusion stage culled.
const OCCLUSION_TINT: [u8; 4] = [40, 120, 255, 255];

/// What the window shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum View {
    /// The culled scene as drawn.
    Shaded,
    /// Every object drawn, those the CPU stages culled tinted by the stage that culled them.
    Tinted,
    /// The software occlusion depth buffer.
    OcclusionBuffer,
    /// One level of its farthest-depth pyramid.
    Pyramid,
}

impl View {
    fn next(self) -> Self {
        match self {
            Self::Shaded => Self::Tinted,
            Self::Tinted => Self::OcclusionBuffer,
            Self::OcclusionBuffer => Self::Pyramid,
            Self::Pyramid => Self::Shaded,
        }
    }
}

/// Opens the event loop, or says why no window can be had (no display, or the display refused). Call once,
/// on the main thread: winit allows one event loop per process.
pub fn open_event_loop() -> Result<EventLoop<()>, String> {
    let has_display = ["DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"]
        .iter()
        .any(|name| std::env::var_os(name).is_some_and(|value| !value.is_empty()));
    if !has_display {
        return Err("neither DISPLAY nor WAYLAND_DISPLAY is set".into());
    }
    // winit panics instead of failing where the keyboard library is missing; that is still "no window".
    match std::panic::catch_unwind(EventLoop::new) {
        Ok(Ok(event_loop)) => Ok(event_loop),
        Ok(Err(error)) => Err(error.to_string()),
        Err(_) => Err("the windowing system could not be opened".into()),
    }
}

/// Runs the game in a window until it is closed (or after `frames` frames), then prints the summary.
pub fn run(prepared: Prepared, event_loop: EventLoop<()>, frames: Option<u32>) -> Result<(), String> {
    event_loop.set_control_flow(ControlFlow::Poll);
    let start = prepared.flight.path.camera_at(0.0, 1.0);
    let (yaw, pitch) = yaw_pitch(start.forward);
    let (width, height) = prepared.resolution;
    let radius = prepared.scene.bounds().map_or(100.0, |(min, max)| (max - min).length() * 0.5);
    let slot_triangles = SlotTriangles::of_world(&prepared.flight.world, &prepared.scene.meshes);
    let mut game = Game {
        prepared,
        size: (width.min(1920), height.min(1080)),
        graphics: None,
        error: None,
        keys: HashSet::new(),
        looking: false,
        autopilot: Some(0.0),
        position: start.position,
        yaw,
        pitch,
        speed: (radius * 0.05).max(1.0),
        frozen: None,
        view: View::Shaded,
        pyramid_level: 0,
        gpu_settings: GpuCullSettings::default(),
        last_frame: Instant::now(),
        last_title: Instant::now(),
        frames: Vec::new(),
        gpu_frames: Vec::new(),
        slot_triangles,
        savings: Vec::new(),
        fps: 0.0,
        frame_limit: frames.map(|n| n as usize),
    };
    println!("{HELP}");
    event_loop.run_app(&mut game).map_err(|e| e.to_string())?;
    print_summary(&game.frames);
    print_gpu_summary(&game.gpu_frames);
    print_savings(&game.savings, &game.gpu_frames);
    game.error.map_or(Ok(()), Err)
}

/// The window, its surface and the GPU pipeline drawing into it.
struct Graphics {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    context: GpuContext,
    culler: GpuCuller,
    present: PresentPass,
}

struct Game {
    prepared: Prepared,
    /// Window size in pixels.
    size: (u32, u32),
    graphics: Option<Graphics>,
    error: Option<String>,
    keys: HashSet<KeyCode>,
    /// Right mouse button held: mouse motion turns the camera.
    looking: bool,
    /// Time along the camera path while following it; `None` in free flight.
    autopilot: Option<f32>,
    position: Vec3,
    yaw: f32,
    pitch: f32,
    /// Free-flight speed in units per second.
    speed: f32,
    /// The camera culling is frozen at.
    frozen: Option<Camera>,
    view: View,
    pyramid_level: usize,
    gpu_settings: GpuCullSettings,
    last_frame: Instant,
    last_title: Instant,
    frames: Vec<CullStats>,
    gpu_frames: Vec<GpuFrameOutput>,
    /// Triangles of each store slot's mesh, for the savings.
    slot_triangles: SlotTriangles,
    /// What each stage saved the draw, per frame.
    savings: Vec<DrawSavings>,
    /// Frames per second, smoothed.
    fps: f32,
    /// Close after this many frames.
    frame_limit: Option<usize>,
}

/// Yaw (around +y, 0 looking down -z) and pitch of a direction.
fn yaw_pitch(forward: Vec3) -> (f32, f32) {
    let f = forward.normalize_or(Vec3::NEG_Z);
    (f.x.atan2(-f.z), f.y.clamp(-1.0, 1.0).asin())
}

fn direction(yaw: f32, pitch: f32) -> Vec3 {
    Vec3::new(yaw.sin() * pitch.cos(), pitch.sin(), -yaw.cos() * pitch.cos())
}

impl Game {
    fn open(&mut self, event_loop: &ActiveEventLoop) -> Result<Graphics, String> {
        let attributes = Window::default_attributes()
            .with_title("cullet")
            .with_inner_size(PhysicalSize::new(self.size.0, self.size.1));
        let window = Arc::new(event_loop.create_window(attributes).map_err(|e| e.to_string())?);
        let display = event_loop.owned_display_handle();
        let instance =
            GpuContext::instance(wgpu::InstanceDescriptor::new_with_display_handle_from_env(Box::new(display)));
        let surface = instance.create_surface(window.clone()).map_err(|e| e.to_string())?;
        let context = GpuContext::for_surface(&instance, &surface).map_err(|e| e.to_string())?;
        let info = &context.adapter_info;
        println!("GPU: {} ({:?}, {:?})", info.name, info.backend, info.device_type);
        let size = window.inner_size();
        self.size = (size.width.max(1), size.height.max(1));
        println!("window opened: {}x{}", self.size.0, self.size.1);
        let mut config = surface
            .get_default_config(&context.adapter, self.size.0, self.size.1)
            .ok_or("the GPU cannot present to this window")?;
        // The colour target holds display values: present them through a non-sRGB view where there is one.
        let formats = surface.get_capabilities(&context.adapter).formats;
        if let Some(&linear) = formats.iter().find(|f| !f.is_srgb()) {
            config.format = linear;
        }
        surface.configure(&context.device, &config);
        let culler =
            GpuCuller::for_world(&context, &self.prepared.flight.world, &self.prepared.scene.meshes, self.size);
        let present = PresentPass::new(&context, config.format);
        Ok(Graphics { window, surface, config, context, culler, present })
    }

    fn camera(&self) -> Camera {
        let aspect = self.size.0 as f32 / self.size.1 as f32;
        let path = &self.prepared.flight.path;
        match self.autopilot {
            Some(t) => path.camera_at(t, aspect),
            None => Camera {
                fov_y: path.fov_y_deg.to_radians(),
                aspect,
                near: path.near,
                far: path.far,
                ..Camera::looking_at(self.position, self.position + direction(self.yaw, self.pitch))
            },
        }
    }

    /// Moves the camera by `delta` seconds of input or of the path.
    fn advance_camera(&mut self, delta: f32) {
        let moving = [KeyCode::KeyW, KeyCode::KeyA, KeyCode::KeyS, KeyCode::KeyD, KeyCode::KeyQ, KeyCode::KeyE];
        if self.autopilot.is_some() && moving.iter().any(|k| self.keys.contains(k)) {
            self.leave_autopilot();
        }
        if let Some(t) = &mut self.autopilot {
            let duration = self.prepared.flight.path.duration();
            *t = if duration > 0.0 { (*t + delta) % duration } else { 0.0 };
            return;
        }
        let forward = direction(self.yaw, self.pitch);
        let right = forward.cross(Vec3::Y).normalize_or(Vec3::X);
        let axis = |plus: KeyCode, minus: KeyCode| {
            f32::from(u8::from(self.keys.contains(&plus))) - f32::from(u8::from(self.keys.contains(&minus)))
        };
        let step = forward * axis(KeyCode::KeyW, KeyCode::KeyS)
            + right * axis(KeyCode::KeyD, KeyCode::KeyA)
            + Vec3::Y * axis(KeyCode::KeyE, KeyCode::KeyQ);
        let boost =
            if self.keys.contains(&KeyCode::ShiftLeft) || self.keys.contains(&KeyCode::ShiftRight) { 5.0 } else { 1.0 };
        self.position += step.normalize_or_zero() * self.speed * boost * delta;
    }

    /// Free flight from wherever the path had the camera.
    fn leave_autopilot(&mut self) {
        let camera = self.camera();
        self.position = camera.position;
        (self.yaw, self.pitch) = yaw_pitch(camera.forward);
        self.autopilot = None;
    }

    fn key(&mut self, code: KeyCode, event_loop: &ActiveEventLoop) {
        let world = &mut self.prepared.flight.world;
        match code {
            KeyCode::Escape => event_loop.exit(),
            KeyCode::KeyP => {
                if self.autopilot.is_some() {
                    self.leave_autopilot();
                } else {
                    self.autopilot = Some(0.0);
                }
            }
            KeyCode::KeyF => self.frozen = if self.frozen.is_some() { None } else { Some(self.camera()) },
            KeyCode::Digit1 => world.resource_mut::<FrustumSettings>().enabled ^= true,
            KeyCode::Digit2 => world.resource_mut::<OcclusionSettings>().enabled ^= true,
            KeyCode::Digit3 => {
                let on = !self.gpu_settings.cluster_cone;
                (self.gpu_settings.cluster_cone, self.gpu_settings.cluster_hzb) = (on, on);
            }
            KeyCode::Digit4 => {
                let s = &mut self.gpu_settings;
                let on = !s.triangle_backface;
                (s.triangle_backface, s.triangle_frustum, s.small_triangles) = (on, on, on);
            }
            KeyCode::KeyV => self.view = self.view.next(),
            KeyCode::BracketLeft => self.pyramid_level = self.pyramid_level.saturating_sub(1),
            KeyCode::BracketRight => self.pyramid_level += 1,
            _ => {}
        }
    }

    /// Culls and draws one frame and shows it.
    fn frame(&mut self) {
        let now = Instant::now();
        let delta = (now - self.last_frame).as_secs_f32().min(0.25);
        self.last_frame = now;
        if delta > 0.0 {
            self.fps = 0.9 * self.fps + 0.1 / delta;
        }
        self.advance_camera(delta);
        let camera = self.camera();
        let cull_camera = self.frozen.map_or(camera, |frozen| Camera { aspect: camera.aspect, ..frozen });
        let stats = self.prepared.flight.run_with_camera(cull_camera, delta);
        self.frames.push(stats);
        let Some(graphics) = self.graphics.as_mut() else { return };
        let world = &mut self.prepared.flight.world;
        let (context, culler) = (&graphics.context, &mut graphics.culler);
        if self.view == View::Tinted {
            // Every object drawn, tinted by the stage that culled it.
            let frustum = world.resource::<FrustumVisible>().0.clone();
            let occlusion = world.resource::<OcclusionState>().visible.clone();
            culler.draw_all_recolored(context, world, &camera, |slot| {
                match (frustum.contains(slot), occlusion.contains(slot)) {
                    (false, _) => Some(FRUSTUM_TINT),
                    (true, false) => Some(OCCLUSION_TINT),
                    (true, true) => None,
                }
            });
        } else {
            match culler.run_world_from(context, world, &camera, &self.gpu_settings) {
                Ok(output) => {
                    self.savings.push(DrawSavings::of_frame(world, &self.slot_triangles, Some(&output)));
                    self.gpu_frames.push(output);
                }
                Err(error) => {
                    eprintln!("{error}");
                    return;
                }
            }
        }

        let frame = match graphics.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(frame) | wgpu::CurrentSurfaceTexture::Suboptimal(frame) => frame,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                graphics.surface.configure(&context.device, &graphics.config);
                return;
            }
            _ => return,
        };
        let target = frame.texture.create_view(&wgpu::TextureViewDescriptor::default());
        let mut encoder = context.device.create_command_encoder(&Default::default());
        let color = culler.targets().color_view();
        let state = world.resource::<OcclusionState>();
        let source = match self.view {
            View::Shaded | View::Tinted => Source::Color(&color),
            View::OcclusionBuffer => Source::Depth(&state.depth),
            View::Pyramid => {
                let levels = state.pyramid.level_count();
                self.pyramid_level = self.pyramid_level.min(levels.saturating_sub(1));
                if levels == 0 {
                    Source::Depth(&state.depth)
                } else {
                    Source::Depth(state.pyramid.level(self.pyramid_level))
                }
            }
        };
        graphics.present.record(context, &mut encoder, source, &target, self.size);
        context.queue.submit([encoder.finish()]);
        graphics.window.pre_present_notify();
        context.queue.present(frame);

        if self.last_title.elapsed() > Duration::from_millis(250) {
            self.last_title = Instant::now();
            let title = self.overlay(&stats);
            if let Some(graphics) = &self.graphics {
                graphics.window.set_title(&title);
            }
        }
    }

    /// The title-bar overlay: counts and times per stage, and what is switched off.
    fn overlay(&self, stats: &CullStats) -> String {
        let world = &self.prepared.flight.world;
        let mut text = format!(
            "cullet | {} objects > frustum {} ({:.0} us) > occlusion {} ({} occluders, {:.0}+{:.0} us)",
            stats.objects,
            stats.after_frustum,
            micros(stats.frustum_time),
            stats.after_occlusion,
            stats.occluders,
            micros(stats.raster_time),
            micros(stats.occlusion_time)
        );
        if let Some(gpu) = self.gpu_frames.last().filter(|_| self.view != View::Tinted) {
            let c = gpu.counters;
            text.push_str(&format!(
                " > clusters {}/{} > triangles {}/{} > {} draws ({:.1} ms)",
                c.clusters_out,
                c.clusters_in,
                c.triangles_out,
                c.triangles_in,
                c.draws,
                micros(gpu.wall_time) / 1e3
            ));
        }
        let mut flags = vec![format!("{:.0} fps", self.fps), format!("view {:?}", self.view)];
        if self.view == View::Pyramid {
            flags.push(format!("level {}", self.pyramid_level));
        }
        if self.frozen.is_some() {
            flags.push("FROZEN".into());
        }
        if self.autopilot.is_some() {
            flags.push("path".into());
        }
        let gpu = self.gpu_frames.last();
        for (skipped, name) in [
            (stats.reused, "reused"),
            (stats.retested > 0, "moved objects re-tested"),
            (stats.occlusion_gated, "occlusion skipped"),
            (gpu.is_some_and(|o| o.cluster_pass_skipped), "cluster pass skipped"),
            (gpu.is_some_and(|o| o.triangle_pass_skipped), "triangle pass skipped"),
        ] {
            if skipped {
                flags.push(name.into());
            }
        }
        for (off, name) in [
            (!world.resource::<FrustumSettings>().enabled, "frustum off"),
            (!world.resource::<OcclusionSettings>().enabled, "occlusion off"),
            (!self.gpu_settings.cluster_cone, "clusters off"),
            (!self.gpu_settings.triangle_backface, "triangles off"),
        ] {
            if off {
                flags.push(name.into());
            }
        }
        text.push_str(&format!(" | {}", flags.join(", ")));
        text
    }
}

impl ApplicationHandler for Game {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.graphics.is_some() {
            return;
        }
        match self.open(event_loop) {
            Ok(graphics) => {
                graphics.window.request_redraw();
                self.graphics = Some(graphics);
            }
            Err(error) => {
                self.error = Some(format!("could not open the game window: {error}"));
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _window: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) if size.width > 0 && size.height > 0 => {
                self.size = (size.width, size.height);
                if let Some(graphics) = self.graphics.as_mut() {
                    graphics.config.width = size.width;
                    graphics.config.height = size.height;
                    graphics.surface.configure(&graphics.context.device, &graphics.config);
                    graphics.culler.resize(&graphics.context, size.width, size.height);
                }
            }
            WindowEvent::KeyboardInput {
                event: KeyEvent { physical_key: PhysicalKey::Code(code), state, repeat, .. },
                ..
            } => {
                if state == ElementState::Pressed {
                    self.keys.insert(code);
                    if !repeat {
                        self.key(code, event_loop);
                    }
                } else {
                    self.keys.remove(&code);
                }
            }
            WindowEvent::MouseInput { state, button: MouseButton::Right, .. } => {
                self.looking = state == ElementState::Pressed;
                if let Some(graphics) = &self.graphics {
                    let window = &graphics.window;
                    window.set_cursor_visible(!self.looking);
                    let mode = if self.looking { CursorGrabMode::Confined } else { CursorGrabMode::None };
                    let _ = window.set_cursor_grab(mode);
                }
            }
            WindowEvent::Focused(false) => self.keys.clear(),
            WindowEvent::RedrawRequested => {
                self.frame();
                if self.frame_limit.is_some_and(|limit| self.frames.len() >= limit) {
                    event_loop.exit();
                }
                if let Some(graphics) = &self.graphics {
                    graphics.window.request_redraw();
                }
            }
            _ => {}
        }
    }

    fn device_event(&mut self, _event_loop: &ActiveEventLoop, _device: DeviceId, event: DeviceEvent) {
        if let DeviceEvent::MouseMotion { delta: (dx, dy) } = event
            && self.looking
        {
            if self.autopilot.is_some() {
                self.leave_autopilot();
            }
            self.yaw += dx as f32 * 0.003;
            self.pitch = (self.pitch - dy as f32 * 0.003).clamp(-1.55, 1.55);
        }
    }
}
