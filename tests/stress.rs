//! Numerical stability and bad input across the whole pipeline (see `cullet_truth::stress` for the cases):
//! world offsets to 1e8, near planes from 1e-5 to 10, finite and infinite far planes, every depth convention,
//! fields of view from 0.5 to 179.5 degrees, aspects from 1:16 to 16:1, objects from 1e-4 to 1e5 units,
//! objects across the near plane, behind the camera and at the far plane, degenerate, sliver and needle
//! triangles, occludees coplanar with occluders, the camera inside an object and inside an occluder. For
//! every case: zero false negatives against the exact rendering on the CPU stages and on the GPU passes, and
//! f32 planes and projection within the documented bound of f64. Bad input: NaN, infinite and huge transforms
//! and bounds, empty meshes and out-of-range indices are refused or dropped with a typed error, nothing
//! panics, and the rest of the scene is culled as before.

use cullet::mesh::Mesh;
use cullet::scene::{Scene, SceneObject};
use cullet::{BoundsError, BoundsStore};
use cullet_test_support::context_for_tests;
use cullet_truth::stress::{F32_AGREEMENT, cases, gpu_false_negatives, run_case};
use glam::{Affine3A, Vec3};

#[test]
fn every_stress_case_is_conservative_on_the_cpu_and_f32_agrees_with_f64() {
    let mut failures = Vec::new();
    for case in cases() {
        let (outcome, _) = run_case(&case);
        println!("{outcome:?}");
        if outcome.false_negatives > 0 {
            failures.push(format!("{} = {}: {} false negatives", case.sweep, case.value, outcome.false_negatives));
        }
        if outcome.plane_error > F32_AGREEMENT || outcome.projection_error > F32_AGREEMENT {
            failures.push(format!(
                "{} = {}: f32 off f64 by {:e} (planes) {:e} (projection)",
                case.sweep, case.value, outcome.plane_error, outcome.projection_error
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Not vacuous: the base case shows the wall's neighbours and culls what hides behind it.
#[test]
fn the_base_case_culls_and_shows_what_it_should() {
    let case = cases().into_iter().find(|c| c.sweep == "world offset" && c.value == 0.0).unwrap();
    let (outcome, _) = run_case(&case);
    assert!(outcome.visible >= 4, "{outcome:?}");
    assert!(outcome.efficiency > 0.5, "{outcome:?}");
}

#[test]
fn every_stress_case_is_conservative_on_the_gpu() {
    let Some(context) = context_for_tests() else { return };
    let mut failures = Vec::new();
    for case in cases() {
        let (_, mut flight) = run_case(&case);
        let missed = gpu_false_negatives(&case, &mut flight, &context).expect("GPU frame");
        if missed > 0 {
            failures.push(format!("{} = {}: {missed} visible triangles culled on the GPU", case.sweep, case.value));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// NaN, infinite and huge transforms and bounds are refused with a typed error naming the entity; the other
/// objects are culled exactly as in the same scene without them.
#[test]
fn bad_objects_are_refused_and_the_rest_is_unaffected() {
    let good = cases().into_iter().find(|c| c.sweep == "world offset" && c.value == 0.0).unwrap();
    let (clean, _) = run_case(&good);
    let mut bad = good.clone();
    let overflowing =
        Affine3A::from_scale_rotation_translation(Vec3::splat(1e38), glam::Quat::IDENTITY, Vec3::splat(3e38));
    let transforms = [
        Affine3A::from_translation(Vec3::new(f32::NAN, 0.0, 0.0)),
        Affine3A::from_translation(Vec3::new(0.0, f32::INFINITY, 0.0)),
        overflowing,
    ];
    for transform in transforms {
        bad.scene.objects.push(SceneObject { mesh: 0, transform, occluder: None, velocity: None, color: [0; 4] });
    }
    // A mesh with a NaN vertex: its bounds are NaN.
    let nan_mesh = Mesh { positions: vec![Vec3::ZERO, Vec3::X, Vec3::NAN], indices: vec![0, 1, 2] };
    let mut meshes = bad.scene.meshes.clone();
    meshes.push(nan_mesh);
    let nan_object = SceneObject {
        mesh: meshes.len() as u32 - 1,
        transform: Affine3A::IDENTITY,
        occluder: None,
        velocity: None,
        color: [0; 4],
    };
    let mut objects = bad.scene.objects.clone();
    objects.push(nan_object);
    bad.scene = Scene::new(meshes, objects);

    let (outcome, mut flight) = run_case(&bad);
    let errors = flight.world.resource_mut::<BoundsStore>().take_errors();
    assert_eq!(errors.len(), 4, "{errors:?}");
    let kinds: Vec<&str> = errors
        .iter()
        .map(|e| match e {
            BoundsError::NonFiniteLocal { .. } => "local",
            BoundsError::NegativeExtent { .. } => "negative",
            BoundsError::NonFiniteTransform { .. } => "transform",
            BoundsError::WorldOverflow { .. } => "overflow",
            _ => "other",
        })
        .collect();
    assert_eq!(kinds, ["transform", "transform", "overflow", "local"], "{errors:?}");
    // The refused objects are not in the store: the rest is judged exactly as before.
    assert_eq!((outcome.objects, outcome.visible, outcome.kept), (clean.objects, clean.visible, clean.kept));
    assert_eq!(outcome.false_negatives, 0);
}

/// Huge but finite objects (scaled to 1e30, or placed at 1e38) are kept and culled conservatively.
#[test]
fn huge_finite_objects_are_culled_conservatively() {
    let mut case = cases().into_iter().find(|c| c.sweep == "world offset" && c.value == 0.0).unwrap();
    for transform in [
        Affine3A::from_scale_rotation_translation(Vec3::splat(1e30), glam::Quat::IDENTITY, Vec3::new(0.0, 0.0, -1e31)),
        Affine3A::from_translation(Vec3::new(1e38, 0.0, 0.0)),
    ] {
        case.scene.objects.push(SceneObject { mesh: 0, transform, occluder: None, velocity: None, color: [0; 4] });
    }
    let (outcome, mut flight) = run_case(&case);
    assert!(flight.world.resource_mut::<BoundsStore>().take_errors().is_empty());
    assert_eq!(outcome.false_negatives, 0, "{outcome:?}");
}

/// Empty meshes and triangles with out-of-range indices draw nothing, in the judge and on the GPU alike, and
/// break nothing else.
#[test]
fn empty_meshes_and_bad_indices_draw_nothing_and_break_nothing() {
    let mut case = cases().into_iter().find(|c| c.sweep == "world offset" && c.value == 0.0).unwrap();
    let bad_indices = Mesh { positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y], indices: vec![0, 1, 7, 0, 1, 2, 5] };
    let mut meshes = case.scene.meshes.clone();
    let mut objects = case.scene.objects.clone();
    for mesh in [Mesh::default(), Mesh { positions: vec![Vec3::ONE], indices: vec![] }, bad_indices] {
        meshes.push(mesh);
        objects.push(SceneObject {
            mesh: meshes.len() as u32 - 1,
            transform: Affine3A::from_translation(case.camera.position + case.camera.forward * 5.0),
            occluder: None,
            velocity: None,
            color: [0; 4],
        });
    }
    case.scene = Scene::new(meshes, objects);
    let (outcome, mut flight) = run_case(&case);
    assert_eq!(outcome.false_negatives, 0);
    let library = cullet::gpu::clusters::ClusterLibrary::build(&case.scene.meshes);
    let last = case.scene.meshes.len() as u32 - 1;
    assert_eq!(library.clusters_of(last).iter().map(|c| c.triangle_count).sum::<u32>(), 1);
    if let Some(context) = context_for_tests() {
        assert_eq!(gpu_false_negatives(&case, &mut flight, &context).expect("GPU frame"), 0);
    }
}
