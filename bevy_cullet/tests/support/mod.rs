//! A headless Bevy app with Bevy's real transform and visibility systems, with or without the plugin.

#![allow(dead_code)]

pub mod bevy_city;
pub mod timing;

use bevy_app::prelude::*;
use bevy_asset::{AssetApp, Assets};
use bevy_camera::visibility::{ViewVisibility, VisibilityClass};
use bevy_camera::{Camera3d, PerspectiveProjection, Projection};
use bevy_cullet::{CulletPlugin, CulletSettings};
use bevy_ecs::prelude::*;
use bevy_mesh::Mesh;
use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
use bevy_transform::prelude::*;
use std::any::TypeId;

/// The visibility class the test entities draw as (a real app's is `Mesh3d`).
pub struct Drawn;

/// Bevy's transform and camera plugins (visibility included), and the plugin with `settings` if given.
pub fn app(settings: Option<CulletSettings>) -> App {
    let mut app = App::new();
    app.add_plugins((TaskPoolPlugin::default(), TransformPlugin, bevy_camera::CameraPlugin));
    // Bevy's bounds systems read these assets; the test entities bring their own `Aabb`.
    app.init_resource::<Assets<Mesh>>().init_resource::<Assets<SkinnedMeshInverseBindposes>>();
    if let Some(settings) = settings {
        app.add_plugins(CulletPlugin).insert_resource(settings);
    }
    app
}

/// [`app`] with Bevy's asset and light plugins too: directional, point and spot lights, their cascades and
/// Bevy's own light visibility checks (which the plugin replaces where it is added).
pub fn app_with_lights(settings: Option<CulletSettings>) -> App {
    let mut app = App::new();
    app.add_plugins((
        TaskPoolPlugin::default(),
        TransformPlugin,
        bevy_asset::AssetPlugin::default(),
        bevy_camera::CameraPlugin,
        bevy_light::LightPlugin,
    ));
    app.init_asset::<Mesh>().init_asset::<SkinnedMeshInverseBindposes>().init_asset::<bevy_image::Image>();
    if let Some(settings) = settings {
        app.add_plugins(CulletPlugin).insert_resource(settings);
    }
    app
}

/// A visibility class naming [`Drawn`].
pub fn drawn() -> VisibilityClass {
    let mut class = VisibilityClass::default();
    class.push(TypeId::of::<Drawn>());
    class
}

/// The Bevy transform and projection of a Cullet camera (Bevy's far plane at `far`).
pub fn bevy_camera(camera: &cullet::Camera, far: f32) -> (Transform, Projection) {
    let v = |v: glam::Vec3| bevy_math::Vec3::from_array(v.to_array());
    let transform = Transform::from_translation(v(camera.position)).looking_to(v(camera.forward), v(camera.up));
    let projection = Projection::Perspective(PerspectiveProjection {
        fov: camera.fov_y,
        aspect_ratio: camera.aspect,
        near: camera.near,
        far,
        ..Default::default()
    });
    (transform, projection)
}

/// Spawns a 3D camera seeing as `camera` does.
pub fn spawn_camera(world: &mut World, camera: &cullet::Camera, far: f32) -> Entity {
    world.spawn((Camera3d::default(), bevy_camera(camera, far))).id()
}

/// Moves a camera spawned by [`spawn_camera`] to `camera`.
pub fn set_camera(world: &mut World, entity: Entity, camera: &cullet::Camera, far: f32) {
    let (transform, projection) = bevy_camera(camera, far);
    let mut entity = world.entity_mut(entity);
    *entity.get_mut::<Transform>().unwrap() = transform;
    *entity.get_mut::<Projection>().unwrap() = projection;
}

/// Whether each of `entities` is visible in some view this frame.
pub fn view_visible(world: &World, entities: &[Entity]) -> Vec<bool> {
    entities.iter().map(|&e| world.get::<ViewVisibility>(e).is_some_and(|v| v.get())).collect()
}

/// The Cullet camera a Bevy camera entity culls with: its transform and projection, as the tests' truth sees
/// them.
pub fn cullet_camera(world: &World, entity: Entity, far: Option<f32>) -> cullet::Camera {
    let transform = world.get::<GlobalTransform>(entity).unwrap();
    let Projection::Perspective(p) = world.get::<Projection>(entity).unwrap() else { panic!("perspective only") };
    let g = |v: bevy_math::Vec3| glam::Vec3::from_array(v.to_array());
    let rotation = transform.rotation();
    cullet::Camera {
        position: g(transform.translation()),
        forward: g(rotation * bevy_math::Vec3::NEG_Z),
        up: g(rotation * bevy_math::Vec3::Y),
        fov_y: p.fov,
        aspect: p.aspect_ratio,
        near: p.near,
        far,
        depth: cullet::DepthConvention::Reversed,
    }
}

/// An entity's world transform as Cullet's.
pub fn world_transform(world: &World, entity: Entity) -> glam::Affine3A {
    glam::Affine3A::from_cols_array(&world.get::<GlobalTransform>(entity).unwrap().affine().to_cols_array())
}
