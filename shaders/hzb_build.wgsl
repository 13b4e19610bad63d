// HZB build: one farthest-depth level from the level below. Depth is 1/w (larger is nearer, 0 is empty), so
// farthest is the minimum. A coarse texel covers the up to 2x2 fine texels under it; on odd sizes the last
// coarse row or column takes the single fine row or column that exists, so no fine texel is dropped.

struct LevelPair {
    fine: HzbLevel,
    coarse: HzbLevel,
}

@group(0) @binding(1) var<storage, read_write> pyramid: array<f32>;
@group(0) @binding(2) var<uniform> pair: LevelPair;

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let fine = pair.fine;
    let coarse = pair.coarse;
    if (id.x >= coarse.width || id.y >= coarse.height) {
        return;
    }
    let x0 = 2u * id.x;
    let y0 = 2u * id.y;
    let x1 = min(x0 + 1u, fine.width - 1u);
    let y1 = min(y0 + 1u, fine.height - 1u);
    let top = min(pyramid[fine.offset + y0 * fine.width + x0], pyramid[fine.offset + y0 * fine.width + x1]);
    let bottom = min(pyramid[fine.offset + y1 * fine.width + x0], pyramid[fine.offset + y1 * fine.width + x1]);
    pyramid[coarse.offset + id.y * coarse.width + id.x] = min(top, bottom);
}
