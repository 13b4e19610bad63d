//! Bevy's math (glam 0.33, through `bevy_math`) to Cullet's (glam 0.34), and Bevy's cameras to Cullet's.

use bevy_camera::Projection;
use bevy_camera::primitives::Aabb;
use bevy_transform::components::GlobalTransform;
use cullet::camera::DepthConvention;
use cullet::culler::ViewInput;
use cullet::frustum::Frustum;
use cullet::{Camera, LocalBounds};
use glam::{Affine3A, DMat4, DQuat, Mat4, Vec3};

/// A `bevy_math` vector as Cullet's.
pub(crate) fn vec3(v: bevy_math::Vec3) -> Vec3 {
    Vec3::from_array(v.to_array())
}

/// A `GlobalTransform` as Cullet's affine transform.
pub(crate) fn affine(transform: &GlobalTransform) -> Affine3A {
    Affine3A::from_cols_array(&transform.affine().to_cols_array())
}

/// A Bevy `Aabb` (local space) as Cullet's local bounds.
pub(crate) fn local_bounds(aabb: &Aabb) -> LocalBounds {
    LocalBounds {
        center: Vec3::from_array(aabb.center.to_array()),
        half_extent: Vec3::from_array(aabb.half_extents.to_array()),
    }
}

/// What Cullet sees of a camera at `transform` with `projection`: the culling frustum (camera-relative planes)
/// or why there is none, and the Cullet camera of a perspective projection, which the occlusion stage needs
/// (orthographic and custom projections get frustum culling only).
///
/// A perspective projection becomes a Cullet [`Camera`] with Bevy's field of view, aspect ratio, near plane,
/// and Bevy's culling far plane (infinite where it is not finite or not beyond near), reversed depth. Other
/// projections give a frustum from their `clip_from_view` matrix, which Bevy lays out with reversed depth.
/// Scale in the camera's transform is ignored, as Bevy's renderer expects none.
pub(crate) fn view_of(transform: &GlobalTransform, projection: &Projection) -> ViewInput {
    let (_, rotation, translation) = transform.to_scale_rotation_translation();
    let position = vec3(translation);
    let forward = vec3(rotation * bevy_math::Vec3::NEG_Z);
    let up = vec3(rotation * bevy_math::Vec3::Y);
    let clip_from_view = Mat4::from_cols_array(&projection.get_clip_from_view().to_cols_array());
    if let Projection::Perspective(perspective) = projection {
        let far = (perspective.far.is_finite() && perspective.far > perspective.near).then_some(perspective.far);
        let camera = Camera {
            position,
            forward,
            up,
            fov_y: perspective.fov,
            aspect: perspective.aspect_ratio,
            near: perspective.near,
            far,
            depth: DepthConvention::Reversed,
        };
        return ViewInput::of_camera(&camera);
    }
    let view_from_relative = DMat4::from_quat(DQuat::from_array(rotation.to_array().map(f64::from))).inverse();
    let clip_from_relative = clip_from_view.as_dmat4() * view_from_relative;
    ViewInput {
        frustum: Frustum::from_clip_from_relative_f64(position, clip_from_relative, DepthConvention::Reversed),
        camera: None,
    }
}
