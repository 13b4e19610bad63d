//! Writes the glTF test scene the tests load (`tests/scenes/city_small.gltf`): a 600-object city from the
//! built-in generator, buildings with their artist occluders as `_occluder` child nodes.
//!
//! `cargo run -p cullet --example write_test_scene [OUT.gltf]`; `tests/gltf.rs` checks that the shipped file
//! is exactly what this writes.

use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::gltf_export::write_gltf;

fn main() -> std::io::Result<()> {
    let out = std::env::args().nth(1).unwrap_or_else(|| "tests/scenes/city_small.gltf".into());
    let city = CityScene::generate(CityParams::with_objects(cullet::scene::city::TEST_SCENE_OBJECTS));
    std::fs::write(&out, write_gltf(&city.scene, "object"))?;
    println!("wrote {out}: {} objects, {} with occluders", city.scene.objects.len(), city.scene.occluder_count());
    Ok(())
}
