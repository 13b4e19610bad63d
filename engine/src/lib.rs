//! # Cullet
//!
//! A data-oriented visibility-culling engine. Each frame, objects flow one way through the stages, each a
//! module of its own, in this order:
//!
//! 1. [`bounds`]: world-space bounding boxes as linear SoA arrays in a `bevy_ecs` resource, updated only where
//!    transforms changed;
//! 2. [`frustum`]: SIMD, parallel box-versus-frustum test, writing a [`visible::VisibleSet`] bitset; many
//!    views (cameras, shadow cascades, cube faces) in one pass with [`frustum::cull_views`], a light view
//!    keeping only the shadow casters whose shadows the camera can see; [`detail`], opt-in and lossy, then drops
//!    the survivors that project under a size in pixels;
//! 3. [`occluders`]: the artist occluders, and which of them to rasterize this frame;
//! 4. [`raster`]: those occluders rasterized into a small conservative [`depth::DepthBuffer`], reduced to its
//!    farthest-depth [`depth::DepthPyramid`];
//! 5. [`occlusion`]: each frustum survivor's box tested against that pyramid; each light view (a sun's
//!    cascade, a lamp's face) has a buffer of its own, seen from its light, and drops its hidden casters;
//! 6. [`lod`], opt-in and lossy: a level of detail for each object the camera keeps, under a pixel error and a
//!    triangle budget;
//! 7. `gpu` (feature `gpu`): on the GPU, the survivors' clusters and triangles culled against the frustum,
//!    normal cones and an HZB primed from the occluder buffer, compacted, and drawn with one
//!    multi-draw-indirect.
//!
//! [`culler`] culls one view through stages 2 to 5 ([`culler::ViewCuller`], a plain type that the pipeline and
//! the Bevy plugin both wrap) and defines the interface every culler implements ([`culler::Culler`]).
//! [`pipeline`] wires stages 1 to 5 into a `bevy_ecs` schedule: [`install`] is the one call that sets a world
//! up for culling. `gpu::GpuCuller::for_world` builds the GPU half for a scene. [`prelude`] has what a user
//! names.
//!
//! [`camera`] holds the camera and camera paths, [`mesh`] what objects draw, [`depth`] the occlusion stages'
//! screen; [`scene`] is demo input (the built-in scenes with feature `scenes`, glTF with feature `gltf`) and
//! [`scene::flight`] flies a camera through a world, frame by frame.
//!
//! Culling is conservative by default: no stage removes an object that could be visible.
//!
//! # Features
//! - `gpu` (default): the GPU passes and the draw (`wgpu`, `meshopt`), and `draw_cost`;
//! - `gltf` (default): glTF import and export (`gltf`);
//! - `scenes` (default): the built-in procedural scenes (`rand`);
//! - `lod` (default): level-of-detail generation (`meshopt`).
//!
//! Without default features the CPU stages (bounds, frustum, occluders, raster, occlusion, the schedule)
//! build on `bevy_ecs`, `glam` and `rayon` alone.
//!
//! # Threads
//! The stages run on rayon's global pool. The thread that runs the schedule waits while they do, unless it is
//! one of rayon's: then it starts each stage's work itself instead of waking a pool thread, which must wake
//! the next, and a wake can take longer than a stage (docs/performance.md measures it). Make it one first thing
//! in `main`, as the game does:
//! ```no_run
//! rayon::ThreadPoolBuilder::new().use_current_thread().build_global().expect("rayon's global pool, once");
//! ```
//! [`parallel`] records each stage's work and span, which bound its speed-up on any number of cores.
//!
//! # Example
//! ```
//! use bevy_ecs::prelude::*;
//! use cullet::prelude::*;
//! use glam::{Affine3A, Vec3};
//!
//! let (mut world, mut schedule) = (World::new(), Schedule::default());
//! cullet::install(&mut world, &mut schedule, PipelineSettings::default());
//! world.insert_resource(Camera::looking_at(Vec3::new(0.0, 2.0, 10.0), Vec3::ZERO));
//! let unit = LocalBounds { center: Vec3::ZERO, half_extent: Vec3::splat(0.5) };
//! world.spawn((unit, ObjectTransform(Affine3A::IDENTITY)));
//! schedule.run(&mut world);
//! world.clear_trackers();
//! assert_eq!(world.resource::<CullStats>().after_occlusion, 1);
//! ```

#![warn(missing_docs)]

pub mod bounds;
pub mod detail;
pub mod frustum;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod lod;
pub mod occluders;
pub mod occlusion;
pub mod raster;

pub mod camera;
pub mod cells;
pub mod culler;
pub mod depth;
#[cfg(feature = "gpu")]
pub mod draw_cost;
pub mod mesh;
pub mod parallel;
pub mod pipeline;
pub mod scene;
pub mod visible;

pub use bounds::{BoundsError, BoundsStore, LocalBounds, ObjectTransform, Static, WorldBounds};
pub use camera::{Camera, CameraPath, DepthConvention};
pub use frustum::{Frustum, SimdBackend};
pub use mesh::{MeshRef, ObjectColor};
pub use occluders::Occluder;
pub use pipeline::{PipelineSettings, install};
pub use visible::VisibleSet;

/// What a user of the engine names: the components to attach, the settings, the resources to read, and the
/// GPU culler where feature `gpu` is on.
pub mod prelude {
    pub use crate::bounds::{BoundsError, BoundsRejected, BoundsStore, LocalBounds, ObjectTransform, Static};
    pub use crate::camera::{Camera, CameraPath, DepthConvention};
    pub use crate::culler::{
        AdaptiveSettings, CullScene, Culled, Culler, LightOcclusion, LightOcclusionSettings, LightViewVisible,
        OcclusionSettings, StageCuller, ViewCuller, ViewFrame, ViewInput, ViewSettings, ViewStats,
    };
    pub use crate::frustum::{Light, LightSource, View, cull_views};
    #[cfg(feature = "gpu")]
    pub use crate::gpu::{GpuContext, GpuCullSettings, GpuCuller, GpuError, GpuGating};
    pub use crate::mesh::{Mesh, MeshRef, ObjectColor};
    pub use crate::occluders::Occluder;
    pub use crate::pipeline::{
        CameraCuller, CullStage, CullStats, FrustumSettings, LightViews, LightViewsVisible, PipelineSettings, install,
    };
    pub use crate::raster::RasterMode;
    pub use crate::visible::VisibleSet;
}
