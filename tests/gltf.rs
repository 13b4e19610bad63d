//! glTF scenes: the shipped test scene round-trips through the exporter and loader, the third-party scenes in
//! `../shared/scenes` load with their documented counts, malformed files are refused with a clear error and
//! never panic, and culling stays conservative on all of them against the exact ground truth.

use cullet::camera::CameraPath;
use cullet::mesh::Mesh;
use cullet::scene::Scene;
use cullet::scene::auto_occluders::{AutoOccluderSettings, add_auto_occluders};
use cullet::scene::city::{CityParams, CityScene, TEST_SCENE_OBJECTS};
use cullet::scene::gltf_export::write_gltf;
use cullet::scene::gltf_import::{GltfError, GltfScene, load_gltf, parse_gltf};
use cullet_test_support::{repo_file, shared_scene};
use cullet_truth::PathMetrics;
use std::path::Path;

fn parse(json: &str) -> Result<GltfScene, GltfError> {
    parse_gltf(json.as_bytes(), None, "test.gltf")
}

fn fly_and_judge(scene: &Scene, path: CameraPath, frames: u32) -> PathMetrics {
    cullet_test_support::fly_and_judge(scene, path, frames, 0..frames)
}

#[test]
fn shipped_test_scene_is_what_the_generator_writes() {
    let city = CityScene::generate(CityParams::with_objects(TEST_SCENE_OBJECTS));
    let shipped = std::fs::read_to_string(repo_file("tests/scenes/city_small.gltf")).unwrap();
    assert!(
        shipped == write_gltf(&city.scene, "object"),
        "tests/scenes/city_small.gltf is stale: run `cargo run -p cullet --example write_test_scene`"
    );
}

#[test]
fn test_scene_round_trips_with_its_artist_occluders() {
    let city = CityScene::generate(CityParams::with_objects(TEST_SCENE_OBJECTS));
    let loaded = load_gltf(&repo_file("tests/scenes/city_small.gltf")).unwrap();
    assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    let scene = &loaded.scene;
    assert_eq!(scene.objects.len(), city.scene.objects.len());
    assert_eq!(loaded.occluder_nodes, city.scene.occluder_count());
    for (read, written) in scene.objects.iter().zip(&city.scene.objects) {
        assert!(read.transform.abs_diff_eq(written.transform, 0.0));
        assert_eq!(read.color, written.color);
        let (read_mesh, written_mesh) = (&scene.meshes[read.mesh as usize], &city.scene.meshes[written.mesh as usize]);
        assert_eq!(read_mesh, written_mesh);
        assert_eq!(
            read.occluder.as_ref().map(|o| o.triangles().to_vec()),
            written.occluder.as_ref().map(|o| o.triangles().to_vec())
        );
    }
}

#[test]
fn test_scene_culls_conservatively_along_its_orbit() {
    let scene = load_gltf(&repo_file("tests/scenes/city_small.gltf")).unwrap().scene;
    let city = CityScene::generate(CityParams::with_objects(TEST_SCENE_OBJECTS));
    let metrics = fly_and_judge(&scene, city.flythrough(), 40);
    assert_eq!((metrics.false_negatives, metrics.image_error_pixels), (0, 0));
    assert!(metrics.efficiency(1) > metrics.efficiency(0), "occlusion culled nothing: {metrics:?}");
}

#[test]
fn truck_town_loads_with_its_documented_counts_and_culls_conservatively() {
    let Some(mut town) = shared_scene("truck_town/town_model.gltf") else { return };
    // 20 drawn nodes with 60 primitives (one object each) and 30 477 triangles; the 15 collision meshes are
    // referenced only by a physics extension, never drawn.
    assert_eq!(town.scene.objects.len(), 60);
    assert_eq!(town.scene.triangle_count(), 30_477);
    assert_eq!(town.occluder_nodes, 0);
    let added = add_auto_occluders(&mut town.scene, &AutoOccluderSettings::default());
    assert!(added > 0);
    let path = town.scene.orbit_path();
    let metrics = fly_and_judge(&town.scene, path, 24);
    assert_eq!((metrics.false_negatives, metrics.image_error_pixels), (0, 0));
    println!("truck_town: {added} automatic occluders; {metrics:?}");
}

#[test]
fn zdm2_loads_as_one_mesh() {
    let Some(map) = shared_scene("zdm2/zdm2.glb") else { return };
    assert_eq!(map.scene.objects.len(), 1);
    assert_eq!(map.scene.meshes[0].triangle_count(), 58_772);
}

/// A one-triangle glTF with its buffer embedded; `patch` edits the JSON before it is parsed.
fn triangle_gltf(patch: impl FnOnce(&mut serde_json::Value)) -> String {
    let mesh = Mesh { positions: vec![glam::Vec3::ZERO, glam::Vec3::X, glam::Vec3::Y], indices: vec![0, 1, 2] };
    let scene = Scene::new(
        vec![mesh],
        vec![cullet::scene::SceneObject {
            mesh: 0,
            transform: glam::Affine3A::IDENTITY,
            occluder: None,
            velocity: None,
            color: [10, 20, 30, 255],
        }],
    );
    let mut json: serde_json::Value = serde_json::from_str(&write_gltf(&scene, "t")).unwrap();
    patch(&mut json);
    json.to_string()
}

/// Edits the bytes of the embedded buffer of a glTF written by [`triangle_gltf`].
fn patch_buffer(json: &mut serde_json::Value, edit: impl FnOnce(&mut Vec<u8>)) {
    use base64::Engine as _;
    let engine = base64::engine::general_purpose::STANDARD;
    let uri = json["buffers"][0]["uri"].as_str().unwrap().to_string();
    let (head, data) = uri.split_once(";base64,").unwrap();
    let mut bytes = engine.decode(data).unwrap();
    edit(&mut bytes);
    json["buffers"][0]["uri"] = format!("{head};base64,{}", engine.encode(bytes)).into();
}

#[test]
fn malformed_files_get_an_error_naming_the_file_and_the_problem() {
    type Patch = Box<dyn FnOnce(&mut serde_json::Value)>;
    let cases: Vec<(&str, Patch)> = vec![
        ("buffer 0", Box::new(|j| j["buffers"][0]["uri"] = "missing.bin".into())),
        ("holds", Box::new(|j| j["buffers"][0]["byteLength"] = 4096.into())),
        (
            "KHR_draco_mesh_compression",
            Box::new(|j| j["extensionsUsed"] = serde_json::json!(["KHR_draco_mesh_compression"])),
        ),
        (
            "EXT_meshopt_compression",
            Box::new(|j| {
                j["extensionsUsed"] = serde_json::json!(["EXT_meshopt_compression"]);
                j["extensionsRequired"] = serde_json::json!(["EXT_meshopt_compression"]);
            }),
        ),
        // The buffer holds the positions (36 bytes), then the indices.
        ("index 7 is out of range", Box::new(|j| patch_buffer(j, |bytes| bytes[36] = 7))),
        (
            "non-finite position",
            Box::new(|j| patch_buffer(j, |bytes| bytes[0..4].copy_from_slice(&f32::NAN.to_le_bytes()))),
        ),
        ("non-finite transform", Box::new(|j| j["nodes"][0]["matrix"][12] = serde_json::json!(1e39))),
        ("reads", Box::new(|j| j["accessors"][1]["count"] = 3000.into())),
        ("not a valid glTF", Box::new(|j| j["nodes"][0]["mesh"] = 5.into())),
        (
            "has no scene",
            Box::new(|j| {
                j.as_object_mut().unwrap().remove("scene");
                j["scenes"] = serde_json::json!([]);
            }),
        ),
    ];
    for (expected, patch) in cases {
        let error = parse(&triangle_gltf(patch)).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(error.starts_with("test.gltf: ") && error.contains(expected), "expected '{expected}', got '{error}'");
    }
    let missing = load_gltf(Path::new("no/such/file.glb")).unwrap_err().to_string();
    assert!(missing.contains("no/such/file.glb") && missing.contains("cannot read"), "{missing}");
    assert!(parse("{not json").unwrap_err().to_string().contains("not a valid glTF"));
}

#[test]
fn usable_geometry_loads_with_warnings() {
    let loaded = parse(&triangle_gltf(|j| {
        j["images"] = serde_json::json!([{"uri": "gone.png"}]);
        let primitive = j["meshes"][0]["primitives"][0].clone();
        j["meshes"][0]["primitives"] = serde_json::json!([primitive.clone(), primitive]);
        j["meshes"][0]["primitives"][1]["mode"] = 1.into();
    }))
    .unwrap();
    assert_eq!(loaded.scene.objects.len(), 1);
    assert_eq!(loaded.scene.objects[0].color, [10, 20, 30, 255]);
    let warnings = loaded.warnings.join("\n");
    assert!(warnings.contains("gone.png") && warnings.contains("Lines"), "{warnings}");
}

#[test]
fn double_sided_materials_draw_both_windings_and_occluder_nodes_are_not_drawn() {
    let loaded = parse(&triangle_gltf(|j| {
        j["materials"][0]["doubleSided"] = true.into();
        // A second node using the same mesh, flagged as occluder through extras, with no drawn parent.
        j["nodes"].as_array_mut().unwrap().push(serde_json::json!({"mesh": 0, "extras": {"occluder": true}}));
        j["scenes"][0]["nodes"] = serde_json::json!([0, 1]);
    }))
    .unwrap();
    assert_eq!(loaded.occluder_nodes, 1);
    let scene = &loaded.scene;
    assert_eq!(scene.objects.len(), 2);
    assert_eq!(scene.meshes[scene.objects[0].mesh as usize].indices, vec![0, 1, 2, 0, 2, 1]);
    let carrier = &scene.objects[1];
    assert_eq!(scene.meshes[carrier.mesh as usize].triangle_count(), 0);
    assert_eq!(carrier.occluder.as_ref().unwrap().triangle_count(), 1);
}

/// Mutated and truncated files (bytes flipped, cut short, JSON values replaced) never panic the loader.
#[test]
fn hostile_files_never_panic() {
    use proptest::prelude::*;
    let gltf = triangle_gltf(|_| {});
    let glb = std::fs::read(repo_file("../shared/scenes/zdm2/zdm2.glb")).ok();
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig { cases: 256, ..ProptestConfig::default() });
    let sources: Vec<Vec<u8>> =
        std::iter::once(gltf.into_bytes()).chain(glb.map(|b| b[..b.len().min(4096)].to_vec())).collect();
    for source in sources {
        let len = source.len();
        runner
            .run(&(proptest::collection::vec((0..len, any::<u8>()), 0..8), 0..=len), |(flips, cut)| {
                let mut bytes = source.clone();
                for (at, value) in flips {
                    bytes[at] = value;
                }
                bytes.truncate(cut.max(1));
                let _ = parse_gltf(&bytes, None, "fuzz.gltf");
                Ok(())
            })
            .unwrap();
    }
}

/// JSON pointers of every number and string in `value`.
fn leaf_pointers(value: &serde_json::Value, at: String, out: &mut Vec<String>) {
    match value {
        serde_json::Value::Object(map) => map.iter().for_each(|(k, v)| leaf_pointers(v, format!("{at}/{k}"), out)),
        serde_json::Value::Array(items) => {
            items.iter().enumerate().for_each(|(i, v)| leaf_pointers(v, format!("{at}/{i}"), out))
        }
        _ => out.push(at),
    }
}

/// Structure-aware fuzzing: valid glTF (the one-triangle file with an occluder child and an `MSFT_lod` level) with
/// up to four of its numbers or strings replaced by hostile values (out-of-range indices, huge counts and
/// offsets, negative numbers, wrong types): a typed error or a scene whose levels can be built, never a panic.
#[test]
fn hostile_field_values_never_panic() {
    use proptest::prelude::*;
    let source: serde_json::Value = serde_json::from_str(&triangle_gltf(|j| {
        j["nodes"].as_array_mut().unwrap().push(serde_json::json!({"mesh": 0, "name": "t0_occluder"}));
        j["nodes"][0]["children"] = serde_json::json!([1]);
        j["meshes"][0]["primitives"][0]["mode"] = 4.into();
        j["nodes"].as_array_mut().unwrap().push(serde_json::json!({"mesh": 0, "scale": [1.5, 1.5, 1.5]}));
        j["nodes"][0]["extensions"] = serde_json::json!({"MSFT_lod": {"ids": [2]}});
    }))
    .unwrap();
    let mut pointers = Vec::new();
    leaf_pointers(&source, String::new(), &mut pointers);
    let hostile = prop_oneof![
        (0i64..8).prop_map(serde_json::Value::from),
        (-3i64..0).prop_map(serde_json::Value::from),
        Just(serde_json::Value::from(u32::MAX)),
        Just(serde_json::Value::from(u64::MAX)),
        Just(serde_json::Value::from(1e300)),
        Just(serde_json::Value::from("x")),
        Just(serde_json::Value::Null),
    ];
    let mut runner =
        proptest::test_runner::TestRunner::new(ProptestConfig { cases: 4096, ..ProptestConfig::default() });
    runner
        .run(&proptest::collection::vec((0..pointers.len(), hostile), 1..5), |edits| {
            let mut json = source.clone();
            for (pointer, value) in edits {
                if let Some(slot) = json.pointer_mut(&pointers[pointer]) {
                    *slot = value;
                }
            }
            if let Ok(loaded) = parse_gltf(json.to_string().as_bytes(), None, "fuzz.gltf") {
                let _ = cullet::lod::LodLibrary::for_scene(&loaded.scene, &cullet::lod::ChainSettings::default());
            }
            Ok(())
        })
        .unwrap();
}

/// A hall (a `_cell` node, or a node whose extras name its cell), a door (a `_portal` node) and a crate: the
/// hall and the door are read as cells and portals and not drawn; a portal that joins nothing drops them with
/// a warning, and the scene loads without them.
#[test]
fn cell_and_portal_nodes_become_the_scenes_cells() {
    let quad = Mesh {
        positions: vec![
            glam::Vec3::new(0.0, 0.0, -0.5),
            glam::Vec3::new(0.0, 0.0, 0.5),
            glam::Vec3::new(0.0, 2.0, 0.5),
            glam::Vec3::new(0.0, 2.0, -0.5),
        ],
        indices: vec![0, 1, 2, 0, 2, 3],
    };
    let object = |mesh, transform| cullet::scene::SceneObject {
        mesh,
        transform,
        occluder: None,
        velocity: None,
        color: [200; 4],
    };
    let scene = Scene::new(
        vec![Mesh::unit_cube(1), quad],
        vec![
            object(
                0,
                glam::Affine3A::from_scale_rotation_translation(
                    glam::Vec3::new(10.0, 3.0, 10.0),
                    glam::Quat::IDENTITY,
                    glam::Vec3::new(0.0, 1.5, 0.0),
                ),
            ),
            object(1, glam::Affine3A::from_translation(glam::Vec3::new(5.0, 0.0, 0.0))),
            object(0, glam::Affine3A::from_translation(glam::Vec3::new(0.0, 0.5, 0.0))),
        ],
    );
    let json: serde_json::Value = serde_json::from_str(&write_gltf(&scene, "hall")).unwrap();
    let named = |patch: &dyn Fn(&mut serde_json::Value)| {
        let mut json = json.clone();
        let nodes = json["nodes"].as_array_mut().unwrap();
        let with_mesh: Vec<usize> = (0..nodes.len()).filter(|&i| nodes[i].get("mesh").is_some()).collect();
        assert_eq!(with_mesh.len(), 3);
        nodes[with_mesh[0]]["name"] = "hall_cell".into();
        nodes[with_mesh[1]]["name"] = "door_portal".into();
        patch(&mut json);
        parse(&json.to_string()).unwrap()
    };
    for loaded in [
        named(&|_| {}),
        named(&|json| {
            let nodes = json["nodes"].as_array_mut().unwrap();
            let hall = nodes.iter_mut().find(|n| n["name"] == "hall_cell").unwrap();
            hall["name"] = "the big room".into();
            hall["extras"] = serde_json::json!({ "cell": "hall" });
        }),
    ] {
        assert_eq!(loaded.scene.objects.len(), 1, "{:?}", loaded.warnings);
        let cells = loaded.scene.cells.as_ref().expect("cells");
        assert_eq!(cells.cells().len(), 1);
        assert_eq!(cells.cells()[0].name, "hall");
        let (min, max) = cells.cells()[0].boxes[0];
        assert!(
            min.abs_diff_eq(glam::Vec3::new(-5.0, 0.0, -5.0), 1e-5)
                && max.abs_diff_eq(glam::Vec3::new(5.0, 3.0, 5.0), 1e-5)
        );
        assert_eq!(cells.portals().len(), 1);
        assert_eq!(cells.portals()[0].joins, (0, None));
    }
    let astray = named(&|json| {
        let nodes = json["nodes"].as_array_mut().unwrap();
        let door = nodes.iter_mut().find(|n| n["name"] == "door_portal").unwrap();
        door.as_object_mut().unwrap().remove("matrix");
        door["translation"] = serde_json::json!([100.0, 0.0, 0.0]);
    });
    assert!(astray.scene.cells.is_none());
    assert!(
        astray.warnings.iter().any(|w| w.contains("cells and portals dropped") && w.contains("door_portal")),
        "{:?}",
        astray.warnings
    );
    assert_eq!(astray.scene.objects.len(), 1);
}

#[test]
fn msft_lod_levels_round_trip_are_measured_and_held_by_the_bounds() {
    use cullet::lod::{ChainSettings, LodError, LodLibrary};
    use glam::{Affine3A, Vec3};
    let fine = Mesh::unit_cube(8);
    let (grown, larger) = (
        Mesh::unit_cube(2).scaled(Vec3::splat(1.1), Vec3::ZERO),
        Mesh::unit_cube(1).scaled(Vec3::splat(1.3), Vec3::ZERO),
    );
    let object =
        |transform| cullet::scene::SceneObject { mesh: 0, transform, occluder: None, velocity: None, color: [90; 4] };
    let placed = Affine3A::from_scale_rotation_translation(
        Vec3::splat(2.0),
        glam::Quat::from_rotation_y(0.7),
        Vec3::new(40.0, 0.0, -3.0),
    );
    let mut scene = Scene::new(vec![fine.clone()], vec![object(placed), object(Affine3A::IDENTITY)]);
    scene.give_levels(0, vec![grown.clone(), larger.clone()]);
    assert!(scene.mesh_bounds[0].half_extent.abs_diff_eq(Vec3::splat(0.65), 1e-6), "bounds hold every level");

    let json = write_gltf(&scene, "box");
    let loaded = parse(&json).unwrap();
    assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    assert_eq!(loaded.scene.objects.len(), 2, "level nodes are not drawn");
    assert_eq!(loaded.scene.given_levels.len(), 1);
    let (mesh, levels) = &loaded.scene.given_levels[0];
    for (read, written) in levels.iter().zip([&grown, &larger]) {
        assert_eq!(read.indices, written.indices);
        assert!(read.positions.iter().zip(&written.positions).all(|(a, b)| a.abs_diff_eq(*b, 1e-5)));
    }
    assert_eq!(loaded.scene.mesh_bounds[*mesh as usize], scene.mesh_bounds[0]);

    // Errors measured: a box grown by 0.05 a side is sqrt(3) * 0.05 away at its corners.
    let library = LodLibrary::for_scene(&loaded.scene, &ChainSettings::default());
    assert!(library.errors().is_empty(), "{:?}", library.errors());
    assert_eq!(library.levels(0), 3);
    assert_eq!([0, 1, 2].map(|l| library.triangles(0, l).unwrap()), [768, 48, 12]);
    let error = |l| library.error(0, l).unwrap();
    assert_eq!(error(0), 0.0);
    assert!((error(1) - 3f32.sqrt() * 0.05).abs() < 1e-4, "{}", error(1));
    assert!((error(2) - 3f32.sqrt() * 0.15).abs() < 1e-4, "{}", error(2));

    // What cannot serve is left out, with why; never a wrong level.
    let patched = |ids: serde_json::Value| {
        let mut json: serde_json::Value = serde_json::from_str(&json).unwrap();
        let node = json["nodes"].as_array_mut().unwrap().iter_mut().find(|n| n.get("extensions").is_some()).unwrap();
        node["extensions"]["MSFT_lod"]["ids"] = ids;
        parse(&json.to_string()).unwrap()
    };
    let reversed = patched(serde_json::json!([1, 0]));
    let library = LodLibrary::for_scene(&reversed.scene, &ChainSettings::default());
    assert_eq!(library.levels(0), 2, "the coarsest first, then a finer one: the finer one is left out");
    assert!(
        matches!(library.errors(), [(0, LodError::NotCoarser { level: 2, triangles: 48, finer: 12 })]),
        "{:?}",
        library.errors()
    );
    let broken = patched(serde_json::json!([99, "a", 2, 0]));
    let [bad_ids @ .., other_node] = broken.warnings.as_slice() else { panic!() };
    assert_eq!(bad_ids.len(), 3, "{:?}", broken.warnings);
    assert!(bad_ids.iter().all(|w| w.contains("MSFT_lod") && w.contains("left out")), "{:?}", broken.warnings);
    assert!(other_node.contains("other levels"), "the second box's node still lists both levels: {other_node}");
    assert_eq!(broken.scene.given_levels[0].1.len(), 1, "only the real level node stays");

    // A level nowhere near its mesh is refused before it is measured.
    let mut stray = Scene::new(vec![fine.clone()], vec![object(Affine3A::IDENTITY)]);
    stray.give_levels(0, vec![Mesh::unit_cube(1).scaled(Vec3::ONE, Vec3::new(1e6, 0.0, 0.0))]);
    let library = LodLibrary::for_scene(&stray, &ChainSettings::default());
    assert_eq!(library.levels(0), 1);
    assert!(matches!(library.errors(), [(0, LodError::StrayLevel { level: 1, .. })]), "{:?}", library.errors());
}
