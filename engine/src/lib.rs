//! # Cullet
//!
//! A data-oriented visibility-culling engine. Each frame, objects flow one way through the stages, each a
//! module of its own:
//!
//! 1. [`bounds`]: world-space bounding boxes as linear SoA arrays in a `bevy_ecs` resource, updated only where
//!    transforms changed;
//! 2. [`frustum`]: SIMD, parallel box-versus-frustum test, writing a [`visible::VisibleSet`] bitset;
//! 3. [`occluder`] selects artist occluders and [`raster`] rasterizes them into a small conservative depth
//!    buffer and its farthest-depth pyramid;
//! 4. [`occlusion`]: each frustum survivor's box tested against that pyramid;
//! 5. [`gpu`]: on the GPU, the survivors' clusters and triangles culled against the frustum, normal cones and
//!    an HZB primed from the occluder buffer, compacted, and drawn with one multi-draw-indirect.
//!
//! [`draw_cost`] accounts what each stage saved the draw (triangles removed, estimated draw time).
//!
//! [`scene`] is the input: meshes and the objects placing them, from the built-in city or a glTF file;
//! [`pipeline`] wires the stages into a `bevy_ecs` schedule;
//! [`camera`] holds the camera and camera paths; [`mesh`] the triangle meshes objects draw; [`flight`] flies a
//! camera through a world, frame by frame.
//!
//! Culling is conservative by default: no stage removes an object that could be visible.

#![warn(missing_docs)]

pub mod bounds;
pub mod camera;
pub mod draw_cost;
pub mod flight;
pub mod frustum;
pub mod gpu;
pub mod mesh;
pub mod occluder;
pub mod occlusion;
pub mod pipeline;
pub mod raster;
pub mod scene;
pub mod visible;

pub use bounds::{BoundsError, BoundsStore, LocalBounds, MeshRef, ObjectTransform, Occluder, Static, WorldBounds};
pub use camera::{Camera, CameraPath};
pub use frustum::{DepthConvention, Frustum, SimdBackend};
pub use visible::VisibleSet;
