//! The camera the pipeline culls for, and camera paths (timed keys interpolated smoothly).

use crate::frustum::{DepthConvention, Frustum, FrustumError};
use bevy_ecs::prelude::*;
use glam::dcamera::rh::proj::{directx, opengl};
use glam::dcamera::rh::view;
use glam::{DMat4, DVec3, Mat4, Vec3};

/// A perspective camera. Its matrices are camera-relative (eye at the origin) so that culling and rendering
/// stay precise far from the world origin; see [`crate::bounds`].
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position in world space.
    pub position: Vec3,
    /// Viewing direction (need not be normalized; must not be parallel to `up`).
    pub forward: Vec3,
    /// Approximate up direction.
    pub up: Vec3,
    /// Vertical field of view in radians, in (0, pi).
    pub fov_y: f32,
    /// Width over height of the viewport.
    pub aspect: f32,
    /// Distance of the near plane, > 0.
    pub near: f32,
    /// Distance of the far plane, or `None` for an infinite far plane.
    pub far: Option<f32>,
    /// How clip-space depth is laid out.
    pub depth: DepthConvention,
}

impl Camera {
    /// A camera at `position` looking at `target`, with 60 degrees vertical field of view, 16:9, near 0.1, an
    /// infinite far plane and reversed depth.
    pub fn looking_at(position: Vec3, target: Vec3) -> Self {
        Self {
            position,
            forward: target - position,
            up: Vec3::Y,
            fov_y: 60f32.to_radians(),
            aspect: 16.0 / 9.0,
            near: 0.1,
            far: None,
            depth: DepthConvention::Reversed,
        }
    }

    /// View matrix with the eye at the origin: rotation only.
    pub fn view_from_relative(&self) -> Mat4 {
        self.view_from_relative_f64().as_mat4()
    }

    /// [`Camera::view_from_relative`] in f64. `forward` is normalized here: glam's look-to matrix expects a
    /// unit direction and would otherwise scale the view.
    pub fn view_from_relative_f64(&self) -> DMat4 {
        view::look_to_mat4(DVec3::ZERO, self.forward.as_dvec3().normalize(), self.up.as_dvec3())
    }

    /// Projection matrix for this camera's depth convention.
    pub fn clip_from_view(&self) -> Mat4 {
        self.clip_from_view_f64().as_mat4()
    }

    /// The projection in f64, from which culling planes are extracted: an f32 projection loses the far plane
    /// when far/near exceeds about 1e6.
    pub fn clip_from_view_f64(&self) -> DMat4 {
        let (fov, aspect, near) = (self.fov_y as f64, self.aspect as f64, self.near as f64);
        match (self.depth, self.far.map(f64::from)) {
            (DepthConvention::Reversed, None) => directx::perspective_infinite_reverse(fov, aspect, near),
            // Swapping near and far of the standard matrix maps near to 1 and far to 0.
            (DepthConvention::Reversed, Some(far)) => directx::perspective(fov, aspect, far, near),
            (DepthConvention::Standard, None) => directx::perspective_infinite(fov, aspect, near),
            (DepthConvention::Standard, Some(far)) => directx::perspective(fov, aspect, near, far),
            (DepthConvention::NegativeOneToOne, Some(far)) => opengl::perspective(fov, aspect, near, far),
            (DepthConvention::NegativeOneToOne, None) => {
                // The limit of the OpenGL matrix as far goes to infinity: z_clip = -z - 2 near, w = -z.
                let f = 1.0 / (0.5 * fov).tan();
                DMat4::from_cols_array(&[
                    f / aspect,
                    0.0,
                    0.0,
                    0.0, //
                    0.0,
                    f,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    -1.0,
                    -1.0,
                    0.0,
                    0.0,
                    -2.0 * near,
                    0.0,
                ])
            }
        }
    }

    /// Clip from camera-relative world space: `clip_from_view * view_from_relative`. Apply it to
    /// `world_point - position`.
    pub fn clip_from_relative(&self) -> Mat4 {
        self.clip_from_relative_f64().as_mat4()
    }

    /// [`Camera::clip_from_relative`] in f64.
    pub fn clip_from_relative_f64(&self) -> DMat4 {
        self.clip_from_view_f64() * self.view_from_relative_f64()
    }

    /// Clip from absolute world space; loses precision far from the origin, prefer
    /// [`Camera::clip_from_relative`].
    pub fn clip_from_world(&self) -> Mat4 {
        self.clip_from_relative() * Mat4::from_translation(-self.position)
    }

    /// The camera-relative culling frustum, its planes extracted from the f64 matrices.
    pub fn frustum(&self) -> Result<Frustum, FrustumError> {
        Frustum::from_clip_from_relative_f64(self.position, self.clip_from_relative_f64(), self.depth)
    }
}

/// One key of a camera path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraKey {
    /// Time of the key in seconds.
    pub t: f32,
    /// Eye position.
    pub position: Vec3,
    /// Point looked at.
    pub look_at: Vec3,
}

/// A timed camera path: Catmull-Rom interpolation of positions and look-at points between keys.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    /// Vertical field of view in degrees.
    pub fov_y_deg: f32,
    /// Near plane distance.
    pub near: f32,
    /// Far plane distance, `None` for infinite.
    pub far: Option<f32>,
    /// Keys in increasing time.
    pub keys: Vec<CameraKey>,
}

impl CameraPath {
    /// Duration from the first to the last key.
    pub fn duration(&self) -> f32 {
        match (self.keys.first(), self.keys.last()) {
            (Some(first), Some(last)) => last.t - first.t,
            _ => 0.0,
        }
    }

    /// Position and look-at point at time `t`, clamped to the path.
    pub fn sample(&self, t: f32) -> (Vec3, Vec3) {
        let keys = &self.keys;
        match keys.len() {
            0 => (Vec3::ZERO, Vec3::NEG_Z),
            1 => (keys[0].position, keys[0].look_at),
            n => {
                let t = t.clamp(keys[0].t, keys[n - 1].t);
                let i = keys.partition_point(|k| k.t <= t).clamp(1, n - 1) - 1;
                let (k1, k2) = (keys[i], keys[i + 1]);
                let (k0, k3) = (keys[i.saturating_sub(1)], keys[(i + 2).min(n - 1)]);
                let span = k2.t - k1.t;
                let u = if span > 0.0 { (t - k1.t) / span } else { 0.0 };
                (
                    catmull_rom(k0.position, k1.position, k2.position, k3.position, u),
                    catmull_rom(k0.look_at, k1.look_at, k2.look_at, k3.look_at, u),
                )
            }
        }
    }

    /// The camera at time `t` for a viewport of `aspect`, reversed depth.
    pub fn camera_at(&self, t: f32, aspect: f32) -> Camera {
        let (position, look_at) = self.sample(t);
        Camera {
            fov_y: self.fov_y_deg.to_radians(),
            aspect,
            near: self.near,
            far: self.far,
            ..Camera::looking_at(position, look_at)
        }
    }
}

fn catmull_rom(p0: Vec3, p1: Vec3, p2: Vec3, p3: Vec3, u: f32) -> Vec3 {
    let (u2, u3) = (u * u, u * u * u);
    0.5 * ((2.0 * p1)
        + (p2 - p0) * u
        + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * u2
        + (3.0 * p1 - p0 - 3.0 * p2 + p3) * u3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_passes_through_its_keys() {
        let path = CameraPath {
            fov_y_deg: 60.0,
            near: 0.1,
            far: None,
            keys: (0..4)
                .map(|i| CameraKey { t: i as f32, position: Vec3::splat(i as f32 * 2.0), look_at: Vec3::ZERO })
                .collect(),
        };
        for key in &path.keys {
            assert!(path.sample(key.t).0.abs_diff_eq(key.position, 1e-5));
        }
        assert!(path.sample(10.0).0.abs_diff_eq(Vec3::splat(6.0), 1e-5));
    }
}
