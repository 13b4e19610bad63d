//! Light views in a Bevy app: for each camera, the shadow cascades of every shadow-mapped directional light,
//! and the cube faces of the point lights and the cone of the spot lights that light its view, are culled in
//! the camera's own frustum pass ([`cullet::culler::ViewCuller::cull_frustum`]), keeping only the casters
//! whose shadows can fall inside the camera's frustum ([`cullet::frustum::View::shadow_casters`]); then each
//! is occlusion culled from its light ([`LightOcclusion`]). [`crate::light_lists`] then writes them to Bevy's
//! per-light visible entities, which Bevy's shadow passes draw.

use crate::NoCulletLightCulling;
use crate::convert;
use bevy_camera::primitives::{CUBE_MAP_FACES, Frustum as BevyFrustum, Sphere};
use bevy_camera::visibility::{InheritedVisibility, RenderLayers};
use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemParam;
use bevy_light::{Cascades, DirectionalLight, PointLight, SpotLight, spot_light_world_from_view};
use bevy_transform::components::{GlobalTransform, Transform};
use cullet::bounds::BoundsStore;
use cullet::camera::DepthConvention;
use cullet::culler::{LightOcclusion, LightViewVisible};
use cullet::frustum::{Frustum, Light, LightView, View, ViewError};
use cullet::visible::VisibleSet;
use glam::{DMat4, Vec3};

/// Which of a light's shadow maps a light view draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(crate) enum ShadowMap {
    /// Cascade `n` of a directional light, for the camera whose view it is.
    Cascade(usize),
    /// Face `n` of a point light's cube map, in Bevy's `CUBE_MAP_FACES` order.
    Face(usize),
    /// A spot light's map.
    Spot,
}

/// One shadow map of a light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct LightMap {
    /// The light.
    pub(crate) light: Entity,
    /// Which of its maps.
    pub(crate) map: ShadowMap,
    /// A lamp's position and range: what lies wholly beyond it is not lit, so casts no shadow that matters.
    pub(crate) reach: Option<(Vec3, f32)>,
    /// Whether the view keeps only the casters that shadow the camera's view, and is occluded from its light:
    /// false for a light with [`crate::NoCulletLightCulling`], whose view keeps every caster of its own.
    pub(crate) narrowed: bool,
}

/// One camera's light views of the frame and what it keeps of them from frame to frame.
#[derive(Default, Debug)]
pub(crate) struct CameraLights {
    /// Each light view's light and shadow map, in the order of `views` (the views that could be built).
    pub(crate) maps: Vec<LightMap>,
    /// Each light view's casters (store slots).
    pub(crate) views: Vec<LightViewVisible>,
    /// Shadow maps whose view could not be built (a degenerate light or cascade): they keep every caster.
    pub(crate) unculled: Vec<LightMap>,
    /// The light views' occlusion, view by view.
    pub(crate) occlusion: LightOcclusion,
    /// Visible sets of views gone, reused for the next frame's.
    pub(crate) spare: Vec<VisibleSet>,
}

/// A directional light as the culling reads it.
type DirectionalItem<'a> = (
    Entity,
    &'a DirectionalLight,
    &'a GlobalTransform,
    &'a Cascades,
    &'a InheritedVisibility,
    Has<NoCulletLightCulling>,
);
/// A point or spot light as the culling reads it.
type LampItem<'a, L> =
    (Entity, &'a L, &'a GlobalTransform, &'a InheritedVisibility, Option<&'a RenderLayers>, Has<NoCulletLightCulling>);

/// The lights a camera's light views are built from.
#[derive(SystemParam)]
pub(crate) struct LightSources<'w, 's> {
    directional: Query<'w, 's, DirectionalItem<'static>>,
    point: Query<'w, 's, LampItem<'static, PointLight>>,
    spot: Query<'w, 's, LampItem<'static, SpotLight>>,
}

impl LightSources<'_, '_> {
    /// The light views of `camera` (entity and its Cullet position), whose frustum is `receivers` and layers
    /// `camera_layers`, with `bevy_frustum` Bevy's frustum of it: every cascade Bevy built for it of each
    /// visible directional light with shadows, and each face of each point light and the map of each spot light
    /// with shadows whose range meets the camera's frustum, as Bevy's own check chooses the lights.
    ///
    /// Each view keeps the casters whose shadows can fall inside `receivers` (where the camera has no frustum,
    /// or the light has [`crate::NoCulletLightCulling`], inside the light's own view). The views of such lights
    /// come last. A map whose view cannot be built is listed in `unculled`.
    pub(crate) fn views_of(
        &self,
        camera: Entity,
        origin: Vec3,
        receivers: Option<&Frustum>,
        camera_layers: &RenderLayers,
        bevy_frustum: &BevyFrustum,
        unculled: &mut Vec<LightMap>,
    ) -> Vec<(LightMap, LightView)> {
        unculled.clear();
        let mut views = Vec::new();
        let mut add = |map: LightMap, built: Result<LightView, ViewError>| match built {
            Ok(view) => views.push((map, view)),
            Err(error) => {
                tracing::warn!("{:?} of light {} keeps every caster: {error}", map.map, map.light);
                unculled.push(map);
            }
        };
        let narrowed_to = |opted_out: bool| if opted_out { None } else { receivers };
        for (entity, light, transform, cascades, inherited, opted_out) in &self.directional {
            if !(light.shadow_maps_enabled && inherited.get()) {
                continue;
            }
            let direction = convert::vec3(transform.forward().into());
            for (index, cascade) in cascades.cascades.get(&camera).into_iter().flatten().enumerate() {
                let clip_from_world = DMat4::from_cols_array(&cascade.clip_from_world.to_cols_array().map(f64::from));
                let built = cascade_view(origin, clip_from_world, direction, narrowed_to(opted_out));
                let map = LightMap { light: entity, map: ShadowMap::Cascade(index), reach: None, narrowed: !opted_out };
                add(map, built);
            }
        }
        let lit = |transform: &GlobalTransform,
                   range: f32,
                   inherited: &InheritedVisibility,
                   layers: Option<&RenderLayers>| {
            let sphere = Sphere { center: transform.translation_vec3a(), radius: range };
            inherited.get()
                && camera_layers.intersects(layers.unwrap_or_default())
                && bevy_frustum.intersects_sphere(&sphere, false)
        };
        for (entity, light, transform, inherited, layers, opted_out) in &self.point {
            if !(light.shadow_maps_enabled && lit(transform, light.range, inherited, layers)) {
                continue;
            }
            let position = convert::vec3(transform.translation());
            let reach = Some((position, light.range));
            for (index, face) in CUBE_MAP_FACES.iter().enumerate() {
                let rotation = Transform::IDENTITY.looking_at(face.target, face.up).rotation;
                let (forward, up) = (rotation * bevy_math::Vec3::NEG_Z, rotation * bevy_math::Vec3::Y);
                let face = lamp_camera(position, forward, up, std::f32::consts::FRAC_PI_2, light.shadow_map_near_z);
                let map = LightMap { light: entity, map: ShadowMap::Face(index), reach, narrowed: !opted_out };
                add(map, lamp_view(face, light.range, narrowed_to(opted_out)));
            }
        }
        for (entity, light, transform, inherited, layers, opted_out) in &self.spot {
            if !(light.shadow_maps_enabled && lit(transform, light.range, inherited, layers)) {
                continue;
            }
            let position = convert::vec3(transform.translation());
            let basis = spot_light_world_from_view(transform).matrix3;
            let (forward, up) = (-basis.z_axis, basis.y_axis);
            let cone =
                lamp_camera(position, forward.into(), up.into(), 2.0 * light.outer_angle, light.shadow_map_near_z);
            let reach = Some((position, light.range));
            let map = LightMap { light: entity, map: ShadowMap::Spot, reach, narrowed: !opted_out };
            add(map, lamp_view(cone, light.range, narrowed_to(opted_out)));
        }
        views.sort_by_key(|(map, _)| !map.narrowed);
        views
    }
}

/// Drops from `view` the casters whose box lies wholly beyond a lamp's `reach` (position and range), as Bevy's
/// own check does with its oriented boxes (a world box holds its oriented box, so this keeps at least what
/// Bevy keeps); a little slack keeps the boxes that only touch the sphere.
pub(crate) fn keep_within_reach(store: &BoundsStore, view: &mut LightViewVisible, (center, range): (Vec3, f32)) {
    let limit = range * (1.0 + 1e-5) + 1e-5;
    let beyond: Vec<usize> = view
        .visible
        .iter()
        .filter(|&slot| {
            let bounds = store.get(slot).expect("a kept slot is stored");
            let outside = ((bounds.center - center).abs() - bounds.half_extent).max(Vec3::ZERO);
            outside.length_squared() > limit * limit
        })
        .collect();
    for &slot in &beyond {
        view.visible.set(slot, false);
    }
    view.kept -= beyond.len();
}

/// The camera of a lamp's shadow map at `position` looking along `forward`, square, `fov` radians wide, its
/// near plane at `near` (far set by [`lamp_view`]), reversed depth as Bevy draws it.
fn lamp_camera(position: Vec3, forward: bevy_math::Vec3, up: bevy_math::Vec3, fov: f32, near: f32) -> cullet::Camera {
    cullet::Camera {
        position,
        forward: convert::vec3(forward),
        up: convert::vec3(up),
        fov_y: fov,
        aspect: 1.0,
        near,
        far: None,
        depth: DepthConvention::Reversed,
    }
}

/// The light view of a lamp's map drawn by `camera`, cut at the light's `range` (nothing beyond it is lit, so
/// nothing beyond it casts a shadow that matters), keeping the casters that shadow `receivers`.
fn lamp_view(mut camera: cullet::Camera, range: f32, receivers: Option<&Frustum>) -> Result<LightView, ViewError> {
    camera.far = Some(range);
    let frustum = camera.frustum()?;
    let light = Light::Point { position: camera.position };
    Ok(LightView {
        view: View::shadow_casters(frustum, light, receivers.unwrap_or(&frustum))?,
        clip_from_relative: camera.clip_from_relative_f64(),
        origin: camera.position,
        depth: camera.depth,
        near: Some(camera.near),
    })
}

/// The light view of a directional light's cascade drawn with `clip_from_world` (Bevy's orthographic box,
/// reversed depth, whose near plane Bevy clamps rather than clips), travelling along `direction`, relative to
/// `origin`, keeping the casters that shadow `receivers`.
fn cascade_view(
    origin: Vec3,
    clip_from_world: DMat4,
    direction: Vec3,
    receivers: Option<&Frustum>,
) -> Result<LightView, ViewError> {
    let clip_from_relative = clip_from_world * DMat4::from_translation(origin.as_dvec3());
    let frustum = Frustum::from_clip_from_relative_f64(origin, clip_from_relative, DepthConvention::Reversed)?;
    let light = Light::Directional { direction };
    Ok(LightView {
        view: View::shadow_casters(frustum, light, receivers.unwrap_or(&frustum))?,
        clip_from_relative,
        origin,
        depth: DepthConvention::Reversed,
        near: None,
    })
}
