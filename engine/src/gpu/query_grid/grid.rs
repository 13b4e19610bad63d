//! The uniform grid of seed 001 (§4.2): cells of one side over the scene's bounds, every object listed in each
//! cell its world box overlaps, and the non-empty cells a frustum reaches visited nearest first.

use crate::bounds::{BoundsStore, WorldBounds};
use crate::frustum::Frustum;
use glam::DVec3;
use rayon::prelude::*;

/// Most cells along one axis; a side that would need more is raised to fit.
pub const MAX_CELLS_PER_AXIS: u32 = 256;
/// Most cells in all; a side that would need more is raised to fit.
pub const MAX_CELLS: u32 = 1 << 21;
/// The automatic side's start, in median object sizes (the largest side of an object's box).
const AUTO_SIDE_IN_OBJECTS: f64 = 2.0;
/// The automatic side grows until the non-empty cells number at most this share of the objects.
const AUTO_CELLS_PER_OBJECT: f64 = 0.5;

/// An object's cells: the inclusive ranges of cell coordinates its box overlaps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Span {
    min: [u32; 3],
    max: [u32; 3],
}

/// A box in world space, in `f64`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellBounds {
    /// Least corner.
    pub min: DVec3,
    /// Greatest corner.
    pub max: DVec3,
}

impl CellBounds {
    const EMPTY: Self = Self { min: DVec3::INFINITY, max: DVec3::NEG_INFINITY };

    fn of(bounds: &WorldBounds) -> Self {
        let (center, extent) = (bounds.center.as_dvec3(), bounds.half_extent.as_dvec3());
        Self { min: center - extent, max: center + extent }
    }

    fn union(self, other: Self) -> Self {
        Self { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    fn intersection(self, other: Self) -> Self {
        Self { min: self.min.max(other.min), max: self.max.min(other.max) }
    }

    fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }

    /// Distance from `point` to the box (0 inside).
    pub fn distance(&self, point: DVec3) -> f64 {
        (self.min - point).max(point - self.max).max(DVec3::ZERO).length()
    }
}

/// Objects binned into a uniform grid of cells, kept up to date as they move.
#[derive(Clone, Debug)]
pub struct UniformGrid {
    origin: DVec3,
    side: f64,
    dims: [u32; 3],
    /// Store slots per cell, cells numbered x fastest, then y, then z.
    cells: Vec<Vec<u32>>,
    /// Each slot's cells, and its box when binned.
    spans: Vec<Span>,
    bounds: Vec<CellBounds>,
    /// Per cell, the union of its objects' boxes clipped to the cell (empty for an empty cell).
    content: Vec<CellBounds>,
    /// Cells whose content box is out of date, and the list of them.
    dirty: Vec<bool>,
    dirty_cells: Vec<u32>,
    /// Cells holding at least one object, in no order, and each cell's place in that list (`u32::MAX` where
    /// empty).
    non_empty: Vec<u32>,
    non_empty_at: Vec<u32>,
}

impl UniformGrid {
    /// The grid over every object of `store`, with cells of `side` (world units; raised so that no axis has
    /// more than [`MAX_CELLS_PER_AXIS`] cells, and none more than [`MAX_CELLS`] in all), or, where `side` is
    /// `None` or not a positive finite number, of twice the median object's size (the largest side of its
    /// box), grown until there are at most half as many non-empty cells as objects.
    pub fn build(store: &BoundsStore, side: Option<f32>) -> Self {
        let bounds = (0..store.len())
            .into_par_iter()
            .map(|slot| CellBounds::of(&store.get(slot).expect("slot below len")))
            .reduce(|| CellBounds::EMPTY, CellBounds::union);
        let bounds = if bounds.is_empty() { CellBounds { min: DVec3::ZERO, max: DVec3::ONE } } else { bounds };
        let size = (bounds.max - bounds.min).max(DVec3::splat(1e-3));
        let smallest = (size.max_element() / f64::from(MAX_CELLS_PER_AXIS))
            .max((size.x * size.y * size.z / f64::from(MAX_CELLS)).cbrt());
        let side = match side.filter(|s| s.is_finite() && *s > 0.0) {
            Some(side) => f64::from(side).max(smallest),
            None => auto_side(store, bounds.min, size, smallest),
        };
        // Rounding the dimensions up may pass the total by a little: at most a cell more per axis.
        let dims = (size / side).ceil().as_uvec3().max(glam::UVec3::ONE).min(glam::UVec3::splat(MAX_CELLS_PER_AXIS));
        let cell_count = (dims.x * dims.y * dims.z) as usize;
        let mut grid = Self {
            origin: bounds.min,
            side,
            dims: dims.to_array(),
            cells: vec![Vec::new(); cell_count],
            spans: Vec::with_capacity(store.len()),
            bounds: Vec::with_capacity(store.len()),
            content: vec![CellBounds::EMPTY; cell_count],
            dirty: vec![false; cell_count],
            dirty_cells: Vec::new(),
            non_empty: Vec::new(),
            non_empty_at: vec![u32::MAX; cell_count],
        };
        for slot in 0..store.len() {
            let span = grid.span_of(&store.get(slot).expect("slot below len"));
            grid.spans.push(span);
            grid.bounds.push(CellBounds::of(&store.get(slot).expect("slot below len")));
            grid.insert(slot as u32, span);
        }
        grid.refresh(store);
        grid
    }

    /// The cells' side in world units.
    pub fn side(&self) -> f64 {
        self.side
    }

    /// Cells along x, y and z.
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// The store slots listed in `cell`.
    pub fn objects(&self, cell: u32) -> &[u32] {
        &self.cells[cell as usize]
    }

    /// The union of `cell`'s objects' boxes clipped to the cell: everything of theirs that the cell holds.
    pub fn content(&self, cell: u32) -> CellBounds {
        self.content[cell as usize]
    }

    /// Number of cells, empty ones included.
    pub fn cell_count(&self) -> usize {
        self.cells.len()
    }

    /// Cells holding at least one object.
    pub fn non_empty(&self) -> &[u32] {
        &self.non_empty
    }

    /// Moves the objects at `slots` to the cells their boxes in `store` overlap now. An object outside the
    /// grid's bounds is listed in the border cells nearest it, which reach out to infinity. Returns false,
    /// changing nothing, where `store` holds a different number of objects (build the grid again).
    pub fn update(&mut self, store: &BoundsStore, slots: &[u32]) -> bool {
        if store.len() != self.spans.len() {
            return false;
        }
        for &slot in slots {
            let Some(bounds) = store.get(slot as usize) else { continue };
            self.bounds[slot as usize] = CellBounds::of(&bounds);
            let (old, new) = (self.spans[slot as usize], self.span_of(&bounds));
            if old != new {
                for cell in self.cells_of(old) {
                    self.cells[cell as usize].retain(|&s| s != slot);
                    self.mark_dirty(cell);
                }
                self.insert(slot, new);
                self.spans[slot as usize] = new;
            } else {
                for cell in self.cells_of(new) {
                    self.mark_dirty(cell);
                }
            }
        }
        self.refresh(store);
        true
    }

    /// The slots whose boxes in `store` differ from those binned, where the caller does not know what moved;
    /// `None` where `store` holds a different number of objects.
    pub fn changed_slots(&self, store: &BoundsStore) -> Option<Vec<u32>> {
        (store.len() == self.bounds.len()).then(|| {
            (0..store.len() as u32)
                .into_par_iter()
                .filter(|&slot| {
                    let now = CellBounds::of(&store.get(slot as usize).expect("slot below len"));
                    now != self.bounds[slot as usize]
                })
                .collect()
        })
    }

    /// The non-empty cells `frustum` may reach, each with the distance from `eye` to its content, nearest
    /// first, into `order`. Every cell holding a point of an object inside the frustum is there.
    pub fn cells_in(&self, frustum: &Frustum, eye: DVec3, order: &mut Vec<(f64, u32)>) {
        order.clear();
        order.par_extend(self.non_empty.par_iter().filter_map(|&cell| {
            let content = self.content[cell as usize];
            let center = (content.min + content.max) * 0.5;
            let half = (content.max - content.min) * 0.5;
            // Rounded outwards to f32, so that the f32 box holds the f64 one.
            let bounds = WorldBounds {
                center: center.as_vec3(),
                half_extent: half.as_vec3() + (center.abs() + half).as_vec3() * 2.0 * f32::EPSILON,
                radius: 0.0,
            };
            let bounds = WorldBounds { radius: bounds.half_extent.length(), ..bounds };
            frustum.intersects(&bounds).then(|| (content.distance(eye), cell))
        }));
        order.par_sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    }

    fn span_of(&self, bounds: &WorldBounds) -> Span {
        let bounds = CellBounds::of(bounds);
        let last = glam::UVec3::from_array(self.dims) - 1;
        let cell = |p: DVec3| ((p - self.origin) / self.side).floor().max(DVec3::ZERO).as_uvec3().min(last);
        Span { min: cell(bounds.min).to_array(), max: cell(bounds.max).to_array() }
    }

    fn cells_of(&self, span: Span) -> impl Iterator<Item = u32> + use<> {
        let [dx, dy, _] = self.dims;
        (span.min[2]..=span.max[2]).flat_map(move |z| {
            (span.min[1]..=span.max[1])
                .flat_map(move |y| (span.min[0]..=span.max[0]).map(move |x| x + dx * (y + dy * z)))
        })
    }

    fn insert(&mut self, slot: u32, span: Span) {
        for cell in self.cells_of(span).collect::<Vec<_>>() {
            self.cells[cell as usize].push(slot);
            self.mark_dirty(cell);
        }
    }

    fn mark_dirty(&mut self, cell: u32) {
        if !std::mem::replace(&mut self.dirty[cell as usize], true) {
            self.dirty_cells.push(cell);
        }
    }

    /// Recomputes the content boxes of the dirty cells, and the non-empty list where it changed.
    fn refresh(&mut self, store: &BoundsStore) {
        let dirty = std::mem::take(&mut self.dirty_cells);
        let fresh: Vec<CellBounds> = dirty
            .par_iter()
            .map(|&cell| {
                let objects = &self.cells[cell as usize];
                let union = objects
                    .iter()
                    .map(|&slot| CellBounds::of(&store.get(slot as usize).expect("a listed slot is stored")))
                    .fold(CellBounds::EMPTY, CellBounds::union);
                if objects.is_empty() { CellBounds::EMPTY } else { union.intersection(self.cell_box(cell)) }
            })
            .collect();
        for (&cell, content) in dirty.iter().zip(fresh) {
            self.content[cell as usize] = content;
            self.dirty[cell as usize] = false;
        }
        for &cell in &dirty {
            let at = self.non_empty_at[cell as usize];
            match (self.cells[cell as usize].is_empty(), at == u32::MAX) {
                (false, true) => {
                    self.non_empty_at[cell as usize] = self.non_empty.len() as u32;
                    self.non_empty.push(cell);
                }
                (true, false) => {
                    self.non_empty.swap_remove(at as usize);
                    if let Some(&moved) = self.non_empty.get(at as usize) {
                        self.non_empty_at[moved as usize] = at;
                    }
                    self.non_empty_at[cell as usize] = u32::MAX;
                }
                _ => {}
            }
        }
    }

    /// The cell's region: its cube, reaching out to infinity past the grid's border, where objects that left
    /// the grid's bounds are listed.
    fn cell_box(&self, cell: u32) -> CellBounds {
        let [dx, dy, _] = self.dims;
        let xyz = glam::UVec3::new(cell % dx, (cell / dx) % dy, cell / (dx * dy));
        let min = self.origin + xyz.as_dvec3() * self.side;
        let (first, last) = (xyz.cmpeq(glam::UVec3::ZERO), xyz.cmpeq(glam::UVec3::from_array(self.dims) - 1));
        CellBounds {
            min: DVec3::select(first, DVec3::NEG_INFINITY, min),
            max: DVec3::select(last, DVec3::INFINITY, min + DVec3::splat(self.side)),
        }
    }
}

/// The automatic side for the objects of `store` in a grid from `origin` over `size`, at least `smallest`:
/// [`AUTO_SIDE_IN_OBJECTS`] times the median of their boxes' largest sides, so that a cell holds a few objects
/// whatever the scene's scale, then a quarter larger at a time until at most [`AUTO_CELLS_PER_OBJECT`] cells
/// per object hold one: large objects (a ground, roads) would otherwise fill every cell of their layer, and
/// each cell in view costs a query.
fn auto_side(store: &BoundsStore, origin: DVec3, size: DVec3, smallest: f64) -> f64 {
    let soa = store.soa();
    let mut sizes: Vec<f32> =
        (0..store.len()).map(|slot| 2.0 * soa.extent_x[slot].max(soa.extent_y[slot]).max(soa.extent_z[slot])).collect();
    if sizes.is_empty() {
        return smallest.max(size.max_element());
    }
    let middle = sizes.len() / 2;
    let median = *sizes.select_nth_unstable_by(middle, f32::total_cmp).1;
    let mut side = (AUTO_SIDE_IN_OBJECTS * f64::from(median)).max(smallest);
    let most = (store.len() as f64 * AUTO_CELLS_PER_OBJECT).max(1.0) as usize;
    while side < size.max_element() && non_empty_cells(store, origin, side) > most {
        side *= 1.25;
    }
    side
}

/// The number of cells of side `side` from `origin` that the objects of `store` overlap.
fn non_empty_cells(store: &BoundsStore, origin: DVec3, side: f64) -> usize {
    let mut cells = std::collections::HashSet::new();
    for slot in 0..store.len() {
        let bounds = CellBounds::of(&store.get(slot).expect("slot below len"));
        let (min, max) = (((bounds.min - origin) / side).floor(), ((bounds.max - origin) / side).floor());
        let (min, max) = (min.as_i64vec3(), max.as_i64vec3());
        for z in min.z..=max.z {
            for y in min.y..=max.y {
                for x in min.x..=max.x {
                    cells.insert((x, y, z));
                }
            }
        }
    }
    cells.len()
}

/// The box of `bounds` camera-relative in `f32`, rounded outwards and grown by `margin` (world units).
pub fn relative_box(bounds: CellBounds, eye: DVec3, margin: f64) -> [[f32; 4]; 2] {
    let outward = |p: DVec3, sign: f64| {
        let p = p - eye + DVec3::splat(sign * margin);
        let f = p.as_vec3();
        // One f32 ulp outwards of the rounded value holds the f64 one.
        let ulp = f.abs() * f32::EPSILON;
        (f + sign as f32 * ulp).extend(0.0).to_array()
    };
    [outward(bounds.min, -1.0), outward(bounds.max, 1.0)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bounds::{LocalBounds, ObjectTransform};
    use crate::camera::Camera;
    use bevy_ecs::entity::Entity;
    use glam::{Affine3A, Vec3};

    /// A deterministic spread of boxes of sizes 0.2 to 6 over a 100 x 20 x 100 region.
    fn boxes(count: u32, seed: u64) -> Vec<(Vec3, Vec3)> {
        (0..count)
            .map(|i| {
                let r = |k: u64| (super::super::spread(i, seed * 8 + k) % 10_000) as f32 / 10_000.0;
                let center = Vec3::new(r(0) * 100.0 - 50.0, r(1) * 20.0, r(2) * 100.0 - 50.0);
                (center, Vec3::new(0.1 + 3.0 * r(3), 0.1 + 3.0 * r(4), 0.1 + 3.0 * r(5)))
            })
            .collect()
    }

    fn world_bounds(index: usize, (center, half_extent): (Vec3, Vec3)) -> WorldBounds {
        let entity = Entity::from_raw_u32(index as u32 + 1).unwrap();
        let local = LocalBounds { center: Vec3::ZERO, half_extent };
        WorldBounds::from_local(entity, &local, &ObjectTransform(Affine3A::from_translation(center)).0).unwrap()
    }

    fn store_of(boxes: &[(Vec3, Vec3)]) -> BoundsStore {
        let mut store = BoundsStore::default();
        for (i, &b) in boxes.iter().enumerate() {
            store.insert(Entity::from_raw_u32(i as u32 + 1).unwrap(), &world_bounds(i, b)).unwrap();
        }
        store
    }

    /// Each object is listed in exactly the cells its box overlaps (border cells reaching out), once each.
    fn assert_lists_exact(grid: &UniformGrid, store: &BoundsStore) {
        let mut listed = vec![0usize; store.len()];
        for cell in 0..grid.cell_count() as u32 {
            let region = grid.cell_box(cell);
            for &slot in grid.objects(cell) {
                let bounds = CellBounds::of(&store.get(slot as usize).unwrap());
                assert!(!bounds.intersection(region).is_empty(), "slot {slot} listed in cell {cell} it misses");
                listed[slot as usize] += 1;
            }
        }
        for (slot, count) in listed.into_iter().enumerate() {
            let bounds = CellBounds::of(&store.get(slot).unwrap());
            let overlapped = (0..grid.cell_count() as u32)
                .filter(|&c| {
                    let overlap = bounds.intersection(grid.cell_box(c));
                    // Boxes touching a cell's face on the far side belong to the next cell alone.
                    !overlap.is_empty() && (overlap.max - overlap.min).min_element() > 0.0
                })
                .count();
            assert!(count >= overlapped.max(1), "slot {slot}: listed {count} times, overlaps {overlapped} cells");
        }
    }

    #[test]
    fn every_object_is_listed_in_the_cells_it_overlaps_before_and_after_moving() {
        let mut boxes = boxes(400, 1);
        let store = store_of(&boxes);
        for side in [None, Some(4.0), Some(25.0), Some(1e-6)] {
            let grid = UniformGrid::build(&store, side);
            assert_lists_exact(&grid, &store);
            assert!(grid.dims().iter().all(|&d| (1..=MAX_CELLS_PER_AXIS).contains(&d)));
        }
        // Move a third of them, some far outside the grid's bounds.
        let mut grid = UniformGrid::build(&store, Some(8.0));
        let mut store = store;
        let moved: Vec<u32> = (0..400).step_by(3).collect();
        for &slot in &moved {
            let (center, half) = boxes[slot as usize];
            boxes[slot as usize] = (center + Vec3::new(slot as f32 * 0.7 - 100.0, 3.0, 40.0), half);
            store.set(slot as usize, &world_bounds(slot as usize, boxes[slot as usize])).unwrap();
        }
        assert!(grid.update(&store, &moved));
        assert_lists_exact(&grid, &store);
        for cell in 0..grid.cell_count() as u32 {
            let content = grid.content(cell);
            for &slot in grid.objects(cell) {
                let held = CellBounds::of(&store.get(slot as usize).unwrap()).intersection(grid.cell_box(cell));
                assert!(content.min.cmple(held.min).all() && content.max.cmpge(held.max).all(), "cell {cell}");
            }
        }
    }

    /// Every object with a point inside the frustum (here its centre) has a cell among those the frustum
    /// reaches, which come nearest first.
    #[test]
    fn the_frustum_reaches_a_cell_of_every_object_it_keeps() {
        let store = store_of(&boxes(600, 2));
        let grid = UniformGrid::build(&store, Some(6.0));
        for (eye, target) in [
            (Vec3::new(0.0, 5.0, 60.0), Vec3::ZERO),
            (Vec3::new(-10.0, 2.0, 0.0), Vec3::new(30.0, 1.0, 10.0)),
            (Vec3::new(0.0, 80.0, 0.0), Vec3::new(1.0, 0.0, 0.0)),
        ] {
            let camera = Camera { fov_y: 1.4, aspect: 2.0, ..Camera::looking_at(eye, target) };
            let frustum = camera.frustum().unwrap();
            let mut order = Vec::new();
            grid.cells_in(&frustum, eye.as_dvec3(), &mut order);
            assert!(order.windows(2).all(|w| w[0].0 <= w[1].0), "nearest first");
            let reached: std::collections::HashSet<u32> = order.iter().map(|&(_, c)| c).collect();
            for slot in 0..store.len() {
                let centre = store.get(slot).unwrap().center - frustum.origin();
                if frustum.planes().iter().all(|p| p.normal.dot(centre) + p.d > 1e-3) {
                    let listed = (0..grid.cell_count() as u32)
                        .any(|c| reached.contains(&c) && grid.objects(c).contains(&(slot as u32)));
                    assert!(listed, "slot {slot}'s centre is in the frustum but none of its cells is");
                }
            }
        }
    }
}
