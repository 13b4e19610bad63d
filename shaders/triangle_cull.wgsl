// Triangle culling: one workgroup per surviving cluster, one thread per triangle. Degenerate, back-facing,
// off-screen and small (eq. 19.4: covering no pixel centre) triangles are removed; survivors are compacted
// into the draw index buffer and each non-empty cluster becomes one indexed indirect draw. A triangle with a
// vertex at w <= 0 skips the screen-space tests and is kept. The engine's `triangle_cull::cull_triangle` is
// the same test on the CPU.

@group(0) @binding(1) var<storage, read> instances: array<Instance>;
@group(0) @binding(2) var<storage, read> clusters: array<Cluster>;
@group(0) @binding(3) var<storage, read> positions: array<f32>;
@group(0) @binding(4) var<storage, read> cluster_indices: array<u32>;
@group(0) @binding(5) var<storage, read> survivors: array<vec2<u32>>;
@group(0) @binding(6) var<storage, read_write> counters: array<atomic<u32>, COUNTER_COUNT>;
@group(0) @binding(7) var<storage, read_write> draw_indices: array<u32>;
@group(0) @binding(8) var<storage, read_write> draws: array<DrawArgs>;

var<workgroup> survivor_total: u32;
var<workgroup> kept_count: atomic<u32>;
var<workgroup> first_index: u32;

fn position(index: u32) -> vec3<f32> {
    return vec3<f32>(positions[3u * index], positions[3u * index + 1u], positions[3u * index + 2u]);
}

// Pixel coordinates, y up (pixel centres at k + 0.5 on both axes either way).
fn to_pixels(clip: vec4<f32>) -> vec2<f32> {
    return pixels_from_ndc(clip.xy / clip.w, view.viewport);
}

fn no_sample_between(lo: f32, hi: f32) -> bool {
    return ceil(lo - SNAP - 0.5) > floor(hi + SNAP - 0.5);
}

// KEEP, or the counter slot of the test that culled the triangle.
fn cull_triangle(instance: Instance, p: array<vec3<f32>, 3>) -> u32 {
    // Two corners at one position stay at one position in every view. Three distinct collinear ones do not:
    // rounding in the transform can open them into a sliver that covers pixel centres.
    if (all(p[0] == p[1]) || all(p[1] == p[2]) || all(p[2] == p[0])) {
        return TRIANGLES_DEGENERATE;
    }
    var clip: array<vec4<f32>, 3>;
    for (var i = 0u; i < 3u; i++) {
        clip[i] = view.clip_from_relative * vec4<f32>(relative_point(instance, p[i], view.camera.xyz), 1.0);
        if (clip[i].w <= 0.0) {
            return KEEP;
        }
    }
    let s0 = to_pixels(clip[0]);
    let s1 = to_pixels(clip[1]);
    let s2 = to_pixels(clip[2]);
    if ((view.flags & VIEW_BACKFACE) != 0u) {
        // Counter-clockwise (y up) faces the camera. Only clearly negative areas are culled: snapping moves
        // the area by at most the perimeter times the snap distance.
        let e0 = s1 - s0;
        let e1 = s2 - s0;
        let area = e0.x * e1.y - e0.y * e1.x;
        let perimeter = length(e0) + length(e1) + length(s2 - s1);
        if (area < -2.0 * SNAP * perimeter) {
            return TRIANGLES_BACKFACE;
        }
    }
    let lo = min(s0, min(s1, s2));
    let hi = max(s0, max(s1, s2));
    if ((view.flags & VIEW_TRIANGLE_FRUSTUM) != 0u) {
        if (any(hi < vec2<f32>(-SNAP)) || any(lo > view.viewport + vec2<f32>(SNAP))) {
            return TRIANGLES_FRUSTUM;
        }
    }
    if ((view.flags & VIEW_SMALL_TRIANGLE) != 0u) {
        if (no_sample_between(lo.x, hi.x) || no_sample_between(lo.y, hi.y)) {
            return TRIANGLES_SMALL;
        }
    }
    return KEEP;
}

@compute @workgroup_size(TRIANGLE_WORKGROUP_SIZE)
fn main(invocation: Invocation) {
    let thread = invocation.thread;
    if (thread == 0u) {
        survivor_total = atomicLoad(&counters[CLUSTERS_OUT]);
        atomicStore(&kept_count, 0u);
    }
    let total = workgroupUniformLoad(&survivor_total);
    let slot = item_index(invocation);
    if (slot >= total) {
        return;
    }
    let survivor = survivors[slot];
    let instance = instances[survivor.x];
    let cluster = clusters[survivor.y];
    var kept = false;
    var local = 0u;
    var corners = vec3<u32>(0u);
    if (thread < cluster.triangle_count) {
        let base = cluster.first_index + 3u * thread;
        corners = vec3<u32>(cluster_indices[base], cluster_indices[base + 1u], cluster_indices[base + 2u]);
        atomicAdd(&counters[TRIANGLES_IN], 1u);
        let verdict = cull_triangle(instance, array<vec3<f32>, 3>(position(corners.x), position(corners.y), position(corners.z)));
        if (verdict == KEEP) {
            kept = true;
            local = atomicAdd(&kept_count, 1u);
        } else {
            atomicAdd(&counters[verdict], 1u);
        }
    }
    workgroupBarrier();
    if (thread == 0u) {
        let count = atomicLoad(&kept_count);
        if (count > 0u) {
            let first = atomicAdd(&counters[INDEX_CURSOR], 3u * count);
            first_index = first;
            draws[atomicAdd(&counters[DRAWS], 1u)] = DrawArgs(3u * count, 1u, first, 0, survivor.x);
            atomicAdd(&counters[TRIANGLES_OUT], count);
        }
    }
    let first = workgroupUniformLoad(&first_index);
    if (kept) {
        draw_indices[first + 3u * local] = corners.x;
        draw_indices[first + 3u * local + 1u] = corners.y;
        draw_indices[first + 3u * local + 2u] = corners.z;
    }
}
