// Cell queries (the query-grid culler, after seed 001): each queried cell's box, camera-relative, drawn with
// depth test and no writes inside an occlusion query of its own. A sample that passes the depth of the objects
// drawn before it means the cell may hold something visible. No fragment stage: only the depth test counts.

// Per cell, the box's near corner then its far corner (camera-relative, xyz; w unused).
@group(0) @binding(1) var<storage, read> boxes: array<vec4<f32>>;

// The 12 triangles of a box, as corner numbers whose bits 0, 1, 2 pick the far x, y, z. Faces are drawn from
// both sides (the pipeline culls none), so their winding does not matter.
const BOX_CORNERS = array<u32, 36>(
    0u, 1u, 3u, 0u, 3u, 2u, // x, y at z near
    4u, 6u, 7u, 4u, 7u, 5u, // z far
    0u, 4u, 5u, 0u, 5u, 1u, // y near
    2u, 3u, 7u, 2u, 7u, 6u, // y far
    0u, 2u, 6u, 0u, 6u, 4u, // x near
    1u, 5u, 7u, 1u, 7u, 3u, // x far
);

@vertex
fn vs(@builtin(vertex_index) vertex: u32, @builtin(instance_index) cell: u32) -> @builtin(position) vec4<f32> {
    let corner = BOX_CORNERS[vertex];
    let far = vec3<bool>((corner & 1u) != 0u, (corner & 2u) != 0u, (corner & 4u) != 0u);
    let relative = select(boxes[2u * cell].xyz, boxes[2u * cell + 1u].xyz, far);
    var clip = view.clip_from_relative * vec4<f32>(relative, 1.0);
    if (view.depth_from_negative_one != 0u) {
        clip.z = (clip.z + clip.w) * 0.5;
    }
    return clip;
}
