// Turns the surviving-cluster count into the triangle pass's indirect dispatch: one workgroup per cluster,
// spread over y beyond MAX_WORKGROUPS_X, as `interface::workgroup_grid` does on the CPU.

@group(0) @binding(1) var<storage, read_write> counters: array<atomic<u32>, COUNTER_COUNT>;
@group(0) @binding(2) var<storage, read_write> dispatch: array<u32, 3>;

@compute @workgroup_size(1)
fn main() {
    let clusters = atomicLoad(&counters[CLUSTERS_OUT]);
    dispatch[0] = clamp(clusters, 1u, MAX_WORKGROUPS_X);
    dispatch[1] = max((clusters + MAX_WORKGROUPS_X - 1u) / MAX_WORKGROUPS_X, 1u);
    dispatch[2] = 1u;
}
