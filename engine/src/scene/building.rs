//! The built-in building: floors of rooms on both sides of a corridor, doors between them, windows to the
//! outside, a stairwell joining the floors and trees around, with its cells and portals ([`crate::cells`]):
//! the scene the portal culler is made for.
//!
//! Walls and slabs are centred on a grid of mid-planes and carry occluders; each cell's box reaches the
//! mid-planes of its walls, and each portal lies in a mid-plane across its opening, as the cells' contract asks.
//! Larger object counts add buildings side by side along z and fill their rooms with more furniture.

use super::{Scene, SceneObject};
use crate::camera::{CameraKey, CameraPath};
use crate::cells::{Cell, Cells};
use crate::mesh::Mesh;
use crate::occluders::Occluder;
use glam::{Affine3A, Quat, Vec3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Height of a storey, slab mid-plane to slab mid-plane.
pub const STOREY: f32 = 3.2;
/// Floors of each building.
pub const FLOORS: u32 = 3;
/// Rooms on each side of a floor's corridor.
pub const ROOMS_PER_SIDE: u32 = 6;
const WALL: f32 = 0.2;
const ROOM: f32 = 6.0;
const HALF_CORRIDOR: f32 = 1.5;
const STAIRWELL: f32 = 4.0;
/// Distance between buildings' centres along z.
const BUILDING_PITCH: f32 = 40.0;
/// Objects a building holds before its rooms get more furniture than the default.
const OBJECTS_PER_BUILDING: usize = 1500;
const DOOR: (f32, f32) = (1.0, 2.2);
/// A window's width, sill and top above its floor's mid-plane.
const WINDOW: (f32, f32, f32) = (1.6, 0.9, 2.1);
const OCCLUDER_INSET: f32 = 0.02;

/// Mesh indices of the building's library.
mod meshes {
    pub const WALL: u32 = 0;
    pub const SLAB: u32 = 1;
    pub const FURNITURE: u32 = 2;
    pub const TREE: u32 = 3;
    pub const GROUND: u32 = 4;
}

fn mesh_library() -> Vec<Mesh> {
    let mut tree = Mesh::unit_cube(1).scaled(Vec3::new(0.4, 3.0, 0.4), Vec3::new(0.0, 1.5, 0.0));
    tree.append(&Mesh::unit_cube(2).scaled(Vec3::new(3.0, 3.0, 3.0), Vec3::new(0.0, 4.2, 0.0)));
    vec![Mesh::unit_cube(2), Mesh::unit_cube(4), Mesh::unit_cube(1), tree, Mesh::unit_cube(1)]
}

/// Length of a floor's corridor: the rooms along one side.
fn corridor_length() -> f32 {
    ROOMS_PER_SIDE as f32 * ROOM
}

/// An opening in a wall: from `along.0` to `along.1` along the wall, from `up.0` to `up.1` in height.
#[derive(Clone, Copy)]
struct Opening {
    along: (f32, f32),
    up: (f32, f32),
}

/// What one building adds to the scene.
struct Builder {
    objects: Vec<SceneObject>,
    cells: Vec<Cell>,
    portals: Vec<(String, Vec<Vec3>)>,
    occluder: Occluder,
}

impl Builder {
    fn solid(&mut self, mesh: u32, min: Vec3, max: Vec3, color: [u8; 4], occludes: bool) {
        let transform = Affine3A::from_scale_rotation_translation(max - min, Quat::IDENTITY, (min + max) * 0.5);
        let occluder = occludes.then(|| self.occluder.clone());
        self.objects.push(SceneObject { mesh, transform, occluder, velocity: None, color });
    }

    /// A wall one storey high from `floor`, in the plane `across = line` (`along_x`: the wall runs along x,
    /// its mid-plane at z = line; else along z at x = line), from `from` to `to` along it and half a wall
    /// beyond each end, with `openings` cut out, each covered by a portal named after `name`.
    #[allow(clippy::too_many_arguments)]
    fn wall(&mut self, name: &str, along_x: bool, line: f32, from: f32, to: f32, floor: f32, openings: &[Opening]) {
        let point = |along: f32, up: f32, across: f32| {
            if along_x { Vec3::new(along, up, across) } else { Vec3::new(across, up, along) }
        };
        let piece = |this: &mut Self, along: (f32, f32), up: (f32, f32)| {
            if along.1 - along.0 > 1e-4 && up.1 - up.0 > 1e-4 {
                let min = point(along.0, up.0, line - WALL * 0.5);
                let max = point(along.1, up.1, line + WALL * 0.5);
                this.solid(meshes::WALL, min.min(max), min.max(max), [226, 220, 208, 255], true);
            }
        };
        let top = floor + STOREY;
        let mut start = from - WALL * 0.5;
        for (index, opening) in openings.iter().enumerate() {
            piece(self, (start, opening.along.0), (floor, top));
            piece(self, opening.along, (floor, opening.up.0));
            piece(self, opening.along, (opening.up.1, top));
            start = opening.along.1;
            let (a, b) = opening.along;
            let (low, high) = opening.up;
            let vertices = vec![point(a, low, line), point(b, low, line), point(b, high, line), point(a, high, line)];
            self.portals.push((format!("{name}_{index}"), vertices));
        }
        piece(self, (start, to + WALL * 0.5), (floor, top));
    }

    fn cell(&mut self, name: String, min: Vec3, max: Vec3) {
        self.cells.push(Cell { name, boxes: vec![(min, max)] });
    }
}

fn door(centre: f32, floor: f32) -> Opening {
    Opening { along: (centre - DOOR.0 * 0.5, centre + DOOR.0 * 0.5), up: (floor, floor + DOOR.1) }
}

fn window(centre: f32, floor: f32) -> Opening {
    Opening { along: (centre - WINDOW.0 * 0.5, centre + WINDOW.0 * 0.5), up: (floor + WINDOW.1, floor + WINDOW.2) }
}

/// One building with its corridor along x from `origin`, and `furniture` pieces in each room.
fn generate_building(rng: &mut Pcg64Mcg, index: usize, origin: Vec3, furniture: usize, builder: &mut Builder) {
    let length = corridor_length();
    let edge = HALF_CORRIDOR + ROOM;
    let at = |x: f32, y: f32, z: f32| origin + Vec3::new(x, y, z);
    let name = |what: String| format!("b{index}_{what}");
    let o = (origin.x, origin.z);

    builder.solid(
        meshes::GROUND,
        at(-20.0, -0.3, -BUILDING_PITCH * 0.5),
        at(length + STAIRWELL + 20.0, 0.0, BUILDING_PITCH * 0.5),
        [110, 140, 90, 255],
        false,
    );
    for level in 0..=FLOORS {
        let y = level as f32 * STOREY;
        let (low, high) = (y - WALL * 0.5, y + WALL * 0.5);
        let color = [170, 160, 150, 255];
        builder.solid(
            meshes::SLAB,
            at(-WALL * 0.5, low, -edge - WALL * 0.5),
            at(length, high, edge + WALL * 0.5),
            color,
            true,
        );
        if level == 0 || level == FLOORS {
            let (min, max) = (
                at(length, low, -HALF_CORRIDOR - WALL * 0.5),
                at(length + STAIRWELL + WALL * 0.5, high, HALF_CORRIDOR + WALL * 0.5),
            );
            builder.solid(meshes::SLAB, min, max, color, true);
        }
    }

    for floor in 0..FLOORS {
        let y = floor as f32 * STOREY;
        let f = |what: &str| name(format!("f{floor}_{what}"));
        let room_doors: Vec<Opening> = (0..ROOMS_PER_SIDE).map(|i| door(o.0 + i as f32 * ROOM + 1.5, y)).collect();
        let windows: Vec<Opening> = (0..ROOMS_PER_SIDE).map(|i| window(o.0 + i as f32 * ROOM + 3.0, y)).collect();
        for side in [-1.0f32, 1.0] {
            let s = if side > 0.0 { "north" } else { "south" };
            // The corridor's wall runs on past the rooms as the stairwell's side.
            builder.wall(
                &f(&format!("{s}_doors")),
                true,
                o.1 + side * HALF_CORRIDOR,
                o.0,
                o.0 + length + STAIRWELL,
                y,
                &room_doors,
            );
            builder.wall(&f(&format!("{s}_windows")), true, o.1 + side * edge, o.0, o.0 + length, y, &windows);
            for i in 1..ROOMS_PER_SIDE {
                // Every other pair of neighbouring rooms shares a door: the cells' graph has cycles.
                let openings = if i % 2 == 1 { vec![door(o.1 + side * 4.5, y)] } else { Vec::new() };
                let (a, b) = (o.1 + side * HALF_CORRIDOR, o.1 + side * edge);
                builder.wall(
                    &f(&format!("{s}_partition{i}")),
                    false,
                    o.0 + i as f32 * ROOM,
                    a.min(b),
                    a.max(b),
                    y,
                    &openings,
                );
            }
            for i in 0..ROOMS_PER_SIDE {
                let x = i as f32 * ROOM;
                let (a, b) = (side * HALF_CORRIDOR, side * edge);
                builder.cell(f(&format!("{s}_room{i}")), at(x, y, a.min(b)), at(x + ROOM, y + STOREY, a.max(b)));
                for _ in 0..furniture {
                    let size =
                        Vec3::new(rng.random_range(0.4..1.6), rng.random_range(0.3..1.2), rng.random_range(0.4..1.6));
                    let inner = (a.abs() + 1.2, b.abs() - 0.4);
                    let cx = rng.random_range(x + 0.4 + size.x * 0.5..x + ROOM - 0.4 - size.x * 0.5);
                    let cz = side * rng.random_range(inner.0 + size.z * 0.5..inner.1 - size.z * 0.5);
                    let min = at(cx - size.x * 0.5, y + WALL * 0.5, cz - size.z * 0.5);
                    let tint = rng.random_range(0..60u8);
                    builder.solid(meshes::FURNITURE, min, min + size, [150 + tint, 100 + tint / 2, 60, 255], false);
                }
            }
        }
        // The west end: the entrance on the ground floor; the east end of the rooms, and the stairwell's door.
        let entrance = if floor == 0 { vec![door(o.1, y)] } else { Vec::new() };
        builder.wall(&f("entrance"), false, o.0, o.1 - edge, o.1 + edge, y, &entrance);
        builder.wall(&f("stair_door"), false, o.0 + length, o.1 - edge, o.1 + edge, y, &[door(o.1, y)]);
        builder.wall(
            &f("stair_window"),
            false,
            o.0 + length + STAIRWELL,
            o.1 - HALF_CORRIDOR,
            o.1 + HALF_CORRIDOR,
            y,
            &[window(o.1, y)],
        );
        builder.cell(f("corridor"), at(0.0, y, -HALF_CORRIDOR), at(length, y + STOREY, HALF_CORRIDOR));
        // A flight of steps along the stairwell's south wall.
        for step in 0..10 {
            let min = at(length + 0.2 + step as f32 * 0.36, y, -HALF_CORRIDOR);
            let max = min + Vec3::new(0.36, WALL * 0.5 + (step + 1) as f32 * STOREY / 10.0, 1.0);
            builder.solid(meshes::FURNITURE, min, max, [140, 140, 150, 255], false);
        }
    }
    let top = FLOORS as f32 * STOREY;
    builder.cell(name("stairwell".into()), at(length, 0.0, -HALF_CORRIDOR), at(length + STAIRWELL, top, HALF_CORRIDOR));

    for k in 0..12 {
        let x = -10.0 + k as f32 * (length + STAIRWELL + 20.0) / 11.0;
        let z = if k % 2 == 0 { -13.0 } else { 13.0 };
        let transform = Affine3A::from_translation(at(x, 0.0, z + rng.random_range(-2.0..2.0)));
        builder.objects.push(SceneObject {
            mesh: meshes::TREE,
            transform,
            occluder: None,
            velocity: None,
            color: [70, 120, 60, 255],
        });
    }
}

/// A generated building scene: buildings of [`FLOORS`] floors side by side along z, at least one, and
/// `objects` objects where that is more than the buildings' structure holds (the extra as furniture).
///
/// The first building stands at the origin; its ground floor's corridor runs from x = 0 along +x at
/// z = 0, its entrance at x = 0.
pub fn building(objects: usize) -> Scene {
    let buildings = objects.div_ceil(OBJECTS_PER_BUILDING).max(1);
    let mut rng = Pcg64Mcg::seed_from_u64(0xB11D);
    let occluder =
        Occluder::new(Mesh::unit_cube(1).scaled(Vec3::splat(1.0 - 2.0 * OCCLUDER_INSET), Vec3::ZERO).triangle_soup());
    let mut builder = Builder { objects: Vec::new(), cells: Vec::new(), portals: Vec::new(), occluder };
    // The structure of one building without furniture, to share the rest of the count among the rooms.
    let mut probe =
        Builder { objects: Vec::new(), cells: Vec::new(), portals: Vec::new(), occluder: builder.occluder.clone() };
    generate_building(&mut rng.clone(), 0, Vec3::ZERO, 0, &mut probe);
    let rooms = (2 * ROOMS_PER_SIDE * FLOORS) as usize;
    let per_building = objects / buildings;
    let furniture = per_building.saturating_sub(probe.objects.len()) / rooms;
    for index in 0..buildings {
        let origin = Vec3::new(0.0, 0.0, index as f32 * BUILDING_PITCH);
        generate_building(&mut rng, index, origin, furniture, &mut builder);
    }
    let cells =
        Cells::joined_by_position(builder.cells, builder.portals).expect("the generator's cells are well formed");
    Scene { cells: Some(cells), ..Scene::new(mesh_library(), builder.objects) }
}

/// The built-in walk through the first building: from outside in through the entrance, standing in the
/// doorway, along the corridor into a room, looking back through two doors and the corridor into the room
/// opposite, out of its window, up the stairwell, into a room upstairs, out through its window and back to an
/// overview. 60 degrees, near 0.1, infinite far; the eye never enters a wall.
pub fn walk() -> CameraPath {
    let (up, end) = (STOREY, corridor_length());
    let keys = [
        (0.0, Vec3::new(-16.0, 2.0, 6.0), Vec3::new(0.0, 1.4, 0.0)),
        (3.0, Vec3::new(-4.0, 1.6, 0.0), Vec3::new(6.0, 1.5, 0.0)),
        (4.5, Vec3::new(0.0, 1.6, 0.0), Vec3::new(8.0, 1.5, 0.0)),
        (7.0, Vec3::new(7.5, 1.6, 0.0), Vec3::new(7.5, 1.5, 6.0)),
        (9.0, Vec3::new(7.5, 1.6, 2.2), Vec3::new(8.5, 1.4, 7.5)),
        (11.0, Vec3::new(10.0, 1.6, 6.0), Vec3::new(7.5, 1.3, -6.0)),
        (13.0, Vec3::new(9.0, 1.6, 6.8), Vec3::new(9.5, 1.0, 20.0)),
        (14.0, Vec3::new(7.5, 1.6, 4.5), Vec3::new(7.5, 1.5, 0.0)),
        (15.0, Vec3::new(7.5, 1.6, 2.5), Vec3::new(7.5, 1.5, 0.0)),
        (16.0, Vec3::new(7.5, 1.6, 1.0), Vec3::new(7.5, 1.5, 0.0)),
        (17.0, Vec3::new(7.5, 1.6, 0.0), Vec3::new(end, 1.6, 0.0)),
        (21.0, Vec3::new(end - 3.0, 1.6, 0.0), Vec3::new(end + 2.0, 2.0, 0.0)),
        (23.0, Vec3::new(end + 2.0, 1.6, 0.0), Vec3::new(end + 2.0, 5.0, 0.3)),
        (26.0, Vec3::new(end + 2.0, up + 1.6, 0.0), Vec3::new(0.0, up + 1.5, 0.0)),
        (27.5, Vec3::new(26.5, up + 1.6, 0.0), Vec3::new(25.5, up + 1.5, 6.0)),
        (29.0, Vec3::new(25.5, up + 1.6, 0.0), Vec3::new(25.5, up + 1.5, 6.0)),
        (30.0, Vec3::new(25.5, up + 1.6, 1.5), Vec3::new(26.0, up + 1.5, 7.5)),
        (31.0, Vec3::new(25.5, up + 1.6, 2.5), Vec3::new(27.0, up + 1.5, 7.5)),
        (32.0, Vec3::new(27.0, up + 1.5, 4.5), Vec3::new(27.0, up + 1.5, 12.0)),
        (33.0, Vec3::new(27.0, up + 1.5, 6.8), Vec3::new(27.0, up + 1.5, 12.0)),
        (35.0, Vec3::new(27.0, up + 1.5, 10.0), Vec3::new(27.0, up + 1.0, 0.0)),
        (37.0, Vec3::new(27.0, up + 1.5, 14.0), Vec3::new(27.0, up, 0.0)),
        (41.0, Vec3::new(-10.0, 18.0, 24.0), Vec3::new(18.0, 3.0, 0.0)),
    ];
    CameraPath {
        fov_y_deg: 60.0,
        near: 0.1,
        far: None,
        keys: keys.into_iter().map(|(t, position, look_at)| CameraKey { t, position, look_at }).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_walk_never_enters_a_wall_and_every_portal_joins_its_neighbours() {
        let scene = building(0);
        let cells = scene.cells.as_ref().unwrap();
        assert_eq!(cells.cells().len(), (FLOORS * (2 * ROOMS_PER_SIDE + 1) + 1) as usize);
        let outside_portals = cells.portals().iter().filter(|portal| portal.joins.1.is_none()).count();
        // Each room's window, the stairwell's windows and the entrance.
        assert_eq!(outside_portals, (FLOORS * (2 * ROOMS_PER_SIDE + 1) + 1) as usize);
        let path = walk();
        let solid: Vec<(Vec3, Vec3)> = scene
            .objects
            .iter()
            .filter(|object| object.mesh == meshes::WALL || object.mesh == meshes::SLAB)
            .map(|object| {
                let half = object.transform.matrix3 * Vec3::splat(0.5);
                let centre = Vec3::from(object.transform.translation);
                (centre - half.abs(), centre + half.abs())
            })
            .collect();
        let mut t = 0.0;
        while t <= path.duration() {
            let (eye, _) = path.sample(t);
            for (min, max) in &solid {
                let margin = Vec3::splat(0.05);
                assert!(!(eye.cmpge(*min - margin).all() && eye.cmple(*max + margin).all()), "{t}: {eye} in a wall");
            }
            t += 0.01;
        }
    }
}
