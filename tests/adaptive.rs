//! Adaptive stages: unchanged frames reuse their result, an occlusion stage that removes too little is skipped
//! and re-probed, the fixed pipeline never gates, and gating adds no false negatives on the built-in scenes
//! (city, field, cad) against the exact rendering.

use cullet::camera::CameraPath;
use cullet::mesh::Mesh;
use cullet::pipeline::{AdaptiveSettings, CullStats, OcclusionSettings};
use cullet::scene::flight::Flight;
use cullet::scene::{Scene, SceneObject};
use cullet::{Camera, ObjectTransform, Occluder};
use glam::{Affine3A, Vec3};

/// A wall with an occluder 20 units in front of the camera and `behind` boxes behind it, `beside` boxes
/// beside it.
fn wall_scene(behind: usize, beside: usize) -> Scene {
    let cube = Mesh::unit_cube(1);
    let occluder = Occluder::new(Mesh::unit_cube(1).scaled(Vec3::splat(0.98), Vec3::ZERO).triangle_soup());
    let mut objects = vec![SceneObject {
        mesh: 0,
        transform: Affine3A::from_scale_rotation_translation(
            Vec3::new(20.0, 10.0, 1.0),
            glam::Quat::IDENTITY,
            Vec3::new(0.0, 0.0, -20.0),
        ),
        occluder: Some(occluder),
        velocity: None,
        color: [200; 4],
    }];
    let place = |x: f32, z: f32| SceneObject {
        mesh: 0,
        transform: Affine3A::from_translation(Vec3::new(x, 0.0, z)),
        occluder: None,
        velocity: None,
        color: [200; 4],
    };
    objects.extend((0..behind).map(|i| place(i as f32 - behind as f32 * 0.5, -40.0)));
    objects.extend((0..beside).map(|i| place(30.0 + i as f32 * 2.0, -60.0)));
    Scene::new(vec![cube], objects)
}

fn flight(scene: &Scene, adaptive: AdaptiveSettings) -> Flight {
    let path = CameraPath { fov_y_deg: 90.0, near: 0.1, far: None, keys: Vec::new() };
    let mut flight = Flight::new(path, 1.0, 1, OcclusionSettings::default(), |world| {
        scene.spawn(world);
    });
    flight.world.insert_resource(adaptive);
    flight
}

fn camera() -> Camera {
    Camera { aspect: 1.0, fov_y: 90f32.to_radians(), ..Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z) }
}

#[test]
fn unchanged_frames_reuse_the_last_result_and_any_change_reruns() {
    let scene = wall_scene(8, 4);
    let mut flight = flight(&scene, AdaptiveSettings::default());
    let first = flight.run_with_camera(camera(), 0.0);
    assert!(!first.reused && first.after_occlusion < first.after_frustum, "{first:?}");
    let second = flight.run_with_camera(camera(), 0.0);
    assert!(second.reused);
    assert_eq!((second.after_frustum, second.after_occlusion), (first.after_frustum, first.after_occlusion));
    // The camera turns: run again.
    let turned = Camera { forward: Vec3::new(0.1, 0.0, -1.0), ..camera() };
    assert!(!flight.run_with_camera(turned, 0.0).reused);
    assert!(flight.run_with_camera(turned, 0.0).reused);
    // An object moves (a static one, so by inserting its new transform): run again.
    let entity = flight.world.resource::<cullet::BoundsStore>().entities()[3];
    flight.world.entity_mut(entity).insert(ObjectTransform(Affine3A::from_translation(Vec3::new(0.0, 0.0, 10.0))));
    let moved = flight.run_with_camera(turned, 0.0);
    assert!(!moved.reused);
    // A setting changes: run again.
    flight.world.resource_mut::<OcclusionSettings>().width = 128;
    assert!(!flight.run_with_camera(turned, 0.0).reused);
    // The fixed pipeline never reuses.
    let mut fixed = self::flight(&scene, AdaptiveSettings::fixed());
    fixed.run_with_camera(camera(), 0.0);
    assert!(!fixed.run_with_camera(camera(), 0.0).reused);
}

#[test]
fn occlusion_that_removes_nothing_is_skipped_then_reprobed() {
    // Nothing behind the wall: occlusion runs, removes nothing.
    let scene = wall_scene(0, 6);
    let adaptive =
        AdaptiveSettings { reuse_unchanged: false, low_benefit_frames: 3, reprobe_every: 5, ..Default::default() };
    let mut flight = flight(&scene, adaptive);
    let gated: Vec<bool> =
        (0..12).map(|_| flight.run_with_camera(camera(), 0.0)).map(|s: CullStats| s.occlusion_gated).collect();
    // 3 frames that remove nothing, 5 skipped, a probe that removes nothing, ...
    assert_eq!(gated, [false, false, false, true, true, true, true, true, false, false, false, true]);
    // Where occlusion pays, it is never skipped.
    let mut paying = self::flight(&wall_scene(8, 0), adaptive);
    assert!((0..12).all(|_| !paying.run_with_camera(camera(), 0.0).occlusion_gated));
}

/// The built-in scenes along their paths, default (adaptive) pipeline: zero false negatives.
#[test]
fn gating_adds_no_false_negatives_on_the_built_in_scenes() {
    let city = cullet::scene::city::CityScene::generate(cullet::scene::city::CityParams::with_objects(3000));
    let scenes = [
        ("city", city.scene.clone(), city.flythrough()),
        ("field", cullet::scene::field::field(3000).0, cullet::scene::field::field(3000).1),
        ("cad", cullet::scene::cad::cad(2000).0, cullet::scene::cad::cad(2000).1),
    ];
    for (name, scene, path) in scenes {
        // The path, then its last frame twice more: reused, and judged again.
        let frames = 24;
        let metrics = cullet_test_support::fly_and_judge(&scene, path, frames, (0..frames).chain([frames - 1; 2]));
        println!("{name}: {metrics:?}");
    }
}

/// Plane coherence in the pipeline: along the city's path, the frustum stage keeps exactly the objects the
/// all-planes test keeps, frame after frame.
#[test]
fn plane_coherence_keeps_exactly_what_all_planes_keep() {
    let city = cullet::scene::city::CityScene::generate(cullet::scene::city::CityParams::with_objects(5000));
    let run = |adaptive: AdaptiveSettings| {
        let mut flight = Flight::new(city.flythrough(), 16.0 / 9.0, 60, OcclusionSettings::default(), |world| {
            city.spawn(world);
        });
        flight.world.insert_resource(adaptive);
        (0..60)
            .map(|frame| {
                flight.run_frame(frame);
                flight.world.resource::<cullet::pipeline::FrustumVisible>().0.clone()
            })
            .collect::<Vec<_>>()
    };
    let coherent = run(AdaptiveSettings { plane_coherence: true, ..AdaptiveSettings::fixed() });
    let all_planes = run(AdaptiveSettings::fixed());
    for (frame, (a, b)) in coherent.iter().zip(&all_planes).enumerate() {
        assert_eq!(a, b, "frame {frame}");
    }
}

/// A static camera over the city while its cars move: after the first frame only the cars are re-tested, and
/// both stages keep exactly what the full (fixed) pipeline keeps, frame after frame. An occluder that moves
/// makes the next frame run in full.
#[test]
fn only_moved_objects_are_retested_and_keep_what_a_full_run_keeps() {
    let city = cullet::scene::city::CityScene::generate(cullet::scene::city::CityParams::with_objects(5000));
    let mut path = city.flythrough();
    path.keys.truncate(1);
    let run = |adaptive: AdaptiveSettings, frames: u32| {
        let mut flight = Flight::new(path.clone(), 16.0 / 9.0, frames, OcclusionSettings::default(), |world| {
            city.spawn(world);
        });
        flight.world.insert_resource(adaptive);
        (0..frames)
            .map(|frame| {
                let stats = flight.run_frame(frame);
                let world = &flight.world;
                let occlusion = world.resource::<cullet::pipeline::OcclusionState>();
                let frustum = world.resource::<cullet::pipeline::FrustumVisible>().0.clone();
                (stats, frustum, occlusion.visible.clone(), occlusion.occluded.clone())
            })
            .collect::<Vec<_>>()
    };
    let frames = 30;
    let adaptive = run(AdaptiveSettings::default(), frames);
    let fixed = run(AdaptiveSettings::fixed(), frames);
    let moving = city.scene.objects.iter().filter(|o| o.velocity.is_some()).count();
    assert!(moving > 0);
    for (frame, (a, f)) in adaptive.iter().zip(&fixed).enumerate() {
        assert_eq!(a.1, f.1, "frame {frame}: frustum");
        assert_eq!(a.2, f.2, "frame {frame}: occlusion visible");
        assert_eq!(a.3, f.3, "frame {frame}: occluded");
        assert_eq!((a.0.after_frustum, a.0.after_occlusion), (f.0.after_frustum, f.0.after_occlusion));
        if frame > 0 {
            assert_eq!(a.0.retested, moving, "frame {frame}: only the cars are re-tested");
        }
    }
    assert!(adaptive[5].0.after_occlusion < adaptive[5].0.after_frustum, "occlusion does cull here");

    // An occluder moves: the next frame runs in full.
    let scene = wall_scene(8, 4);
    let mut flight = flight(&scene, AdaptiveSettings::default());
    flight.run_with_camera(camera(), 0.0);
    let boxes: Vec<_> = flight
        .world
        .query::<(bevy_ecs::entity::Entity, &ObjectTransform)>()
        .iter(&flight.world)
        .map(|(e, _)| e)
        .collect();
    let wall = boxes.into_iter().find(|&e| flight.world.get::<Occluder>(e).is_some()).unwrap();
    let mut moved_wall = *flight.world.get::<ObjectTransform>(wall).unwrap();
    moved_wall.0.translation.x += 5.0;
    flight.world.entity_mut(wall).insert(moved_wall);
    let after = flight.run_with_camera(camera(), 0.0);
    assert_eq!((after.reused, after.retested), (false, 0), "{after:?}");
}
