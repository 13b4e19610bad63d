//! The built-in city in a real Bevy window (`DefaultPlugins`), flown along its fly-through and culled by
//! `bevy_cullet`. On screen: frames per second, the visibility systems' CPU time, and what the plugin kept.
//!
//! Keys: C switches the plugin (off: Bevy's own visibility check), O switches occlusion, L the plugin's culling of
//! the sun's shadow cascades (off: Bevy's light checks), Esc quits.
//!
//! `cargo run --release -p bevy_cullet_demo -- --objects 20000` (under Xvfb and lavapipe in a headless
//! machine: `xvfb-run -a ...`). `--frames N` spreads N frames along the path, quits and prints the means;
//! `--screenshot F` saves the window at the last frame. `--headless` draws into an image of `--resolution`
//! instead of a window and waits for the GPU at the end of each frame, so that the mean frame time is the
//! rendered frame's on a machine without a display.

use bevy::app::{AppExit, ScheduleRunnerPlugin};
use bevy::camera::RenderTarget;
use bevy::camera::visibility::{VisibilitySystems, VisibleEntities};
use bevy::diagnostic::{DiagnosticsStore, FrameCount, FrameTimeDiagnosticsPlugin};
use bevy::light::CascadeShadowConfigBuilder;
use bevy::prelude::*;
use bevy::render::render_resource::{PollType, TextureFormat};
use bevy::render::renderer::RenderDevice;
use bevy::render::view::screenshot::{Screenshot, save_to_disk};
use bevy::render::{Render, RenderApp, RenderSystems};
use bevy::window::ExitCondition;
use bevy::winit::WinitPlugin;
use bevy_cullet::{CulletLightStats, CulletPlugin, CulletSettings, CulletSystems, CulletView, spawn_scene};
use clap::Parser;
use cullet::scene::city::{CityParams, CityScene};
use std::any::TypeId;
use std::collections::HashMap;
use std::time::{Duration, Instant};

#[derive(Parser, Resource, Clone)]
struct Args {
    /// Objects in the city.
    #[arg(long, default_value_t = 20_000)]
    objects: usize,
    /// Window size, WIDTHxHEIGHT.
    #[arg(long, default_value = "1280x720")]
    resolution: String,
    /// Start with the plugin off (Bevy's own check).
    #[arg(long)]
    bevy_check: bool,
    /// Quit after this many frames, printing the mean frame and visibility times.
    #[arg(long)]
    frames: Option<u64>,
    /// Save the window to this PNG at the last frame (with `--frames`).
    #[arg(long)]
    screenshot: Option<std::path::PathBuf>,
    /// No window: draw into an image of `--resolution`, waiting for the GPU at the end of each frame (needs
    /// `--frames`).
    #[arg(long, requires = "frames", conflicts_with = "screenshot")]
    headless: bool,
}

impl Args {
    /// `--resolution` as `(width, height)`.
    ///
    /// # Panics
    /// If it is not `WIDTHxHEIGHT`.
    fn size(&self) -> (u32, u32) {
        self.resolution
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
            .expect("--resolution WIDTHxHEIGHT")
    }
}

/// The city's fly-through, played in a loop.
#[derive(Resource)]
struct Flight(cullet::CameraPath);

/// The text on screen.
#[derive(Component)]
struct Hud;

/// When the frame's visibility systems started and ended, and the run's sums.
#[derive(Resource, Default)]
struct Timing {
    start: Option<Instant>,
    visibility: Duration,
    frames: u64,
    visibility_sum: Duration,
    frame_sum: Duration,
}

fn main() -> AppExit {
    let args = Args::parse();
    let (width, height) = args.size();
    let mut app = App::new();
    if args.headless {
        let no_window = WindowPlugin { primary_window: None, exit_condition: ExitCondition::DontExit, ..default() };
        app.add_plugins((
            DefaultPlugins.set(no_window).disable::<WinitPlugin>(),
            ScheduleRunnerPlugin::run_loop(Duration::ZERO),
        ));
        // Without a swapchain nothing paces the frames: wait for the GPU so that a frame's time includes its
        // rendering.
        app.sub_app_mut(RenderApp).add_systems(Render, wait_for_gpu.in_set(RenderSystems::Cleanup));
    } else {
        app.add_plugins(DefaultPlugins.set(WindowPlugin {
            primary_window: Some(Window {
                title: "Cullet city in Bevy: C switches the plugin, O occlusion".into(),
                resolution: (width, height).into(),
                ..default()
            }),
            ..default()
        }));
    }
    app.add_plugins((CulletPlugin, FrameTimeDiagnosticsPlugin::default()))
        .insert_resource(CulletSettings { enabled: !args.bevy_check, ..default() })
        .insert_resource(args)
        .init_resource::<Timing>()
        .add_systems(Startup, setup)
        .add_systems(Update, (fly, keys, show))
        .add_systems(
            PostUpdate,
            (
                start_timer.in_set(CulletSystems::Mirror),
                stop_timer.after(VisibilitySystems::MarkNewlyHiddenEntitiesInvisible),
            ),
        );
    app.run()
}

/// Spawns the city (one Bevy mesh per Cullet mesh, one material per colour), the camera, a light and the text.
fn setup(world: &mut World) {
    let args = world.resource::<Args>().clone();
    let city = CityScene::generate(CityParams::with_objects(args.objects));
    let mesh_handles: Vec<Handle<Mesh>> = {
        let mut meshes = world.resource_mut::<Assets<Mesh>>();
        city.scene.meshes.iter().map(|mesh| meshes.add(bevy_mesh(mesh))).collect()
    };
    let mut materials: HashMap<[u8; 4], Handle<StandardMaterial>> = HashMap::new();
    for object in &city.scene.objects {
        materials.entry(object.color).or_insert_with(|| {
            let [r, g, b, _] = object.color;
            world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
                base_color: Color::srgb_u8(r, g, b),
                perceptual_roughness: 0.9,
                ..default()
            })
        });
    }
    spawn_scene(world, &city.scene, |object, entity| {
        entity.insert((
            Mesh3d(mesh_handles[object.mesh as usize].clone()),
            MeshMaterial3d(materials[&object.color].clone()),
        ));
    });
    let path = city.flythrough();
    let camera = world
        .spawn((
            Camera3d::default(),
            Projection::Perspective(PerspectiveProjection {
                fov: 60f32.to_radians(),
                near: 0.1,
                far: 1e5,
                ..default()
            }),
            camera_transform(&path, 0.0),
        ))
        .id();
    if args.headless {
        let (width, height) = args.size();
        let target = Image::new_target_texture(width, height, TextureFormat::Rgba8UnormSrgb, None);
        let target = world.resource_mut::<Assets<Image>>().add(target);
        world.entity_mut(camera).insert(RenderTarget::Image(target.into()));
    }
    // A sun with shadows: the plugin culls its cascades with the camera (L switches to Bevy's light checks).
    world.spawn((
        DirectionalLight { illuminance: 12000.0, shadow_maps_enabled: true, ..default() },
        CascadeShadowConfigBuilder { first_cascade_far_bound: 60.0, maximum_distance: 800.0, ..default() }.build(),
        Transform::from_xyz(300.0, 800.0, 200.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
    world.spawn((
        Hud,
        Text::new(""),
        TextFont { font_size: FontSize::Px(16.0), ..default() },
        Node { position_type: PositionType::Absolute, top: Val::Px(8.0), left: Val::Px(8.0), ..default() },
        BackgroundColor(Color::srgba(0.0, 0.0, 0.0, 0.6)),
    ));
    world.insert_resource(Flight(path));
}

/// A Cullet mesh as a Bevy one: flat-shaded, so each triangle gets its own vertices and normal.
fn bevy_mesh(mesh: &cullet::mesh::Mesh) -> Mesh {
    let positions: Vec<[f32; 3]> = mesh.indices.iter().map(|&i| mesh.positions[i as usize].to_array()).collect();
    let mut mesh = Mesh::new(bevy::mesh::PrimitiveTopology::TriangleList, default())
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions);
    mesh.compute_flat_normals();
    mesh
}

fn camera_transform(path: &cullet::CameraPath, t: f32) -> Transform {
    let (position, target) = path.sample(t);
    let v = |v: glam::Vec3| Vec3::from_array(v.to_array());
    Transform::from_translation(v(position)).looking_at(v(target), Vec3::Y)
}

/// Flies the camera along the path: looping in real time, or with `--frames` a fixed step a frame, so that
/// every run sees the same views.
fn fly(
    time: Res<Time>,
    frame: Res<FrameCount>,
    args: Res<Args>,
    flight: Res<Flight>,
    mut camera: Single<&mut Transform, With<Camera3d>>,
) {
    let duration = flight.0.duration();
    let t = match args.frames {
        Some(frames) => duration * (frame.0 as f32 / frames as f32).min(1.0),
        None => time.elapsed_secs() % duration,
    };
    **camera = camera_transform(&flight.0, t);
}

/// Blocks until the GPU has finished the frame's work (headless runs).
fn wait_for_gpu(device: Res<RenderDevice>) {
    if let Err(error) = device.poll(PollType::wait_indefinitely()) {
        warn!("waiting for the GPU: {error}");
    }
}

fn keys(keys: Res<ButtonInput<KeyCode>>, mut settings: ResMut<CulletSettings>, mut exit: MessageWriter<AppExit>) {
    if keys.just_pressed(KeyCode::KeyC) {
        settings.enabled = !settings.enabled;
    }
    if keys.just_pressed(KeyCode::KeyO) {
        settings.occlusion.enabled = !settings.occlusion.enabled;
    }
    if keys.just_pressed(KeyCode::KeyL) {
        settings.lights = !settings.lights;
    }
    if keys.just_pressed(KeyCode::Escape) {
        exit.write(AppExit::Success);
    }
}

fn start_timer(mut timing: ResMut<Timing>) {
    timing.start = Some(Instant::now());
}

fn stop_timer(mut timing: ResMut<Timing>) {
    if let Some(start) = timing.start.take() {
        timing.visibility = start.elapsed();
    }
}

/// Updates the text; with `--frames`, sums the times, saves the screenshot and quits at the end.
#[allow(clippy::too_many_arguments)] // a Bevy system: each parameter is data it reads or writes
fn show(
    mut commands: Commands,
    args: Res<Args>,
    settings: Res<CulletSettings>,
    diagnostics: Res<DiagnosticsStore>,
    time: Res<Time>,
    mut timing: ResMut<Timing>,
    camera: Single<(&CulletView, &VisibleEntities)>,
    light_stats: Res<CulletLightStats>,
    mut text: Single<&mut Text, With<Hud>>,
    mut exit: MessageWriter<AppExit>,
) {
    let (view, visible) = *camera;
    let stats = view.stats();
    let fps = diagnostics.get(&FrameTimeDiagnosticsPlugin::FPS).and_then(|d| d.smoothed()).unwrap_or(0.0);
    let culling = if settings.enabled { "Cullet" } else { "Bevy's check" };
    let occlusion = if settings.occlusion.enabled { "on" } else { "off" };
    let lights = if settings.enabled && settings.lights { "Cullet" } else { "Bevy's checks" };
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    text.0 = format!(
        "{fps:.0} fps   visibility systems {:.2} ms   culling: {culling} (C)   occlusion: {occlusion} (O)\n\
         meshes drawn: {}\n\
         Cullet: {} objects, frustum kept {}, occlusion kept {} ({} occluders)\n\
         stages: frustum {:.2} ms, raster {:.2} ms, occlusion {:.2} ms, write {:.2} ms\n\
         sun's cascades: {lights} (L), {} views keep {} casters ({} hidden from the sun), write {:.2} ms",
        ms(timing.visibility),
        visible.len(TypeId::of::<Mesh3d>()),
        stats.objects,
        stats.after_frustum,
        stats.after_occlusion,
        stats.occluders,
        ms(stats.frustum_time),
        ms(stats.raster_time),
        ms(stats.occlusion_time),
        ms(stats.write_time),
        stats.light_views,
        stats.light_casters,
        stats.light_occluded,
        ms(light_stats.write_time),
    );
    let Some(frames) = args.frames else { return };
    // The first frames load and mirror everything.
    timing.frames += 1;
    if timing.frames > 5 && timing.frames <= frames {
        let (visibility, delta) = (timing.visibility, time.delta());
        timing.visibility_sum += visibility;
        timing.frame_sum += delta;
    }
    if timing.frames == frames
        && let Some(path) = &args.screenshot
    {
        commands.spawn(Screenshot::primary_window()).observe(save_to_disk(path.clone()));
    }
    // A screenshot is read back some frames after it is asked for.
    let last = if args.screenshot.is_some() { frames + 8 } else { frames + 2 };
    if timing.frames == last {
        let counted = (frames - 5) as f64;
        println!(
            "{} objects, {culling}: mean frame {:.2} ms, visibility systems {:.3} ms over {} frames",
            args.objects,
            ms(timing.frame_sum) / counted,
            ms(timing.visibility_sum) / counted,
            counted
        );
        exit.write(AppExit::Success);
    }
}
