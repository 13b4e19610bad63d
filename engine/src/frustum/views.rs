//! Many views a frame: cameras, shadow cascades, cube-map faces, split screens, culled in one pass over the
//! bounds ([`cull_views`]).
//!
//! Each [`View`] gets its own visible set. The pass reads each word of 64 objects once and tests it against
//! every view while it is in cache; each view runs its own group hierarchy, so a view that sees little of the
//! world costs little.
//!
//! # Shadow casters
//! A light view ([`View::shadow_casters`]) keeps the objects whose shadows can fall on what the camera sees.
//! With `V` the light view's frustum and `C` the camera's (the *receivers*), an object `O` is **needed** by the
//! light view when the region it shadows meets `V ∩ C`:
//! - for a [`Light::Directional`] light travelling along `d`: some `p + t d` with `p` in `O`, `t >= 0`, lies in
//!   `V ∩ C`;
//! - for a [`Light::Point`] at `l`: some `l + s (p - l)` with `p` in `O`, `s >= 1`, lies in `V ∩ C`.
//!
//! So a caster between the light and `V`'s near plane is kept (it shadows what the map covers: a renderer
//! clamps its depth, "pancaking"), and a caster inside `V` whose shadow falls outside the camera's frustum is
//! dropped. `O` stands for its bounding box here; receivers are the camera's whole frustum, not only its
//! visible surfaces, so the test is conservative against the exact shadowing too.
//!
//! The test is a plane test on the swept box: it drops `O` when one plane of `V` or `C` has the whole swept
//! box outside, by more than the same rounding slack as the frustum test. It is exact per plane (it may keep
//! a box whose sweep misses `V ∩ C` near an edge, never the reverse).

use super::{
    Frustum, FrustumError, GroupClass, GroupLanes, MAX_VIEWS_PER_PASS, PLANE_TEST_TOLERANCE, Plane, SimdBackend,
    cull_pass, lane_magnitudes,
};
use crate::bounds::{BoundsStore, GroupBounds, SIMD_LANES};
use crate::camera::Camera;
use crate::camera::DepthConvention;
use crate::visible::VisibleSet;
use glam::dcamera::rh::proj::directx;
use glam::dcamera::rh::view;
use glam::{DMat3, DMat4, DVec3, Vec3};

/// Where a light view's light comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// A light at infinity (the sun): `direction` is the way its light travels, from the light into the scene.
    /// It need not be normalized; it must be finite and not zero.
    Directional {
        /// Direction of travel, world space.
        direction: Vec3,
    },
    /// A point light (or a spot light's apex), world space.
    Point {
        /// Position of the light.
        position: Vec3,
    },
}

/// One view to cull for: a camera, a light view, a reflection probe's face.
///
/// Build it from any [`Frustum`] (perspective or orthographic, any [`DepthConvention`]), or as a light view
/// that keeps only the shadow casters the camera can see shadows of ([`View::shadow_casters`]).
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    test: ViewTest,
}

#[derive(Clone, Debug, PartialEq)]
enum ViewTest {
    Frustum(Frustum),
    Casters(Box<CasterVolume>),
}

/// Why a light view could not be built.
#[derive(thiserror::Error, Clone, Copy, Debug, PartialEq)]
pub enum ViewError {
    /// The light's direction or position is not finite, or the direction is zero.
    #[error("the light's direction or position is not finite, or its direction is zero")]
    BadLight,
    /// A frustum of the view could not be built.
    #[error(transparent)]
    Frustum(#[from] FrustumError),
}

impl View {
    /// A view that keeps what may lie inside `frustum`: the same bits as [`super::cull_frustum`] gives.
    pub fn new(frustum: Frustum) -> Self {
        Self { test: ViewTest::Frustum(frustum) }
    }

    /// A light view that keeps the shadow casters its light can throw a shadow from onto `receivers`, the
    /// camera's frustum, inside `light_view`, the light's own frustum (a cascade, a cube face, a spot cone).
    /// See the module's definition of what is kept.
    ///
    /// # Errors
    /// [`ViewError::BadLight`] for a light that is not finite or a zero direction.
    pub fn shadow_casters(light_view: Frustum, light: Light, receivers: &Frustum) -> Result<Self, ViewError> {
        Ok(Self { test: ViewTest::Casters(Box::new(CasterVolume::new(&light_view, light, receivers)?)) })
    }

    /// Whether this view keeps only shadow casters ([`View::shadow_casters`]).
    pub fn is_light_view(&self) -> bool {
        matches!(self.test, ViewTest::Casters(_))
    }

    pub(super) fn classify_group(&self, group: &GroupBounds, backend: SimdBackend) -> GroupClass {
        let (outside, inside) = self.classify_groups(std::slice::from_ref(group), backend);
        match (outside & 1, inside & 1) {
            (1, _) => GroupClass::Outside,
            (_, 1) => GroupClass::Inside,
            _ => GroupClass::Crossing,
        }
    }

    #[inline]
    pub(super) fn classify_groups(&self, groups: &[GroupBounds], backend: SimdBackend) -> (u8, u8) {
        match &self.test {
            ViewTest::Frustum(frustum) => frustum.classify_groups_with(groups, backend),
            ViewTest::Casters(volume) => volume.classify_groups(groups, backend),
        }
    }

    #[inline]
    pub(super) fn cull_word(
        &self,
        store: &BoundsStore,
        base: usize,
        backend: SimdBackend,
        planes: Option<&mut [u8]>,
    ) -> u64 {
        match &self.test {
            ViewTest::Frustum(frustum) => frustum.cull_word_with(store, base, backend, planes),
            ViewTest::Casters(volume) => volume.cull_word(store, base, backend),
        }
    }
}

/// Culls every object of `store` for every view of `views`, in one parallel pass: `visible[i]` (resized to the
/// store) gets view `i`'s set, and the returned counts its number of objects. `visible` is resized to
/// `views.len()` sets, reusing their allocations.
///
/// A [`View::new`] view gives the same bits as [`super::cull_frustum`] with its frustum.
///
/// # Example
/// ```
/// use cullet::frustum::{Light, View, cube_face_cameras, cull_views};
/// use cullet::{BoundsStore, Camera, WorldBounds};
/// use glam::Vec3;
///
/// let mut store = BoundsStore::default();
/// let entity = bevy_ecs::entity::Entity::from_raw_u32(1).unwrap();
/// let bounds = WorldBounds::new(entity, Vec3::new(0.0, 0.0, -5.0), Vec3::splat(0.5)).unwrap();
/// store.insert(entity, &bounds).unwrap();
/// let camera = Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z).frustum().unwrap();
/// let mut views = vec![View::new(camera)];
/// let lamp = Vec3::new(0.0, 4.0, -5.0);
/// for face in cube_face_cameras(lamp, 0.05, Some(20.0)) {
///     let face = face.frustum().unwrap();
///     views.push(View::shadow_casters(face, Light::Point { position: lamp }, &camera).unwrap());
/// }
/// let mut visible = Vec::new();
/// let counts = cull_views(&store, &views, &mut visible);
/// assert_eq!(counts[0], 1); // the camera sees the box
/// assert_eq!(counts[1..].iter().sum::<usize>(), 1); // one face of the lamp, straight below it, casts it
/// ```
pub fn cull_views(store: &BoundsStore, views: &[View], visible: &mut Vec<VisibleSet>) -> Vec<usize> {
    cull_views_with(store, views, SimdBackend::Auto, visible)
}

/// [`cull_views`] with a chosen backend; every backend gives the same bits.
pub fn cull_views_with(
    store: &BoundsStore,
    views: &[View],
    backend: SimdBackend,
    visible: &mut Vec<VisibleSet>,
) -> Vec<usize> {
    visible.resize_with(views.len(), VisibleSet::default);
    // Views past a pass's capacity go in further passes.
    let passes = views.chunks(MAX_VIEWS_PER_PASS).zip(visible.chunks_mut(MAX_VIEWS_PER_PASS));
    passes
        .flat_map(|(views, sets)| {
            let outputs = sets.iter_mut().map(|set| (set, None)).collect();
            cull_pass(store, views, backend, outputs)
        })
        .collect()
}

/// A light whose views follow the camera each frame: what the pipeline's [`crate::pipeline::LightViews`] lists.
#[derive(Clone, Debug, PartialEq)]
pub enum LightSource {
    /// A sun's shadow cascades: one light view ([`cascade_frustum`]) per consecutive pair of `splits`, view
    /// distances from the camera in increasing order.
    Sun {
        /// The way its light travels (need not be normalized).
        direction: Vec3,
        /// Cascade boundaries, e.g. `[0.1, 12.0, 40.0, 120.0, 400.0]` for four cascades.
        splits: Vec<f32>,
    },
    /// A point light's six cube faces ([`cube_face_cameras`]).
    Lamp {
        /// World position.
        position: Vec3,
        /// Near distance of its faces, > 0.
        near: f32,
        /// Far distance of its faces, or `None` for infinite.
        range: Option<f32>,
    },
}

/// One light view of a frame: what it culls with, and the matrix its shadow map is drawn with.
#[derive(Clone, Debug, PartialEq)]
pub struct LightView {
    /// The caster view ([`View::shadow_casters`]) for the frame's camera.
    pub view: View,
    /// Clip from `origin`-relative world space, in f64.
    pub clip_from_relative: DMat4,
    /// The world point `clip_from_relative` is relative to.
    pub origin: Vec3,
    /// The clip-space depth convention of `clip_from_relative`.
    pub depth: DepthConvention,
    /// The near distance of a perspective view (a lamp's face, whose `clip_from_relative` gives `w` as the
    /// distance along its axis); `None` for a sun's orthographic cascade, whose shadow map clamps the depth
    /// of what lies nearer the light than its near plane rather than clipping it.
    pub near: Option<f32>,
}

impl LightSource {
    /// A short name of its view `index` (in [`LightSource::light_views`]' order), for tables and displays:
    /// `sun cascade 1`, or `lamp -y`.
    pub fn view_name(&self, index: usize) -> String {
        match self {
            Self::Sun { .. } => format!("sun cascade {}", index + 1),
            Self::Lamp { .. } => {
                let face = ["+x", "-x", "+y", "-y", "+z", "-z"].get(index).copied().unwrap_or("?");
                format!("lamp {face}")
            }
        }
    }

    /// Its light views for `camera` (the receivers): a sun's cascades in order, or a lamp's faces in
    /// [`cube_face_cameras`]' order.
    ///
    /// # Errors
    /// [`ViewError`] for a light or camera that gives no valid frustum (splits not increasing from 0 or more,
    /// a direction or position that is not finite, a near distance that is not positive).
    pub fn light_views(&self, camera: &Camera) -> Result<Vec<LightView>, ViewError> {
        let receivers = camera.frustum()?;
        match self {
            Self::Sun { direction, splits } => splits
                .windows(2)
                .map(|split| {
                    let light = Light::Directional { direction: *direction };
                    let matrix = cascade_clip_from_relative(camera, *direction, split[0], split[1])?;
                    let frustum =
                        Frustum::from_clip_from_relative_f64(camera.position, matrix, DepthConvention::Standard)?;
                    Ok(LightView {
                        view: View::shadow_casters(frustum, light, &receivers)?,
                        clip_from_relative: matrix,
                        origin: camera.position,
                        depth: DepthConvention::Standard,
                        near: None,
                    })
                })
                .collect(),
            Self::Lamp { position, near, range } => cube_face_cameras(*position, *near, *range)
                .iter()
                .map(|face| {
                    let light = Light::Point { position: *position };
                    Ok(LightView {
                        view: View::shadow_casters(face.frustum()?, light, &receivers)?,
                        clip_from_relative: face.clip_from_relative_f64(),
                        origin: face.position,
                        depth: face.depth,
                        near: Some(face.near),
                    })
                })
                .collect(),
        }
    }
}

/// The frustum of a directional light's cascade: an orthographic box looking along `direction` that holds the
/// part of `camera`'s frustum between view distances `near` and `far` (its bounding sphere, so the box does
/// not change size as the camera turns). Planes are relative to the camera's position, standard depth.
///
/// Its near plane is the sphere's: casters nearer the light are kept by [`View::shadow_casters`] all the same.
///
/// # Errors
/// [`FrustumError`] where the camera, the direction or the distances give no finite, non-empty box
/// (`0 <= near < far` and a finite `far` are required).
pub fn cascade_frustum(camera: &Camera, direction: Vec3, near: f32, far: f32) -> Result<Frustum, FrustumError> {
    let clip_from_relative = cascade_clip_from_relative(camera, direction, near, far)?;
    Frustum::from_clip_from_relative_f64(camera.position, clip_from_relative, DepthConvention::Standard)
}

/// The clip-from-relative matrix of [`cascade_frustum`]'s box, for `camera.position`-relative points, in f64:
/// what a renderer draws the cascade's shadow map with.
///
/// # Errors
/// As [`cascade_frustum`].
pub fn cascade_clip_from_relative(
    camera: &Camera,
    direction: Vec3,
    near: f32,
    far: f32,
) -> Result<DMat4, FrustumError> {
    let (near, far) = (f64::from(near), f64::from(far));
    let direction = direction.as_dvec3();
    if !(0.0 <= near && near < far && far.is_finite() && direction.is_finite() && direction.length() > 0.0) {
        return Err(FrustumError::NonFinite);
    }
    // The slice's corners, camera-relative: the view's inverse rotation applied to its view-space corners.
    let relative_from_view = camera.view_from_relative_f64().inverse();
    let tan_y = (0.5 * f64::from(camera.fov_y)).tan();
    let tan_x = tan_y * f64::from(camera.aspect);
    let corners = [near, far].into_iter().flat_map(|distance| {
        [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)].map(|(sx, sy)| {
            relative_from_view.transform_point3(DVec3::new(sx * tan_x * distance, sy * tan_y * distance, -distance))
        })
    });
    let corners: Vec<DVec3> = corners.collect();
    let center = corners.iter().sum::<DVec3>() / corners.len() as f64;
    let radius = corners.iter().map(|c| c.distance(center)).fold(0.0, f64::max);
    if !(radius.is_finite() && radius > 0.0) {
        return Err(FrustumError::NonFinite);
    }
    let direction = direction.normalize();
    let up = if direction.y.abs() < 0.99 { DVec3::Y } else { DVec3::X };
    let light_from_relative = view::look_to_mat4(center, direction, up);
    let clip_from_light = directx::orthographic(-radius, radius, -radius, radius, -radius, radius);
    Ok(clip_from_light * light_from_relative)
}

/// The cameras of the six 90-degree faces of a cube map at `position` (+X, -X, +Y, -Y, +Z, -Z, with the usual
/// cube-map up vectors), each with near distance `near` and far distance `far` (`None`: infinite), reversed
/// depth. [`Camera::frustum`] gives each face's frustum, and reports a near distance that is not positive.
pub fn cube_face_cameras(position: Vec3, near: f32, far: Option<f32>) -> [Camera; 6] {
    [
        (Vec3::X, Vec3::NEG_Y),
        (Vec3::NEG_X, Vec3::NEG_Y),
        (Vec3::Y, Vec3::Z),
        (Vec3::NEG_Y, Vec3::NEG_Z),
        (Vec3::Z, Vec3::NEG_Y),
        (Vec3::NEG_Z, Vec3::NEG_Y),
    ]
    .map(|(forward, up)| Camera {
        position,
        forward,
        up,
        fov_y: std::f32::consts::FRAC_PI_2,
        aspect: 1.0,
        near,
        far,
        depth: DepthConvention::Reversed,
    })
}

/// The sweep's reach where `V` has no far plane: far beyond any box, yet finite, so that a plane the sweep moves
/// away from (`climb` 0) still rejects (0 times an infinite length would be NaN).
const UNBOUNDED_REACH: f32 = 1e30;

/// Most planes a caster volume has: a light frustum's six and the camera's six.
const MAX_VOLUME_PLANES: usize = 12;

/// `V ∩ C` and the light, relative to `V`'s origin: the planes of both frustums, each with what the sweep
/// away from the light needs.
#[derive(Clone, Debug, PartialEq)]
struct CasterVolume {
    origin: Vec3,
    planes: [VolumePlane; MAX_VOLUME_PLANES],
    plane_count: usize,
    sweep: Sweep,
}

#[derive(Clone, Copy, Debug, PartialEq, Default)]
struct VolumePlane {
    normal: Vec3,
    d: f32,
    /// Rounding slack of `d`, as [`Frustum`]'s `slack_d`.
    slack_d: f32,
    /// Directional: `max(0, normal · direction)` rounded up, how fast the sweep climbs toward the inside.
    /// Point: 0.
    climb: f32,
    /// The box is outside when its farthest point, plus `climb` times the sweep's length, is below this.
    /// Directional: 0. Point: 0, or, where the light is outside the plane, just above the light's distance
    /// (rounded down): a box farther out than the light stays out along every ray from it.
    limit: f32,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Sweep {
    /// Along `direction` (unit length), no farther than `reach` along it from the origin: the farthest point
    /// of `V` (or [`UNBOUNDED_REACH`] for an unbounded `V`).
    Directional { direction: Vec3, reach: f32 },
    /// Away from a point light.
    Point,
}

impl CasterVolume {
    fn new(light_view: &Frustum, light: Light, receivers: &Frustum) -> Result<Self, ViewError> {
        let origin = light_view.origin;
        let shift = (origin.as_dvec3() - receivers.origin.as_dvec3()).abs().element_sum();
        let own = light_view.planes().iter().zip(light_view.slack_d).map(|(plane, slack_d)| (*plane, slack_d));
        // The receivers' planes moved to this origin: `d` grows by `normal · (origin - receivers' origin)`.
        let moved = receivers.planes().iter().zip(receivers.slack_d).map(|(plane, slack_d)| {
            let offset = plane.normal.as_dvec3().dot(origin.as_dvec3() - receivers.origin.as_dvec3());
            let d = f64::from(plane.d) + offset;
            let slack = slack_d + PLANE_TEST_TOLERANCE * (d.abs() + offset.abs() + shift * 1e-7) as f32;
            (Plane { normal: plane.normal, d: d as f32 }, slack)
        });
        let mut volume =
            Self { origin, planes: [VolumePlane::default(); MAX_VOLUME_PLANES], plane_count: 0, sweep: Sweep::Point };
        match light {
            Light::Directional { direction } => {
                let direction = direction.as_dvec3();
                if !direction.is_finite() || direction.length() == 0.0 {
                    return Err(ViewError::BadLight);
                }
                let direction = direction.normalize();
                // Rounded up past the slack by which the planes' tests may widen `V`.
                let reach = farthest_along(light_view, direction).map_or(UNBOUNDED_REACH, |(reach, magnitude)| {
                    (reach + 4.0 * PLANE_TEST_TOLERANCE as f64 * (reach.abs() + magnitude)) as f32
                });
                volume.sweep = Sweep::Directional { direction: direction.as_vec3(), reach };
                for (plane, slack_d) in own.chain(moved) {
                    let climb = plane.normal.as_dvec3().dot(direction) + PLANE_TEST_TOLERANCE as f64;
                    volume.push(plane, slack_d, climb.max(0.0) as f32, 0.0);
                }
            }
            Light::Point { position } => {
                if !position.is_finite() {
                    return Err(ViewError::BadLight);
                }
                let light = (position - origin).as_dvec3();
                let magnitude = light.abs().element_sum();
                for (plane, slack_d) in own.chain(moved) {
                    let distance = plane.normal.as_dvec3().dot(light) + f64::from(plane.d);
                    let slack = f64::from(slack_d) + 2.0 * PLANE_TEST_TOLERANCE as f64 * (magnitude + distance.abs());
                    // Outside when farther out than 0 and than the light: `far <= light` is `far < next_up(light)`.
                    let light = (distance - slack) as f32;
                    volume.push(plane, slack_d, 0.0, if light < 0.0 { light.next_up() } else { 0.0 });
                }
            }
        }
        Ok(volume)
    }

    fn push(&mut self, plane: Plane, slack_d: f32, climb: f32, limit: f32) {
        self.planes[self.plane_count] = VolumePlane { normal: plane.normal, d: plane.d, slack_d, climb, limit };
        self.plane_count += 1;
    }

    /// For 8 boxes, one per lane (centre relative to the origin, half extent): the bits of those whose whole
    /// sweep is outside one plane, and of those inside every plane. Written lane-parallel so that it
    /// vectorizes.
    #[inline(always)]
    fn test_lanes(&self, center: &[[f32; SIMD_LANES]; 3], extent: &[[f32; SIMD_LANES]; 3]) -> (u8, u8) {
        let magnitude = lane_magnitudes(center, extent);
        // Directional: how far the sweep can go before it leaves `V` for good, rounded up.
        let mut length = [0f32; SIMD_LANES];
        if let Sweep::Directional { direction, reach } = self.sweep {
            let (d, abs_d) = (direction, direction.abs());
            for lane in 0..SIMD_LANES {
                let nearest = d.x * center[0][lane] + d.y * center[1][lane] + d.z * center[2][lane]
                    - (abs_d.x * extent[0][lane] + abs_d.y * extent[1][lane] + abs_d.z * extent[2][lane]);
                let free = (reach - nearest).max(0.0);
                length[lane] = free + PLANE_TEST_TOLERANCE * (free + reach.abs() + magnitude[lane]);
            }
        }
        let mut outside = [false; SIMD_LANES];
        let mut crossing = [false; SIMD_LANES];
        for plane in &self.planes[..self.plane_count] {
            let (n, abs_n) = (plane.normal, plane.normal.abs());
            for lane in 0..SIMD_LANES {
                let dist = n.x * center[0][lane] + n.y * center[1][lane] + n.z * center[2][lane] + plane.d;
                let reach = abs_n.x * extent[0][lane] + abs_n.y * extent[1][lane] + abs_n.z * extent[2][lane];
                let slack = PLANE_TEST_TOLERANCE * magnitude[lane] + plane.slack_d;
                outside[lane] |= dist + reach + slack + plane.climb * length[lane] < plane.limit;
                crossing[lane] |= dist - reach - slack < 0.0;
            }
        }
        let bits = |flags: [bool; SIMD_LANES]| flags.iter().enumerate().fold(0u8, |b, (i, &f)| b | (f as u8) << i);
        let outside = bits(outside);
        (outside, !bits(crossing) & !outside)
    }

    fn classify_groups(&self, groups: &[GroupBounds], backend: SimdBackend) -> (u8, u8) {
        match backend {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `resolve` (in `cull_pass`) picks Avx2 only where the processor reports AVX2, the target
            // feature; the function reads `groups` through safe indexing only.
            SimdBackend::Avx2 => unsafe { self.classify_groups_avx2(groups) },
            _ => self.classify_groups_portable(groups),
        }
    }

    /// [`CasterVolume::classify_groups_portable`] with the lanes in AVX2 registers.
    ///
    /// # Safety
    /// The processor must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn classify_groups_avx2(&self, groups: &[GroupBounds]) -> (u8, u8) {
        let GroupLanes { center, extent, empty, valid } = GroupLanes::of(groups, self.origin);
        let register = |lanes: &[f32; SIMD_LANES]| avx2::load(lanes);
        let (outside, inside) =
            avx2::test_lanes::<true>(self, center.each_ref().map(register), extent.each_ref().map(register));
        ((outside | empty) & valid, inside & !empty & valid)
    }

    /// Up to 8 groups: the bits of those outside and of those inside, as `Frustum::classify_groups` gives them.
    fn classify_groups_portable(&self, groups: &[GroupBounds]) -> (u8, u8) {
        let GroupLanes { center, extent, empty, valid } = GroupLanes::of(groups, self.origin);
        let (outside, inside) = self.test_lanes(&center, &extent);
        // An empty group (or a lane past the groups) has no member to keep.
        ((outside | empty) & valid, inside & !empty & valid)
    }

    fn cull_word(&self, store: &BoundsStore, base: usize, backend: SimdBackend) -> u64 {
        match backend {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `resolve` (in `cull_pass`) picks Avx2 only where the processor reports AVX2, the target
            // feature; the function reads the store through safe indexing only.
            SimdBackend::Avx2 => unsafe { self.cull_word_avx2(store, base) },
            _ => self.cull_word_portable(store, base),
        }
    }

    /// [`CasterVolume::cull_word_portable`] with the lanes in AVX2 registers.
    ///
    /// # Safety
    /// The processor must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn cull_word_avx2(&self, store: &BoundsStore, base: usize) -> u64 {
        use std::arch::x86_64::_mm256_sub_ps;
        let soa = store.soa();
        let lanes = |array: &[f32], i: usize| avx2::load(array[i..i + SIMD_LANES].try_into().unwrap());
        let mut word = 0u64;
        for block in 0..64 / SIMD_LANES {
            let i = base + block * SIMD_LANES;
            let centers = [soa.center_x, soa.center_y, soa.center_z];
            let center = [0, 1, 2].map(|axis| _mm256_sub_ps(lanes(centers[axis], i), avx2::splat(self.origin[axis])));
            let extent = [soa.extent_x, soa.extent_y, soa.extent_z].map(|array| lanes(array, i));
            let (outside, _) = avx2::test_lanes::<false>(self, center, extent);
            word |= u64::from(!outside) << (block * SIMD_LANES);
        }
        word
    }

    /// The bits of the 64 objects from `base` whose sweep may meet the volume.
    ///
    /// # Panics
    /// If `base + 64` is past the store's padded arrays.
    #[inline(always)]
    fn cull_word_portable(&self, store: &BoundsStore, base: usize) -> u64 {
        let soa = store.soa();
        let lanes = |array: &[f32], i: usize| -> [f32; SIMD_LANES] { array[i..i + SIMD_LANES].try_into().unwrap() };
        let mut word = 0u64;
        for block in 0..64 / SIMD_LANES {
            let i = base + block * SIMD_LANES;
            let mut center = [lanes(soa.center_x, i), lanes(soa.center_y, i), lanes(soa.center_z, i)];
            for (axis, center) in center.iter_mut().enumerate() {
                center.iter_mut().for_each(|c| *c -= self.origin[axis]);
            }
            let extent = [lanes(soa.extent_x, i), lanes(soa.extent_y, i), lanes(soa.extent_z, i)];
            let (outside, _) = self.test_lanes(&center, &extent);
            word |= u64::from(!outside) << (block * SIMD_LANES);
        }
        word
    }
}

/// The largest `direction · (p - origin)` over the frustum's corners `p`, and the largest corner's magnitude
/// (sum of its coordinates' sizes), where it has six planes (a finite far plane); `None` for an unbounded
/// frustum.
fn farthest_along(frustum: &Frustum, direction: DVec3) -> Option<(f64, f64)> {
    let planes = frustum.planes();
    if planes.len() < 6 {
        return None;
    }
    // Planes are near, left, right, bottom, top, far (`Frustum::from_clip_from_relative_f64`).
    let (mut farthest, mut magnitude) = (f64::MIN, 0f64);
    for depth in [0, 5] {
        for side in [1, 2] {
            for height in [3, 4] {
                let rows = [planes[depth], planes[side], planes[height]];
                let normals =
                    DMat3::from_cols(rows[0].normal.as_dvec3(), rows[1].normal.as_dvec3(), rows[2].normal.as_dvec3())
                        .transpose();
                if normals.determinant().abs() < 1e-12 {
                    return None;
                }
                let corner = normals.inverse() * -DVec3::new(rows[0].d.into(), rows[1].d.into(), rows[2].d.into());
                farthest = farthest.max(direction.dot(corner));
                magnitude = magnitude.max(corner.abs().element_sum());
            }
        }
    }
    (farthest.is_finite() && magnitude.is_finite()).then_some((farthest, magnitude))
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! [`CasterVolume::test_lanes`] in AVX2 registers: the same operations in the same order (no fused
    //! multiply-add), so both give the same bits.
    use super::{CasterVolume, PLANE_TEST_TOLERANCE, SIMD_LANES, Sweep};
    use std::arch::x86_64::*;

    /// Eight lanes into a register.
    #[target_feature(enable = "avx2")]
    pub(super) fn load(lanes: &[f32; SIMD_LANES]) -> __m256 {
        // SAFETY: `lanes` holds exactly the 8 floats the unaligned load reads.
        unsafe { _mm256_loadu_ps(lanes.as_ptr()) }
    }

    /// One value in every lane.
    #[target_feature(enable = "avx2")]
    pub(super) fn splat(value: f32) -> __m256 {
        _mm256_set1_ps(value)
    }

    #[target_feature(enable = "avx2")]
    fn abs(v: __m256) -> __m256 {
        _mm256_andnot_ps(_mm256_set1_ps(-0.0), v)
    }

    /// `a.x * v[0] + a.y * v[1] + a.z * v[2]`, summed left to right.
    #[target_feature(enable = "avx2")]
    fn dot(a: glam::Vec3, v: &[__m256; 3]) -> __m256 {
        let xy = _mm256_add_ps(_mm256_mul_ps(splat(a.x), v[0]), _mm256_mul_ps(splat(a.y), v[1]));
        _mm256_add_ps(xy, _mm256_mul_ps(splat(a.z), v[2]))
    }

    /// [`CasterVolume::test_lanes`]. Without `CROSSING` only the bits of the boxes outside are computed (the
    /// second set is empty), and the planes stop once every lane is outside.
    #[target_feature(enable = "avx2")]
    pub(super) fn test_lanes<const CROSSING: bool>(
        volume: &CasterVolume,
        center: [__m256; 3],
        extent: [__m256; 3],
    ) -> (u8, u8) {
        let zero = _mm256_setzero_ps();
        let tolerance = splat(PLANE_TEST_TOLERANCE);
        let centers = _mm256_add_ps(_mm256_add_ps(abs(center[0]), abs(center[1])), abs(center[2]));
        let magnitude = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(centers, extent[0]), extent[1]), extent[2]);
        let length = match volume.sweep {
            Sweep::Directional { direction, reach } => {
                let nearest = _mm256_sub_ps(dot(direction, &center), dot(direction.abs(), &extent));
                let free = _mm256_max_ps(_mm256_sub_ps(splat(reach), nearest), zero);
                let bound = _mm256_add_ps(_mm256_add_ps(free, splat(reach.abs())), magnitude);
                _mm256_add_ps(free, _mm256_mul_ps(tolerance, bound))
            }
            Sweep::Point => zero,
        };
        let base_slack = _mm256_mul_ps(tolerance, magnitude);
        let (mut outside, mut crossing) = (zero, zero);
        for plane in &volume.planes[..volume.plane_count] {
            let dist = _mm256_add_ps(dot(plane.normal, &center), splat(plane.d));
            let reach = dot(plane.normal.abs(), &extent);
            let slack = _mm256_add_ps(base_slack, splat(plane.slack_d));
            let farthest = _mm256_add_ps(_mm256_add_ps(dist, reach), slack);
            let swept = _mm256_add_ps(farthest, _mm256_mul_ps(splat(plane.climb), length));
            outside = _mm256_or_ps(outside, _mm256_cmp_ps::<_CMP_LT_OQ>(swept, splat(plane.limit)));
            if CROSSING {
                let nearest = _mm256_sub_ps(_mm256_sub_ps(dist, reach), slack);
                crossing = _mm256_or_ps(crossing, _mm256_cmp_ps::<_CMP_LT_OQ>(nearest, zero));
            } else if _mm256_movemask_ps(outside) == 0xFF {
                break;
            }
        }
        let outside = _mm256_movemask_ps(outside) as u8;
        if CROSSING { (outside, !(_mm256_movemask_ps(crossing) as u8) & !outside) } else { (outside, 0) }
    }
}
