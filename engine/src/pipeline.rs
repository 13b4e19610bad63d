//! The culling pipeline as `bevy_ecs` systems, one per stage, in a fixed order: data flows one way, each stage
//! narrowing the [`VisibleSet`] of the stage before.

use crate::bounds::{BoundsStore, on_bounds_removed, sync_bounds};
use crate::camera::Camera;
use crate::frustum::{FrustumError, cull_frustum};
use crate::visible::VisibleSet;
use bevy_ecs::prelude::*;
use std::time::{Duration, Instant};

/// The stages, in the order they run.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CullStage {
    /// Bring the SoA bounds up to date with changed entities.
    Bounds,
    /// Cull against the view frustum.
    Frustum,
}

/// Output of the frustum stage: store slots whose boxes touch the frustum.
#[derive(Resource, Default, Debug, Clone)]
pub struct FrustumVisible(pub VisibleSet);

/// Per-frame counts and timings of each stage.
#[derive(Resource, Default, Debug, Clone, Copy, PartialEq)]
pub struct CullStats {
    /// Objects in the store.
    pub objects: usize,
    /// Objects whose bounds were recomputed this frame.
    pub bounds_recomputed: usize,
    /// Objects left after frustum culling.
    pub after_frustum: usize,
    /// Time spent bringing bounds up to date.
    pub bounds_time: Duration,
    /// Time spent frustum culling.
    pub frustum_time: Duration,
    /// Set when the camera could not produce a frustum; the stage then keeps every object.
    pub frustum_error: Option<FrustumError>,
}

/// Sets up a world for culling: the [`BoundsStore`], the removal observer and the stage outputs. The
/// [`Camera`] resource must be inserted by the caller.
pub fn init_world(world: &mut World) {
    world.init_resource::<BoundsStore>();
    world.init_resource::<FrustumVisible>();
    world.init_resource::<CullStats>();
    world.add_observer(on_bounds_removed);
}

/// Adds the culling stages to `schedule`, in order.
pub fn add_systems(schedule: &mut Schedule) {
    schedule.configure_sets((CullStage::Bounds, CullStage::Frustum).chain());
    schedule.add_systems((
        sync_bounds.in_set(CullStage::Bounds),
        frustum_stage.in_set(CullStage::Frustum),
    ));
}

/// Culls the store against the [`Camera`]'s frustum into [`FrustumVisible`]. A camera that gives no valid
/// frustum culls nothing (everything stays visible) and reports the error in [`CullStats`].
pub fn frustum_stage(
    store: Res<BoundsStore>,
    camera: Res<Camera>,
    mut visible: ResMut<FrustumVisible>,
    mut stats: ResMut<CullStats>,
) {
    let start = Instant::now();
    stats.objects = store.len();
    stats.bounds_recomputed = store.recomputed_last_sync;
    stats.bounds_time = store.last_sync_time;
    match camera.frustum() {
        Ok(frustum) => {
            stats.after_frustum = cull_frustum(&store, &frustum, &mut visible.0);
            stats.frustum_error = None;
        }
        Err(error) => {
            tracing::warn!("frustum stage skipped: {error}");
            visible.0 = VisibleSet::all(store.len());
            stats.after_frustum = store.len();
            stats.frustum_error = Some(error);
        }
    }
    stats.frustum_time = start.elapsed();
}
