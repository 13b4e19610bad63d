//! The engine in a plain `bevy_ecs` world, CPU stages only: 10 000 boxes in a grid, a row of walls that carry
//! occluders, one frame culled, the visible set read back.
//!
//! `cargo run -p cullet --no-default-features --example plain_world`

use bevy_ecs::prelude::*;
use cullet::prelude::*;
use glam::{Affine3A, Vec3};

fn main() {
    let (mut world, mut schedule) = (World::new(), Schedule::default());
    cullet::install(&mut world, &mut schedule, PipelineSettings::default());

    // 100 x 100 unit boxes on the ground, 4 units apart.
    let unit_box = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) };
    for i in 0..10_000 {
        let position = Vec3::new((i % 100) as f32 * 4.0 - 200.0, 0.5, (i / 100) as f32 * 4.0 - 200.0);
        world.spawn((unit_box, ObjectTransform(Affine3A::from_translation(position)), Static));
    }

    // Five walls across the view, 20 wide and 10 high: each object's occluder is its own box's faces.
    let wall = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::new(10.0, 5.0, 0.5) };
    let occluder = Occluder::new(Mesh::unit_cube(1).scaled(wall.half_extent * 2.0, Vec3::ZERO).triangle_soup());
    for x in [-40.0, -20.0, 0.0, 20.0, 40.0] {
        let transform = ObjectTransform(Affine3A::from_translation(Vec3::new(x, 5.0, -20.0)));
        world.spawn((wall, transform, occluder.clone(), Static));
    }

    // Eye height, looking down the grid past the walls.
    world.insert_resource(Camera::looking_at(Vec3::new(0.0, 2.0, 0.0), Vec3::new(0.0, 2.0, -100.0)));

    schedule.run(&mut world);
    world.clear_trackers();

    let stats = *world.resource::<CullStats>();
    let store = world.resource::<BoundsStore>();
    let visible = &world.resource::<CameraCuller>().visible();
    let visible_entities: Vec<Entity> = visible.iter().map(|slot| store.entities()[slot]).collect();
    println!(
        "{} objects: {} in the frustum ({:.0} us), {} after occlusion by {} occluders ({:.0} us raster, {:.0} us test)",
        stats.objects,
        stats.after_frustum,
        stats.frustum_time.as_secs_f64() * 1e6,
        stats.after_occlusion,
        stats.occluders,
        stats.raster_time.as_secs_f64() * 1e6,
        stats.occlusion_time.as_secs_f64() * 1e6,
    );
    println!("first visible entities: {:?}", &visible_entities[..visible_entities.len().min(5)]);
    assert!(stats.after_occlusion < stats.after_frustum, "the walls hide part of the grid");
}
