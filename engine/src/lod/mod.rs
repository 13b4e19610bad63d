//! Levels of detail (seed 000 sections 19.9): fewer triangles where nobody can see the difference, and a
//! frame that keeps a triangle budget. Lossy by design and off until asked for; the judge
//! (`cullet_truth::lod`) measures the image error it costs.
//!
//! - `chain` (feature `lod`): each mesh's levels, simplified by meshoptimizer, with each level's geometric
//!   error in the mesh's own units.
//!   A scene may bring its own levels instead (glTF `MSFT_lod`, [`crate::scene::Scene::given_levels`]): their
//!   error is measured, as the distance between the surfaces (`distance`).
//! - [`LodLibrary`]: every mesh's levels as one flat mesh list (what the GPU culler clusters and draws) with
//!   each level's error and triangle count.
//! - [`select`]: each frame, a level per object the camera keeps: the coarsest whose error projects under a
//!   threshold in pixels, with hysteresis; then, under a triangle budget, levels chosen best-first by benefit
//!   over cost ([`budget`]). [`install`] adds it to the culling schedule as [`crate::pipeline::CullStage::Lod`].
//!
//! Culling stays conservative: the levels are never read by the culling stages, which test each object's
//! full-detail bounds, and occluders are the artist's or made from the full-detail mesh. A level's vertices are
//! a subset of the full-detail mesh's, so it lies inside the same bounds; a scene's own levels grow the mesh's
//! bounds to hold them ([`crate::scene::Scene::give_levels`]).
//!
//! # Example
//! ```
//! # #[cfg(feature = "lod")] {
//! use bevy_ecs::prelude::*;
//! use cullet::lod::{ChainSettings, LodLibrary, LodSelection, LodSettings};
//! use cullet::prelude::*;
//! use glam::{Affine3A, Vec3};
//!
//! let library = LodLibrary::build(&[Mesh::unit_cube(8)], &ChainSettings::default());
//! assert_eq!(library.levels(0), 2, "a subdivided box: itself, and 12 triangles at no error");
//! let (mut world, mut schedule) = (World::new(), Schedule::default());
//! cullet::install(&mut world, &mut schedule, PipelineSettings::default());
//! cullet::lod::install(&mut world, &mut schedule, library, LodSettings::pixels(1.0, 1080));
//! world.insert_resource(Camera::looking_at(Vec3::new(0.0, 2.0, 30.0), Vec3::ZERO));
//! let unit = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) };
//! let object = world.spawn((unit, ObjectTransform(Affine3A::IDENTITY), MeshRef(0))).id();
//! schedule.run(&mut world);
//! let slot = world.resource::<BoundsStore>().slot_of(object).unwrap();
//! let selection = world.resource::<LodSelection>();
//! assert_eq!(selection.level(slot), Some(1));
//! assert_eq!(selection.stats().triangles, 12);
//! # }
//! ```

pub mod budget;
#[cfg(feature = "lod")]
pub mod chain;
mod library;
pub mod select;

#[cfg(feature = "lod")]
pub mod distance;

#[cfg(feature = "lod")]
pub use chain::{ChainSettings, build_chain, build_chain_keeping_vertices, given_chain};
#[cfg(feature = "lod")]
pub use distance::surface_distance;
pub use library::LodLibrary;
pub use select::{LodSelection, LodSettings, LodStats, install};

use crate::mesh::Mesh;
use thiserror::Error;

/// Most levels a mesh has, the full-detail mesh included.
pub const MAX_LEVELS: usize = 8;

/// One level of a mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct LodLevel {
    /// Its triangles, in the full-detail mesh's space.
    pub mesh: Mesh,
    /// How far its surface may lie from the full-detail mesh's, in the mesh's units (0 for the full-detail
    /// mesh itself).
    pub error: f32,
}

/// Why a mesh has no levels but itself, or why levels were refused.
#[derive(Error, Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum LodError {
    /// The index count is not a multiple of 3.
    #[error("{indices} indices are not whole triangles")]
    PartialTriangle {
        /// The index count.
        indices: usize,
    },
    /// An index points past the positions.
    #[error("index {index} points past the mesh's {positions} positions")]
    IndexOutOfRange {
        /// The index.
        index: u32,
        /// The number of positions.
        positions: usize,
    },
    /// A position is NaN or infinite.
    #[error("vertex {vertex} is not finite")]
    NonFinitePosition {
        /// Its index.
        vertex: usize,
    },
    /// Levels given for a mesh are not finest first: a level's error is below the one before it, negative or
    /// not finite, or the first level's is not 0.
    #[error("level {level}'s error {error} does not follow the finer levels'")]
    UnorderedLevels {
        /// The level.
        level: usize,
        /// Its error.
        error: f32,
    },
    /// A level a scene brings has no fewer triangles than the level before it: it is left out.
    #[error("given level {level} has {triangles} triangles, no fewer than the {finer} of the level before it")]
    NotCoarser {
        /// The level (1 for the first coarser level the scene gives).
        level: usize,
        /// Its triangles.
        triangles: usize,
        /// The kept level before it's.
        finer: usize,
    },
    /// A level a scene brings lies farther from the mesh than the mesh is large (or has no triangles): not a
    /// level of this mesh. It is left out.
    #[error("given level {level} lies {distance} from the mesh, more than the mesh's size {size}")]
    StrayLevel {
        /// The level (1 for the first coarser level the scene gives).
        level: usize,
        /// Its distance from the mesh, at least (infinite for a level without triangles).
        distance: f32,
        /// The mesh's largest side.
        size: f32,
    },
    /// A mesh was given no level, or more than [`MAX_LEVELS`].
    #[error("{levels} levels given; a mesh has 1 to {MAX_LEVELS}")]
    LevelCount {
        /// How many were given.
        levels: usize,
    },
}
