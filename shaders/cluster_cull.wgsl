// Cluster culling: one workgroup per instance the CPU stages kept; its threads walk the instance's clusters and
// append the survivors of the frustum, normal-cone and HZB tests (and the opt-in, lossy small-cluster test)
// to a compact list. Where the triangle pass is skipped (VIEW_DRAW_CLUSTERS), each survivor's draw is written
// here instead, over the cluster's own indices. The engine's `cluster_cull::cull_cluster` is the same test on the CPU.
//
// Two-phase occlusion runs the pass twice a frame. The early phase (VIEW_PHASE_EARLY) tests only the clusters
// visible last frame; the late phase (VIEW_PHASE_LATE), against the HZB merged from the early phase's depth,
// tests every cluster, marks those it keeps with this frame's number, and appends only those not drawn early.
// Its tests reject everything the early phase's do (the merged HZB is nowhere farther than the CPU's), so a
// cluster visible last frame that it keeps was drawn early.

@group(0) @binding(1) var<storage, read> instances: array<Instance>;
@group(0) @binding(2) var<storage, read> meshes: array<MeshInfo>;
@group(0) @binding(3) var<storage, read> clusters: array<Cluster>;
@group(0) @binding(4) var<storage, read> visible: array<u32>;
@group(0) @binding(5) var<storage, read_write> counters: array<atomic<u32>, COUNTER_COUNT>;
@group(0) @binding(6) var<storage, read_write> survivors: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read_write> draws: array<DrawArgs>;
// Two-phase occlusion's visibility: first, per instance, the index of its first cluster's entry; then, per
// cluster of every instance, the last frame it was visible. Unused (a placeholder) with one phase.
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
    if ((view.flags & VIEW_HZB) != 0u && hidden_by_hzb(center, radius)) {
        return CLUSTERS_HZB;
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
    let phase = view.flags & (VIEW_PHASE_EARLY | VIEW_PHASE_LATE);
    let first_entry = select(0u, visibility[instance_index], phase != 0u);
    for (var c = thread; c < mesh.cluster_count; c += CLUSTER_WORKGROUP_SIZE) {
        let cluster_index = mesh.first_cluster + c;
        let seen_last_frame = phase != 0u && visibility[first_entry + c] + 1u == view.frame;
        if (phase == VIEW_PHASE_EARLY && !seen_last_frame) {
            continue;
        }
        atomicAdd(&counters[CLUSTERS_IN], 1u);
        let cluster = clusters[cluster_index];
        let verdict = cull_cluster(instance, cluster);
        if (verdict == KEEP) {
            if (phase == VIEW_PHASE_LATE) {
                visibility[first_entry + c] = view.frame;
                if (seen_last_frame) {
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
