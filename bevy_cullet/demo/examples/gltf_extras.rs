//! Bevy's own glTF loader, with the plugin: `assets/extras_occluder.gltf` has a node `wall` whose `extras` say
//! `"occluder": true` and a node `crate` without extras, both drawing a cube. Once the scene has spawned, the
//! wall's primitive must be an occluder that is no longer drawn, and the crate a drawn mesh; the program says
//! which and exits with an error otherwise (or after 600 frames without the scene).
//!
//! `cargo run --ignore-rust-version --example gltf_extras` (under `xvfb-run -a` on a machine without a display).

use bevy::app::AppExit;
use bevy::prelude::*;
use bevy_cullet::CulletPlugin;
use cullet::Occluder;

fn main() -> AppExit {
    App::new()
        .add_plugins(DefaultPlugins)
        .add_plugins(CulletPlugin)
        .add_systems(Startup, setup)
        .add_systems(Update, check)
        .run()
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    commands.spawn((Camera3d::default(), Transform::default()));
    commands.spawn(WorldAssetRoot(assets.load(GltfAssetLabel::Scene(0).from_asset("extras_occluder.gltf"))));
}

/// Each named node's primitive: whether it still draws a mesh, and whether it is an occluder.
fn check(
    mut frames: Local<u32>,
    nodes: Query<(&Name, &Children)>,
    primitives: Query<(Has<Mesh3d>, Has<Occluder>)>,
    mut exit: MessageWriter<AppExit>,
) {
    *frames += 1;
    let primitive = |node: &str| {
        let (_, children) = nodes.iter().find(|(name, _)| name.as_str() == node)?;
        children.iter().find_map(|child| primitives.get(child).ok())
    };
    let (wall, crate_) = (primitive("wall"), primitive("crate"));
    let spawned = wall.is_some() && crate_.is_some();
    if spawned || *frames > 600 {
        println!("after {} frames: wall (drawn, occluder) {wall:?}, crate {crate_:?}", *frames);
        let expected = wall == Some((false, true)) && crate_ == Some((true, false));
        // The wall turns into an occluder one frame after it spawns: give it a few frames.
        if expected {
            println!("the wall, marked by its glTF extras, is an occluder and no longer drawn; the crate is drawn");
            exit.write(AppExit::Success);
        } else if *frames > 600 || (spawned && *frames > 30) {
            exit.write(AppExit::error());
        }
    }
}
