//! The ground-truth oracle on hand-made scenes whose visible sets and pixel counts are known exactly.

use cullet::mesh::Mesh;
use cullet::{Camera, VisibleSet};
use cullet_truth::metrics::FrameMetrics;
use cullet_truth::render::NO_OBJECT;
use cullet_truth::{ReferenceObject, ReferenceSettings, render_ids};
use glam::{Affine3A, Vec3};

/// 64x64 pixels, 90 degrees: at distance d, `x in [-d, d]` spans the whole width, 32 pixels per d.
fn square_camera() -> (Camera, ReferenceSettings) {
    let camera = Camera { fov_y: 90f32.to_radians(), aspect: 1.0, ..Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z) };
    (camera, ReferenceSettings { width: 64, height: 64, cull_back_faces: true })
}

fn cube() -> Mesh {
    Mesh::unit_cube(1)
}

/// A box of size `size` centred at `center`.
fn placed(mesh: &Mesh, center: Vec3, size: Vec3) -> ReferenceObject<'_> {
    ReferenceObject::new(mesh, Affine3A::from_scale_rotation_translation(size, glam::Quat::IDENTITY, center))
}

fn visible(objects: &[ReferenceObject], camera: &Camera, settings: &ReferenceSettings) -> Vec<usize> {
    render_ids(camera, objects, settings).visibility().visible.iter().collect()
}

/// A 2x2 face at distance 4 spans x, y in [-1, 1]: 8 pixels a unit, 16x16 pixels from 24 to 40, whose edges
/// at 24.0 and 40.0 fall between pixel centres.
#[test]
fn a_face_covers_exactly_its_pixels() {
    let (camera, settings) = square_camera();
    let mesh = cube();
    // The cube's front face is at z = -4 (centre -5, size 2).
    let ids = render_ids(&camera, &[placed(&mesh, Vec3::new(0.0, 0.0, -5.0), Vec3::splat(2.0))], &settings);
    let covered: Vec<(u32, u32)> =
        (0..64).flat_map(|y| (0..64).map(move |x| (x, y))).filter(|&(x, y)| ids.object_at(x, y) == 0).collect();
    assert_eq!(covered.len(), 256);
    assert!(covered.iter().all(|&(x, y)| (24..40).contains(&x) && (24..40).contains(&y)));
    // Only the front face's two triangles show.
    let triangles = ids.visible_triangles();
    assert_eq!(triangles.len(), 2, "{triangles:?}");
    // Depth is 1/w = 1/4 everywhere on the face.
    let pixel = (32 * 64 + 32) as usize;
    assert_eq!(ids.depths()[pixel], 0.25);
}

#[test]
fn nearer_objects_hide_farther_ones() {
    let (camera, settings) = square_camera();
    let mesh = cube();
    let wall = placed(&mesh, Vec3::new(0.0, 0.0, -10.0), Vec3::new(100.0, 100.0, 1.0));
    let behind = placed(&mesh, Vec3::new(0.0, 0.0, -20.0), Vec3::ONE);
    let in_front = placed(&mesh, Vec3::new(0.0, 0.0, -5.0), Vec3::ONE);
    assert_eq!(visible(&[wall.clone(), behind.clone(), in_front], &camera, &settings), vec![0, 2]);
    // Order does not matter for strict depth differences.
    assert_eq!(visible(&[behind, wall], &camera, &settings), vec![1]);
}

/// Clipped away: what lies between the eye and the near plane, behind the camera, beyond a finite far plane.
/// A box around the eye whose only front face is in front of the near plane is invisible too (its other
/// faces face away).
#[test]
fn the_near_and_far_planes_clip() {
    let (mut camera, settings) = square_camera();
    camera.near = 1.0;
    camera.far = Some(50.0);
    let mesh = cube();
    let objects = [
        placed(&mesh, Vec3::new(0.0, 0.0, -0.5), Vec3::splat(0.2)), // between the eye and the near plane
        placed(&mesh, Vec3::new(0.0, 0.0, 5.0), Vec3::ONE),         // behind the camera
        placed(&mesh, Vec3::new(0.0, 0.0, -60.0), Vec3::splat(4.0)), // beyond the far plane
        placed(&mesh, Vec3::new(0.8, 0.0, -1.0), Vec3::splat(1.0)), // straddles the near plane
        placed(&mesh, Vec3::new(3.0, 0.0, -50.0), Vec3::splat(2.0)), // straddles the far plane
    ];
    assert_eq!(visible(&objects, &camera, &settings), vec![3, 4]);
    camera.far = None;
    assert_eq!(visible(&objects, &camera, &settings), vec![2, 3, 4]);
    let prism_around_eye = placed(&mesh, Vec3::new(0.0, 0.0, -1.0), Vec3::splat(1.0));
    assert!(visible(&[prism_around_eye], &camera, &settings).is_empty());
}

/// A box smaller than a pixel that falls between pixel centres covers no sample: not visible.
#[test]
fn a_box_between_pixel_centres_is_not_visible() {
    let (camera, settings) = square_camera();
    let mesh = cube();
    // At distance 4, a pixel is 1/8 unit; pixel centres at x = (k + 0.5)/8 - 4... the gap around x = 0 (the
    // boundary between pixels 31 and 32) is 1/16 unit on each side.
    let tiny = placed(&mesh, Vec3::new(0.0, 0.0, -4.0), Vec3::splat(0.05));
    assert!(visible(&[tiny], &camera, &settings).is_empty());
    let small = placed(&mesh, Vec3::new(0.0, 0.0, -4.0), Vec3::splat(0.2));
    assert_eq!(visible(&[small], &camera, &settings), vec![0]);
}

#[test]
fn back_faces_are_culled_like_the_draw_pass() {
    let (camera, mut settings) = square_camera();
    let mesh = cube();
    let around_camera = placed(&mesh, Vec3::ZERO, Vec3::splat(10.0));
    assert!(visible(std::slice::from_ref(&around_camera), &camera, &settings).is_empty());
    settings.cull_back_faces = false;
    assert_eq!(visible(&[around_camera], &camera, &settings), vec![0]);
}

/// Two identical objects: the first drawn owns every pixel, as with a `LESS` depth test.
#[test]
fn exact_depth_ties_go_to_the_first_object() {
    let (camera, settings) = square_camera();
    let mesh = cube();
    let a = placed(&mesh, Vec3::new(0.0, 0.0, -5.0), Vec3::splat(2.0));
    assert_eq!(visible(&[a.clone(), a], &camera, &settings), vec![0]);
}

#[test]
fn objects_far_from_the_origin_render_like_near_ones() {
    let (mut camera, settings) = square_camera();
    let mesh = cube();
    // Exactly representable in f32 with the -5 below: the judge must be exact there, not merely close.
    let offset = Vec3::new(1.0e7, -3.0e6, 1.6e7);
    camera.position = offset;
    let ids = render_ids(&camera, &[placed(&mesh, offset + Vec3::new(0.0, 0.0, -5.0), Vec3::splat(2.0))], &settings);
    assert_eq!(ids.objects().iter().filter(|&&o| o == 0).count(), 256);
}

#[test]
fn metrics_name_the_stage_that_culled_a_visible_object() {
    let (camera, settings) = square_camera();
    let mesh = cube();
    let objects = [
        placed(&mesh, Vec3::new(-2.0, 0.0, -5.0), Vec3::ONE), // visible
        placed(&mesh, Vec3::new(2.0, 0.0, -5.0), Vec3::ONE),  // visible
        placed(&mesh, Vec3::new(0.0, 0.0, 5.0), Vec3::ONE),   // behind
        placed(&mesh, Vec3::new(0.0, 50.0, -5.0), Vec3::ONE), // above the view
    ];
    let truth = render_ids(&camera, &objects, &settings);
    let set = |slots: &[usize]| {
        let mut s = VisibleSet::new(4);
        slots.iter().for_each(|&i| s.set(i, true));
        s
    };
    let (frustum, occlusion) = (set(&[0, 1, 3]), set(&[0]));
    let metrics = FrameMetrics::new(&truth.visibility(), &[("frustum", &frustum), ("occlusion", &occlusion)]);
    assert_eq!(metrics.visible, 2);
    assert_eq!(metrics.stages[0].false_positives, 1);
    assert_eq!(metrics.stages[0].efficiency, 0.5);
    assert_eq!(metrics.stages[1].efficiency, 1.5, "culled 3 of 2 cullable: one of them visible");
    assert_eq!(metrics.false_negatives.len(), 1);
    assert_eq!((metrics.false_negatives[0].object, metrics.false_negatives[0].stage), (1, "occlusion"));
    let lost = truth.objects().iter().filter(|&&o| o == 1).count();
    assert!(lost > 0);
    assert_eq!(metrics.image_error_pixels, lost);
    assert!(truth.objects().iter().all(|&o| o == NO_OBJECT || o < 2));
}
