//! Levels of detail: generation, selection with hysteresis, the triangle budget, and their image error
//! judged exactly against full detail on the city fly-through.

use bevy_ecs::prelude::*;
use cullet::VisibleSet;
use cullet::culler::OcclusionSettings;
use cullet::lod::{self, ChainSettings, LodError, LodLevel, LodLibrary, LodSelection, LodSettings};
use cullet::mesh::Mesh;
use cullet::prelude::*;
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use cullet_truth::ReferenceSettings;
use cullet_truth::lod::{ImageError, judge_lod};
use glam::{Affine3A, Vec3};

/// A flight through a city of `objects` objects with level selection installed.
fn city_flight(objects: usize, frames: u32, settings: LodSettings) -> Flight {
    let city = CityScene::generate(CityParams::with_objects(objects));
    let library = LodLibrary::build(&city.scene.meshes, &ChainSettings::default());
    let mut flight = Flight::new(city.flythrough(), 16.0 / 9.0, frames, OcclusionSettings::default(), |world| {
        city.scene.spawn(world);
    });
    lod::install(&mut flight.world, &mut flight.schedule, library, settings);
    flight
}

#[test]
fn one_pixel_of_error_halves_the_city_s_triangles_and_changes_almost_no_pixel() {
    // At the resolution the threshold is meant for: a pixel of a 1080-line frame.
    let (width, height, frames) = (1920, 1080, 12);
    let mut flight = city_flight(4_000, frames, LodSettings::pixels(1.0, height));
    let reference = ReferenceSettings { width, height, cull_back_faces: true };
    let (mut full, mut drawn, mut error) = (0, 0, ImageError::default());
    for frame in 0..frames {
        flight.run_frame(frame);
        let stats = flight.world.resource::<LodSelection>().stats();
        (full, drawn) = (full + stats.triangles_full, drawn + stats.triangles);
        error.add(&judge_lod(&flight.world, flight.world.resource::<LodLibrary>(), &reference));
    }
    assert!(drawn * 2 <= full, "{drawn} of {full} triangles drawn");
    assert!(error.changed_fraction() <= 0.001, "{error:?}");
}

#[test]
fn hysteresis_keeps_an_object_near_the_threshold_at_its_level() {
    // A sphere-ish mesh with real levels: a subdivided box bent into a ball.
    let mut ball = Mesh::unit_cube(12);
    for p in &mut ball.positions {
        *p = p.normalize() * 0.5;
    }
    let library = LodLibrary::build(&[ball], &ChainSettings::default());
    assert!(library.levels(0) >= 3, "{} levels", library.levels(0));
    let (mut world, mut schedule) = (World::new(), Schedule::default());
    cullet::install(&mut world, &mut schedule, PipelineSettings::default());
    lod::install(&mut world, &mut schedule, library.clone(), LodSettings::pixels(1.0, 1080));
    let unit = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) };
    let object = world.spawn((unit, ObjectTransform(Affine3A::IDENTITY), MeshRef(0))).id();
    // Find a distance where the level switches, then wobble around it by less than the hysteresis.
    let level_at = |world: &mut World, schedule: &mut Schedule, distance: f32| {
        world.insert_resource(Camera::looking_at(Vec3::new(0.0, 0.0, distance), Vec3::ZERO));
        schedule.run(world);
        world.clear_trackers();
        let slot = world.resource::<BoundsStore>().slot_of(object).unwrap();
        world.resource::<LodSelection>().level(slot).unwrap()
    };
    let mut distance = 1.0;
    let start = level_at(&mut world, &mut schedule, distance);
    while level_at(&mut world, &mut schedule, distance * 1.02) == start {
        distance *= 1.02;
        assert!(distance < 1e5, "no switch");
    }
    let switches_before = world.resource::<LodSelection>().stats().switches;
    assert_eq!(switches_before, 1, "one switch on the way out");
    let mut switches = 0;
    for frame in 0..20 {
        let wobble = if frame % 2 == 0 { 0.97 } else { 1.03 };
        level_at(&mut world, &mut schedule, distance * wobble);
        switches += world.resource::<LodSelection>().stats().switches;
    }
    assert!(switches <= 1, "{switches} switches wobbling across the threshold");
}

#[test]
fn the_budget_is_never_exceeded_and_the_choice_stays_stable() {
    let frames = 24;
    let budget = 30_000;
    let settings = LodSettings { triangle_budget: Some(budget), ..LodSettings::pixels(1.0, 1080) };
    let mut flight = city_flight(4_000, frames, settings);
    let (mut switches, mut objects, mut over_threshold) = (0, 0, 0);
    for frame in 0..frames {
        flight.run_frame(frame);
        let stats = flight.world.resource::<LodSelection>().stats();
        assert!(stats.triangles <= budget, "frame {frame}: {} triangles", stats.triangles);
        (switches, objects) = (switches + stats.switches, objects + stats.objects);
        over_threshold += (stats.triangles < stats.triangles_full) as usize;
    }
    assert!(over_threshold > 0, "the budget bound some frame");
    assert!(switches * 10 < objects, "{switches} switches over {objects} object-frames");

    // A budget below every object's coarsest level drops the smallest on screen, and still holds.
    let tiny = LodSettings { triangle_budget: Some(100), ..LodSettings::pixels(1.0, 1080) };
    let mut flight = city_flight(2_000, 2, tiny);
    flight.run_frame(0);
    let selection = flight.world.resource::<LodSelection>();
    let stats = selection.stats();
    assert!(stats.triangles <= 100 && stats.dropped > 0, "{stats:?}");
    // Dropping an object, and drawing it again, changes the mesh it draws: a GPU copy rewrites it.
    let dropped: Vec<u32> = selection.dropped().iter().map(|slot| slot as u32).collect();
    assert!(dropped.iter().all(|slot| selection.changed().binary_search(slot).is_ok()));
    *flight.world.resource_mut::<LodSettings>() = LodSettings::pixels(1.0, 1080);
    flight.run_frame(1);
    let selection = flight.world.resource::<LodSelection>();
    assert_eq!(selection.dropped().count(), 0);
    assert!(dropped.iter().all(|slot| selection.changed().binary_search(slot).is_ok()), "restored objects");
}

#[test]
fn off_means_full_detail_at_no_cost() {
    let mut flight = city_flight(2_000, 3, LodSettings::pixels(2.0, 1080));
    flight.run_frame(0);
    assert!(
        flight.world.resource::<LodSelection>().stats().triangles
            < flight.world.resource::<LodSelection>().stats().triangles_full
    );
    *flight.world.resource_mut::<LodSettings>() = LodSettings::default();
    flight.run_frame(1);
    let selection = flight.world.resource::<LodSelection>();
    assert!(!selection.changed().is_empty(), "back to full detail");
    let store = flight.world.resource::<BoundsStore>();
    assert!((0..store.len()).all(|slot| selection.level(slot).is_none_or(|l| l == 0)));
    flight.run_frame(2);
    let selection = flight.world.resource::<LodSelection>();
    assert_eq!((selection.changed().len(), selection.stats().objects), (0, 0));
}

#[test]
fn given_levels_are_checked() {
    let cube = Mesh::unit_cube(1);
    let level = |error| LodLevel { mesh: cube.clone(), error };
    assert!(LodLibrary::from_chains(vec![vec![level(0.0), level(0.5)]]).is_ok());
    assert!(matches!(LodLibrary::from_chains(vec![vec![]]), Err(LodError::LevelCount { levels: 0 })));
    assert!(matches!(
        LodLibrary::from_chains(vec![vec![level(0.0), level(0.5), level(0.2)]]),
        Err(LodError::UnorderedLevels { level: 2, .. })
    ));
    assert!(matches!(LodLibrary::from_chains(vec![vec![level(f32::NAN)]]), Err(LodError::UnorderedLevels { .. })));
    // A broken mesh keeps itself as its only level, and says why.
    let mut broken = Mesh::unit_cube(2);
    broken.indices[5] = 1_000;
    let library = LodLibrary::build(&[Mesh::unit_cube(8), broken], &ChainSettings::default());
    assert_eq!((library.levels(0), library.levels(1)), (2, 1));
    assert!(matches!(library.errors(), [(1, LodError::IndexOutOfRange { index: 1_000, .. })]));
}

#[test]
fn degenerate_input_keeps_full_detail_and_never_panics() {
    let library = LodLibrary::from_chains(vec![vec![
        LodLevel { mesh: Mesh::unit_cube(8), error: 0.0 },
        LodLevel { mesh: Mesh::unit_cube(1), error: 0.01 },
    ]])
    .unwrap();
    let store = cullet_test_support::store_of(&[(Vec3::new(0.0, 0.0, -100.0), Vec3::splat(0.5)); 3]);
    let mut selection = LodSelection::default();
    // Slot 0 a zero scale, slot 1 a NaN scale, slot 2 no levels.
    selection.set_object(0, Some(0), 0.0);
    selection.set_object(1, Some(0), f32::NAN);
    selection.set_object(2, None, 1.0);
    let camera = Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z);
    // A set longer than the store, every bit set.
    let visible = VisibleSet::all(200);
    for settings in [
        LodSettings::pixels(1.0, 1080),
        LodSettings::pixels(f32::INFINITY, 1080),
        LodSettings { triangle_budget: Some(0), ..LodSettings::pixels(1.0, 1080) },
        LodSettings { hysteresis: 7.0, ..LodSettings::pixels(1.0, 0) },
    ] {
        selection.select(&library, &store, &camera, &visible, &settings);
        assert!(selection.stats().triangles <= settings.triangle_budget.unwrap_or(u64::MAX));
    }
    let mut camera = camera;
    camera.position = Vec3::NAN;
    selection.select(&library, &store, &camera, &visible, &LodSettings::pixels(1.0, 1080));
    assert_eq!([selection.level(0), selection.level(1), selection.level(2)], [Some(0), Some(0), None]);
    // Far from the origin, the same choice as near it.
    let offset = Vec3::splat(1e6);
    let far_store = cullet_test_support::store_of(&[(offset + Vec3::new(0.0, 0.0, -100.0), Vec3::splat(0.5))]);
    let mut far = LodSelection::default();
    far.set_object(0, Some(0), 1.0);
    let far_camera = Camera::looking_at(offset, offset + Vec3::NEG_Z);
    far.select(&library, &far_store, &far_camera, &VisibleSet::all(1), &LodSettings::pixels(1.0, 1080));
    let mut near = LodSelection::default();
    near.set_object(0, Some(0), 1.0);
    let near_store = cullet_test_support::store_of(&[(Vec3::new(0.0, 0.0, -100.0), Vec3::splat(0.5))]);
    near.select(
        &library,
        &near_store,
        &Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z),
        &VisibleSet::all(1),
        &LodSettings::pixels(1.0, 1080),
    );
    assert_eq!(far.level(0), near.level(0));
    // Detail culling too takes a set longer than the store.
    let mut longer = VisibleSet::all(200);
    let detail = cullet::detail::DetailSettings { min_pixels: 4.0, viewport_height: 1080 };
    cullet::detail::cull_small(&store, &Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z), &detail, &mut longer);
}
