//! The WGSL of Cullet's GPU passes, one pass a file, as source text.
//!
//! Every pass is put together by the engine (`cullet::gpu`) as the constants it generates from Rust, then
//! [`COMMON`], then the pass's own file: no constant shared by Rust and WGSL is written here. The files are in
//! the order the passes run each frame; [`PASSES`] lists the compute and render passes by name.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

/// Shared structs (instance, cluster, view, shadows), the view and HZB bindings, and the math every pass uses.
pub const COMMON: &str = include_str!("../common.wgsl");
/// One farthest-depth level of the hierarchical z-buffer from the level below.
pub const HZB_BUILD: &str = include_str!("../hzb_build.wgsl");
/// Cluster culling: frustum, normal cone, HZB and small-cluster tests; survivors appended.
pub const CLUSTER_CULL: &str = include_str!("../cluster_cull.wgsl");
/// The surviving-cluster count turned into the triangle pass's indirect dispatch.
pub const PREPARE_TRIANGLES: &str = include_str!("../prepare_triangles.wgsl");
/// Triangle culling: degenerate, back-facing, off-screen and small triangles; survivors compacted.
pub const TRIANGLE_CULL: &str = include_str!("../triangle_cull.wgsl");
/// Two-phase occlusion: the early phase's depth reduced to the HZB's level 0 and merged with the CPU's.
pub const HZB_MERGE: &str = include_str!("../hzb_merge.wgsl");
/// The shadow casters each sun cascade kept, depth only.
pub const SHADOW: &str = include_str!("../shadow.wgsl");
/// The draw: vertex pulling, flat shading with shadows, object ID and depth.
pub const DRAW: &str = include_str!("../draw.wgsl");
/// The query-grid culler's cell boxes, each inside an occlusion query of its own.
pub const CELL_QUERY: &str = include_str!("../cell_query.wgsl");

/// Each pass's name and source, in the order the passes run (without [`COMMON`], which each includes).
pub const PASSES: [(&str, &str); 8] = [
    ("hzb_build", HZB_BUILD),
    ("cluster_cull", CLUSTER_CULL),
    ("prepare_triangles", PREPARE_TRIANGLES),
    ("triangle_cull", TRIANGLE_CULL),
    ("shadow", SHADOW),
    ("draw", DRAW),
    ("hzb_merge", HZB_MERGE),
    ("cell_query", CELL_QUERY),
];
