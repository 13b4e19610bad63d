// Two-phase occlusion's merge: level 0 of the late HZB from the depth the early phase drew, texel by texel the
// nearer of two conservative farthest depths, that depth's and the CPU occluder pyramid's (`hzb`, group 1).
// A texel covers the pixels whose centres fall in it (one more on each side, as f32 rounding may place a
// centre on either side of a border); their farthest depth bounds everything the early phase drew there.

struct Merge {
    level: HzbLevel,
    // The view's size in level-0 texels, as `View.hzb_size`.
    screen_size: vec2<f32>,
    // 1/w = depth * inv_w_scale + inv_w_offset.
    inv_w_scale: f32,
    inv_w_offset: f32,
    // The depth target's clear value: nothing drawn there.
    empty_depth: f32,
    // 1 to merge with the CPU pyramid, 0 for the depth alone.
    with_cpu: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(1) var<storage, read_write> merged: array<f32>;
@group(0) @binding(2) var<uniform> merge: Merge;
@group(0) @binding(3) var depth: texture_depth_2d;

// 1/w of a depth-buffer value, moved a few ulps farther so that the depth's rounding never makes it nearer.
fn inv_w_of(value: f32) -> f32 {
    if (value == merge.empty_depth) {
        return 0.0;
    }
    let farther = value + sign(merge.empty_depth - value) * abs(value) * DEPTH_ULPS;
    return max(farther * merge.inv_w_scale + merge.inv_w_offset, 0.0);
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let level = merge.level;
    if (id.x >= level.width || id.y >= level.height) {
        return;
    }
    let pixels = vec2<f32>(textureDimensions(depth));
    let per_texel = pixels / merge.screen_size;
    let last = vec2<i32>(pixels) - 1;
    // Pixel centres p + 0.5 in [x, x + 1) texels: p from x * per_texel - 0.5 up, widened by one on each side.
    let lo = clamp(vec2<i32>(floor(vec2<f32>(id.xy) * per_texel - 0.5)), vec2<i32>(0), last);
    let hi = clamp(vec2<i32>(ceil(vec2<f32>(id.xy + 1u) * per_texel - 0.5)), lo, last);
    var farthest = 3.4e38;
    for (var y = lo.y; y <= hi.y; y++) {
        for (var x = lo.x; x <= hi.x; x++) {
            farthest = min(farthest, inv_w_of(textureLoad(depth, vec2<i32>(x, y), 0)));
        }
    }
    if (merge.with_cpu != 0u) {
        farthest = max(farthest, hzb_texel(level, id.x, id.y));
    }
    merged[level.offset + id.y * level.width + id.x] = farthest;
}
