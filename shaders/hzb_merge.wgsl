// Two-phase occlusion's merge: level 0 of the late HZB, one texel per pixel of the depth the early phase drew,
// the nearer of two conservative farthest depths: that pixel's, and the CPU occluder pyramid's (`hzb`, group
// 1) at the pixel's centre (the least of the CPU texels within a rounding margin of it, where it lies on a
// border).

struct Merge {
    // Level 0 of the merged pyramid: the depth target's size.
    level: HzbLevel,
    // Level 0 of the CPU pyramid, and the view's size in its texels (as `View.hzb_size` for it).
    cpu_level: HzbLevel,
    cpu_screen_size: vec2<f32>,
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

// 1/w of a depth-buffer value, moved a few ulps farther so that the value's rounding never makes it nearer.
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
    var farthest = inv_w_of(textureLoad(depth, vec2<i32>(id.xy), 0));
    if (merge.with_cpu != 0u) {
        let centre = (vec2<f32>(id.xy) + 0.5) / vec2<f32>(f32(level.width), f32(level.height)) * merge.cpu_screen_size;
        let lo = vec2<u32>(max(floor(centre - RECT_MARGIN), vec2<f32>(0.0)));
        let hi = vec2<u32>(max(floor(centre + RECT_MARGIN), vec2<f32>(0.0)));
        let cpu = min(
            min(hzb_texel(merge.cpu_level, lo.x, lo.y), hzb_texel(merge.cpu_level, hi.x, lo.y)),
            min(hzb_texel(merge.cpu_level, lo.x, hi.y), hzb_texel(merge.cpu_level, hi.x, hi.y)),
        );
        farthest = max(farthest, cpu);
    }
    merged[level.offset + id.y * level.width + id.x] = farthest;
}
