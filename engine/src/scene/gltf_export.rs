//! Writing a [`Scene`] as one self-contained glTF 2.0 file (JSON, buffer embedded as a base64 data URI), the
//! form [`super::gltf_import`] reads back: one node per object with its matrix, one glTF mesh per used (mesh,
//! colour) pair with a flat-colour material, and each occluder as a child node named `<object>_occluder`
//! holding the occluder's triangles in the object's local space; a mesh's given levels of detail
//! ([`Scene::given_levels`]) as `MSFT_lod` level nodes outside the scene's hierarchy. Velocities are not
//! written (glTF scenes are static).

use super::Scene;
use crate::occluders::Occluder;
use base64::Engine as _;
use serde_json::{Value, json};
use std::collections::HashMap;

/// Accumulates the binary buffer and its views and accessors.
#[derive(Default)]
struct Buffers {
    bytes: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Buffers {
    /// Appends positions (with their min/max, as glTF requires) and returns the accessor index.
    fn positions(&mut self, points: &[glam::Vec3]) -> usize {
        let (min, max) = points
            .iter()
            .fold((glam::Vec3::splat(f32::INFINITY), glam::Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), &p| {
                (lo.min(p), hi.max(p))
            });
        let floats: Vec<f32> = points.iter().flat_map(|p| p.to_array()).collect();
        let view = self.view(bytemuck::cast_slice(&floats), 34962);
        self.accessors.push(json!({
            "bufferView": view, "componentType": 5126, "count": points.len(), "type": "VEC3",
            "min": min.to_array(), "max": max.to_array(),
        }));
        self.accessors.len() - 1
    }

    /// Appends `u32` indices and returns the accessor index.
    fn indices(&mut self, indices: &[u32]) -> usize {
        let view = self.view(bytemuck::cast_slice(indices), 34963);
        self.accessors
            .push(json!({"bufferView": view, "componentType": 5125, "count": indices.len(), "type": "SCALAR"}));
        self.accessors.len() - 1
    }

    fn view(&mut self, data: &[u8], target: u32) -> usize {
        let offset = self.bytes.len();
        self.bytes.extend_from_slice(data);
        self.bytes.resize(self.bytes.len().next_multiple_of(4), 0);
        self.views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": data.len(), "target": target}));
        self.views.len() - 1
    }
}

/// The glTF JSON of `scene`; objects are named `<prefix><index>`.
pub fn write_gltf(scene: &Scene, prefix: &str) -> String {
    let mut buffers = Buffers::default();
    let mut meshes: Vec<Value> = Vec::new();
    let mut materials: Vec<Value> = Vec::new();
    let mut material_of: HashMap<[u8; 4], usize> = HashMap::new();
    let mut mesh_of: HashMap<(u32, usize, [u8; 4]), usize> = HashMap::new();
    let mut occluder_mesh_of: HashMap<*const glam::Vec3, usize> = HashMap::new();
    let mut geometry: HashMap<(u32, usize), (usize, usize)> = HashMap::new();
    let mut nodes: Vec<Value> = Vec::new();
    let mut roots = Vec::new();

    for (index, object) in scene.objects.iter().enumerate() {
        let material = *material_of.entry(object.color).or_insert_with(|| {
            let c = object.color.map(|c| f32::from(c) / 255.0);
            materials.push(json!({"pbrMetallicRoughness": {"baseColorFactor": [c[0], c[1], c[2], 1.0],
                "metallicFactor": 0.0, "roughnessFactor": 1.0}}));
            materials.len() - 1
        });
        let levels = scene.given_levels.iter().find(|(mesh, _)| *mesh == object.mesh).map_or(&[][..], |(_, l)| l);
        // Level 0 is the mesh itself, the others its given levels, each written once per colour.
        let mut mesh_of_level = |level: usize| {
            *mesh_of.entry((object.mesh, level, object.color)).or_insert_with(|| {
                let source = if level == 0 { &scene.meshes[object.mesh as usize] } else { &levels[level - 1] };
                let (positions, indices) = *geometry
                    .entry((object.mesh, level))
                    .or_insert_with(|| (buffers.positions(&source.positions), buffers.indices(&source.indices)));
                meshes.push(json!({"primitives": [{"attributes": {"POSITION": positions}, "indices": indices,
                    "material": material}]}));
                meshes.len() - 1
            })
        };
        let matrix = glam::Mat4::from(object.transform).to_cols_array();
        let mut node = json!({"name": format!("{prefix}{index}"), "mesh": mesh_of_level(0), "matrix": matrix});
        if !levels.is_empty() {
            let mut ids = Vec::new();
            for level in 1..=levels.len() {
                nodes.push(json!({"name": format!("{prefix}{index}_lod{level}"), "mesh": mesh_of_level(level),
                    "matrix": matrix}));
                ids.push(nodes.len() - 1);
            }
            node["extensions"] = json!({"MSFT_lod": {"ids": ids}});
        }
        if let Some(occluder) = &object.occluder {
            let occluder_mesh = occluder_mesh(occluder, &mut occluder_mesh_of, &mut buffers, &mut meshes);
            nodes.push(json!({"name": format!("{prefix}{index}{}", super::gltf_import::OCCLUDER_SUFFIX),
                "mesh": occluder_mesh}));
            node["children"] = json!([nodes.len() - 1]);
        }
        nodes.push(node);
        roots.push(nodes.len() - 1);
    }

    let data = base64::engine::general_purpose::STANDARD.encode(&buffers.bytes);
    let mut document = json!({
        "asset": {"version": "2.0", "generator": "cullet gltf_export"},
        "scene": 0,
        "scenes": [{"nodes": roots}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "accessors": buffers.accessors,
        "bufferViews": buffers.views,
        "buffers": [{"byteLength": buffers.bytes.len(), "uri": format!("data:application/octet-stream;base64,{data}")}],
    });
    if !scene.given_levels.is_empty() {
        document["extensionsUsed"] = json!(["MSFT_lod"]);
    }
    serde_json::to_string(&document).expect("a JSON value always serializes")
}

/// The glTF mesh of an occluder's triangle soup, written once per shared occluder.
fn occluder_mesh(
    occluder: &Occluder,
    written: &mut HashMap<*const glam::Vec3, usize>,
    buffers: &mut Buffers,
    meshes: &mut Vec<Value>,
) -> usize {
    *written.entry(occluder.triangles().as_ptr()).or_insert_with(|| {
        let positions = buffers.positions(occluder.triangles());
        meshes.push(json!({"primitives": [{"attributes": {"POSITION": positions}}]}));
        meshes.len() - 1
    })
}
