//! Stress cases: the whole pipeline at the edges of its numeric range, judged against the exact rendering.
//!
//! Each case is a small scene built around a camera: a wall with an artist occluder and objects hidden behind
//! it or peeking past its edges, objects straddling the near plane, behind the camera and at the far plane,
//! an occludee lying on the occluder's face, a building that contains the camera (with its occluder),
//! degenerate, sliver and needle triangles. [`cases`] sweeps one parameter at a time from a base case
//! (world offset, near plane, far plane, depth convention, field of view, aspect, object size) and adds some
//! combined extremes. [`run_case`] culls one frame on the CPU and judges it; [`gpu_false_negatives`] checks
//! the GPU passes of the same frame against the same judgement.

use crate::half_spaces::exact_half_spaces;
use crate::judge::{judge_frame, render_world};
use crate::{JudgeSettings, ReferenceSettings};
use cullet::camera::CameraPath;
use cullet::camera::DepthConvention;
use cullet::gpu::{GpuContext, GpuCullSettings, GpuCuller, GpuError};
use cullet::mesh::Mesh;
use cullet::pipeline::{CameraCuller, CullStats};

use cullet::culler::OcclusionSettings;
use cullet::scene::flight::Flight;
use cullet::scene::{Scene, SceneObject};
use cullet::{Camera, Occluder};
use glam::{Affine3A, DVec4, Quat, Vec3};

/// One stress case: a scene, the camera it is seen from and the resolution it is judged at.
#[derive(Clone, Debug)]
pub struct StressCase {
    /// The swept parameter's name, as reported.
    pub sweep: &'static str,
    /// Its value in this case.
    pub value: f64,
    /// The scene, every object with a mesh of its own.
    pub scene: Scene,
    /// The camera.
    pub camera: Camera,
    /// Judged at this many pixels across and down.
    pub width: u32,
    /// See `width`.
    pub height: u32,
}

/// The parameters a case is built from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CaseParams {
    /// World position of the camera (the scene moves with it).
    pub offset: Vec3,
    /// Near-plane distance.
    pub near: f32,
    /// Far-plane distance, or `None` for infinite.
    pub far: Option<f32>,
    /// Depth convention of the camera.
    pub depth: DepthConvention,
    /// Vertical field of view in degrees.
    pub fov_deg: f32,
    /// Width over height.
    pub aspect: f32,
    /// Scale of the scene (every size and distance), 1 for a wall 20 units away.
    pub size: f32,
}

impl Default for CaseParams {
    fn default() -> Self {
        Self {
            offset: Vec3::ZERO,
            near: 0.1,
            far: None,
            depth: DepthConvention::Reversed,
            fov_deg: 60.0,
            aspect: 16.0 / 9.0,
            size: 1.0,
        }
    }
}

/// What one case gave.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StressOutcome {
    /// The case's sweep and value.
    pub sweep: &'static str,
    /// See `sweep`.
    pub value: f64,
    /// Objects in the scene.
    pub objects: usize,
    /// Objects the exact rendering shows.
    pub visible: usize,
    /// Objects the CPU stages kept.
    pub kept: usize,
    /// Visible objects the CPU stages culled.
    pub false_negatives: usize,
    /// Culling efficiency `culled / (objects - visible)` of the CPU stages.
    pub efficiency: f64,
    /// Largest difference between the engine's f32 frustum planes and exact f64 planes (unit normals; the
    /// offset relative to `1 + |d|`).
    pub plane_error: f64,
    /// Largest difference between the f32 and f64 clip matrices, relative to the largest element.
    pub projection_error: f64,
}

/// Relative bound, documented in the README, on [`StressOutcome::plane_error`] and
/// [`StressOutcome::projection_error`]: the f32 planes and matrices are the f64 ones rounded once, so a few
/// f32 ulps; the frustum test's own slack (`2^-20`) is larger.
pub const F32_AGREEMENT: f64 = 1.0 / (1u64 << 21) as f64;

/// The swept cases: one parameter at a time from [`CaseParams::default`], then combined extremes.
pub fn cases() -> Vec<StressCase> {
    let base = CaseParams::default();
    let mut cases = Vec::new();
    let diagonal = Vec3::new(1.0, 0.37, -0.61).normalize();
    for offset in [0.0, 1e2, 1e4, 1e5, 1e6, 1e7, 3e7, 1e8] {
        cases.push(build("world offset", offset as f64, CaseParams { offset: diagonal * offset, ..base }));
    }
    for near in [1e-5, 1e-3, 0.1, 1.0, 10.0] {
        cases.push(build("near", near as f64, CaseParams { near, ..base }));
    }
    for far in [25.0, 45.0, 1e3, 1e6] {
        cases.push(build("far", far as f64, CaseParams { far: Some(far), ..base }));
    }
    for (i, depth) in [DepthConvention::Reversed, DepthConvention::Standard, DepthConvention::NegativeOneToOne]
        .into_iter()
        .enumerate()
    {
        cases.push(build("depth convention", i as f64, CaseParams { depth, far: Some(1e4), ..base }));
    }
    for fov_deg in [0.5, 5.0, 60.0, 120.0, 170.0, 179.5] {
        cases.push(build("fov", fov_deg as f64, CaseParams { fov_deg, ..base }));
    }
    for aspect in [1.0 / 16.0, 0.25, 1.0, 4.0, 16.0] {
        cases.push(build("aspect", aspect as f64, CaseParams { aspect, ..base }));
    }
    for size in [1e-4, 1e-2, 1.0, 1e2, 1e5] {
        cases.push(build("object size", size as f64, CaseParams { size, near: 0.1 * size, ..base }));
    }
    let extremes = [
        CaseParams { offset: diagonal * 1e7, near: 1e-5, depth: DepthConvention::Standard, far: Some(1e5), ..base },
        CaseParams { offset: diagonal * 1e6, fov_deg: 179.5, aspect: 16.0, ..base },
        CaseParams { offset: diagonal * 1e5, fov_deg: 0.5, aspect: 1.0 / 16.0, size: 100.0, near: 10.0, ..base },
        CaseParams { size: 1e-4, near: 1e-5, depth: DepthConvention::NegativeOneToOne, far: Some(1.0), ..base },
    ];
    for (i, params) in extremes.into_iter().enumerate() {
        cases.push(build("combined", i as f64, params));
    }
    cases
}

/// The case scene for `params`, seen from its camera.
pub fn build(sweep: &'static str, value: f64, params: CaseParams) -> StressCase {
    let s = params.size;
    // The camera looks down -z, turned a little so nothing is axis-aligned on screen.
    let rotation = Quat::from_rotation_y(0.13) * Quat::from_rotation_x(-0.05);
    let place = |p: Vec3| params.offset + rotation * (p * s);
    let mut meshes = Vec::new();
    let mut objects = Vec::new();
    let mut add = |mesh: Mesh, transform: Affine3A, occluder: Option<Occluder>| {
        meshes.push(mesh);
        objects.push(SceneObject {
            mesh: meshes.len() as u32 - 1,
            transform,
            occluder,
            velocity: None,
            color: [200, 200, 200, 255],
        });
    };
    let cube = Mesh::unit_cube(2);
    let inner_box =
        |inset: f32| Occluder::new(Mesh::unit_cube(1).scaled(Vec3::splat(1.0 - inset), Vec3::ZERO).triangle_soup());
    let boxed = |center: Vec3, size: Vec3| Affine3A::from_scale_rotation_translation(size * s, rotation, place(center));
    // The wall: 16 x 8 x 1 at 20 units, its occluder 2% inside.
    add(cube.clone(), boxed(Vec3::new(0.0, 0.0, -20.0), Vec3::new(16.0, 8.0, 1.0)), Some(inner_box(0.02)));
    // Behind it: hidden boxes, and boxes peeking past its left and top edges.
    for (i, x) in [-5.0, -2.0, 1.0, 4.0].into_iter().enumerate() {
        add(cube.clone(), boxed(Vec3::new(x, -1.0 + i as f32, -30.0), Vec3::splat(1.0)), None);
    }
    add(cube.clone(), boxed(Vec3::new(-8.45, 0.0, -30.0), Vec3::splat(1.0)), None);
    add(cube.clone(), boxed(Vec3::new(0.0, 5.6, -35.0), Vec3::splat(1.0)), None);
    // On the occluder's front face (coplanar with it), inside the wall: hidden by the wall itself.
    add(cube.clone(), boxed(Vec3::new(3.0, 0.0, -19.51), Vec3::new(1.0, 1.0, 0.0)), None);
    // Beside the wall, visible; and far beyond it, for finite far planes.
    add(cube.clone(), boxed(Vec3::new(12.0, 0.0, -25.0), Vec3::splat(2.0)), None);
    add(cube.clone(), boxed(Vec3::new(-30.0, 0.0, -60.0), Vec3::splat(4.0)), None);
    add(cube.clone(), boxed(Vec3::new(0.0, 20.0, -40.0), Vec3::splat(3.0)), None);
    // Straddling the near plane, and behind the camera.
    let near = params.near / s;
    add(cube.clone(), boxed(Vec3::new(0.2 * near, 0.0, -near), Vec3::splat(near)), None);
    add(cube.clone(), boxed(Vec3::new(0.0, 0.0, 10.0), Vec3::splat(2.0)), None);
    // A building around a point beside the camera, with its occluder: the camera is outside it here; the
    // "inside" case below puts the camera in one.
    add(cube.clone(), boxed(Vec3::new(-6.0, 0.0, -8.0), Vec3::new(3.0, 6.0, 3.0)), Some(inner_box(0.02)));
    // Degenerate (zero-area), sliver and needle triangles.
    let odd = Mesh {
        positions: vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::X * 2.0,
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(6.0, 0.001, 0.0),
            Vec3::new(6.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.01, 8.0, 0.0),
            Vec3::new(0.0, 8.0, 0.0),
        ],
        indices: vec![0, 1, 2, 3, 5, 4, 6, 7, 8, 8, 7, 6],
    };
    add(
        odd,
        Affine3A::from_scale_rotation_translation(Vec3::splat(s), rotation, place(Vec3::new(9.0, -4.0, -18.0))),
        None,
    );
    // The camera inside an object's box and inside an occluder (a hollow hall whose occluder is its own box).
    add(cube.clone(), boxed(Vec3::new(0.0, 0.0, 0.0), Vec3::splat(0.5 * near.max(1e-3) + 0.01)), Some(inner_box(0.0)));

    let (width, height) = resolution(params.aspect);
    let camera = Camera {
        fov_y: params.fov_deg.to_radians(),
        aspect: params.aspect,
        near: params.near,
        far: params.far.map(|f| f * s),
        depth: params.depth,
        // The direction itself, not the difference of two points that far from the origin.
        forward: rotation * Vec3::NEG_Z,
        ..Camera::looking_at(params.offset, params.offset + Vec3::NEG_Z)
    };
    StressCase { sweep, value, scene: Scene::new(meshes, objects), camera, width, height }
}

/// About 100 000 pixels at `aspect`, at least 16 along each side.
fn resolution(aspect: f32) -> (u32, u32) {
    let height = (100_000.0 / aspect).sqrt();
    ((height * aspect).round().max(16.0) as u32, height.round().max(16.0) as u32)
}

/// Culls one frame of `case` on the CPU (conservative defaults) and judges it; returns the outcome and the
/// flight, whose world the GPU check reuses.
pub fn run_case(case: &StressCase) -> (StressOutcome, Flight) {
    let path = CameraPath { fov_y_deg: 60.0, near: 0.1, far: None, keys: Vec::new() };
    let mut flight = Flight::new(path, case.camera.aspect, 1, OcclusionSettings::default(), |world| {
        case.scene.spawn(world);
    });
    let _: CullStats = flight.run_with_camera(case.camera, 0.0);
    let settings = JudgeSettings {
        reference: ReferenceSettings { width: case.width, height: case.height, ..ReferenceSettings::default() },
        occlusion_ideal: false,
    };
    let judgement = judge_frame(&flight.world, &case.scene.meshes, &settings);
    let metrics = &judgement.metrics;
    let culled_invisible = (metrics.objects - metrics.visible).max(1);
    let kept = metrics.stages.last().map_or(metrics.objects, |s| s.kept);
    let outcome = StressOutcome {
        sweep: case.sweep,
        value: case.value,
        objects: metrics.objects,
        visible: metrics.visible,
        kept,
        false_negatives: metrics.false_negatives.len(),
        efficiency: (metrics.objects - kept) as f64 / culled_invisible as f64,
        plane_error: plane_error(&case.camera),
        projection_error: projection_error(&case.camera),
    };
    (outcome, flight)
}

/// Largest deviation of the engine's f32 frustum planes from the exact ones (see [`StressOutcome`]).
pub fn plane_error(camera: &Camera) -> f64 {
    let Ok(frustum) = camera.frustum() else { return 0.0 };
    let exact = exact_planes(camera);
    frustum
        .planes()
        .iter()
        .map(|plane| {
            let normal = plane.normal.as_dvec3();
            // The exact plane this one approximates: the one with the closest normal.
            exact
                .iter()
                .map(|p| {
                    let n = p.truncate();
                    (normal - n).abs().max_element().max((f64::from(plane.d) - p.w).abs() / (1.0 + p.w.abs()))
                })
                .fold(f64::INFINITY, f64::min)
        })
        .fold(0.0, f64::max)
}

/// Largest deviation of the f32 clip matrix from the f64 one, relative to its largest element.
pub fn projection_error(camera: &Camera) -> f64 {
    let exact = camera.clip_from_relative_f64();
    let rounded = camera.clip_from_relative().as_dmat4();
    let scale = exact.to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    (exact - rounded).to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs())) / scale.max(f64::MIN_POSITIVE)
}

/// [`exact_half_spaces`] normalized to unit normals.
fn exact_planes(camera: &Camera) -> Vec<DVec4> {
    exact_half_spaces(camera).into_iter().map(|p| p / p.truncate().length()).collect()
}

/// Triangles the exact rendering shows, of objects the CPU stages kept, that the GPU cluster and triangle
/// passes culled, in the frame `flight` has just culled for `case` (its world's instances are uploaded here).
///
/// # Errors
/// [`GpuError::Lost`] when the device is lost.
pub fn gpu_false_negatives(case: &StressCase, flight: &mut Flight, context: &GpuContext) -> Result<usize, GpuError> {
    let size = (case.width, case.height);
    let mut culler = GpuCuller::for_world(context, &flight.world, &case.scene.meshes, size);
    culler.run_world(context, &mut flight.world, &GpuCullSettings::default())?;
    let (_, indices) = culler.read_survivors(context)?;
    let survivors: std::collections::HashSet<[u32; 3]> = indices.chunks_exact(3).map(canonical).collect();
    // Global vertex index of each mesh's first vertex: the library appends meshes' vertices in order.
    let first_vertex: Vec<u32> = case
        .scene
        .meshes
        .iter()
        .scan(0u32, |next, mesh| {
            let first = *next;
            *next += mesh.positions.len() as u32;
            Some(first)
        })
        .collect();
    let reference = ReferenceSettings { width: case.width, height: case.height, ..ReferenceSettings::default() };
    let truth = render_world(&flight.world, &case.scene.meshes, &reference);
    let kept = &flight.world.resource::<CameraCuller>().visible();
    let instances = culler.scene().instances();
    Ok(truth
        .visible_triangles()
        .into_iter()
        .filter(|&(slot, _)| kept.contains(slot as usize))
        .filter(|&(slot, triangle)| {
            let mesh = instances[slot as usize].mesh as usize;
            let corners = &case.scene.meshes[mesh].indices[3 * triangle as usize..][..3];
            !survivors.contains(&canonical(&corners.iter().map(|&i| first_vertex[mesh] + i).collect::<Vec<_>>()))
        })
        .count())
}

/// A triangle's corners rotated to start at the smallest index, keeping the winding.
fn canonical(corners: &[u32]) -> [u32; 3] {
    let first = (0..3).min_by_key(|&i| corners[i]).unwrap_or(0);
    [corners[first], corners[(first + 1) % 3], corners[(first + 2) % 3]]
}
