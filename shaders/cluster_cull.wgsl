// Cluster culling: one workgroup per instance the CPU stages kept; its threads walk the instance's clusters and
// append the survivors of the frustum (bounding sphere), normal-cone and HZB (the cluster's box) tests (and the opt-in, lossy small-cluster test)
// to a compact list. Where the triangle pass is skipped (VIEW_DRAW_CLUSTERS), each survivor's draw is written
// here instead, over the cluster's own indices. The engine's `cluster_cull::cull_cluster` is the same test on the CPU.
//
// Two-phase occlusion runs the pass twice a frame, and keeps per cluster what happened to it last (frame f):
// 2f visible to the late phase, 2f + 1 drawn by the early phase. The early phase (VIEW_PHASE_EARLY) tests
// only the clusters visible last frame and marks those it keeps as drawn; the late phase (VIEW_PHASE_LATE)
// tests every cluster against the HZB merged from the early phase's depth, marks those it keeps as visible,
// and appends only those the early phase did not draw. Where the late phase runs in two steps, its first
// (VIEW_PHASE_LATE_OCCLUDERS) marks visible and appends only the kept clusters likely to hide others, and the
// second skips those.

@group(0) @binding(1) var<storage, read> instances: array<Instance>;
@group(0) @binding(2) var<storage, read> meshes: array<MeshInfo>;
@group(0) @binding(3) var<storage, read> clusters: array<Cluster>;
@group(0) @binding(4) var<storage, read> visible: array<u32>;
@group(0) @binding(5) var<storage, read_write> counters: array<atomic<u32>, COUNTER_COUNT>;
@group(0) @binding(6) var<storage, read_write> survivors: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read_write> draws: array<DrawArgs>;
// Two-phase occlusion's visibility: first, per instance, the index of its first cluster's entry; then, per
// cluster of every instance, its last mark (see above). Unused (a placeholder) with one phase.
@group(0) @binding(8) var<storage, read_write> visibility: array<u32>;
// The HZB is `hzb` of common.wgsl, group 1.

// KEEP, or the counter slot of the test that culled the cluster.
fn cull_cluster(instance: Instance, cluster: Cluster) -> u32 {
    let center = relative_point(instance, cluster.center, view.camera.xyz);
    let radius = cluster.radius * instance.max_scale;
    for (var i = 0u; i < 6u; i++) {
        let plane = view.planes[i];
        if (dot(plane.xyz, center) + plane.w < -radius) {
            return CLUSTERS_FRUSTUM;
        }
    }
    if ((view.flags & VIEW_CONE) != 0u && (instance.flags & INSTANCE_CONE_SAFE) != 0u && cluster.cone_cutoff < 1.0) {
        // In mesh space, where the cone was made: which side of a plane the camera is on survives any
        // invertible transform without mirroring, even a non-uniform scale.
        let camera = camera_in_mesh_space(instance, view.camera.xyz);
        if (dot(normalize(cluster.cone_apex - camera), cluster.cone_axis) >= cluster.cone_cutoff + CONE_SLACK) {
            return CLUSTERS_CONE;
        }
    }
    if ((view.flags & VIEW_HZB) != 0u) {
        let box = box_footprint(center, box_axes(instance, cluster.extent));
        if (!box.reaches_near && (hidden_behind(box, false) || ((view.flags & VIEW_SECOND_HZB) != 0u && hidden_behind(box, true)))) {
            return CLUSTERS_HZB;
        }
    }
    if ((view.flags & VIEW_SMALL_CLUSTER) != 0u) {
        let clip = view.clip_from_relative * vec4<f32>(center, 1.0);
        let pixels = 2.0 * radius * view.focal_pixels / clip.w;
        if (clip.w - radius > view.near && pixels < SMALL_CLUSTER_PIXELS) {
            return CLUSTERS_SMALL;
        }
    }
    return KEEP;
}

// Whether a cluster kept by the late phase is likely to hide others: its box covers LATE_OCCLUDER_AREA of the
// view or reaches the near plane.
fn likely_occluder(instance: Instance, cluster: Cluster) -> bool {
    let center = relative_point(instance, cluster.center, view.camera.xyz);
    let box = box_footprint(center, box_axes(instance, cluster.extent));
    let size = clamp(box.hi, vec2<f32>(0.0), vec2<f32>(1.0)) - clamp(box.lo, vec2<f32>(0.0), vec2<f32>(1.0));
    return box.reaches_near || size.x * size.y >= LATE_OCCLUDER_AREA;
}

@compute @workgroup_size(CLUSTER_WORKGROUP_SIZE)
fn main(invocation: Invocation) {
    let thread = invocation.thread;
    let slot = item_index(invocation);
    if (slot >= view.visible_count) {
        return;
    }
    let instance_index = visible[slot];
    let instance = instances[instance_index];
    if (instance.mesh >= arrayLength(&meshes)) {
        return; // No mesh: nothing to draw.
    }
    let mesh = meshes[instance.mesh];
    let phase = view.flags & (VIEW_PHASE_EARLY | VIEW_PHASE_LATE | VIEW_PHASE_FINAL | VIEW_PHASE_LATE_OCCLUDERS);
    var first_entry = 0u;
    if (phase != 0u) {
        first_entry = visibility[instance_index];
    }
    for (var c = thread; c < mesh.cluster_count; c += CLUSTER_WORKGROUP_SIZE) {
        let cluster_index = mesh.first_cluster + c;
        var mark = 0u;
        if (phase != 0u) {
            mark = visibility[first_entry + c];
        }
        if (phase == VIEW_PHASE_EARLY && mark != 2u * view.frame - 2u) {
            continue; // Not visible last frame.
        }
        if (phase == VIEW_PHASE_FINAL) {
            // A cluster the late phase kept that the frame's final depth hides is not drawn early next frame.
            if (mark == 2u * view.frame && cull_cluster(instance, clusters[cluster_index]) != KEEP) {
                visibility[first_entry + c] = 0u;
            }
            continue;
        }
        if (phase == VIEW_PHASE_LATE && mark == 2u * view.frame) {
            continue; // Drawn by the late phase's first step.
        }
        let cluster = clusters[cluster_index];
        if (phase == VIEW_PHASE_LATE_OCCLUDERS) {
            if (mark == 2u * view.frame + 1u || cull_cluster(instance, cluster) != KEEP || !likely_occluder(instance, cluster)) {
                continue; // Drawn early, or left to the late phase's second step.
            }
            visibility[first_entry + c] = 2u * view.frame;
        }
        atomicAdd(&counters[CLUSTERS_IN], 1u);
        var verdict = KEEP;
        if (phase != VIEW_PHASE_LATE_OCCLUDERS) {
            verdict = cull_cluster(instance, cluster);
        }
        if (verdict == KEEP) {
            if (phase == VIEW_PHASE_EARLY) {
                visibility[first_entry + c] = 2u * view.frame + 1u;
            } else if (phase == VIEW_PHASE_LATE) {
                visibility[first_entry + c] = 2u * view.frame;
                if (mark == 2u * view.frame + 1u) {
                    atomicAdd(&counters[CLUSTERS_DRAWN_EARLY], 1u);
                    continue;
                }
            }
            survivors[atomicAdd(&counters[CLUSTERS_OUT], 1u)] = vec2<u32>(instance_index, cluster_index);
            if ((view.flags & VIEW_DRAW_CLUSTERS) != 0u) {
                draws[atomicAdd(&counters[DRAWS], 1u)] =
                    DrawArgs(3u * cluster.triangle_count, 1u, cluster.first_index, 0, instance_index);
                atomicAdd(&counters[TRIANGLES_OUT], cluster.triangle_count);
            }
        } else {
            atomicAdd(&counters[verdict], 1u);
        }
    }
}
