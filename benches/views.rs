//! Many views a frame: one camera, a sun's four shadow cascades and a point light's six cube faces, over the
//! built-in city's fly-through. Cullet's one pass over all eleven views ([`cull_views`]) against eleven passes
//! of its own, against the camera's view alone, and against Bevy's per-view `Frustum::intersects_obb` on the
//! same objects; then what each light view keeps, as a plain light frustum and as a shadow-caster view.
//!
//! `cargo bench -p cullet-benches --bench views [objects]` (1e6 by default; `CULLET_VIEWS_FRAMES` sets the
//! number of frames, 20 by default).

use bevy_camera::primitives::{Aabb, Frustum as BevyFrustum};
use bevy_shape::ViewFrustum;
use cullet::frustum::{Light, View, cascade_clip_from_relative, cascade_frustum, cube_face_cameras, cull_views};
use cullet::scene::city::{CityParams, CityScene};
use cullet::{BoundsStore, Camera, VisibleSet};
use glam::{DMat4, Vec3};
use std::hint::black_box;
use std::time::{Duration, Instant};

#[path = "bevy_frustum/mod.rs"]
mod bevy_frustum;
use bevy_frustum::cull_bevy;

/// Cascade splits, in view distance (m).
const SPLITS: [f32; 5] = [0.1, 12.0, 40.0, 120.0, 400.0];
/// The sun's direction of travel.
const SUN: Vec3 = Vec3::new(0.35, -1.0, 0.25);
/// The point light, relative to the camera, and its faces' far distance.
const LAMP_OFFSET: Vec3 = Vec3::new(4.0, 6.0, -8.0);
const LAMP_RANGE: f32 = 60.0;
/// Passes over the path; the fastest counts.
const PASSES: usize = 5;

/// One frame's eleven views, as Cullet culls them and as Bevy's frustums of the same matrices.
struct FrameViews {
    /// Camera, cascades (shadow casters), cube faces (shadow casters).
    casters: Vec<View>,
    /// Camera, then the same light frustums as plain views.
    plain: Vec<View>,
    bevy: Vec<BevyFrustum>,
}

fn frame_views(camera: &Camera) -> FrameViews {
    let camera_frustum = camera.frustum().unwrap();
    let bevy_frustum = |clip_from_world: DMat4| {
        let m = bevy_math::Mat4::from_cols_array(&clip_from_world.as_mat4().to_cols_array());
        BevyFrustum(ViewFrustum::from_clip_from_world(&m))
    };
    let to_relative = DMat4::from_translation(-camera.position.as_dvec3());
    let mut views = FrameViews {
        casters: vec![View::new(camera_frustum)],
        plain: vec![View::new(camera_frustum)],
        bevy: vec![bevy_frustum(camera.clip_from_relative_f64() * to_relative)],
    };
    let sun = Light::Directional { direction: SUN };
    for split in SPLITS.windows(2) {
        let frustum = cascade_frustum(camera, SUN, split[0], split[1]).unwrap();
        views.casters.push(View::shadow_casters(frustum, sun, &camera_frustum).unwrap());
        views.plain.push(View::new(frustum));
        let matrix = cascade_clip_from_relative(camera, SUN, split[0], split[1]).unwrap();
        views.bevy.push(bevy_frustum(matrix * to_relative));
    }
    let lamp = camera.position + LAMP_OFFSET;
    for face in cube_face_cameras(lamp, 0.05, Some(LAMP_RANGE)) {
        let frustum = face.frustum().unwrap();
        views.casters.push(View::shadow_casters(frustum, Light::Point { position: lamp }, &camera_frustum).unwrap());
        views.plain.push(View::new(frustum));
        let to_face = DMat4::from_translation(-face.position.as_dvec3());
        views.bevy.push(bevy_frustum(face.clip_from_relative_f64() * to_face));
    }
    views
}

/// The fastest of [`PASSES`] runs of `frame` over every frame, in ms per frame.
fn time_per_frame(frames: &[FrameViews], mut frame: impl FnMut(&FrameViews)) -> f64 {
    let mut best = Duration::MAX;
    for _ in 0..PASSES {
        let start = Instant::now();
        frames.iter().for_each(&mut frame);
        best = best.min(start.elapsed());
    }
    best.as_secs_f64() * 1e3 / frames.len() as f64
}

fn main() {
    let objects: usize = std::env::args().skip(1).find_map(|a| a.parse().ok()).unwrap_or(1_000_000);
    let frame_count: usize = std::env::var("CULLET_VIEWS_FRAMES").ok().and_then(|v| v.parse().ok()).unwrap_or(20);
    let city = CityScene::generate(CityParams::with_objects(objects));
    let mut store = BoundsStore::default();
    let mut bevy_objects = Vec::with_capacity(objects);
    for (i, object) in city.scene.objects.iter().enumerate() {
        let local = city.scene.mesh_bounds[object.mesh as usize];
        let entity = bevy_ecs::entity::Entity::from_raw_u32(i as u32 + 1).unwrap();
        store.update(entity, &local, &cullet::ObjectTransform(object.transform)).unwrap();
        let aabb = Aabb {
            center: bevy_math::Vec3A::from_array(local.center.to_array()),
            half_extents: bevy_math::Vec3A::from_array(local.half_extent.to_array()),
        };
        bevy_objects.push((aabb, bevy_math::Affine3A::from_cols_array(&object.transform.to_cols_array())));
    }
    let path = city.flythrough();
    let duration = path.duration();
    let frames: Vec<FrameViews> = (0..frame_count)
        .map(|i| frame_views(&path.camera_at(duration * (i as f32 + 0.5) / frame_count as f32, 16.0 / 9.0)))
        .collect();
    let threads = rayon::current_num_threads();
    println!("# {} objects, {frame_count} frames of the fly-through, {threads} threads", store.len());
    println!(
        "# views: camera, 4 cascades of a sun (splits {SPLITS:?} m), 6 faces of a point light (range {LAMP_RANGE} m)"
    );

    let mut sets = Vec::new();
    let camera_alone = time_per_frame(&frames, |f| {
        black_box(cull_views(&store, &f.casters[..1], &mut sets));
    });
    let one_pass = time_per_frame(&frames, |f| {
        black_box(cull_views(&store, &f.casters, &mut sets));
    });
    let separate = time_per_frame(&frames, |f| {
        for view in &f.casters {
            black_box(cull_views(&store, std::slice::from_ref(view), &mut sets));
        }
    });
    let plain_one_pass = time_per_frame(&frames, |f| {
        black_box(cull_views(&store, &f.plain, &mut sets));
    });
    let mut visible = VisibleSet::default();
    let bevy = time_per_frame(&frames, |f| {
        for frustum in &f.bevy {
            black_box(cull_bevy(&bevy_objects, frustum, &mut visible));
        }
    });
    println!();
    println!("| configuration | ms/frame | x camera alone |");
    println!("| --- | --- | --- |");
    for (name, ms) in [
        ("camera alone (1 view)", camera_alone),
        ("11 views, one pass (shadow casters)", one_pass),
        ("11 views, a pass each (shadow casters)", separate),
        ("11 views, one pass (plain light frustums)", plain_one_pass),
        ("11 views, Bevy's intersects_obb per view", bevy),
    ] {
        println!("| {name} | {ms:.3} | {:.2} |", ms / camera_alone);
    }

    // What each view keeps, averaged over the frames.
    let names: Vec<String> = std::iter::once("camera".to_string())
        .chain((1..SPLITS.len()).map(|i| format!("cascade {i}")))
        .chain(["+x", "-x", "+y", "-y", "+z", "-z"].map(|face| format!("lamp {face}")))
        .collect();
    let mut kept_casters = vec![0usize; names.len()];
    let mut kept_plain = vec![0usize; names.len()];
    for frame in &frames {
        let counts = cull_views(&store, &frame.casters, &mut sets);
        kept_casters.iter_mut().zip(counts).for_each(|(total, count)| *total += count);
        let counts = cull_views(&store, &frame.plain, &mut sets);
        kept_plain.iter_mut().zip(counts).for_each(|(total, count)| *total += count);
    }
    println!();
    println!("| view | kept as a plain frustum | kept as shadow casters | casters saved |");
    println!("| --- | --- | --- | --- |");
    let per_frame = |total: usize| total as f64 / frames.len() as f64;
    for ((name, plain), casters) in names.iter().zip(&kept_plain).zip(&kept_casters) {
        let saved = if *plain > 0 { 100.0 * (1.0 - *casters as f64 / *plain as f64) } else { 0.0 };
        println!("| {name} | {:.0} | {:.0} | {saved:.1}% |", per_frame(*plain), per_frame(*casters));
    }
    let (plain_lights, caster_lights): (usize, usize) = (kept_plain[1..].iter().sum(), kept_casters[1..].iter().sum());
    println!(
        "| all light views | {:.0} | {:.0} | {:.1}% |",
        per_frame(plain_lights),
        per_frame(caster_lights),
        100.0 * (1.0 - caster_lights as f64 / plain_lights.max(1) as f64)
    );
}
