// Shadow map: the casters one light view kept, as depth only, into that view's layer. `view` holds the light's
// clip-from-relative matrix and, in `camera`, the point it is relative to.

@group(0) @binding(1) var<storage, read> instances: array<Instance>;

@vertex
fn vs(@location(0) position: vec3<f32>, @builtin(instance_index) instance: u32) -> @builtin(position) vec4<f32> {
    let relative = relative_point(instances[instance], position, view.camera.xyz);
    var clip = view.clip_from_relative * vec4<f32>(relative, 1.0);
    // Casters between the sun and the cascade's near plane still cast: their depth is clamped to the near
    // plane ("pancaking"), not clipped. Orthographic, so w is 1.
    clip.z = max(clip.z, 0.0);
    return clip;
}
