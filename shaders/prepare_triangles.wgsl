// Turns the surviving-cluster count into the triangle pass's indirect dispatch: one workgroup per cluster,
// spread over y beyond the 65535-workgroup limit of x.

@group(0) @binding(0) var<storage, read_write> counters: array<atomic<u32>, COUNTER_COUNT>;
@group(0) @binding(1) var<storage, read_write> dispatch: array<u32, 3>;

@compute @workgroup_size(1)
fn main() {
    let clusters = atomicLoad(&counters[CLUSTERS_OUT]);
    let x = min(clusters, 65535u);
    dispatch[0] = max(x, 1u);
    dispatch[1] = max((clusters + 65534u) / 65535u, 1u);
    dispatch[2] = 1u;
}
