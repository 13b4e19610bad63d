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
    // Half-size along each mesh axis of a box about `center` that holds the cluster (at most `radius`).
    extent: vec3<f32>,
    triangle_count: u32,
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
    // Two-phase occlusion's frame number (see cluster_cull.wgsl).
    frame: u32,
    _pad: u32,
    // A second pyramid in the same buffer, tested too with VIEW_SECOND_HZB, laid out as the first.
    second_hzb_size: vec2<f32>,
    second_hzb_level_count: u32,
    _pad2: u32,
    second_hzb_levels: array<HzbLevel, MAX_HZB_LEVELS>,
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

// The half-axes, camera-relative, of the instance's image of the mesh-space box with half-size `extent` along
// the mesh axes: the matrix's columns scaled by it.
fn box_axes(instance: Instance, extent: vec3<f32>) -> mat3x3<f32> {
    let rotation = transpose(mat3x3<f32>(instance.row0.xyz, instance.row1.xyz, instance.row2.xyz));
    return mat3x3<f32>(rotation[0] * extent.x, rotation[1] * extent.y, rotation[2] * extent.z);
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

// Where a box lies on screen: its corners' extent in fractions of the view (x right, y down, 0 to 1 across
// it) and the nearest corner's 1/w; `reaches_near` where a corner is at or before the near plane (such a box is
// never hidden).
struct Footprint {
    lo: vec2<f32>,
    hi: vec2<f32>,
    nearest: f32,
    reaches_near: bool,
}

// The footprint of the box `center + axes * s` for s in [-1, 1]^3 (camera-relative; the columns of `axes` are
// its half-axes).
fn box_footprint(center: vec3<f32>, axes: mat3x3<f32>) -> Footprint {
    var box = Footprint(vec2<f32>(3.4e38), vec2<f32>(-3.4e38), 0.0, false);
    for (var corner = 0u; corner < 8u; corner++) {
        let sign = vec3<f32>(
            select(-1.0, 1.0, (corner & 1u) != 0u),
            select(-1.0, 1.0, (corner & 2u) != 0u),
            select(-1.0, 1.0, (corner & 4u) != 0u),
        );
        let clip = view.clip_from_relative * vec4<f32>(center + axes * sign, 1.0);
        if (clip.w <= view.near) {
            box.reaches_near = true;
            return box;
        }
        let inv_w = 1.0 / clip.w;
        // Texel rows count from the top: y flipped.
        let screen = pixels_from_ndc(vec2<f32>(clip.x * inv_w, -(clip.y * inv_w)), vec2<f32>(1.0));
        box.lo = min(box.lo, screen);
        box.hi = max(box.hi, screen);
        box.nearest = max(box.nearest, inv_w);
    }
    return box;
}

// Level `index` of the view's first pyramid, or of its second.
fn hzb_level(second: bool, index: u32) -> HzbLevel {
    if (second) {
        return view.second_hzb_levels[index];
    }
    return view.hzb_levels[index];
}

// Whether `box` lies wholly behind the view's first pyramid (or `second`); see eq. 19.5. The engine's
// `cluster_cull::hidden_behind` is the same test on the CPU.
fn hidden_behind(box: Footprint, second: bool) -> bool {
    // The view's size in level-0 texels, and the last texel, which may reach past the view (the size is then
    // a fraction less than the level's).
    let size = select(view.hzb_size, view.second_hzb_size, second);
    let level_count = select(view.hzb_level_count, view.second_hzb_level_count, second);
    let base = hzb_level(second, 0u);
    let top = vec2<f32>(f32(base.width - 1u), f32(base.height - 1u));
    let lo_texel = vec2<u32>(clamp(floor(box.lo * size - RECT_MARGIN), vec2<f32>(0.0), top));
    let hi_texel = vec2<u32>(clamp(floor(box.hi * size + RECT_MARGIN), vec2<f32>(0.0), top));
    let span = max(hi_texel.x - lo_texel.x, hi_texel.y - lo_texel.y) + 1u;
    // One level finer than eq. 19.5's (where the rectangle spans at most 2x2 texels): at most 4x4 texels, each
    // a quarter of the area, so the bound is tighter for the same rectangle.
    let level_index = min(firstLeadingBit(max(span, 1u) * 2u - 1u), level_count - 1u);
    let finer = select(level_index - 1u, 0u, level_index == 0u);
    let level = hzb_level(second, finer);
    let a = lo_texel >> vec2<u32>(finer);
    let b = hi_texel >> vec2<u32>(finer);
    var farthest = 3.4e38;
    for (var y = a.y; y <= b.y; y++) {
        for (var x = a.x; x <= b.x; x++) {
            farthest = min(farthest, hzb_texel(level, x, y));
        }
    }
    return box.nearest * (1.0 + DEPTH_MARGIN) < farthest;
}
