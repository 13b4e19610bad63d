//! The camera the pipeline culls for, and camera paths (timed keys interpolated smoothly).

use bevy_ecs::prelude::*;
use glam::dcamera::rh::proj::{directx, opengl};
use glam::dcamera::rh::view;
use glam::{DMat4, DVec3, Mat4, Vec3};

/// How clip-space depth maps the near and far planes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum DepthConvention {
    /// `0 <= z <= w`, near at 0 (Direct3D, Vulkan, wgpu).
    Standard,
    /// `0 <= z <= w`, near at 1, far (possibly infinite) at 0: the most precise choice for floating-point depth.
    #[default]
    Reversed,
    /// `-w <= z <= w`, near at -1 (OpenGL).
    NegativeOneToOne,
}

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
    /// The focal length in pixels in a frame `viewport_height` pixels tall: a length at distance `d` straight
    /// ahead spans `length * focal / d` pixels.
    pub fn focal_pixels(&self, viewport_height: u32) -> f32 {
        0.5 * viewport_height as f32 / (0.5 * self.fov_y).tan()
    }

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

    /// The affine map from a depth-buffer value (wgpu's 0..1, an OpenGL-style depth already mapped there as the
    /// engine's draw maps it) to `1/w`, the depth the HZB holds: `1/w = depth * scale + offset`, returned as
    /// `(scale, offset)`. Exact for every convention and for an infinite far plane, since a perspective
    /// projection's depth is affine in `1/w`.
    pub fn inv_w_from_depth(&self) -> (f64, f64) {
        let projection = self.clip_from_view_f64();
        // A view-space point at distance d: clip z = -m22 d + m32, clip w = d, so depth = -m22 + m32 / d.
        let (mut alpha, mut beta) = (-projection.z_axis.z, projection.w_axis.z);
        if self.depth == DepthConvention::NegativeOneToOne {
            (alpha, beta) = (0.5 * (alpha + 1.0), 0.5 * beta);
        }
        (1.0 / beta, -alpha / beta)
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

    /// Whether every field is in its documented range: a finite position, a finite non-zero `forward`, a
    /// finite `up`, `fov_y` in (0, pi), a finite `aspect` > 0, a finite `near` > 0 and a finite `far` beyond
    /// `near` (or none).
    ///
    /// # Errors
    /// The first field out of range, named.
    pub fn validate(&self) -> Result<(), &'static str> {
        let finite = |v: Vec3| v.is_finite();
        if !finite(self.position) {
            return Err("position is not finite");
        }
        if !finite(self.forward) || self.forward == Vec3::ZERO {
            return Err("forward is not a finite non-zero direction");
        }
        if !finite(self.up) {
            return Err("up is not finite");
        }
        if !(self.fov_y > 0.0 && self.fov_y < std::f32::consts::PI) {
            return Err("fov_y is not in (0, pi)");
        }
        if !(self.aspect.is_finite() && self.aspect > 0.0) {
            return Err("aspect is not finite and positive");
        }
        if !(self.near.is_finite() && self.near > 0.0) {
            return Err("near is not finite and positive");
        }
        if self.far.is_some_and(|far| !(far.is_finite() && far > self.near)) {
            return Err("far is not finite and beyond near");
        }
        Ok(())
    }
}

/// One key of a camera path.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraKey {
    /// Time of the key in seconds.
    pub t: f32,
    /// Eye position.
    pub position: Vec3,
    /// Point looked at.
    pub look_at: Vec3,
}

/// A timed camera path: Catmull-Rom interpolation of positions and look-at points between keys.
///
/// As JSON ([`CameraPath::from_json`]): `{"fov_y_deg": 60, "near": 0.1, "far": null, "keys": [{"t": 0.0,
/// "position": [x, y, z], "look_at": [x, y, z]}, ...]}`, `far: null` meaning an infinite far plane.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
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

/// Why a camera path was refused.
#[derive(Debug, thiserror::Error)]
pub enum CameraPathError {
    /// Not valid JSON, or not the documented shape.
    #[error("camera path is not valid: {0}")]
    Json(#[from] serde_json::Error),
    /// Valid JSON that describes no usable camera.
    #[error("camera path is not usable: {0}")]
    Invalid(String),
}

impl CameraPath {
    /// Parses and checks a camera path: at least one key, times strictly increasing, every number finite,
    /// field of view in (0, 180) degrees, near > 0, far (if any) beyond near, never looking at the eye.
    pub fn from_json(json: &str) -> Result<Self, CameraPathError> {
        let path: Self = serde_json::from_str(json)?;
        let invalid = |why: String| Err(CameraPathError::Invalid(why));
        if path.keys.is_empty() {
            return invalid("no keys".into());
        }
        if !(path.fov_y_deg > 0.0 && path.fov_y_deg < 180.0) {
            return invalid(format!("fov_y_deg {} is not in (0, 180)", path.fov_y_deg));
        }
        if !(path.near > 0.0 && path.near.is_finite()) {
            return invalid(format!("near {} is not a positive number", path.near));
        }
        if let Some(far) = path.far.filter(|&far| !(far > path.near && far.is_finite())) {
            return invalid(format!("far {far} is not beyond near {}", path.near));
        }
        for (i, key) in path.keys.iter().enumerate() {
            if !key.t.is_finite() || !key.position.is_finite() || !key.look_at.is_finite() {
                return invalid(format!("key {i} has a non-finite number"));
            }
            if key.position == key.look_at {
                return invalid(format!("key {i} looks at its own position"));
            }
            if i > 0 && key.t <= path.keys[i - 1].t {
                return invalid(format!("key {i} time {} does not follow {}", key.t, path.keys[i - 1].t));
            }
        }
        Ok(path)
    }

    /// The same path moved by `offset` (positions and look-at points alike).
    pub fn translated(&self, offset: Vec3) -> Self {
        let keys = self
            .keys
            .iter()
            .map(|k| CameraKey { position: k.position + offset, look_at: k.look_at + offset, ..*k })
            .collect();
        Self { keys, ..self.clone() }
    }

    /// Duration from the first to the last key.
    pub fn duration(&self) -> f32 {
        match (self.keys.first(), self.keys.last()) {
            (Some(first), Some(last)) => last.t - first.t,
            _ => 0.0,
        }
    }

    /// Position and look-at point at time `t`, clamped to the path.
    pub fn sample(&self, t: f32) -> (Vec3, Vec3) {
        let (origin, position, look_at) = self.sample_relative(t);
        (origin + position, origin + look_at)
    }

    /// [`CameraPath::sample`] relative to the first key's position, returned first: interpolating small
    /// numbers keeps the view direction exact however far the path lies from the world origin.
    fn sample_relative(&self, t: f32) -> (Vec3, Vec3, Vec3) {
        let keys = &self.keys;
        let origin = keys.first().map_or(Vec3::ZERO, |k| k.position);
        let relative = |k: &CameraKey| (k.position - origin, k.look_at - origin);
        match keys.len() {
            0 => (Vec3::ZERO, Vec3::ZERO, Vec3::NEG_Z),
            1 => (origin, Vec3::ZERO, keys[0].look_at - origin),
            n => {
                let t = t.clamp(keys[0].t, keys[n - 1].t);
                let i = keys.partition_point(|k| k.t <= t).clamp(1, n - 1) - 1;
                let (k1, k2) = (relative(&keys[i]), relative(&keys[i + 1]));
                let (k0, k3) = (relative(&keys[i.saturating_sub(1)]), relative(&keys[(i + 2).min(n - 1)]));
                let span = keys[i + 1].t - keys[i].t;
                let u = if span > 0.0 { (t - keys[i].t) / span } else { 0.0 };
                (origin, catmull_rom(k0.0, k1.0, k2.0, k3.0, u), catmull_rom(k0.1, k1.1, k2.1, k3.1, u))
            }
        }
    }

    /// The camera at time `t` for a viewport of `aspect`, reversed depth. Its direction comes from the path's
    /// relative samples, so it stays exact far from the origin.
    pub fn camera_at(&self, t: f32, aspect: f32) -> Camera {
        let (origin, position, look_at) = self.sample_relative(t);
        Camera {
            fov_y: self.fov_y_deg.to_radians(),
            aspect,
            near: self.near,
            far: self.far,
            forward: look_at - position,
            ..Camera::looking_at(origin + position, origin + look_at)
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
    fn depth_maps_back_to_inverse_w_in_every_convention() {
        for depth in [DepthConvention::Standard, DepthConvention::Reversed, DepthConvention::NegativeOneToOne] {
            for far in [None, Some(500.0)] {
                let camera = Camera { depth, far, near: 0.05, ..Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z) };
                let (scale, offset) = camera.inv_w_from_depth();
                for distance in [0.05, 1.0, 37.0, 499.0] {
                    let clip = camera.clip_from_view_f64() * glam::DVec4::new(0.3, -0.2, -distance, 1.0);
                    let mut ndc_z = clip.z / clip.w;
                    if depth == DepthConvention::NegativeOneToOne {
                        ndc_z = 0.5 * (ndc_z + 1.0);
                    }
                    let inv_w = ndc_z * scale + offset;
                    assert!((inv_w * distance - 1.0).abs() < 1e-9, "{depth:?} {far:?} at {distance}: {inv_w}");
                }
            }
        }
    }

    #[test]
    fn camera_paths_parse_from_the_documented_json_and_bad_ones_are_refused() {
        let json = r#"{"fov_y_deg": 60, "near": 0.1, "far": null,
            "keys": [{"t": 0.0, "position": [0, 2, 10], "look_at": [0, 0, 0]},
                     {"t": 5.0, "position": [10, 2, 0], "look_at": [0, 0, 0]}]}"#;
        let path = CameraPath::from_json(json).unwrap();
        assert_eq!(path.far, None);
        assert_eq!(path.keys[1].position, Vec3::new(10.0, 2.0, 0.0));
        assert_eq!(path.duration(), 5.0);
        for (bad, why) in [
            (r#"{"fov_y_deg": 60, "near": 0.1, "far": null, "keys": []}"#, "no keys"),
            (
                r#"{"fov_y_deg": 190, "near": 0.1, "far": null, "keys": [{"t": 0, "position": [0,0,1], "look_at": [0,0,0]}]}"#,
                "fov",
            ),
            (
                r#"{"fov_y_deg": 60, "near": 0.1, "far": 0.05, "keys": [{"t": 0, "position": [0,0,1], "look_at": [0,0,0]}]}"#,
                "far",
            ),
            (
                r#"{"fov_y_deg": 60, "near": 0.1, "far": null, "keys": [{"t": 1, "position": [0,0,1], "look_at": [0,0,0]}, {"t": 1, "position": [0,0,2], "look_at": [0,0,0]}]}"#,
                "follow",
            ),
            (
                r#"{"fov_y_deg": 60, "near": 0.1, "far": null, "keys": [{"t": 0, "position": [0,0,0], "look_at": [0,0,0]}]}"#,
                "own position",
            ),
            (
                r#"{"fov_y_deg": 60, "near": 0.1, "keys": [{"t": 0, "position": [0,0,1], "look_at": [0,0,0]}], "extra": 1}"#,
                "unknown field",
            ),
            ("not json", "expected"),
        ] {
            let error = CameraPath::from_json(bad).unwrap_err().to_string();
            assert!(error.contains(why), "{bad}: {error}");
        }
    }

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
