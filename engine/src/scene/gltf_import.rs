//! glTF 2.0 scenes (`.gltf` with external or embedded buffers, or `.glb`), read with the `gltf` crate.
//!
//! What is read: the default scene's node hierarchy and transforms; every triangle primitive (lists, strips
//! and fans) as one object drawing one [`Mesh`], shared by every node that uses the same glTF mesh; the
//! material's base colour factor as a flat colour; double-sided materials get each triangle twice, once per
//! winding, since the draw pass and the ground truth cull back faces. Textures are not used.
//!
//! Artist occluders: a node whose name ends in `_occluder`, or whose `extras` holds `"occluder": true`,
//! supplies its mesh's triangles as an [`Occluder`] and is not drawn. The occluder belongs to the object drawn
//! by the node's parent (its first primitive), in that object's local space, so the occlusion stage skips it
//! when the camera is inside that object; an occluder node whose parent draws nothing is carried by an object
//! of its own that has the occluder's vertices for bounds and no triangles.
//!
//! Cells and portals ([`crate::cells`]): a node whose name ends in `_cell`, or whose `extras` holds
//! `"cell": "name"`, is not drawn; the box around its mesh's vertices, in world space, is one box of the cell
//! of that name (the node's name without the suffix, or the extras' name), so several nodes make a cell of
//! several boxes. A node whose name ends in `_portal`, or whose `extras` holds `"portal": true`, is not drawn
//! either; its mesh's vertices in world space are a portal's, joined to the cells whose boxes hold its centre
//! ([`Cells::joined_by_position`]). Cells and portals that break the rules there are dropped with a warning
//! naming the problem, and the scene is culled without them: never with a wrong graph.
//!
//! Levels of detail: a drawn node whose `MSFT_lod` extension lists coarser level nodes (`"ids"`, finest first)
//! gives its mesh those levels ([`Scene::give_levels`]), primitive by primitive: each level node's mesh must
//! draw as many primitives, and is placed by the level node's own transform in place of the node's. Level nodes
//! are normally outside the scene's hierarchy (one inside it is also drawn as an object of its own). The
//! levels' `MSFT_screencoverage` is not read: the engine chooses levels by their geometric error, which
//! `cullet::lod::LodLibrary::for_scene` measures. A level that breaks these rules is left out with a warning.
//!
//! Malformed files are refused with a [`GltfError`] naming the file and the problem: unreadable or invalid
//! JSON, missing or short buffers, compressed geometry (Draco, meshopt), unsupported required extensions,
//! accessors outside their buffers, indices out of range, non-finite positions or transforms, cyclic node
//! graphs. Problems that leave the geometry usable (missing images, points and lines, primitives without
//! positions) are returned as warnings. Nothing in here panics on any input.

use super::{Scene, SceneObject};
use crate::cells::{Cell, Cells};
use crate::mesh::Mesh;
use crate::occluders::Occluder;
use base64::Engine as _;
use glam::{Affine3A, Mat4, Vec3};
use std::path::{Path, PathBuf};

/// Suffix of a node name that marks an artist occluder.
pub const OCCLUDER_SUFFIX: &str = "_occluder";
/// Suffix of a node name that marks a box of a cell.
pub const CELL_SUFFIX: &str = "_cell";
/// Suffix of a node name that marks a portal.
pub const PORTAL_SUFFIX: &str = "_portal";

/// A glTF file that could not be loaded.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {problem}")]
pub struct GltfError {
    /// The file, as given.
    pub file: String,
    /// What is wrong with it.
    pub problem: GltfProblem,
}

/// What is wrong with a glTF file.
#[derive(Debug, thiserror::Error)]
pub enum GltfProblem {
    /// The file or one of its buffers could not be read.
    #[error("cannot read {what}: {error}")]
    Io {
        /// The file that failed.
        what: String,
        /// The reason.
        error: std::io::Error,
    },
    /// Not glTF, or glTF that breaks the specification (reported by the `gltf` crate's validation).
    #[error("not a valid glTF file: {0}")]
    Invalid(String),
    /// An extension the file requires that the loader does not implement.
    #[error("requires the unsupported extension {0}{hint}", hint = compression_hint(.0))]
    UnsupportedExtension(String),
    /// A buffer's bytes are missing or shorter than declared.
    #[error("buffer {index}: {why}")]
    Buffer {
        /// Index of the buffer.
        index: usize,
        /// What is wrong.
        why: String,
    },
    /// A mesh primitive's data is unusable.
    #[error("mesh {mesh} ('{name}') primitive {primitive}: {why}")]
    Primitive {
        /// Index of the mesh.
        mesh: usize,
        /// Its name, or empty.
        name: String,
        /// Index of the primitive in the mesh.
        primitive: usize,
        /// What is wrong.
        why: String,
    },
    /// A node is unusable.
    #[error("node {node} ('{name}'): {why}")]
    Node {
        /// Index of the node.
        node: usize,
        /// Its name, or empty.
        name: String,
        /// What is wrong.
        why: String,
    },
    /// The file has no scene to show.
    #[error("has no scene")]
    NoScene,
}

fn compression_hint(extension: &str) -> &'static str {
    match extension {
        "KHR_draco_mesh_compression" | "EXT_meshopt_compression" | "KHR_mesh_quantization" => {
            " (compressed or quantized geometry is not supported; export the scene uncompressed)"
        }
        _ => "",
    }
}

/// A scene loaded from glTF, with what was skipped.
#[derive(Clone, Debug, Default)]
pub struct GltfScene {
    /// The scene.
    pub scene: Scene,
    /// Problems that left the geometry usable, one line each.
    pub warnings: Vec<String>,
    /// Number of artist occluder nodes found.
    pub occluder_nodes: usize,
}

/// Loads a `.gltf` or `.glb` file; external buffers and images are looked up next to it.
pub fn load_gltf(path: &Path) -> Result<GltfScene, GltfError> {
    let file = path.display().to_string();
    let error = |problem| GltfError { file: file.clone(), problem };
    let bytes = std::fs::read(path).map_err(|e| error(GltfProblem::Io { what: "the file".into(), error: e }))?;
    parse_gltf(&bytes, path.parent(), &file)
}

/// Loads glTF from `bytes` (JSON or GLB); external buffers and images are looked up in `base_dir` (none may
/// be referenced without one). `file` names the source in errors.
pub fn parse_gltf(bytes: &[u8], base_dir: Option<&Path>, file: &str) -> Result<GltfScene, GltfError> {
    Loader::new(bytes, base_dir).and_then(Loader::load).map_err(|problem| GltfError { file: file.into(), problem })
}

/// Extensions a file may require: one the loader reads (`MSFT_lod`), and those that change nothing it reads.
const SUPPORTED_REQUIRED_EXTENSIONS: [&str; 5] = [
    LOD_EXTENSION,
    "KHR_materials_unlit",
    "KHR_texture_transform",
    "KHR_materials_emissive_strength",
    "KHR_lights_punctual",
];

/// The node extension that lists a node's coarser levels of detail.
const LOD_EXTENSION: &str = "MSFT_lod";

struct Loader {
    document: gltf::Document,
    geometry: Geometry,
}

/// The file's buffers, read into meshes; collects warnings on the way.
struct Geometry {
    buffers: Vec<Vec<u8>>,
    warnings: Vec<String>,
}

/// Objects drawn for one glTF mesh: (engine mesh, colour) per triangle primitive.
type MeshObjects = Vec<(u32, [u8; 4])>;

impl Loader {
    fn new(bytes: &[u8], base_dir: Option<&Path>) -> Result<Self, GltfProblem> {
        let invalid = |e: gltf::Error| GltfProblem::Invalid(e.to_string());
        let unvalidated = gltf::Gltf::from_slice_without_validation(bytes).map_err(invalid)?;
        let root = unvalidated.document.into_json();
        check_validator_preconditions(&root)?;
        // The `gltf` crate's validator indexes some arrays unchecked; what the check above does not catch
        // still becomes an error here, not a crash.
        let document = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| gltf::Document::from_json(root)))
            .map_err(|_| GltfProblem::Invalid("the glTF validator failed on malformed indices".into()))?
            .map_err(invalid)?;
        let gltf = gltf::Gltf { document, blob: unvalidated.blob };
        for extension in gltf.document.extensions_required() {
            if !SUPPORTED_REQUIRED_EXTENSIONS.contains(&extension) {
                return Err(GltfProblem::UnsupportedExtension(extension.into()));
            }
        }
        for extension in gltf.document.extensions_used() {
            if !compression_hint(extension).is_empty() {
                return Err(GltfProblem::UnsupportedExtension(extension.into()));
            }
        }
        let mut warnings = Vec::new();
        let mut buffers = Vec::new();
        for buffer in gltf.document.buffers() {
            let index = buffer.index();
            let data = match buffer.source() {
                gltf::buffer::Source::Bin => gltf
                    .blob
                    .clone()
                    .ok_or_else(|| GltfProblem::Buffer { index, why: "the GLB binary chunk is missing".into() })?,
                gltf::buffer::Source::Uri(uri) => read_uri(uri, base_dir)
                    .map_err(|why| GltfProblem::Buffer { index, why: format!("'{}': {why}", short(uri)) })?,
            };
            if data.len() < buffer.length() {
                return Err(GltfProblem::Buffer {
                    index,
                    why: format!("holds {} bytes, {} declared", data.len(), buffer.length()),
                });
            }
            buffers.push(data);
        }
        for image in gltf.document.images() {
            if let gltf::image::Source::Uri { uri, .. } = image.source()
                && !uri.starts_with("data:")
            {
                let found = base_dir.map(|dir| dir.join(percent_decode(uri))).is_some_and(|p| p.is_file());
                if !found {
                    warnings.push(format!("image {} '{}' not found (textures are not used)", image.index(), uri));
                }
            }
        }
        Ok(Self { document: gltf.document, geometry: Geometry { buffers, warnings } })
    }

    fn load(self) -> Result<GltfScene, GltfProblem> {
        let Self { document, mut geometry } = self;
        let mut meshes = Vec::new();
        let mut drawn: Vec<Option<MeshObjects>> = vec![None; document.meshes().len()];
        let mut objects = Vec::new();
        let mut occluder_nodes = 0;
        let mut cells: Vec<Cell> = Vec::new();
        let mut portals: Vec<(String, Vec<Vec3>)> = Vec::new();
        // Drawn nodes that list coarser levels: (node, its local transform).
        let mut with_levels: Vec<(gltf::Node, Affine3A)> = Vec::new();
        let scene = document.default_scene().or_else(|| document.scenes().next()).ok_or(GltfProblem::NoScene)?;

        // Depth-first over the hierarchy: (node, parent's world transform, first object drawn by the parent).
        let mut visited = vec![false; document.nodes().len()];
        let mut stack: Vec<(gltf::Node, Affine3A, Option<usize>)> =
            scene.nodes().map(|node| (node, Affine3A::IDENTITY, None)).collect();
        stack.reverse();
        while let Some((node, parent_world, parent_object)) = stack.pop() {
            let node_problem = |why: String| GltfProblem::Node {
                node: node.index(),
                name: node.name().unwrap_or_default().into(),
                why,
            };
            if std::mem::replace(&mut visited[node.index()], true) {
                return Err(node_problem("reached twice: the node graph has a cycle or a shared child".into()));
            }
            let local = Affine3A::from_mat4(Mat4::from_cols_array_2d(&node.transform().matrix()));
            if !local.is_finite() {
                return Err(node_problem("non-finite transform".into()));
            }
            let world = parent_world * local;
            if !world.is_finite() {
                return Err(node_problem("its world transform overflows".into()));
            }
            let mut first_object = None;
            if let Some(mesh) = node.mesh() {
                if let Some(role) = cell_or_portal(&node) {
                    let points: Vec<Vec3> =
                        geometry.triangles_of(&mesh)?.iter().map(|&p| world.transform_point3(p)).collect();
                    match role {
                        Role::Cell(name) => {
                            let bounds = points
                                .iter()
                                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(min, max), &p| (min.min(p), max.max(p)));
                            match cells.iter_mut().find(|cell| cell.name == name) {
                                Some(cell) => cell.boxes.push(bounds),
                                None => cells.push(Cell { name, boxes: vec![bounds] }),
                            }
                        }
                        Role::Portal(name) => portals.push((name, points)),
                    }
                } else if is_occluder(&node) {
                    occluder_nodes += 1;
                    let triangles = geometry.triangles_of(&mesh)?;
                    match parent_object {
                        Some(owner) => {
                            let owner: &mut SceneObject = &mut objects[owner];
                            let soup: Vec<Vec3> = triangles.iter().map(|&p| local.transform_point3(p)).collect();
                            owner.occluder = Some(merge_occluder(owner.occluder.take(), soup));
                        }
                        None => {
                            meshes.push(Mesh { positions: triangles.clone(), indices: Vec::new() });
                            objects.push(SceneObject {
                                mesh: meshes.len() as u32 - 1,
                                transform: world,
                                occluder: Some(Occluder::new(triangles)),
                                velocity: None,
                                color: [0; 4],
                            });
                        }
                    }
                } else {
                    let index = mesh.index();
                    if drawn[index].is_none() {
                        drawn[index] = Some(geometry.meshes_of(&mesh, &mut meshes)?);
                    }
                    if node.extension_value(LOD_EXTENSION).is_some() {
                        with_levels.push((node.clone(), local));
                    }
                    for &(mesh, color) in drawn[index].iter().flatten() {
                        first_object.get_or_insert(objects.len());
                        objects.push(SceneObject { mesh, transform: world, occluder: None, velocity: None, color });
                    }
                }
            }
            for child in node.children().collect::<Vec<_>>().into_iter().rev() {
                stack.push((child, world, first_object));
            }
        }
        let mut scene = Scene::new(meshes, objects);
        // Per glTF mesh, the levels (mesh, placement) the first node drawing it gave.
        let mut given: Vec<Option<Vec<(usize, Affine3A)>>> = vec![None; drawn.len()];
        for (node, local) in with_levels {
            let Some(mesh) = node.mesh() else { continue };
            let (levels, mut warnings) = level_nodes(&document, &node, local);
            let signature: Vec<_> =
                levels.iter().filter_map(|(level, placement)| Some((level.mesh()?.index(), *placement))).collect();
            match &given[mesh.index()] {
                Some(first) if same_levels(first, &signature) => continue,
                Some(_) => {
                    geometry.warnings.push(format!(
                        "node {}: mesh {} has other levels from another node; its {LOD_EXTENSION} is ignored",
                        node.index(),
                        mesh.index()
                    ));
                    continue;
                }
                None => given[mesh.index()] = Some(signature),
            }
            let primitives = drawn[mesh.index()].as_deref().unwrap_or_default();
            let levels = geometry.levels_of(&node, &levels, primitives.len(), &mut warnings)?;
            geometry.warnings.extend(warnings);
            for (primitive, levels) in levels {
                scene.give_levels(primitives[primitive].0, levels);
            }
        }
        if !cells.is_empty() || !portals.is_empty() {
            match Cells::joined_by_position(cells, portals) {
                Ok(cells) => scene.cells = Some(cells),
                Err(error) => {
                    geometry.warnings.push(format!("cells and portals dropped, culled without them: {error}"))
                }
            }
        }
        Ok(GltfScene { scene, warnings: geometry.warnings, occluder_nodes })
    }
}

impl Geometry {
    /// The engine meshes of `mesh`'s triangle primitives, appended to `meshes`, with their colours.
    fn meshes_of(&mut self, mesh: &gltf::Mesh, meshes: &mut Vec<Mesh>) -> Result<MeshObjects, GltfProblem> {
        let mut out = Vec::new();
        for primitive in mesh.primitives() {
            let Some(read) = self.read_primitive(mesh, &primitive)? else { continue };
            let material = primitive.material();
            let factor = material.pbr_metallic_roughness().base_color_factor();
            let color = factor.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8);
            let mut triangles = read;
            if material.double_sided() {
                let back: Vec<u32> = triangles.indices.chunks_exact(3).flat_map(|t| [t[0], t[2], t[1]]).collect();
                triangles.indices.extend(back);
            }
            meshes.push(triangles);
            out.push((meshes.len() as u32 - 1, color));
        }
        Ok(out)
    }

    /// The meshes of `node`'s level nodes ([`level_nodes`]), placed in the space of `node`'s mesh, per drawn
    /// primitive of that mesh: `(primitive, levels)`. Each level node's mesh must draw as many primitives as
    /// `node`'s, which it replaces primitive by primitive; one that does not is left out, with a warning added to
    /// `warnings`.
    fn levels_of(
        &mut self,
        node: &gltf::Node,
        level_nodes: &[(gltf::Node, Affine3A)],
        primitives: usize,
        warnings: &mut Vec<String>,
    ) -> Result<Vec<(usize, Vec<Mesh>)>, GltfProblem> {
        let mut levels: Vec<Vec<Mesh>> = vec![Vec::new(); primitives];
        for (level, placement) in level_nodes {
            let Some(mesh) = level.mesh() else { continue };
            let mut read = Vec::new();
            self.meshes_of(&mesh, &mut read)?;
            if read.len() != primitives {
                let why = format!("level node {} draws {} primitives, not {primitives}", level.index(), read.len());
                warnings.push(level_warning(node, why));
                continue;
            }
            for (primitive, mut triangles) in read.into_iter().enumerate() {
                triangles.positions.iter_mut().for_each(|p| *p = placement.transform_point3(*p));
                levels[primitive].push(triangles);
            }
        }
        Ok(levels.into_iter().enumerate().filter(|(_, levels)| !levels.is_empty()).collect())
    }

    /// Every triangle of `mesh`'s primitives as a triangle soup (for occluders).
    fn triangles_of(&mut self, mesh: &gltf::Mesh) -> Result<Vec<Vec3>, GltfProblem> {
        let mut soup = Vec::new();
        for primitive in mesh.primitives() {
            if let Some(read) = self.read_primitive(mesh, &primitive)? {
                soup.extend(read.triangle_soup());
            }
        }
        Ok(soup)
    }

    /// A primitive as an indexed triangle list; `None` (with a warning) for points, lines or no positions.
    fn read_primitive(&mut self, mesh: &gltf::Mesh, primitive: &gltf::Primitive) -> Result<Option<Mesh>, GltfProblem> {
        let problem = |why: String| GltfProblem::Primitive {
            mesh: mesh.index(),
            name: mesh.name().unwrap_or_default().into(),
            primitive: primitive.index(),
            why,
        };
        let label =
            format!("mesh {} ('{}') primitive {}", mesh.index(), mesh.name().unwrap_or_default(), primitive.index());
        use gltf::mesh::Mode;
        let mode = primitive.mode();
        if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
            self.warnings.push(format!("{label}: {mode:?} are not drawn"));
            return Ok(None);
        }
        let Some(positions) = primitive.get(&gltf::Semantic::Positions) else {
            self.warnings.push(format!("{label}: no POSITION attribute, not drawn"));
            return Ok(None);
        };
        check_accessor(&positions, &self.buffers, gltf::accessor::DataType::F32, gltf::accessor::Dimensions::Vec3)
            .map_err(|why| problem(format!("POSITION {why}")))?;
        if let Some(indices) = primitive.indices() {
            check_accessor(&indices, &self.buffers, indices.data_type(), gltf::accessor::Dimensions::Scalar)
                .map_err(|why| problem(format!("indices {why}")))?;
            use gltf::accessor::DataType;
            if !matches!(indices.data_type(), DataType::U8 | DataType::U16 | DataType::U32) {
                return Err(problem(format!("indices of type {:?}", indices.data_type())));
            }
        }
        let buffers = &self.buffers;
        let reader = primitive.reader(|buffer| buffers.get(buffer.index()).map(Vec::as_slice));
        let positions: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| problem("POSITION cannot be read".into()))?
            .map(Vec3::from_array)
            .collect();
        if let Some(bad) = positions.iter().position(|p| !p.is_finite()) {
            return Err(problem(format!("vertex {bad} has a non-finite position")));
        }
        let raw: Vec<u32> = match reader.read_indices() {
            Some(indices) => indices.into_u32().collect(),
            None => (0..positions.len() as u32).collect(),
        };
        if let Some(&bad) = raw.iter().find(|&&i| i as usize >= positions.len()) {
            return Err(problem(format!("index {bad} is out of range ({} vertices)", positions.len())));
        }
        let indices = match mode {
            Mode::TriangleStrip => (2..raw.len())
                .flat_map(
                    |i| if i % 2 == 0 { [raw[i - 2], raw[i - 1], raw[i]] } else { [raw[i - 1], raw[i - 2], raw[i]] },
                )
                .collect(),
            Mode::TriangleFan => (2..raw.len()).flat_map(|i| [raw[0], raw[i - 1], raw[i]]).collect(),
            _ => {
                if !raw.len().is_multiple_of(3) {
                    self.warnings
                        .push(format!("{label}: {} indices, not a multiple of 3; the rest dropped", raw.len()));
                }
                raw[..raw.len() / 3 * 3].to_vec()
            }
        };
        Ok(Some(Mesh { positions, indices }))
    }
}

/// Indices that the `gltf` crate's validator dereferences before checking them (gltf-json 1.4: a primitive's
/// POSITION accessor), checked first so that such files get a clear error.
fn check_validator_preconditions(root: &gltf::json::Root) -> Result<(), GltfProblem> {
    use gltf::json::validation::Checked;
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            let position = primitive.attributes.get(&Checked::Valid(gltf::json::mesh::Semantic::Positions));
            if let Some(accessor) = position.filter(|a| a.value() >= root.accessors.len()) {
                return Err(GltfProblem::Primitive {
                    mesh: m,
                    name: mesh.name.clone().unwrap_or_default(),
                    primitive: p,
                    why: format!("POSITION names accessor {}, which does not exist", accessor.value()),
                });
            }
        }
    }
    Ok(())
}

/// What a cell or portal node is.
enum Role {
    /// A box of the cell of this name.
    Cell(String),
    /// A portal of this name.
    Portal(String),
}

/// The node's role in the cells and portals, from its name's suffix or its extras (`"cell": "name"`,
/// `"portal": true`); `None` for other nodes.
fn cell_or_portal(node: &gltf::Node) -> Option<Role> {
    let name = node.name().unwrap_or_default();
    let extras = extras_of(node);
    let extra = |key: &str| extras.as_ref().and_then(|v| v.get(key).cloned());
    if let Some(cell) = name.strip_suffix(CELL_SUFFIX) {
        return Some(Role::Cell(cell.to_string()));
    }
    if let Some(serde_json::Value::String(cell)) = extra("cell") {
        return Some(Role::Cell(cell));
    }
    let flagged = extra("portal") == Some(serde_json::Value::Bool(true));
    let fallback = || format!("node {}", node.index());
    (name.ends_with(PORTAL_SUFFIX) || flagged)
        .then(|| Role::Portal(if name.is_empty() { fallback() } else { name.to_string() }))
}

/// The level nodes `node` lists in its `MSFT_lod` extension (`{"ids": [node, ...]}`, finest first), each with
/// the transform that places its mesh in the space of `node`'s mesh: the level node's own transform, in place of
/// `node`'s (`local`). An id that names no other node, a level node without a mesh, and one that cannot be
/// placed are left out, with a warning each.
fn level_nodes<'a>(
    document: &'a gltf::Document,
    node: &gltf::Node,
    local: Affine3A,
) -> (Vec<(gltf::Node<'a>, Affine3A)>, Vec<String>) {
    let ids = node.extension_value(LOD_EXTENSION).and_then(|lod| lod.get("ids")).and_then(|ids| ids.as_array());
    let to_mesh_space = local.inverse();
    let (mut levels, mut warnings) = (Vec::new(), Vec::new());
    for id in ids.into_iter().flatten() {
        let level = id.as_u64().and_then(|id| document.nodes().nth(id as usize));
        let Some(level) = level.filter(|level| level.index() != node.index()) else {
            warnings.push(level_warning(node, format!("level {id} is not another node")));
            continue;
        };
        if level.mesh().is_none() {
            warnings.push(level_warning(node, format!("level node {} has no mesh", level.index())));
            continue;
        }
        let placement = to_mesh_space * Affine3A::from_mat4(Mat4::from_cols_array_2d(&level.transform().matrix()));
        if !placement.is_finite() {
            warnings.push(level_warning(node, format!("level node {} cannot be placed", level.index())));
            continue;
        }
        levels.push((level, placement));
    }
    (levels, warnings)
}

/// Whether two nodes' levels (each level's glTF mesh and placement) are the same meshes placed alike.
fn same_levels(a: &[(usize, Affine3A)], b: &[(usize, Affine3A)]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|((ma, pa), (mb, pb))| ma == mb && pa.abs_diff_eq(*pb, 1e-4))
}

/// A warning about `node`'s `MSFT_lod` level.
fn level_warning(node: &gltf::Node, why: String) -> String {
    format!("node {}: {LOD_EXTENSION} {why}; that level is left out", node.index())
}

/// Whether `node` is an artist occluder: its name ends in [`OCCLUDER_SUFFIX`] or its extras say
/// `"occluder": true`.
fn is_occluder(node: &gltf::Node) -> bool {
    let named = node.name().is_some_and(|n| n.ends_with(OCCLUDER_SUFFIX));
    let flagged = extras_of(node).is_some_and(|v| v.get("occluder") == Some(&serde_json::Value::Bool(true)));
    named || flagged
}

/// The node's extras as JSON, where it has them and they parse.
fn extras_of(node: &gltf::Node) -> Option<serde_json::Value> {
    node.extras().as_ref().and_then(|raw| serde_json::from_str(raw.get()).ok())
}

/// An occluder of `soup`'s triangles added to `existing`'s.
fn merge_occluder(existing: Option<Occluder>, soup: Vec<Vec3>) -> Occluder {
    match existing {
        Some(occluder) => Occluder::new([occluder.triangles(), &soup[..]].concat()),
        None => Occluder::new(soup),
    }
}

/// Checks that every element `accessor` reads lies inside its buffer view and buffer, and that it has the
/// expected type, so reading it cannot fail half-way.
fn check_accessor(
    accessor: &gltf::Accessor,
    buffers: &[Vec<u8>],
    data_type: gltf::accessor::DataType,
    dimensions: gltf::accessor::Dimensions,
) -> Result<(), String> {
    if accessor.data_type() != data_type || accessor.dimensions() != dimensions {
        return Err(format!("has type {:?} {:?}", accessor.data_type(), accessor.dimensions()));
    }
    if accessor.sparse().is_some() {
        return Err("is sparse (not supported)".into());
    }
    let Some(view) = accessor.view() else {
        return Err("has no buffer view".into());
    };
    let element = accessor.size();
    let stride = view.stride().unwrap_or(element);
    let count = accessor.count();
    let needed = match count {
        // The specification asks for at least one element, and the `gltf` reader assumes it.
        0 => return Err("has no elements".into()),
        n => (n - 1).checked_mul(stride).and_then(|s| s.checked_add(element)),
    }
    .and_then(|n| n.checked_add(accessor.offset()))
    .ok_or("size overflows")?;
    if needed > view.length() || stride < element {
        return Err(format!("reads {needed} bytes from a {}-byte buffer view", view.length()));
    }
    let buffer = buffers.get(view.buffer().index()).ok_or("names a missing buffer")?;
    let end = view.offset().checked_add(view.length()).ok_or("size overflows")?;
    if end > buffer.len() {
        return Err(format!("buffer view ends at byte {end} of a {}-byte buffer", buffer.len()));
    }
    Ok(())
}

/// The bytes a buffer URI names: a base64 `data:` URI, or a file relative to `base_dir`.
fn read_uri(uri: &str, base_dir: Option<&Path>) -> Result<Vec<u8>, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, data) = rest.split_once(";base64,").ok_or("a data URI that is not base64")?;
        return base64::engine::general_purpose::STANDARD.decode(data).map_err(|e| format!("bad base64: {e}"));
    }
    if uri.contains("://") {
        return Err("only files next to the glTF and data URIs are read".into());
    }
    let dir = base_dir.ok_or("an external file, and no folder to look in")?;
    let path: PathBuf = dir.join(percent_decode(uri));
    std::fs::read(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))
}

/// A URI path with `%XX` escapes decoded (glTF URIs are percent-encoded); bad escapes are kept as they are.
fn percent_decode(uri: &str) -> String {
    percent_encoding::percent_decode_str(uri).decode_utf8_lossy().into_owned()
}

/// A URI cut to a readable length for messages (data URIs are long).
fn short(uri: &str) -> String {
    if uri.len() > 60 { format!("{}...", &uri[..uri.floor_char_boundary(60)]) } else { uri.into() }
}
