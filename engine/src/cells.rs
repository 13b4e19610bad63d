//! Cells and portals: an interior's rooms and the openings between them, the input of the portal culler
//! ([`crate::culler::PortalCuller`]), as the artist occluders are the occlusion stage's.
//!
//! # The contract
//! - A **cell** is a region of space: the union of its world-space boxes. Everything outside every cell's
//!   boxes is one more region, the **outside**.
//! - A **portal** is an opening that joins two cells, or a cell and the outside. The convex hull of its
//!   vertices covers the opening; it need not be flat.
//! - The scene promises that light goes from one region into another only through portals: the boundary of
//!   each cell (of the union of its boxes) lies inside opaque matter (a wall, a floor, a ceiling), except where it crosses an
//!   opening, and there a portal's hull covers the opening. Boxes reach *into* their walls, not through them: a
//!   box that reaches through an outer wall puts that wall's outer face inside the cell, where the outside cannot
//!   see it. The simplest layout stops each box at the middle of its walls, so that neighbouring cells meet
//!   there and each portal lies in that middle plane, across its opening.
//!
//! Under that promise the portal culler removes nothing visible. A scene that breaks it (a hole in a wall with no
//! portal over it) can lose what is seen through the hole: the exact judge measures that, the culler cannot.
//! Cycles in the graph of cells are allowed (rooms around a courtyard, two doors into one hall).
//!
//! [`Cells::new`] takes portals that name their cells; [`Cells::joined_by_position`] finds them from where each
//! portal lies, as the glTF loader does. Both refuse malformed data with a [`CellsError`].

use bevy_ecs::prelude::Resource;
use glam::Vec3;
use std::sync::atomic::{AtomicU64, Ordering};

/// A region of space: the union of its boxes.
#[derive(Clone, Debug, PartialEq)]
pub struct Cell {
    /// A name for errors and debugging (unique among a scene's cells).
    pub name: String,
    /// World-space boxes, each as its minimum and maximum corner.
    pub boxes: Vec<(Vec3, Vec3)>,
}

/// An opening between two regions.
#[derive(Clone, Debug, PartialEq)]
pub struct Portal {
    /// A name for errors and debugging.
    pub name: String,
    /// World-space points whose convex hull covers the opening (at least three, not all on one line).
    pub vertices: Vec<Vec3>,
    /// The cells it joins, by index into the cells: the second is `None` where the portal leads outside.
    pub joins: (usize, Option<usize>),
}

impl Portal {
    /// The mean of its vertices.
    pub fn centre(&self) -> Vec3 {
        mean(&self.vertices)
    }
}

/// Why a set of cells and portals was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CellsError {
    /// Two cells share a name.
    #[error("two cells are called '{0}'")]
    DuplicateCell(String),
    /// A cell without boxes.
    #[error("cell '{0}' has no boxes")]
    EmptyCell(String),
    /// A box that is not finite, or whose minimum exceeds its maximum.
    #[error("cell '{cell}': box {index} is not finite or is inside out")]
    BadBox {
        /// The cell.
        cell: String,
        /// Index of the box in the cell.
        index: usize,
    },
    /// A portal with fewer than three vertices, a vertex that is not finite, or all its vertices on one line.
    #[error("portal '{0}' covers no area: it needs three or more finite vertices, not all on one line")]
    FlatPortal(String),
    /// A portal whose cell index is out of range.
    #[error("portal '{portal}' joins cell {cell}, and there are {cells} cells")]
    UnknownCell {
        /// The portal.
        portal: String,
        /// The index it names.
        cell: usize,
        /// How many cells there are.
        cells: usize,
    },
    /// A portal that joins a cell to itself.
    #[error("portal '{portal}' joins cell '{cell}' to itself")]
    JoinsItself {
        /// The portal.
        portal: String,
        /// The cell.
        cell: String,
    },
    /// A portal found in no cell's boxes ([`Cells::joined_by_position`]).
    #[error("portal '{0}' joins nothing: its centre lies in no cell's box")]
    JoinsNothing(String),
    /// A portal found in more than two cells' boxes ([`Cells::joined_by_position`]).
    #[error("portal '{portal}' lies in the boxes of {} cells ({}): a portal joins two; name its cells", cells.len(), cells.join(", "))]
    JoinsMany {
        /// The portal.
        portal: String,
        /// The cells whose boxes hold its centre.
        cells: Vec<String>,
    },
}

/// The cells and portals of a scene, checked: a `bevy_ecs` resource that the portal culler reads from the
/// world. Without one, a world has no cells, and the portal culler culls by the frustum alone.
#[derive(Resource, Clone, Debug)]
pub struct Cells {
    cells: Vec<Cell>,
    portals: Vec<Portal>,
    /// Per region (each cell, then the outside), the portals that touch it.
    portals_of: Vec<Vec<u32>>,
    /// Different for every set of cells built or changed: what a culler's per-object bookkeeping was made for.
    id: u64,
}

impl PartialEq for Cells {
    fn eq(&self, other: &Self) -> bool {
        (&self.cells, &self.portals) == (&other.cells, &other.portals)
    }
}

fn next_id() -> u64 {
    static NEXT: AtomicU64 = AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

impl Cells {
    /// Cells and the portals between them, each portal naming its cells.
    ///
    /// # Errors
    /// Two cells of one name, a cell without boxes or with a box not finite or inside out, a portal covering no
    /// area, naming a cell out of range or joining a cell to itself: see [`CellsError`].
    pub fn new(cells: Vec<Cell>, portals: Vec<Portal>) -> Result<Self, CellsError> {
        for (index, cell) in cells.iter().enumerate() {
            if cells[..index].iter().any(|other| other.name == cell.name) {
                return Err(CellsError::DuplicateCell(cell.name.clone()));
            }
            if cell.boxes.is_empty() {
                return Err(CellsError::EmptyCell(cell.name.clone()));
            }
            let bad =
                cell.boxes.iter().position(|(min, max)| !(min.is_finite() && max.is_finite() && min.cmple(*max).all()));
            if let Some(index) = bad {
                return Err(CellsError::BadBox { cell: cell.name.clone(), index });
            }
        }
        for portal in &portals {
            if !covers_area(&portal.vertices) {
                return Err(CellsError::FlatPortal(portal.name.clone()));
            }
            let (first, second) = portal.joins;
            for cell in std::iter::once(first).chain(second) {
                if cell >= cells.len() {
                    return Err(CellsError::UnknownCell { portal: portal.name.clone(), cell, cells: cells.len() });
                }
            }
            if second == Some(first) {
                return Err(CellsError::JoinsItself { portal: portal.name.clone(), cell: cells[first].name.clone() });
            }
        }
        let mut portals_of = vec![Vec::new(); cells.len() + 1];
        for (index, portal) in portals.iter().enumerate() {
            let (first, second) = portal.joins;
            portals_of[first].push(index as u32);
            portals_of[second.unwrap_or(cells.len())].push(index as u32);
        }
        Ok(Self { cells, portals, portals_of, id: next_id() })
    }

    /// Cells, and portals given as a name and vertices, each joining the cells whose boxes hold its centre (the
    /// mean of its vertices): two cells, or one cell and the outside.
    ///
    /// # Errors
    /// As [`Cells::new`], and a portal whose centre lies in no cell's box ([`CellsError::JoinsNothing`]) or in
    /// more than two cells' ([`CellsError::JoinsMany`]).
    pub fn joined_by_position(cells: Vec<Cell>, portals: Vec<(String, Vec<Vec3>)>) -> Result<Self, CellsError> {
        let mut joined = Vec::with_capacity(portals.len());
        for (name, vertices) in portals {
            if !covers_area(&vertices) {
                return Err(CellsError::FlatPortal(name));
            }
            let centre = mean(&vertices);
            let holding: Vec<usize> = (0..cells.len()).filter(|&cell| cell_holds(&cells[cell], centre)).collect();
            let joins = match holding[..] {
                [] => return Err(CellsError::JoinsNothing(name)),
                [only] => (only, None),
                [first, second] => (first, Some(second)),
                _ => {
                    let names = holding.iter().map(|&cell| cells[cell].name.clone()).collect();
                    return Err(CellsError::JoinsMany { portal: name, cells: names });
                }
            };
            joined.push(Portal { name, vertices, joins });
        }
        Self::new(cells, joined)
    }

    /// The cells.
    pub fn cells(&self) -> &[Cell] {
        &self.cells
    }

    /// The portals.
    pub fn portals(&self) -> &[Portal] {
        &self.portals
    }

    /// The number of regions: the cells, and the outside after them (region `cells().len()`).
    pub fn region_count(&self) -> usize {
        self.cells.len() + 1
    }

    /// The region of the outside.
    pub fn outside(&self) -> usize {
        self.cells.len()
    }

    /// The portals that touch region `region` (a cell's index, or [`Cells::outside`]), each with its index.
    ///
    /// # Panics
    /// Where `region` is past [`Cells::region_count`].
    pub fn portals_of(&self, region: usize) -> impl Iterator<Item = (usize, &Portal)> + '_ {
        self.portals_of[region].iter().map(|&portal| (portal as usize, &self.portals[portal as usize]))
    }

    /// The region across `portal` from `region`.
    pub fn across(&self, portal: &Portal, region: usize) -> usize {
        let (first, second) = (portal.joins.0, portal.joins.1.unwrap_or(self.cells.len()));
        if region == first { second } else { first }
    }

    /// The regions a box (minimum and maximum corner) reaches into: every cell one of whose boxes it touches,
    /// and the outside unless one cell's box holds it whole. Appended to `regions`.
    pub fn regions_of_box(&self, min: Vec3, max: Vec3, regions: &mut Vec<u32>) {
        let mut held = false;
        for (index, cell) in self.cells.iter().enumerate() {
            let mut touches = false;
            for &(cell_min, cell_max) in &cell.boxes {
                if min.cmple(cell_max).all() && max.cmpge(cell_min).all() {
                    touches = true;
                    held |= min.cmpge(cell_min).all() && max.cmple(cell_max).all();
                }
            }
            if touches {
                regions.push(index as u32);
            }
        }
        if !held {
            regions.push(self.cells.len() as u32);
        }
    }

    /// Moves every cell and portal by `offset`.
    pub fn translate(&mut self, offset: Vec3) {
        for cell in &mut self.cells {
            for (min, max) in &mut cell.boxes {
                (*min, *max) = (*min + offset, *max + offset);
            }
        }
        for portal in &mut self.portals {
            for vertex in &mut portal.vertices {
                *vertex += offset;
            }
        }
        self.id = next_id();
    }

    /// Different for every set of cells built or moved.
    pub(crate) fn id(&self) -> u64 {
        self.id
    }
}

/// The mean of `points` (the origin for none).
fn mean(points: &[Vec3]) -> Vec3 {
    points.iter().copied().sum::<Vec3>() / points.len().max(1) as f32
}

/// Whether `point` lies in one of `cell`'s boxes (boundary included).
fn cell_holds(cell: &Cell, point: Vec3) -> bool {
    cell.boxes.iter().any(|&(min, max)| point.cmpge(min).all() && point.cmple(max).all())
}

/// Whether the convex hull of `vertices` has area: three or more finite points, not all on one line.
fn covers_area(vertices: &[Vec3]) -> bool {
    let Some(&first) = vertices.first() else { return false };
    if vertices.len() < 3 || vertices.iter().any(|v| !v.is_finite()) {
        return false;
    }
    let axis = vertices.iter().map(|v| *v - first).max_by(|a, b| a.length().total_cmp(&b.length())).unwrap_or_default();
    let scale = axis.length();
    // Some vertex off the line through the first and the farthest, by more than rounding.
    vertices.iter().any(|v| (*v - first).cross(axis).length() > scale * scale * 1e-5)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn room(name: &str, min: Vec3, max: Vec3) -> Cell {
        Cell { name: name.into(), boxes: vec![(min, max)] }
    }

    fn door(x: f32) -> Vec<Vec3> {
        vec![Vec3::new(x, 0.0, -0.5), Vec3::new(x, 0.0, 0.5), Vec3::new(x, 2.0, 0.5), Vec3::new(x, 2.0, -0.5)]
    }

    #[test]
    fn portals_join_the_cells_that_hold_their_centres() {
        let cells = vec![
            room("a", Vec3::new(-5.0, 0.0, -5.0), Vec3::new(0.1, 3.0, 5.0)),
            room("b", Vec3::new(-0.1, 0.0, -5.0), Vec3::new(5.0, 3.0, 5.0)),
        ];
        let cells =
            Cells::joined_by_position(cells, vec![("inner".into(), door(0.0)), ("front".into(), door(5.0))]).unwrap();
        assert_eq!(cells.portals()[0].joins, (0, Some(1)));
        assert_eq!(cells.portals()[1].joins, (1, None));
        assert_eq!(cells.portals_of(cells.outside()).count(), 1);
        assert_eq!(cells.across(&cells.portals()[1], 1), cells.outside());
        let mut regions = Vec::new();
        cells.regions_of_box(Vec3::new(-1.0, 0.0, 0.0), Vec3::new(-0.5, 1.0, 1.0), &mut regions);
        assert_eq!(regions, [0]);
        regions.clear();
        cells.regions_of_box(Vec3::new(-0.05, 0.0, 0.0), Vec3::new(6.0, 1.0, 1.0), &mut regions);
        assert_eq!(regions, [0, 1, 2], "a box through the wall and out of the building is in both rooms and outside");
    }

    #[test]
    fn malformed_cells_and_portals_are_refused_by_name() {
        let a = || room("a", Vec3::ZERO, Vec3::ONE);
        let portal = |vertices, joins| Portal { name: "p".into(), vertices, joins };
        let flat = vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0];
        let cases: Vec<(Vec<Cell>, Vec<Portal>, CellsError)> = vec![
            (vec![a(), a()], vec![], CellsError::DuplicateCell("a".into())),
            (vec![Cell { name: "e".into(), boxes: vec![] }], vec![], CellsError::EmptyCell("e".into())),
            (vec![room("a", Vec3::ONE, Vec3::ZERO)], vec![], CellsError::BadBox { cell: "a".into(), index: 0 }),
            (
                vec![room("a", Vec3::ZERO, Vec3::splat(f32::NAN))],
                vec![],
                CellsError::BadBox { cell: "a".into(), index: 0 },
            ),
            (vec![a()], vec![portal(flat, (0, None))], CellsError::FlatPortal("p".into())),
            (
                vec![a()],
                vec![portal(door(0.0), (0, Some(3)))],
                CellsError::UnknownCell { portal: "p".into(), cell: 3, cells: 1 },
            ),
            (
                vec![a()],
                vec![portal(door(0.0), (0, Some(0)))],
                CellsError::JoinsItself { portal: "p".into(), cell: "a".into() },
            ),
        ];
        for (cells, portals, error) in cases {
            assert_eq!(Cells::new(cells, portals), Err(error));
        }
        let nowhere = Cells::joined_by_position(vec![a()], vec![("p".into(), door(9.0))]);
        assert_eq!(nowhere, Err(CellsError::JoinsNothing("p".into())));
        let big = || room("b", Vec3::splat(-9.0), Vec3::splat(9.0));
        let many = Cells::joined_by_position(
            vec![big(), Cell { name: "c".into(), ..big() }, Cell { name: "d".into(), ..big() }],
            vec![("p".into(), door(0.0))],
        );
        assert!(matches!(many, Err(CellsError::JoinsMany { cells, .. }) if cells.len() == 3));
    }
}
