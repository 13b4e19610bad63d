//! Frustum culling against an exact f64 reference: conservative everywhere, identical across SIMD backends,
//! and stable at extreme cameras.

use cullet::frustum::{FrustumOptions, PlaneCoherence, SimdBackend, cull_frustum};
use cullet::{BoundsStore, Camera, DepthConvention, Frustum, VisibleSet};
use cullet_test_support::{reference_keeps, reference_planes, store_of};
use glam::Vec3;
use proptest::prelude::*;

/// Culls with every backend, checks they agree bit for bit and never cull what the f64 reference keeps, and
/// returns the visible set.
fn cull_and_check(store: &BoundsStore, camera: &Camera) -> VisibleSet {
    let frustum = camera.frustum().expect("valid camera");
    let mut scalar = VisibleSet::default();
    let mut simd = VisibleSet::default();
    let scalar_count = cull_frustum(
        store,
        &frustum,
        FrustumOptions { backend: SimdBackend::Scalar, ..Default::default() },
        &mut scalar,
    );
    let simd_count =
        cull_frustum(store, &frustum, FrustumOptions { backend: SimdBackend::Avx2, ..Default::default() }, &mut simd);
    assert_eq!(scalar, simd, "SIMD and scalar backends disagree");
    assert_eq!(scalar_count, simd_count);
    assert_eq!(scalar_count, scalar.count());
    let planes = reference_planes(camera);
    for slot in 0..store.len() {
        let bounds = store.get(slot).unwrap();
        if reference_keeps(&planes, camera.position.as_dvec3(), &bounds) {
            assert!(scalar.contains(slot), "culled a box the f64 reference keeps: {bounds:?} for {camera:?}");
            assert!(frustum.intersects(&bounds), "single-object test culls what the f64 reference keeps");
        }
    }
    scalar
}

fn camera_strategy() -> impl Strategy<Value = Camera> {
    (
        prop::array::uniform3(-1.0e7f32..1.0e7),
        prop::array::uniform3(-1.0f32..1.0),
        1.0f32..179.0,
        0.1f32..10.0,
        -4.0f32..1.0,
        prop::option::of(10.0f32..1.0e6),
        prop::sample::select(vec![
            DepthConvention::Standard,
            DepthConvention::Reversed,
            DepthConvention::NegativeOneToOne,
        ]),
    )
        .prop_filter("forward must not be parallel to up", |(_, f, ..)| {
            Vec3::from(*f).normalize_or_zero().cross(Vec3::Y).length() > 1e-3
        })
        .prop_map(|(position, forward, fov, aspect, log_near, far, depth)| {
            let near = 10f32.powf(log_near);
            Camera {
                position: Vec3::from(position),
                forward: Vec3::from(forward),
                up: Vec3::Y,
                fov_y: fov.to_radians(),
                aspect,
                near,
                far: far.map(|f| f.max(near * 2.0)),
                depth,
            }
        })
}

/// Boxes around the camera at distances from 1e-4 to 1e6, of sizes from 0 to 1e4: many straddle a plane.
fn boxes_strategy() -> impl Strategy<Value = Vec<(Vec3, f32, Vec3)>> {
    prop::collection::vec(
        (prop::array::uniform3(-1.0f32..1.0), -4.0f32..6.0, prop::array::uniform3(0.0f32..1.0), -5.0f32..4.0),
        1..200,
    )
    .prop_map(|boxes| {
        boxes
            .into_iter()
            .map(|(direction, log_distance, extent, log_size)| {
                let size = if log_size < -4.5 { 0.0 } else { 10f32.powf(log_size) };
                (Vec3::from(direction).normalize_or(Vec3::X), 10f32.powf(log_distance), Vec3::from(extent) * size)
            })
            .collect()
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1024))]

    #[test]
    fn never_culls_what_the_f64_reference_keeps(camera in camera_strategy(), boxes in boxes_strategy()) {
        let boxes: Vec<(Vec3, Vec3)> =
            boxes.iter().map(|&(dir, dist, extent)| (camera.position + dir * dist, extent)).collect();
        cull_and_check(&store_of(&boxes), &camera);
    }

    /// Boxes placed exactly on a frustum plane, just inside and just outside: the hardest cases for rounding.
    #[test]
    fn boxes_touching_a_plane_are_kept(
        camera in camera_strategy(),
        picks in prop::collection::vec((0usize..6, prop::array::uniform3(-1.0f32..1.0), -3.0f32..3.0, -1e-3f32..1e-3), 1..64),
    ) {
        let frustum = camera.frustum().unwrap();
        let planes = frustum.planes();
        let boxes: Vec<(Vec3, Vec3)> = picks
            .iter()
            .map(|&(plane, offset, log_size, nudge)| {
                let plane = planes[plane % planes.len()];
                let extent = Vec3::splat(10f32.powf(log_size));
                // A point on the plane, moved along it, then the box moved so its nearest corner touches it.
                let on_plane = -plane.normal * plane.d + Vec3::from(offset) * 10.0;
                let on_plane = on_plane - plane.normal * plane.distance(on_plane);
                let reach = plane.normal.abs().dot(extent);
                (camera.position + on_plane - plane.normal * (reach + nudge), extent)
            })
            .collect();
        cull_and_check(&store_of(&boxes), &camera);
    }
}

fn camera_at(position: Vec3, forward: Vec3) -> Camera {
    Camera { forward, ..Camera::looking_at(position, position + Vec3::Z) }
}

#[test]
fn obvious_cases() {
    let camera = camera_at(Vec3::ZERO, Vec3::NEG_Z);
    let store = store_of(&[
        (Vec3::new(0.0, 0.0, -10.0), Vec3::ONE),   // in front: kept
        (Vec3::new(0.0, 0.0, 10.0), Vec3::ONE),    // behind the camera: culled
        (Vec3::new(0.0, 0.0, 0.0), Vec3::ONE),     // camera inside the box, straddles the near plane: kept
        (Vec3::new(0.0, 0.0, 0.05), Vec3::ZERO),   // zero-size point behind the near plane: culled
        (Vec3::new(0.0, 0.0, -0.2), Vec3::ZERO),   // zero-size point in front: kept
        (Vec3::new(500.0, 0.0, -10.0), Vec3::ONE), // far to the right: culled
        (Vec3::new(0.0, 0.0, -1e30), Vec3::ONE),   // very far with an infinite far plane: kept
    ]);
    let visible = cull_and_check(&store, &camera);
    assert_eq!(visible.iter().collect::<Vec<_>>(), vec![0, 2, 4, 6]);
}

#[test]
fn finite_far_plane_culls_beyond_it() {
    let camera = Camera { far: Some(100.0), ..camera_at(Vec3::ZERO, Vec3::NEG_Z) };
    let store = store_of(&[(Vec3::new(0.0, 0.0, -99.5), Vec3::ONE), (Vec3::new(0.0, 0.0, -102.0), Vec3::ONE)]);
    for depth in [DepthConvention::Standard, DepthConvention::Reversed, DepthConvention::NegativeOneToOne] {
        let visible = cull_and_check(&store, &Camera { depth, ..camera });
        assert_eq!(visible.iter().collect::<Vec<_>>(), vec![0], "{depth:?}");
    }
}

#[test]
fn camera_ten_million_units_from_the_origin_stays_precise() {
    let origin = Vec3::new(1.0e7, 2.0e3, -1.0e7);
    let camera = camera_at(origin, Vec3::NEG_Z);
    // Boxes of 1 unit half-extent at 50 units, 10 units inside and 16 outside the right plane (at 60 degrees
    // vertical and 16:9 the horizontal half-angle is about 45.7 degrees). f32 positions are quantized to 1 unit
    // here and stored boxes grow by up to 5 units, so this is what culling can still resolve.
    let half_width = (30f32.to_radians().tan() * 16.0 / 9.0) * 50.0;
    let store = store_of(&[
        (origin + Vec3::new(half_width - 10.0, 0.0, -50.0), Vec3::ONE),
        (origin + Vec3::new(half_width + 16.0, 0.0, -50.0), Vec3::ONE),
        (origin + Vec3::new(0.0, 0.0, 20.0), Vec3::ONE),
    ]);
    let visible = cull_and_check(&store, &camera);
    assert_eq!(visible.iter().collect::<Vec<_>>(), vec![0], "culling must still resolve a few units at 1e7");
}

#[test]
fn tiny_near_plane_with_infinite_far() {
    for depth in [DepthConvention::Standard, DepthConvention::Reversed, DepthConvention::NegativeOneToOne] {
        let camera = Camera { near: 1e-4, far: None, depth, ..camera_at(Vec3::ZERO, Vec3::NEG_Z) };
        let frustum = camera.frustum().unwrap();
        assert_eq!(frustum.planes().len(), 5, "the infinite far plane is dropped");
        let store = store_of(&[
            (Vec3::new(0.0, 0.0, -2e-4), Vec3::ZERO),   // just past the near plane: kept
            (Vec3::new(0.0, 0.0, -0.5e-4), Vec3::ZERO), // just before it: culled
            (Vec3::new(0.0, 0.0, -1e-4), Vec3::ZERO),   // exactly on it: kept
            (Vec3::new(0.0, 0.0, -1e12), Vec3::ONE),    // far away: kept
        ]);
        let visible = cull_and_check(&store, &camera);
        assert_eq!(visible.iter().collect::<Vec<_>>(), vec![0, 2, 3], "{depth:?}");
    }
}

#[test]
fn extreme_fields_of_view_and_aspects() {
    let boxes: Vec<(Vec3, Vec3)> = (0..2000)
        .map(|i| {
            let a = i as f32 * 0.37;
            let b = i as f32 * 0.11;
            (Vec3::new(a.sin() * b.cos(), b.sin(), a.cos() * b.cos()) * (1.0 + i as f32 * 0.05), Vec3::splat(0.1))
        })
        .collect();
    let store = store_of(&boxes);
    for fov in [1.0f32, 10.0, 90.0, 170.0, 179.0] {
        for aspect in [0.1f32, 1.0, 10.0] {
            let camera = Camera { fov_y: fov.to_radians(), aspect, ..camera_at(Vec3::ZERO, Vec3::new(0.3, 0.1, -1.0)) };
            let visible = cull_and_check(&store, &camera);
            assert!(visible.count() < boxes.len(), "fov {fov} aspect {aspect}: something is culled");
        }
    }
}

/// Groups of 64 spatially coherent boxes: whole groups outside, inside and crossing, checked against the
/// reference and against per-object culling of the same boxes in shuffled order (where no group is decided).
/// Temporal coherence (last frame's rejecting plane tried first) gives the same bits as the full test, frame
/// after frame of a turning camera, and is used: blocks do remember a plane.
#[test]
fn plane_coherence_gives_the_same_bits_as_the_full_test() {
    // Scattered boxes, so that groups cross the frustum and the per-object kernel runs.
    let boxes: Vec<(Vec3, Vec3)> = (0..20_000)
        .map(|i| {
            let t = i as f32;
            let position = Vec3::new((t * 12.9898).sin(), (t * 4.1414).sin() * 0.1, (t * 78.233).sin()) * 500.0;
            (position, Vec3::splat(0.5 + (i % 5) as f32))
        })
        .collect();
    let store = store_of(&boxes);
    let mut coherence = PlaneCoherence::default();
    let mut remembered = 0;
    for frame in 0..40 {
        let angle = frame as f32 * 0.05;
        let camera = camera_at(Vec3::new(frame as f32, 2.0, 0.0), Vec3::new(angle.sin(), -0.05, -angle.cos()));
        let frustum = camera.frustum().unwrap();
        let (mut plain, mut coherent) = (VisibleSet::default(), VisibleSet::default());
        let plain_count = cull_frustum(
            &store,
            &frustum,
            FrustumOptions { backend: SimdBackend::Auto, ..Default::default() },
            &mut plain,
        );
        let coherent_count = cull_frustum(
            &store,
            &frustum,
            FrustumOptions { backend: SimdBackend::Auto, coherence: Some(&mut coherence), ..Default::default() },
            &mut coherent,
        );
        assert_eq!(plain, coherent, "frame {frame}");
        assert_eq!(plain_count, coherent_count);
        remembered += coherence.blocks_with_plane();
    }
    if SimdBackend::Auto.resolve() == SimdBackend::Avx2 {
        assert!(remembered > 0, "no block ever remembered a plane");
    }
}

#[test]
fn group_culling_agrees_with_per_object_culling() {
    let camera = camera_at(Vec3::new(3.0, 2.0, 1.0), Vec3::new(0.4, -0.1, -1.0));
    let mut boxes = Vec::new();
    for cluster in 0..200 {
        let angle = cluster as f32 * 0.7;
        let centre = Vec3::new(angle.sin(), (cluster % 7) as f32 * 0.1 - 0.3, angle.cos()) * (5.0 + cluster as f32);
        for i in 0..64 {
            let offset = Vec3::new((i % 4) as f32, (i / 16) as f32, ((i / 4) % 4) as f32) * 0.7;
            boxes.push((centre + offset, Vec3::splat(0.2 + (i % 3) as f32 * 0.1)));
        }
    }
    let grouped = cull_and_check(&store_of(&boxes), &camera);
    // A fixed permutation that scatters every group.
    let order: Vec<usize> = (0..boxes.len()).map(|i| (i * 7919) % boxes.len()).collect();
    let shuffled: Vec<(Vec3, Vec3)> = order.iter().map(|&i| boxes[i]).collect();
    let scattered = cull_and_check(&store_of(&shuffled), &camera);
    for (new_slot, &old_slot) in order.iter().enumerate() {
        assert_eq!(grouped.contains(old_slot), scattered.contains(new_slot), "box {old_slot}");
    }
    assert!(grouped.count() > 0 && grouped.count() < boxes.len());
}

#[test]
fn invalid_matrices_are_errors_not_silent_culls() {
    let camera = camera_at(Vec3::ZERO, Vec3::NEG_Z);
    assert!(Frustum::from_clip_from_relative(Vec3::NAN, camera.clip_from_relative(), camera.depth).is_err());
    let mut matrix = camera.clip_from_relative();
    matrix.x_axis.x = f32::INFINITY;
    assert!(Frustum::from_clip_from_world(matrix, camera.depth).is_err());
    assert!(Frustum::from_clip_from_world(glam::Mat4::ZERO, camera.depth).is_err());
}

#[test]
fn padding_never_shows_up_and_large_stores_split_across_tasks() {
    // 10_000 boxes: several rayon tasks and a partly filled last word of padding at the origin, in view.
    let camera = camera_at(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z);
    let boxes: Vec<(Vec3, Vec3)> = (0..10_000).map(|i| (Vec3::new(0.0, 0.0, 1000.0 + i as f32), Vec3::ONE)).collect();
    let visible = cull_and_check(&store_of(&boxes), &camera);
    assert_eq!(visible.count(), 0, "all boxes are behind the camera; padding slots must not appear");
    assert_eq!(visible.len(), 10_000);
}
