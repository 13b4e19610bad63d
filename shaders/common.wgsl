// Declarations shared by every GPU stage; the engine puts this file, after the constants it generates from
// Rust (`gpu::interface::wgsl_prelude`: view flags, counter slots, margins, KEEP), before each stage's shader.
// The struct layouts here are checked against the engine's #[repr(C)] structs by a naga reflection test.

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
    // The view's size in HZB level-0 texels: maps NDC to texels (a fraction less than level 0's size where
    // its texels are pixel blocks that do not divide the view).
    hzb_size: vec2<f32>,
    hzb_levels: array<HzbLevel, MAX_HZB_LEVELS>,
    hzb_level_count: u32,
    visible_count: u32,
    // VIEW_* bits: which tests run.
    flags: u32,
    near: f32,
    // Maps clip z into wgpu's 0..1 for an OpenGL-style (-1..1) projection.
    depth_from_negative_one: u32,
    // Pixels per unit of size at unit view distance, vertically: the projection's y scale times half the height.
    focal_pixels: f32,
    // Two-phase occlusion's frame number: clusters marked with `frame - 1` were visible last frame.
    frame: u32,
    _pad: u32,
}

// The draw's shadows: each sun cascade's clip space (x, y in -1..1, z in 0..1 from the sun) from the draw
// camera's relative world space, nearest cascade first; `count` 0 draws without shadows.
struct Shadows {
    cascade_from_relative: array<mat4x4<f32>, MAX_CASCADES>,
    count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// One indexed indirect draw, as wgpu's `DrawIndexedIndirectArgs`.
struct DrawArgs {
    index_count: u32,
    instance_count: u32,
    first_index: u32,
    base_vertex: i32,
    first_instance: u32,
}

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

// The view every pass that culls or draws reads. (Passes that do not use it, such as the HZB build, leave
// binding 0 of group 0 free.) A read-only storage buffer, not a uniform: Mesa's lavapipe specialises a shader
// on the uniform values its branches read and, once that paid off, recompiles it with LLVM every time its
// pipeline is bound. In the game's window that was the cluster and triangle passes recompiled every frame,
// about 250 ms a frame at 320x180; storage reads are never specialised.
@group(0) @binding(0) var<storage, read> view: View;

// What a culling pass's entry point is given: one workgroup per item (instance, cluster), spread over y past
// MAX_WORKGROUPS_X (`interface::workgroup_grid`), its threads over the item's parts.
struct Invocation {
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) workgroups: vec3<u32>,
    @builtin(local_invocation_index) thread: u32,
}

// The item this workgroup works on: its index in the dispatch.
fn item_index(invocation: Invocation) -> u32 {
    return invocation.workgroup.x + invocation.workgroup.y * invocation.workgroups.x;
}

// Pixel coordinates of a point in normalized device coordinates on a `size` target, y up (pixel centres at
// k + 0.5 on both axes); pass -y for rows counted from the top.
fn pixels_from_ndc(ndc: vec2<f32>, size: vec2<f32>) -> vec2<f32> {
    return (ndc * 0.5 + 0.5) * size;
}

// The HZB the cluster pass tests against: every level, one after another (`view.hzb_levels` says where).
@group(1) @binding(0) var<storage, read> hzb: array<f32>;

fn hzb_texel(level: HzbLevel, x: u32, y: u32) -> f32 {
    return hzb[level.offset + min(y, level.height - 1u) * level.width + min(x, level.width - 1u)];
}

// Whether the box `center ± extent` (camera-relative) lies wholly behind the HZB; see eq. 19.5. The engine's
// `cluster_cull::hidden_by_hzb` is the same test on the CPU.
fn hidden_by_hzb(center: vec3<f32>, extent: f32) -> bool {
    var lo = vec2<f32>(3.4e38);
    var hi = vec2<f32>(-3.4e38);
    var nearest = 0.0;
    for (var corner = 0u; corner < 8u; corner++) {
        let sign = vec3<f32>(
            select(-1.0, 1.0, (corner & 1u) != 0u),
            select(-1.0, 1.0, (corner & 2u) != 0u),
            select(-1.0, 1.0, (corner & 4u) != 0u),
        );
        let clip = view.clip_from_relative * vec4<f32>(center + sign * extent, 1.0);
        if (clip.w <= view.near) {
            return false; // Reaches the near plane: visible.
        }
        let inv_w = 1.0 / clip.w;
        // Texel rows count from the top: y flipped.
        let screen = pixels_from_ndc(vec2<f32>(clip.x * inv_w, -(clip.y * inv_w)), view.hzb_size);
        lo = min(lo, screen);
        hi = max(hi, screen);
        nearest = max(nearest, inv_w);
    }
    // The last texel, which may reach past the view (`hzb_size` is then a fraction less than the level's size).
    let size = vec2<f32>(f32(view.hzb_levels[0].width - 1u), f32(view.hzb_levels[0].height - 1u));
    let lo_texel = vec2<u32>(clamp(floor(lo - RECT_MARGIN), vec2<f32>(0.0), size));
    let hi_texel = vec2<u32>(clamp(floor(hi + RECT_MARGIN), vec2<f32>(0.0), size));
    let span = max(hi_texel.x - lo_texel.x, hi_texel.y - lo_texel.y) + 1u;
    // Eq. 19.5: the lowest level where the rectangle spans at most 2x2 texels.
    let level_index = min(firstLeadingBit(max(span, 1u) * 2u - 1u), view.hzb_level_count - 1u);
    let level = view.hzb_levels[level_index];
    let a = lo_texel >> vec2<u32>(level_index);
    let b = hi_texel >> vec2<u32>(level_index);
    let farthest = min(
        min(hzb_texel(level, a.x, a.y), hzb_texel(level, b.x, a.y)),
        min(hzb_texel(level, a.x, b.y), hzb_texel(level, b.x, b.y)),
    );
    return nearest * (1.0 + DEPTH_MARGIN) < farthest;
}
