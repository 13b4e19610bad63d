//! Levels of detail through the plugin: each entity the main camera keeps gets the level Cullet's selection
//! chooses, written as a component where it changes.

mod support;

use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::Visibility;
use bevy_cullet::{CulletLod, CulletLodStats, CulletSettings, LodLevel};
use bevy_math::Vec3;
use bevy_transform::prelude::*;
use cullet::MeshRef;
use cullet::lod::{LodLevel as Level, LodLibrary, LodSettings};
use cullet::mesh::Mesh;
use support::*;

#[test]
fn kept_entities_get_their_level_and_follow_the_camera() {
    let mut app = app(Some(CulletSettings::default()));
    // Two levels: full detail, and a box 0.05 units off it.
    let library = LodLibrary::from_chains(vec![vec![
        Level { mesh: Mesh::unit_cube(8), error: 0.0 },
        Level { mesh: Mesh::unit_cube(1), error: 0.05 },
    ]])
    .unwrap();
    app.world_mut().insert_resource(CulletLod { library, settings: LodSettings::pixels(1.0, 1080) });
    let camera = cullet::Camera {
        fov_y: 90f32.to_radians(),
        aspect: 1.0,
        ..cullet::Camera::looking_at(glam::Vec3::ZERO, glam::Vec3::NEG_Z)
    };
    spawn_camera(app.world_mut(), &camera, 1000.0);
    let unit = Aabb::from_min_max(Vec3::splat(-0.5), Vec3::splat(0.5));
    let mut spawn = |z: f32| {
        let at = Transform::from_xyz(0.0, 0.0, z);
        app.world_mut().spawn((unit, at, Visibility::default(), drawn(), MeshRef(0))).id()
    };
    let (near, far, behind) = (spawn(-5.0), spawn(-500.0), spawn(50.0));
    app.update();
    let level = |app: &bevy_app::App, entity| app.world().get::<LodLevel>(entity).copied();
    // 0.05 units project to about 5 pixels at 5 units (focal 540 px), 0.05 at 500.
    assert_eq!(level(&app, near), Some(LodLevel { level: 0, dropped: false }));
    assert_eq!(level(&app, far), Some(LodLevel { level: 1, dropped: false }));
    assert_eq!(level(&app, behind), None, "not kept: never chosen for");
    let stats = app.world().resource::<CulletLodStats>().0;
    assert_eq!((stats.objects, stats.triangles_full, stats.triangles), (2, 2 * 768, 768 + 12));

    // The far one comes near: full detail the next frame.
    app.world_mut().get_mut::<Transform>(far).unwrap().translation = Vec3::new(1.0, 0.0, -5.0);
    app.update();
    assert_eq!(level(&app, far), Some(LodLevel { level: 0, dropped: false }));

    // A budget below both: the smaller on screen is dropped, and its level says so.
    app.world_mut().resource_mut::<CulletLod>().settings.triangle_budget = Some(20);
    app.world_mut().get_mut::<Transform>(far).unwrap().translation = Vec3::new(0.0, 0.0, -50.0);
    app.update();
    assert!(level(&app, far).unwrap().dropped && !level(&app, near).unwrap().dropped);
    assert!(app.world().resource::<CulletLodStats>().0.triangles <= 20);
    // Without the budget it is drawn again, and its level says so.
    app.world_mut().resource_mut::<CulletLod>().settings.triangle_budget = None;
    app.update();
    assert!(!level(&app, far).unwrap().dropped);
}

/// Levels made from a Bevy mesh: each entity with [`LodMeshes`] draws the mesh of its level, and one the triangle
/// budget drops leaves the camera's visible list (and comes back when the budget allows it).
#[test]
fn lod_meshes_follow_the_level_and_dropped_entities_leave_the_visible_list() {
    use bevy_asset::Assets;
    use bevy_camera::visibility::VisibleEntities;
    use bevy_cullet::{LodMeshes, mesh_levels};
    use bevy_mesh::{Mesh, Mesh3d, Meshable};

    let mut app = app(Some(CulletSettings::default()));
    let sphere = bevy_shape::Sphere::new(1.0).mesh().ico(5).unwrap();
    let levels = mesh_levels(&sphere, &cullet::lod::ChainSettings::default()).unwrap();
    assert!(levels.meshes.len() >= 3, "{} levels", levels.meshes.len());
    let coarsest_triangles = levels.chain.last().unwrap().mesh.triangle_count() as u64;
    for (level, mesh) in levels.chain.iter().zip(&levels.meshes) {
        // Every vertex kept, with its normal: only the triangles change.
        assert_eq!(mesh.count_vertices(), sphere.count_vertices());
        assert!(mesh.attribute(Mesh::ATTRIBUTE_NORMAL).is_some());
        assert_eq!(mesh.indices().unwrap().len(), 3 * level.mesh.triangle_count());
    }
    let handles: Vec<_> = {
        let mut assets = app.world_mut().resource_mut::<Assets<Mesh>>();
        levels.meshes.into_iter().map(|mesh| assets.add(mesh)).collect()
    };
    let library = LodLibrary::from_chains(vec![levels.chain]).unwrap();
    app.world_mut().insert_resource(CulletLod { library, settings: LodSettings::pixels(1.0, 1080) });
    let camera = cullet::Camera {
        fov_y: 90f32.to_radians(),
        aspect: 1.0,
        ..cullet::Camera::looking_at(glam::Vec3::ZERO, glam::Vec3::NEG_Z)
    };
    let camera_entity = spawn_camera(app.world_mut(), &camera, 1000.0);
    let mut spawn = |z: f32| {
        let at = Transform::from_xyz(0.0, 0.0, z);
        let meshes = (Mesh3d(handles[0].clone()), LodMeshes(handles.clone()));
        app.world_mut().spawn((meshes, at, Visibility::default(), drawn(), MeshRef(0))).id()
    };
    let (near, far) = (spawn(-2.0), spawn(-300.0));
    // The first frame computes the bounds from the mesh; the second culls and chooses.
    app.update();
    app.update();
    let drawn_mesh = |app: &bevy_app::App, entity| app.world().get::<Mesh3d>(entity).unwrap().0.clone();
    let level = |app: &bevy_app::App, entity| app.world().get::<LodLevel>(entity).copied().unwrap();
    let (near_level, far_level) = (level(&app, near), level(&app, far));
    assert!(near_level.level < far_level.level, "{near_level:?} {far_level:?}");
    for (entity, chosen) in [(near, near_level), (far, far_level)] {
        assert_eq!(drawn_mesh(&app, entity), handles[chosen.level as usize]);
    }
    let listed = |app: &bevy_app::App, entity| {
        let visible = app.world().get::<VisibleEntities>(camera_entity).unwrap();
        visible.entities.values().any(|list| list.contains(&entity))
    };
    assert!(listed(&app, near) && listed(&app, far));

    // A budget of one coarsest level: one of the two is dropped and leaves the list, the other stays.
    let coarsest = coarsest_triangles;
    app.world_mut().resource_mut::<CulletLod>().settings.triangle_budget = Some(coarsest);
    app.update();
    let (dropped, kept) = if level(&app, near).dropped { (near, far) } else { (far, near) };
    assert!(level(&app, dropped).dropped && !level(&app, kept).dropped);
    assert!(!listed(&app, dropped) && listed(&app, kept));
    app.world_mut().resource_mut::<CulletLod>().settings.triangle_budget = None;
    app.update();
    assert!(!level(&app, dropped).dropped && listed(&app, dropped));
}
