// Declarations shared by every GPU stage; the engine prepends this file to each stage's shader.

// One object to draw: a 3x4 object-to-world matrix (rows; translation in w) and its mesh.
struct Instance {
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    mesh: u32,
    // INSTANCE_CONE_SAFE: invertible without mirroring, so the cone test (done in mesh space) is valid.
    flags: u32,
    // Largest axis scale of the matrix: scales bounding-sphere radii.
    max_scale: f32,
    // Flat colour, RGBA8 (red in the low byte); 0: pick one from the instance index.
    color: u32,
}

// A meshlet: bounding sphere and normal cone in mesh space (meshoptimizer's), and its triangles.
struct Cluster {
    center: vec3<f32>,
    radius: f32,
    cone_apex: vec3<f32>,
    cone_cutoff: f32,
    cone_axis: vec3<f32>,
    // Offset of its first index in the cluster index buffer (three global vertex indices a triangle).
    first_index: u32,
    triangle_count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct MeshInfo {
    first_cluster: u32,
    cluster_count: u32,
}

struct HzbLevel {
    width: u32,
    height: u32,
    offset: u32,
    _pad: u32,
}

struct View {
    // Clip from camera-relative world space (world minus camera position).
    clip_from_relative: mat4x4<f32>,
    // Frustum planes, camera-relative, unit normals pointing inside; unused ones are (0, 0, 0, 1).
    planes: array<vec4<f32>, 6>,
    camera: vec4<f32>,
    // Render target width, height in pixels.
    viewport: vec2<f32>,
    // HZB level-0 width, height in texels.
    hzb_size: vec2<f32>,
    hzb_levels: array<HzbLevel, 16>,
    hzb_level_count: u32,
    visible_count: u32,
    // VIEW_* bits: which tests run.
    flags: u32,
    near: f32,
    // Maps clip z into wgpu's 0..1 for an OpenGL-style (-1..1) projection.
    depth_from_negative_one: u32,
    // Pixels per unit of size at unit view distance, vertically: the projection's y scale times half the height.
    focal_pixels: f32,
    _pad1: u32,
    _pad2: u32,
}

const INSTANCE_CONE_SAFE: u32 = 1u;

// One indexed indirect draw, as wgpu's `DrawIndexedIndirectArgs`.
struct DrawArgs {
    index_count: u32,
    instance_count: u32,
    first_index: u32,
    base_vertex: i32,
    first_instance: u32,
}

const VIEW_CONE: u32 = 1u;
const VIEW_HZB: u32 = 2u;
const VIEW_SMALL_CLUSTER: u32 = 4u;
const VIEW_BACKFACE: u32 = 8u;
const VIEW_SMALL_TRIANGLE: u32 = 16u;
const VIEW_TRIANGLE_FRUSTUM: u32 = 32u;
// The triangle pass is skipped: the cluster pass writes each surviving cluster's draw, of its uncompacted
// triangles in the cluster index buffer.
const VIEW_DRAW_CLUSTERS: u32 = 64u;

// Counter slots (see the engine's `GpuCounters`).
const CLUSTERS_IN: u32 = 0u;
const CLUSTERS_FRUSTUM: u32 = 1u;
const CLUSTERS_CONE: u32 = 2u;
const CLUSTERS_HZB: u32 = 3u;
const CLUSTERS_SMALL: u32 = 4u;
const CLUSTERS_OUT: u32 = 5u;
const TRIANGLES_IN: u32 = 6u;
const TRIANGLES_DEGENERATE: u32 = 7u;
const TRIANGLES_BACKFACE: u32 = 8u;
const TRIANGLES_FRUSTUM: u32 = 9u;
const TRIANGLES_SMALL: u32 = 10u;
const TRIANGLES_OUT: u32 = 11u;
const DRAWS: u32 = 12u;
const INDEX_CURSOR: u32 = 13u;
const COUNTER_COUNT: u32 = 16u;

// A point of the instance's mesh, relative to the camera: the translation is made relative first, so the
// result stays precise far from the world origin.
fn relative_point(instance: Instance, p: vec3<f32>, camera: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(
        dot(instance.row0.xyz, p) + (instance.row0.w - camera.x),
        dot(instance.row1.xyz, p) + (instance.row1.w - camera.y),
        dot(instance.row2.xyz, p) + (instance.row2.w - camera.z),
    );
}

// The camera in the instance's mesh space: the inverse of the 3x3 part (rows a, b, c; its inverse has
// columns cross(b, c), cross(c, a), cross(a, b) over the determinant) applied to camera minus translation.
fn camera_in_mesh_space(instance: Instance, camera: vec3<f32>) -> vec3<f32> {
    let a = instance.row0.xyz;
    let b = instance.row1.xyz;
    let c = instance.row2.xyz;
    let v = vec3<f32>(camera.x - instance.row0.w, camera.y - instance.row1.w, camera.z - instance.row2.w);
    return (cross(b, c) * v.x + cross(c, a) * v.y + cross(a, b) * v.z) / dot(a, cross(b, c));
}
