// Draw: survivors of the culling passes, or every cluster with culling off, through the same shader into
// colour, object ID and depth. The instance index comes from the indirect draw's first instance.

@group(0) @binding(1) var<storage, read> instances: array<Instance>;
@group(0) @binding(2) var<uniform> shadows: Shadows;
@group(0) @binding(3) var shadow_map: texture_depth_2d_array;
@group(0) @binding(4) var shadow_sampler: sampler_comparison;

struct Varyings {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) instance: u32,
    // Camera-relative world position, for the face normal.
    @location(1) relative: vec3<f32>,
}

struct Targets {
    @location(0) color: vec4<f32>,
    @location(1) object: u32,
}

@vertex
fn vs(@location(0) position: vec3<f32>, @builtin(instance_index) instance: u32) -> Varyings {
    let relative = relative_point(instances[instance], position, view.camera.xyz);
    var clip = view.clip_from_relative * vec4<f32>(relative, 1.0);
    if (view.depth_from_negative_one != 0u) {
        clip.z = (clip.z + clip.w) * 0.5;
    }
    return Varyings(clip, instance, relative);
}

// 1 where the sun reaches the point (camera-relative), 0 in a caster's shadow: the first cascade that holds
// the point decides; outside every cascade it is lit.
fn sunlit(relative: vec3<f32>) -> f32 {
    for (var cascade = 0u; cascade < shadows.count; cascade++) {
        let p = shadows.cascade_from_relative[cascade] * vec4<f32>(relative, 1.0);
        if (all(abs(p.xy) <= vec2<f32>(1.0)) && p.z <= 1.0) {
            let uv = p.xy * vec2<f32>(0.5, -0.5) + 0.5;
            return textureSampleCompareLevel(shadow_map, shadow_sampler, uv, cascade, p.z);
        }
    }
    return 1.0;
}

@fragment
fn fs(in: Varyings) -> Targets {
    // The instance's flat colour, or one from a hash of its index.
    let packed = instances[in.instance].color;
    var color = unpack4x8unorm(packed).rgb;
    if (packed == 0u) {
        let h = in.instance * 0x9e3779b9u;
        color = vec3<f32>(f32(h >> 24u), f32((h >> 16u) & 255u), f32((h >> 8u) & 255u)) / 255.0 * 0.8 + 0.2;
    }
    // Lit by a fixed sun through the face normal, so neighbouring faces of one colour stay apart.
    let normal = normalize(cross(dpdx(in.relative), dpdy(in.relative)));
    let sun = normalize(vec3<f32>(0.4, 0.8, 0.3));
    let light = 0.45 + 0.55 * abs(dot(normal, sun));
    // Shadows darken what the culled cascades' casters hide from the sun; without cascades nothing changes.
    let shade = 0.6 + 0.4 * sunlit(in.relative);
    return Targets(vec4<f32>(color * light * shade, 1.0), in.instance);
}
