//! Everything the Rust side and the WGSL shaders share, defined once, here: the view flags, the counter slots,
//! the test margins and the limits. [`wgsl_prelude`] writes them as WGSL `const`s, which the engine puts before
//! `common.wgsl` and each pass's shader; no shader defines them again.
//!
//! The struct layouts the shaders read ([`GpuView`], [`super::scene::GpuInstance`],
//! [`super::clusters::GpuCluster`], [`super::clusters::GpuMesh`], [`HzbLevel`], and wgpu's
//! `DrawIndexedIndirectArgs`) are declared in `common.wgsl` as WGSL structs; a test reflects them with naga,
//! without a GPU, and checks every member's offset and every size against the `#[repr(C)]` Rust structs.

use bytemuck::{Pod, Zeroable};
use glam::Mat4;

/// View flag: normal-cone test of clusters.
pub const VIEW_CONE: u32 = 1;
/// View flag: HZB test of clusters.
pub const VIEW_HZB: u32 = 2;
/// View flag: small-cluster test (lossy).
pub const VIEW_SMALL_CLUSTER: u32 = 4;
/// View flag: back-face test of triangles.
pub const VIEW_BACKFACE: u32 = 8;
/// View flag: small-triangle test (eq. 19.4).
pub const VIEW_SMALL_TRIANGLE: u32 = 16;
/// View flag: viewport test of triangles.
pub const VIEW_TRIANGLE_FRUSTUM: u32 = 32;
/// View flag: the triangle pass is skipped; the cluster pass writes each surviving cluster's draw, over its
/// uncompacted triangles in the cluster index buffer.
pub const VIEW_DRAW_CLUSTERS: u32 = 64;
/// View flag: the early phase of two-phase occlusion; only clusters visible last frame
/// ([`GpuView::frame`] minus one in the cluster visibility buffer) are tested and drawn.
pub const VIEW_PHASE_EARLY: u32 = 128;
/// View flag: the late phase of two-phase occlusion; every cluster is tested (against the HZB merged from the
/// early phase's depth), its visibility recorded for the next frame, and only those not drawn early are kept.
pub const VIEW_PHASE_LATE: u32 = 256;
/// View flag: the HZB test also tests against the second pyramid ([`GpuView::second_hzb_levels`]); a cluster
/// behind either is hidden. Two-phase occlusion's late phase tests the merged pyramid and the CPU's.
pub const VIEW_SECOND_HZB: u32 = 512;
/// View flag: after two-phase occlusion's late draw, the clusters the late phase marked visible are tested
/// against the pyramid of the frame's final depth, and those it hides lose their mark, so that the next frame
/// does not draw them early. Nothing is counted or kept.
pub const VIEW_PHASE_FINAL: u32 = 1024;
/// View flag: the first step of two-phase occlusion's late phase. Every cluster not drawn early is tested as
/// the late phase tests it, and of those kept only the ones likely to hide others (a footprint of at least
/// [`LATE_OCCLUDER_AREA`] of the view, or reaching the near plane) are marked visible and drawn; the depth
/// is merged again before the late phase tests the rest. Only what it keeps is counted.
pub const VIEW_PHASE_LATE_OCCLUDERS: u32 = 2048;

/// Set in [`super::scene::GpuInstance::flags`] when the transform is invertible and does not mirror: the cone
/// test, run in mesh space with the camera brought there, is then valid (which side of a plane a point lies on
/// survives such a transform, non-uniform scale included).
pub const INSTANCE_CONE_SAFE: u32 = 1;

/// Most HZB pyramid levels (a 32768-texel side); the length of [`GpuView::hzb_levels`].
pub const MAX_HZB_LEVELS: usize = 16;

/// The slots of the counter buffer the passes count into with atomics; [`super::GpuCounters`] reads them back.
pub mod counter {
    /// Clusters tested.
    pub const CLUSTERS_IN: u32 = 0;
    /// Clusters culled by the frustum test.
    pub const CLUSTERS_FRUSTUM: u32 = 1;
    /// Clusters culled by the normal-cone test.
    pub const CLUSTERS_CONE: u32 = 2;
    /// Clusters culled by the HZB test.
    pub const CLUSTERS_HZB: u32 = 3;
    /// Clusters culled by the small-cluster test.
    pub const CLUSTERS_SMALL: u32 = 4;
    /// Clusters kept; also the length of the survivor list.
    pub const CLUSTERS_OUT: u32 = 5;
    /// Triangles tested.
    pub const TRIANGLES_IN: u32 = 6;
    /// Triangles culled as degenerate.
    pub const TRIANGLES_DEGENERATE: u32 = 7;
    /// Triangles culled as back-facing.
    pub const TRIANGLES_BACKFACE: u32 = 8;
    /// Triangles culled outside the viewport.
    pub const TRIANGLES_FRUSTUM: u32 = 9;
    /// Triangles culled as covering no pixel centre.
    pub const TRIANGLES_SMALL: u32 = 10;
    /// Triangles kept.
    pub const TRIANGLES_OUT: u32 = 11;
    /// Indirect draws written; the draw count of the multi-draw.
    pub const DRAWS: u32 = 12;
    /// Next free index of the compacted index buffer.
    pub const INDEX_CURSOR: u32 = 13;
    /// Clusters the late phase of two-phase occlusion kept that the early phase had drawn (not drawn again).
    pub const CLUSTERS_DRAWN_EARLY: u32 = 14;
    /// Slots in the buffer (a multiple of 4, room to spare).
    pub const COUNTER_COUNT: u32 = 16;
}

/// Cone test slack: a cluster is called back-facing only this far past meshoptimizer's cutoff.
pub const CONE_SLACK: f32 = 1e-3;
/// HZB rectangle margin in texels: covers the f32 rounding of the projection.
pub const RECT_MARGIN: f32 = 1e-3;
/// HZB relative depth margin: covers the f32 rounding of `1/w`.
pub const DEPTH_MARGIN: f32 = 1e-5;
/// Relative step a depth-buffer value is moved farther before two-phase occlusion turns it into `1/w`: four
/// f32 ulps, so that the value's rounding never brings the depth it stands for nearer.
pub const DEPTH_ULPS: f32 = 4.8e-7;
/// Small-cluster test (lossy): a bounding sphere under this many pixels across is culled.
pub const SMALL_CLUSTER_PIXELS: f32 = 1.0;
/// The share of the view a cluster's screen-space box must cover for [`VIEW_PHASE_LATE_OCCLUDERS`] to draw it
/// first.
pub const LATE_OCCLUDER_AREA: f32 = 1.0 / 1024.0;
/// Pixels a vertex may move when the rasterizer snaps it to its sub-pixel grid (1/256 on common hardware):
/// the triangle pass's screen-space tests keep everything within this margin.
pub const SNAP: f32 = 1.0 / 128.0;
/// The verdict of a GPU test that keeps its cluster or triangle; any other verdict is the counter slot of the
/// test that culled it.
pub const KEEP: u32 = u32::MAX;
/// Threads per workgroup of the cluster pass (one workgroup per instance, its threads over the clusters).
pub const CLUSTER_WORKGROUP_SIZE: u32 = 64;
/// Threads per workgroup of the triangle pass (one workgroup per cluster, one thread per triangle): at least
/// [`super::clusters::MAX_CLUSTER_TRIANGLES`].
pub const TRIANGLE_WORKGROUP_SIZE: u32 = 128;
/// Most workgroups along x of one dispatch; larger counts spread over y (the shaders' `item_index`).
pub const MAX_WORKGROUPS_X: u32 = 65535;

/// Most sun cascades the draw shades with (`MAX_CASCADES` in WGSL).
pub const MAX_CASCADES: usize = 4;

/// One level's size and place in the pyramid buffer (`HzbLevel` in the shaders).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct HzbLevel {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Offset of its first texel in the pyramid buffer, in texels.
    pub offset: u32,
    /// Padding.
    pub _pad: u32,
}

/// The draw's shadows (`Shadows` in `common.wgsl`): where each cascade's shadow map lies.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuShadows {
    /// Per cascade, columns: its clip space (x and y in -1..1, z in 0..1 from the sun) from the draw camera's
    /// relative world space.
    pub cascade_from_relative: [[[f32; 4]; 4]; MAX_CASCADES],
    /// Cascades in use, nearest first; 0 draws without shadows.
    pub count: u32,
    /// Padding.
    pub _pad: [u32; 3],
}

/// The per-frame view every pass reads (`View` in `common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuView {
    /// Clip from camera-relative world space, columns.
    pub clip_from_relative: [[f32; 4]; 4],
    /// Camera-relative frustum planes, unit inward normals; unused ones `(0, 0, 0, 1)`.
    pub planes: [[f32; 4]; 6],
    /// Camera position in xyz.
    pub camera: [f32; 4],
    /// Render-target size in pixels.
    pub viewport: [f32; 2],
    /// HZB level-0 size in texels.
    pub hzb_size: [f32; 2],
    /// HZB level sizes and offsets.
    pub hzb_levels: [HzbLevel; MAX_HZB_LEVELS],
    /// Number of HZB levels.
    pub hzb_level_count: u32,
    /// Instances in the visible list.
    pub visible_count: u32,
    /// `VIEW_*` flags.
    pub flags: u32,
    /// Near-plane distance.
    pub near: f32,
    /// 1 when clip z must be mapped from -1..1 to 0..1.
    pub depth_from_negative_one: u32,
    /// Pixels per unit at unit distance, vertically.
    pub focal_pixels: f32,
    /// The frame number of two-phase occlusion (the late phase marks the clusters it finds visible with it).
    pub frame: u32,
    /// Padding.
    pub _pad: u32,
    /// The second pyramid's level-0 size in texels, as `hzb_size` (with [`VIEW_SECOND_HZB`]).
    pub second_hzb_size: [f32; 2],
    /// Its number of levels.
    pub second_hzb_level_count: u32,
    /// Padding.
    pub _pad2: u32,
    /// Its level sizes and offsets, in the same buffer as the first's.
    pub second_hzb_levels: [HzbLevel; MAX_HZB_LEVELS],
}

impl GpuView {
    /// The view of `camera` rendering into `viewport` (width, height) pixels, with no HZB, no flags and no
    /// instances: what every pass that draws through a camera needs.
    pub fn of_camera(camera: &crate::camera::Camera, viewport: (u32, u32)) -> Self {
        let mut planes = [[0.0, 0.0, 0.0, 1.0]; 6];
        if let Ok(frustum) = camera.frustum() {
            for (slot, plane) in planes.iter_mut().zip(frustum.planes()) {
                *slot = glam::Vec4::from((plane.normal, plane.d)).to_array();
            }
        }
        let (width, height) = viewport;
        GpuView {
            clip_from_relative: camera.clip_from_relative_f64().as_mat4().to_cols_array_2d(),
            planes,
            camera: camera.position.extend(0.0).to_array(),
            viewport: [width as f32, height as f32],
            near: camera.near,
            depth_from_negative_one: u32::from(camera.depth == crate::camera::DepthConvention::NegativeOneToOne),
            focal_pixels: camera.focal_pixels(height),
            ..GpuView::zeroed()
        }
    }

    /// `clip_from_relative` as a matrix.
    pub fn clip_from_relative(&self) -> Mat4 {
        Mat4::from_cols_array_2d(&self.clip_from_relative)
    }
}

/// The workgroup grid for `count` workgroups: at most [`MAX_WORKGROUPS_X`] along x, the rest along y (the
/// shaders' `item_index` undoes it; workgroups past `count` return at once).
pub fn workgroup_grid(count: u32) -> (u32, u32) {
    (count.clamp(1, MAX_WORKGROUPS_X), count.div_ceil(MAX_WORKGROUPS_X).max(1))
}

/// The WGSL declarations of every constant above, put before `common.wgsl` in every shader.
pub fn wgsl_prelude() -> String {
    use counter::*;
    let u32s = [
        ("VIEW_CONE", VIEW_CONE),
        ("VIEW_HZB", VIEW_HZB),
        ("VIEW_SMALL_CLUSTER", VIEW_SMALL_CLUSTER),
        ("VIEW_BACKFACE", VIEW_BACKFACE),
        ("VIEW_SMALL_TRIANGLE", VIEW_SMALL_TRIANGLE),
        ("VIEW_TRIANGLE_FRUSTUM", VIEW_TRIANGLE_FRUSTUM),
        ("VIEW_DRAW_CLUSTERS", VIEW_DRAW_CLUSTERS),
        ("VIEW_PHASE_EARLY", VIEW_PHASE_EARLY),
        ("VIEW_PHASE_LATE", VIEW_PHASE_LATE),
        ("VIEW_SECOND_HZB", VIEW_SECOND_HZB),
        ("VIEW_PHASE_FINAL", VIEW_PHASE_FINAL),
        ("VIEW_PHASE_LATE_OCCLUDERS", VIEW_PHASE_LATE_OCCLUDERS),
        ("INSTANCE_CONE_SAFE", INSTANCE_CONE_SAFE),
        ("MAX_HZB_LEVELS", MAX_HZB_LEVELS as u32),
        ("MAX_CASCADES", MAX_CASCADES as u32),
        ("CLUSTERS_IN", CLUSTERS_IN),
        ("CLUSTERS_FRUSTUM", CLUSTERS_FRUSTUM),
        ("CLUSTERS_CONE", CLUSTERS_CONE),
        ("CLUSTERS_HZB", CLUSTERS_HZB),
        ("CLUSTERS_SMALL", CLUSTERS_SMALL),
        ("CLUSTERS_OUT", CLUSTERS_OUT),
        ("TRIANGLES_IN", TRIANGLES_IN),
        ("TRIANGLES_DEGENERATE", TRIANGLES_DEGENERATE),
        ("TRIANGLES_BACKFACE", TRIANGLES_BACKFACE),
        ("TRIANGLES_FRUSTUM", TRIANGLES_FRUSTUM),
        ("TRIANGLES_SMALL", TRIANGLES_SMALL),
        ("TRIANGLES_OUT", TRIANGLES_OUT),
        ("DRAWS", DRAWS),
        ("INDEX_CURSOR", INDEX_CURSOR),
        ("CLUSTERS_DRAWN_EARLY", CLUSTERS_DRAWN_EARLY),
        ("COUNTER_COUNT", COUNTER_COUNT),
        ("KEEP", KEEP),
        ("CLUSTER_WORKGROUP_SIZE", CLUSTER_WORKGROUP_SIZE),
        ("TRIANGLE_WORKGROUP_SIZE", TRIANGLE_WORKGROUP_SIZE),
        ("MAX_WORKGROUPS_X", MAX_WORKGROUPS_X),
    ];
    let f32s = [
        ("CONE_SLACK", CONE_SLACK),
        ("RECT_MARGIN", RECT_MARGIN),
        ("DEPTH_MARGIN", DEPTH_MARGIN),
        ("DEPTH_ULPS", DEPTH_ULPS),
        ("SMALL_CLUSTER_PIXELS", SMALL_CLUSTER_PIXELS),
        ("LATE_OCCLUDER_AREA", LATE_OCCLUDER_AREA),
        ("SNAP", SNAP),
    ];
    let mut wgsl = String::from("// Generated from the engine's gpu::interface: the constants Rust and WGSL share.\n");
    for (name, value) in u32s {
        wgsl.push_str(&format!("const {name}: u32 = {value}u;\n"));
    }
    for (name, value) in f32s {
        // `{:?}` prints the shortest decimal that reads back as the same f32.
        wgsl.push_str(&format!("const {name}: f32 = {value:?};\n"));
    }
    wgsl
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f32_constants_round_trip_through_their_wgsl_text() {
        let prelude = wgsl_prelude();
        for (name, value) in [("SNAP", SNAP), ("DEPTH_MARGIN", DEPTH_MARGIN), ("CONE_SLACK", CONE_SLACK)] {
            let line = prelude.lines().find(|l| l.starts_with(&format!("const {name}:"))).unwrap();
            let text = line.rsplit("= ").next().unwrap().trim_end_matches(';');
            assert_eq!(text.parse::<f32>().unwrap(), value, "{line}");
        }
    }

    /// Every stage's assembled source, as the engine compiles it.
    fn stage_sources() -> Vec<(&'static str, String)> {
        cullet_shaders::PASSES.into_iter().map(|(name, stage)| (name, super::super::shader_source(stage))).collect()
    }

    fn parse(name: &str, source: &str) -> naga::Module {
        let module = naga::front::wgsl::parse_str(source)
            .unwrap_or_else(|error| panic!("{name}: {}", error.emit_to_string(source)));
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
            .validate(&module)
            .unwrap_or_else(|error| panic!("{name}: {}", error.emit_to_string(source)));
        module
    }

    #[test]
    fn every_stage_compiles_with_the_generated_prelude() {
        for (name, source) in stage_sources() {
            parse(name, &source);
        }
    }

    /// The byte size and `(member, offset)` list of the WGSL struct `name`.
    fn wgsl_layout(module: &naga::Module, name: &str) -> (u32, Vec<(String, u32)>) {
        let (_, ty) = module
            .types
            .iter()
            .find(|(_, ty)| ty.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("no struct {name} in common.wgsl"));
        let naga::TypeInner::Struct { members, span } = &ty.inner else { panic!("{name} is not a struct") };
        (*span, members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset)).collect())
    }

    #[test]
    fn common_wgsl_struct_layouts_equal_the_rust_structs() {
        use super::super::clusters::{GpuCluster, GpuMesh};
        use super::super::hzb::HzbLevel;
        use super::super::scene::GpuInstance;
        use std::mem::{offset_of, size_of};
        use wgpu::util::DrawIndexedIndirectArgs as DrawArgs;

        let module = parse("common", &super::super::shader_source(""));
        // Each WGSL member against the Rust field (or array element) at the same offset.
        // A struct's name and size, and its members with their offsets.
        type Layout = (&'static str, usize, Vec<(&'static str, usize)>);
        let expected: [Layout; 7] = [
            (
                "View",
                size_of::<GpuView>(),
                vec![
                    ("clip_from_relative", offset_of!(GpuView, clip_from_relative)),
                    ("planes", offset_of!(GpuView, planes)),
                    ("camera", offset_of!(GpuView, camera)),
                    ("viewport", offset_of!(GpuView, viewport)),
                    ("hzb_size", offset_of!(GpuView, hzb_size)),
                    ("hzb_levels", offset_of!(GpuView, hzb_levels)),
                    ("hzb_level_count", offset_of!(GpuView, hzb_level_count)),
                    ("visible_count", offset_of!(GpuView, visible_count)),
                    ("flags", offset_of!(GpuView, flags)),
                    ("near", offset_of!(GpuView, near)),
                    ("depth_from_negative_one", offset_of!(GpuView, depth_from_negative_one)),
                    ("focal_pixels", offset_of!(GpuView, focal_pixels)),
                    ("frame", offset_of!(GpuView, frame)),
                    ("_pad", offset_of!(GpuView, _pad)),
                    ("second_hzb_size", offset_of!(GpuView, second_hzb_size)),
                    ("second_hzb_level_count", offset_of!(GpuView, second_hzb_level_count)),
                    ("_pad2", offset_of!(GpuView, _pad2)),
                    ("second_hzb_levels", offset_of!(GpuView, second_hzb_levels)),
                ],
            ),
            (
                "Instance",
                size_of::<GpuInstance>(),
                vec![
                    ("row0", offset_of!(GpuInstance, rows)),
                    ("row1", offset_of!(GpuInstance, rows) + 16),
                    ("row2", offset_of!(GpuInstance, rows) + 32),
                    ("mesh", offset_of!(GpuInstance, mesh)),
                    ("flags", offset_of!(GpuInstance, flags)),
                    ("max_scale", offset_of!(GpuInstance, max_scale)),
                    ("color", offset_of!(GpuInstance, color)),
                ],
            ),
            (
                "Cluster",
                size_of::<GpuCluster>(),
                vec![
                    ("center", offset_of!(GpuCluster, center)),
                    ("radius", offset_of!(GpuCluster, radius)),
                    ("cone_apex", offset_of!(GpuCluster, cone_apex)),
                    ("cone_cutoff", offset_of!(GpuCluster, cone_cutoff)),
                    ("cone_axis", offset_of!(GpuCluster, cone_axis)),
                    ("first_index", offset_of!(GpuCluster, first_index)),
                    ("extent", offset_of!(GpuCluster, extent)),
                    ("triangle_count", offset_of!(GpuCluster, triangle_count)),
                ],
            ),
            (
                "MeshInfo",
                size_of::<GpuMesh>(),
                vec![
                    ("first_cluster", offset_of!(GpuMesh, first_cluster)),
                    ("cluster_count", offset_of!(GpuMesh, cluster_count)),
                ],
            ),
            (
                "HzbLevel",
                size_of::<HzbLevel>(),
                vec![
                    ("width", offset_of!(HzbLevel, width)),
                    ("height", offset_of!(HzbLevel, height)),
                    ("offset", offset_of!(HzbLevel, offset)),
                    ("_pad", offset_of!(HzbLevel, _pad)),
                ],
            ),
            (
                "DrawArgs",
                size_of::<DrawArgs>(),
                vec![
                    ("index_count", offset_of!(DrawArgs, index_count)),
                    ("instance_count", offset_of!(DrawArgs, instance_count)),
                    ("first_index", offset_of!(DrawArgs, first_index)),
                    ("base_vertex", offset_of!(DrawArgs, base_vertex)),
                    ("first_instance", offset_of!(DrawArgs, first_instance)),
                ],
            ),
            (
                "Shadows",
                size_of::<GpuShadows>(),
                vec![
                    ("cascade_from_relative", offset_of!(GpuShadows, cascade_from_relative)),
                    ("count", offset_of!(GpuShadows, count)),
                    ("_pad0", offset_of!(GpuShadows, _pad)),
                    ("_pad1", offset_of!(GpuShadows, _pad) + 4),
                    ("_pad2", offset_of!(GpuShadows, _pad) + 8),
                ],
            ),
        ];
        for (name, size, members) in expected {
            let (span, wgsl) = wgsl_layout(&module, name);
            assert_eq!(span as usize, size, "size of {name}");
            let rust: Vec<(String, u32)> =
                members.into_iter().map(|(m, offset)| (m.to_string(), offset as u32)).collect();
            assert_eq!(wgsl, rust, "members and offsets of {name}");
        }
    }

    #[test]
    fn workgroup_grid_covers_every_workgroup() {
        for count in [0, 1, 65535, 65536, 200_000] {
            let (x, y) = workgroup_grid(count);
            assert!(x <= MAX_WORKGROUPS_X && u64::from(x) * u64::from(y) >= u64::from(count));
        }
    }
}
