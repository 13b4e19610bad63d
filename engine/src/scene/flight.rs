//! A scene flown through along a camera path: the world, its culling schedule and the camera, advanced one
//! frame at a time. The sample game, the tests and the benchmarks all drive the pipeline through it, or any
//! [`Culler`] ([`Flight::for_cullers`], [`Flight::cull_frame`]).

use super::Velocity;
use crate::bounds::BoundsStore;
use crate::bounds::ObjectTransform;
use crate::camera::CameraPath;
use crate::culler::{AdaptiveSettings, CullScene, Culled, Culler, OcclusionSettings};
use crate::parallel;
use crate::pipeline::{self, CullStage, CullStats, PipelineSettings};
use bevy_ecs::prelude::*;
use rayon::prelude::*;
use std::time::Duration;

/// Seconds simulated by the current frame.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameDelta(pub f32);

/// Moves objects with a [`Velocity`] by one [`FrameDelta`]; only their transforms change, so only their bounds
/// are recomputed. In parallel over runs of table rows (a 1e7-object city moves 200 000 cars a frame).
pub fn move_objects(delta: Res<FrameDelta>, mut movers: Query<(&Velocity, &mut ObjectTransform)>) {
    let step = |velocity: &Velocity, transform: &mut ObjectTransform| {
        transform.0.translation += glam::Vec3A::from(velocity.0 * delta.0);
    };
    let Ok(tables) = movers.contiguous_iter_mut() else {
        // Not stored in tables (not the case of these components): one walk on this thread.
        for (velocity, mut transform) in &mut movers {
            step(velocity, &mut transform);
        }
        return;
    };
    let mut runs = Vec::new();
    for (velocities, transforms) in tables {
        // Every mover's transform changes: all marked changed at once.
        let (transforms, _) = bevy_ecs::change_detection::ContiguousMut::split(transforms);
        runs.extend(velocities.chunks(MOVES_PER_TASK).zip(transforms.chunks_mut(MOVES_PER_TASK)));
    }
    parallel::region(|region| {
        runs.into_par_iter().for_each(|(velocities, transforms)| {
            region
                .task(|| velocities.iter().zip(transforms).for_each(|(velocity, transform)| step(velocity, transform)))
        })
    });
}

/// Movers one task of [`move_objects`] moves.
const MOVES_PER_TASK: usize = 4096;

/// A world being flown through: `frames` frames spread evenly over the camera path's duration.
pub struct Flight {
    /// The world: scene entities and the pipeline's resources.
    pub world: World,
    /// Moving objects, then the culling stages.
    pub schedule: Schedule,
    /// The camera path.
    pub path: CameraPath,
    /// Viewport width over height.
    pub aspect: f32,
    /// Frames along the path.
    pub frames: u32,
}

impl Flight {
    /// A world with the culling pipeline installed ([`pipeline::install`]) with `occlusion` settings, filled by
    /// `spawn`, with the camera at the start of `path`.
    pub fn new(
        path: CameraPath,
        aspect: f32,
        frames: u32,
        occlusion: OcclusionSettings,
        spawn: impl FnOnce(&mut World),
    ) -> Self {
        let (mut world, mut schedule) = (World::new(), Schedule::default());
        let settings = PipelineSettings { occlusion, adaptive: AdaptiveSettings::default(), ..Default::default() };
        pipeline::install(&mut world, &mut schedule, settings);
        spawn(&mut world);
        world.insert_resource(path.camera_at(0.0, aspect));
        world.init_resource::<FrameDelta>();
        schedule.add_systems(move_objects.before(CullStage::Bounds));
        Self { world, schedule, path, aspect, frames }
    }

    /// A world with only the bounds stage installed ([`pipeline::install_bounds`]), filled by `spawn`, with the
    /// camera at the start of `path`: each frame, [`Flight::cull_frame`] moves the objects, brings the store
    /// up to date and runs a [`Culler`] of your choice on it.
    pub fn for_cullers(path: CameraPath, aspect: f32, frames: u32, spawn: impl FnOnce(&mut World)) -> Self {
        let (mut world, mut schedule) = (World::new(), Schedule::default());
        pipeline::install_bounds(&mut world, &mut schedule);
        spawn(&mut world);
        world.insert_resource(path.camera_at(0.0, aspect));
        world.init_resource::<FrameDelta>();
        schedule.add_systems(move_objects.before(CullStage::Bounds));
        Self { world, schedule, path, aspect, frames }
    }

    /// Places the camera for frame `frame`, moves objects by one frame (none on frame 0), brings the store up
    /// to date and culls with `culler`, telling it what moved in place ([`BoundsStore::take_moves`]). Returns
    /// the bounds stage's time ([`BoundsStore::last_sync_time`], as [`CullStats::bounds_time`]) and what the
    /// culler kept. Meant for a
    /// flight made by [`Flight::for_cullers`]; on one with the whole pipeline, the pipeline takes the moves
    /// first and the culler is told none.
    pub fn cull_frame<'c>(&mut self, frame: u32, culler: &'c mut dyn Culler) -> (Duration, Culled<'c>) {
        let delta = self.frame_delta();
        let camera = self.path.camera_at(frame as f32 * delta, self.aspect);
        self.world.insert_resource(camera);
        self.world.resource_mut::<FrameDelta>().0 = if frame == 0 { 0.0 } else { delta };
        self.schedule.run(&mut self.world);
        self.world.clear_trackers();
        let mut store = self.world.resource_mut::<BoundsStore>();
        let (bounds_time, moves) = (store.last_sync_time(), store.take_moves());
        let scene = CullScene { world: &self.world, moves: moves.as_ref() };
        (bounds_time, culler.cull(&scene, &camera))
    }

    /// Seconds between frames.
    pub fn frame_delta(&self) -> f32 {
        self.path.duration() / self.frames.saturating_sub(1).max(1) as f32
    }

    /// Places the camera for frame `frame`, moves objects by one frame (none on frame 0) and culls.
    pub fn run_frame(&mut self, frame: u32) -> CullStats {
        let delta = self.frame_delta();
        let camera = self.path.camera_at(frame as f32 * delta, self.aspect);
        self.run_with_camera(camera, if frame == 0 { 0.0 } else { delta })
    }

    /// Culls for `camera` after moving objects by `delta` seconds: one frame of a camera not on the path (the
    /// game's free flight).
    pub fn run_with_camera(&mut self, camera: crate::camera::Camera, delta: f32) -> CullStats {
        self.world.insert_resource(camera);
        self.world.resource_mut::<FrameDelta>().0 = delta;
        self.schedule.run(&mut self.world);
        self.world.clear_trackers();
        *self.world.resource::<CullStats>()
    }
}
