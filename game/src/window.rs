//! The windowed game (winit): the scene culled and drawn every frame, following the camera path until the
//! player takes over with free flight. Each stage can be switched off, culling frozen at one camera while
//! the player flies around to see what was culled, and the window shows debug views: objects tinted by the
//! stage that culled them, the software occlusion buffer and each level of its pyramid. The heads-up display
//! ([`crate::hud`]) shows each stage's figures, live plots, the debug views' legends and the controls; the
//! title bar keeps a short summary.

use crate::hud::controls::{Controls, View};
use crate::hud::painter::{HudPainter, Work};
use crate::hud::{FRUSTUM_TINT, HELP, Hud, HudFrame, LEVEL_COLOURS, OCCLUSION_TINT};
use crate::present::{PresentPass, Source};
use crate::report::{Spread, kept_by_light_view, print_gpu_summary, print_savings, print_summary};
use crate::validation::Validation;
use crate::{Args, Prepared};
use cullet::draw_cost::{DrawSavings, SlotTriangles};
use cullet::gpu::{GpuContext, GpuCullSettings, GpuCuller, GpuFrameOutput};
use cullet::lod::LodSelection;
use cullet::pipeline::{CameraCuller, CullStats};
use cullet::{BoundsStore, Camera};
use glam::Vec3;
use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{DeviceEvent, DeviceId, ElementState, KeyEvent, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{CursorGrabMode, Window, WindowId};

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

/// Runs the game in a window until it is closed (or after `--frames` frames), then prints the summary.
pub fn run(args: &Args, prepared: Prepared, event_loop: EventLoop<()>) -> Result<(), String> {
    event_loop.set_control_flow(ControlFlow::Poll);
    let start = prepared.flight.path.camera_at(0.0, 1.0);
    let (yaw, pitch) = yaw_pitch(start.forward);
    let (width, height) = prepared.resolution;
    let radius = prepared.scene.bounds().map_or(100.0, |(min, max)| (max - min).length() * 0.5);
    let slot_triangles = SlotTriangles::of_world(&prepared.flight.world, &prepared.scene.meshes);
    if let Some(dir) = &args.screenshots {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
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
        view: args.view,
        pyramid_level: 0,
        gpu_settings: GpuCullSettings { two_phase: args.two_phase, ..GpuCullSettings::default() },
        hud: Hud::new(!args.no_hud),
        hud_times: Vec::new(),
        hud_stale: true,
        validation: args.validate.then(|| Validation::new(width, height)),
        screenshots: args.screenshots.clone().map(|dir| (dir, args.every.max(1))),
        last_frame: Instant::now(),
        last_title: Instant::now(),
        frames: Vec::new(),
        gpu_frames: Vec::new(),
        slot_triangles,
        savings: Vec::new(),
        fps: 0.0,
        frame_limit: args.frames.map(|n| n as usize),
    };
    println!("window controls:\n{HELP}");
    event_loop.run_app(&mut game).map_err(|e| e.to_string())?;
    print_summary(&game.frames);
    print_gpu_summary(&game.gpu_frames);
    print_savings(&game.savings, &game.gpu_frames);
    print_hud_summary(&game.hud_times);
    if let Some(validation) = &game.validation {
        println!("\n{}", validation.summary());
        validation.verdict()?;
    }
    game.error.map_or(Ok(()), Err)
}

/// What the HUD cost in one frame.
struct HudTime {
    /// CPU time of the thread: recording the frame's figures and painting.
    cpu: Duration,
    /// The part of a build done.
    work: Work,
    /// Wall time in egui's pass, tessellating, and uploading and recording.
    wall: [Duration; 3],
}

/// The HUD's CPU budget a frame, in milliseconds (its issue's target): the summary counts the frames over it.
const HUD_BUDGET_MS: f64 = 0.3;

/// The frames over which the HUD shows the most it cost a frame: a second at 60 frames a second.
const HUD_PEAK_FRAMES: usize = 60;

/// Prints the HUD's CPU time per frame it was drawn in, the frames over budget, and the cost of each part of
/// a build. The first frame, which builds it whole and loads egui's fonts, is told apart.
fn print_hud_summary(times: &[HudTime]) {
    let Some((first, times)) = times.split_first() else { return };
    let ms = |duration: Duration| duration.as_secs_f64() * 1e3;
    let cpu = Spread::of(times.iter().map(|t| ms(t.cpu)).collect());
    let over_budget = times.iter().filter(|t| ms(t.cpu) > HUD_BUDGET_MS).count();
    println!(
        "HUD CPU time per frame over {} frames after the first: mean {:.3} ms, median {:.3} ms, 95th percentile \
         {:.3} ms, 99th {:.3} ms, most {:.3} ms, {over_budget} frames over {HUD_BUDGET_MS} ms (the first frame: \
         {:.3} ms, with egui's fonts)",
        times.len(),
        cpu.mean,
        cpu.median,
        cpu.p95,
        cpu.p99,
        cpu.max,
        ms(first.cpu),
    );
    let steps = [
        (Work::Begin, "beginning egui's pass"),
        (Work::Pass, "egui's pass whole, answering input"),
        (Work::Part(0), "the figures window"),
        (Work::Part(1), "the plots window, ending the pass"),
        (Work::Tessellate, "tessellating"),
        (Work::Upload, "uploading"),
        (Work::Whole, "whole builds"),
    ];
    for (work, what) in steps {
        let frames: Vec<&HudTime> = times.iter().filter(|t| t.work == work).collect();
        if frames.is_empty() {
            continue;
        }
        let spread = |value: fn(&HudTime) -> Duration| Spread::of(frames.iter().map(|t| ms(value(t))).collect());
        let cpu = spread(|t| t.cpu);
        println!(
            "  {what}: {} frames, {:.3} ms CPU each on average, most {:.3} ms (wall: pass {:.3}, tessellate \
             {:.3}, upload and record {:.3})",
            frames.len(),
            cpu.mean,
            cpu.max,
            spread(|t| t.wall[0]).mean,
            spread(|t| t.wall[1]).mean,
            spread(|t| t.wall[2]).mean,
        );
    }
}

/// The window, its surface and the GPU pipeline drawing into it.
struct Graphics {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    context: GpuContext,
    culler: GpuCuller,
    present: PresentPass,
    hud: HudPainter,
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
    hud: Hud,
    /// What the HUD cost in each frame it was drawn.
    hud_times: Vec<HudTime>,
    /// A key changed what the HUD shows: build it again.
    hud_stale: bool,
    /// The live judge, with `--validate`.
    validation: Option<Validation>,
    /// Folder and frame interval of `--screenshots`.
    screenshots: Option<(PathBuf, u32)>,
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
        let context = GpuContext::for_surface(&instance, &surface).map_err(|e| crate::gpu_error_message(&e))?;
        let info = &context.adapter_info;
        println!("GPU: {} ({:?}, {:?})", info.name, info.backend, info.device_type);
        let size = window.inner_size();
        self.size = (size.width.max(1), size.height.max(1));
        println!("window opened: {}x{}", self.size.0, self.size.1);
        let mut config = surface
            .get_default_config(&context.adapter, self.size.0, self.size.1)
            .ok_or("the GPU cannot present to this window")?;
        // The colour target holds display values: present them through a non-sRGB view where there is one.
        let capabilities = surface.get_capabilities(&context.adapter);
        if let Some(&linear) = capabilities.formats.iter().find(|f| !f.is_srgb()) {
            config.format = linear;
        }
        if self.screenshots.is_some() {
            // Screenshots copy the frame the player sees, HUD included, out of the surface.
            if capabilities.usages.contains(wgpu::TextureUsages::COPY_SRC) {
                config.usage |= wgpu::TextureUsages::COPY_SRC;
            } else {
                println!("--screenshots: this surface cannot be copied from, so no screenshot is saved");
                self.screenshots = None;
            }
        }
        surface.configure(&context.device, &config);
        if let Some(validation) = &mut self.validation {
            validation.set_resolution(self.size.0, self.size.1);
        }
        let hud = HudPainter::new(&window, &context, config.format, Hud::PARTS);
        let culler =
            GpuCuller::for_world(&context, &self.prepared.flight.world, &self.prepared.scene.meshes, self.size);
        let present = PresentPass::new(&context, config.format);
        Ok(Graphics { window, surface, config, context, culler, present, hud })
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

    /// The settings the keys and the HUD change, as they are now.
    fn controls(&self) -> Controls {
        let world = &self.prepared.flight.world;
        Controls::of(world, self.gpu_settings, self.frozen.is_some(), self.view, self.pyramid_level)
    }

    /// Takes changed settings from the keys or the HUD: the pipeline's into the world, the window's here.
    fn set_controls(&mut self, controls: Controls) {
        controls.apply(&mut self.prepared.flight.world);
        self.gpu_settings = controls.gpu;
        self.view = controls.view;
        self.pyramid_level = controls.pyramid_level;
        if controls.frozen != self.frozen.is_some() {
            self.frozen = controls.frozen.then(|| self.camera());
        }
    }

    fn key(&mut self, code: KeyCode, event_loop: &ActiveEventLoop) {
        self.hud_stale = true;
        let mut controls = self.controls();
        match code {
            KeyCode::Escape => event_loop.exit(),
            KeyCode::KeyP => {
                if self.autopilot.is_some() {
                    self.leave_autopilot();
                } else {
                    self.autopilot = Some(0.0);
                }
            }
            KeyCode::KeyH => self.hud.visible ^= true,
            KeyCode::F1 => {
                self.hud.help ^= true;
                self.hud.visible |= self.hud.help;
            }
            KeyCode::KeyF => controls.frozen ^= true,
            KeyCode::Digit1 => controls.frustum.enabled ^= true,
            KeyCode::Digit2 => controls.occlusion.enabled ^= true,
            KeyCode::Digit3 => controls.set_clusters(!controls.clusters_on()),
            KeyCode::Digit4 => controls.set_triangles(!controls.triangles_on()),
            KeyCode::Digit5 => controls.gpu.two_phase ^= true,
            KeyCode::KeyV => controls.view = controls.view.next(),
            KeyCode::BracketLeft => controls.pyramid_level = controls.pyramid_level.saturating_sub(1),
            KeyCode::BracketRight => controls.pyramid_level += 1,
            _ => {}
        }
        self.set_controls(controls);
    }

    /// Culls and draws one frame, with the HUD over it, and shows it.
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
        if let Some(validation) = &mut self.validation {
            validation.judge(&self.prepared.flight.world, &self.prepared.scene.meshes);
        }
        let Some(graphics) = self.graphics.as_mut() else { return };
        let world = &mut self.prepared.flight.world;
        let (context, culler) = (&graphics.context, &mut graphics.culler);
        let mut gpu_output = None;
        if self.view == View::Tinted {
            // Every object drawn, tinted by the stage that culled it.
            let frustum = world.resource::<CameraCuller>().frustum_visible().clone();
            let occlusion = world.resource::<CameraCuller>().visible().clone();
            culler.debug().recolored(context, world, &camera, |slot| {
                match (frustum.contains(slot), occlusion.contains(slot)) {
                    (false, _) => Some(FRUSTUM_TINT),
                    (true, false) => Some(OCCLUSION_TINT),
                    (true, true) => None,
                }
            });
        } else if self.view == View::Levels && world.contains_resource::<LodSelection>() {
            // Every object drawn at its level, coloured by it.
            let levels: Vec<Option<u8>> = {
                let selection = world.resource::<LodSelection>();
                (0..world.resource::<BoundsStore>().len()).map(|slot| selection.level(slot)).collect()
            };
            culler.debug().recolored(context, world, &camera, |slot| {
                let level = levels.get(slot).copied().flatten()?;
                Some(LEVEL_COLOURS[(level as usize).min(LEVEL_COLOURS.len() - 1)])
            });
        } else {
            match culler.debug().run_world_from(context, world, &camera, &self.gpu_settings) {
                Ok(output) => gpu_output = Some(output),
                Err(error) => {
                    eprintln!("{error}");
                    return;
                }
            }
        }
        let savings = DrawSavings::of_frame(world, &self.slot_triangles, gpu_output.as_ref());

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
        let state = world.resource::<CameraCuller>();
        let levels = state.pyramid().level_count();
        self.pyramid_level = self.pyramid_level.min(levels.saturating_sub(1));
        let source = match self.view {
            View::Shaded | View::Tinted | View::Levels => Source::Color(&color),
            View::Pyramid if levels > 0 => Source::Depth(state.pyramid().level(self.pyramid_level)),
            View::OcclusionBuffer | View::Pyramid => Source::Depth(state.depth()),
        };
        graphics.present.record(context, &mut encoder, source, &target, self.size);

        let pyramid = (0..levels).map(|level| state.pyramid().level(level)).map(|b| (b.width(), b.height())).collect();
        let hud_frame = HudFrame {
            stats,
            gpu: gpu_output.clone(),
            savings,
            fps: self.fps,
            hud_time: self.hud_times.iter().rev().take(HUD_PEAK_FRAMES).map(|t| t.cpu).max().unwrap_or_default(),
            following_path: self.autopilot.is_some(),
            buffer: (state.depth().width(), state.depth().height()),
            pyramid,
            viewport: self.size,
            light_views: kept_by_light_view(world),
        };
        let recording = cpu_time::ThreadTime::now();
        let refreshed = self.hud.record(hud_frame, delta);
        let record_cpu = recording.elapsed();
        let controls_before =
            Controls::of(world, self.gpu_settings, self.frozen.is_some(), self.view, self.pyramid_level);
        let mut controls = controls_before;
        let (hud, validation) = (&self.hud, self.validation.as_ref());
        // The HUD's content changes when its figures are refreshed, or when a key changed what it shows.
        let changed = refreshed || std::mem::take(&mut self.hud_stale);
        let painted = hud.visible.then(|| {
            graphics.hud.paint(&graphics.window, context, &mut encoder, &target, self.size, changed, |ctx, part| {
                hud.ui_part(ctx, part, validation, &mut controls)
            })
        });
        if let Some(painted) = &painted {
            let cpu = record_cpu + painted.cpu_time;
            self.hud_times.push(HudTime { cpu, work: painted.work, wall: painted.wall_times });
        }
        context.queue.submit([encoder.finish()]);
        let frame_number = self.frames.len() - 1;
        let screenshot = self
            .screenshots
            .as_ref()
            .filter(|(_, every)| frame_number.is_multiple_of(*every as usize))
            .map(|(dir, _)| dir.join(format!("frame_{frame_number:05}.png")));
        if let Some(file) = screenshot {
            match save_screenshot(context, &frame.texture, graphics.config.format, &file) {
                Ok(()) => {
                    let regions: Vec<String> = painted
                        .map_or(Vec::new(), |p| p.regions)
                        .iter()
                        .map(|[x0, y0, x1, y1]| format!("{x0},{y0},{x1},{y1}"))
                        .collect();
                    println!("screenshot {}: HUD over pixels [{}]", file.display(), regions.join(" "));
                }
                Err(error) => eprintln!("screenshot {}: {error}", file.display()),
            }
        }
        graphics.window.pre_present_notify();
        context.queue.present(frame);
        if let Some(gpu) = gpu_output {
            self.savings.push(savings);
            self.gpu_frames.push(gpu);
        }
        if controls != controls_before {
            self.set_controls(controls);
        }

        if self.last_title.elapsed() > Duration::from_millis(250) {
            self.last_title = Instant::now();
            let title = self.title(&stats);
            if let Some(graphics) = &self.graphics {
                graphics.window.set_title(&title);
            }
        }
    }

    /// The title bar's short summary: frame rate, objects after each CPU stage, and the HUD key.
    fn title(&self, stats: &CullStats) -> String {
        let frozen = if self.frozen.is_some() { " | FROZEN" } else { "" };
        format!(
            "cullet | {:.0} fps | {} > {} > {} objects{frozen} | H: HUD, F1: keys",
            self.fps, stats.objects, stats.after_frustum, stats.after_occlusion
        )
    }
}

/// Saves the surface texture `texture` (of `format`, copyable) as a PNG file.
fn save_screenshot(
    context: &GpuContext,
    texture: &wgpu::Texture,
    format: wgpu::TextureFormat,
    file: &std::path::Path,
) -> Result<(), String> {
    use wgpu::TextureFormat as F;
    let swap_red_blue = match format {
        F::Rgba8Unorm | F::Rgba8UnormSrgb => false,
        F::Bgra8Unorm | F::Bgra8UnormSrgb => true,
        other => return Err(format!("surface format {other:?} is not saved")),
    };
    let mut pixels = context.read_texture(texture, wgpu::TextureAspect::All, 4).map_err(|e| e.to_string())?;
    if swap_red_blue {
        pixels.chunks_exact_mut(4).for_each(|texel| texel.swap(0, 2));
    }
    for texel in pixels.chunks_exact_mut(4) {
        // The window shows colours, not coverage: store them opaque.
        texel[3] = 255;
    }
    image::RgbaImage::from_raw(texture.width(), texture.height(), pixels)
        .ok_or("screenshot size mismatch")?
        .save(file)
        .map_err(|e| e.to_string())
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
        if let Some(graphics) = self.graphics.as_mut().filter(|_| self.hud.visible)
            && graphics.hud.on_window_event(&graphics.window, &event)
        {
            // A click or drag on the HUD, or typing into it: not the game's.
            return;
        }
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) if size.width > 0 && size.height > 0 => {
                self.size = (size.width, size.height);
                // A pixel-centre or masked buffer is conservative only for the frame it samples: it follows the
                // window, as does the frame the settings stand for.
                let controls = self.controls();
                let occlusion = controls.occlusion.resized_to(size.width, size.height);
                if occlusion != controls.occlusion {
                    self.set_controls(Controls { occlusion, ..controls });
                }
                if let Some(graphics) = self.graphics.as_mut() {
                    graphics.config.width = size.width;
                    graphics.config.height = size.height;
                    graphics.surface.configure(&graphics.context.device, &graphics.config);
                    graphics.culler.resize(&graphics.context, size.width, size.height);
                }
                if let Some(validation) = &mut self.validation {
                    validation.set_resolution(size.width, size.height);
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
