// Present: one full-screen triangle showing a texture in the window, nearest texel, as colour or as depth.
// The game's window shows the drawn frame, the software occlusion buffer or one level of its pyramid with it.

struct Params {
    // Window size in pixels.
    target_size: vec2<f32>,
    // 0: colour; 1: depth (reversed 1/w, 0 where nothing was written).
    mode: u32,
    // Multiplies depth so that the nearest texel shows white.
    depth_scale: f32,
}

@group(0) @binding(0) var source: texture_2d<f32>;
@group(0) @binding(1) var<uniform> params: Params;

@vertex
fn vs(@builtin(vertex_index) index: u32) -> @builtin(position) vec4<f32> {
    let corner = vec2<f32>(f32((index << 1u) & 2u), f32(index & 2u));
    return vec4<f32>(corner * 2.0 - 1.0, 0.0, 1.0);
}

@fragment
fn fs(@builtin(position) pixel: vec4<f32>) -> @location(0) vec4<f32> {
    let size = textureDimensions(source);
    let texel = min(vec2<u32>(pixel.xy / params.target_size * vec2<f32>(size)), size - 1u);
    let value = textureLoad(source, texel, 0);
    if (params.mode == 0u) {
        return vec4<f32>(value.rgb, 1.0);
    }
    if (value.r <= 0.0) {
        // No occluder: dark blue, so empty texels stand out from far ones.
        return vec4<f32>(0.05, 0.05, 0.2, 1.0);
    }
    // Reversed depth falls off as 1/distance: a fourth root spreads near and far over the grey range.
    let grey = clamp(pow(value.r * params.depth_scale, 0.25), 0.0, 1.0);
    return vec4<f32>(grey, grey, grey, 1.0);
}
