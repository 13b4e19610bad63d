//! The image error of levels of detail: a frame rendered exactly with each object's chosen level
//! ([`cullet::lod::LodSelection`]) against the same frame at full detail.

use crate::judge::reference_objects;
use crate::render::{IdBuffer, NO_OBJECT, ReferenceObject, ReferenceSettings, render_ids};
use bevy_ecs::world::World;
use cullet::lod::{LodLibrary, LodSelection};
use cullet::mesh::Mesh;
use cullet::{BoundsStore, Camera, ObjectColor};
use std::borrow::Cow;

/// How one frame drawn at the chosen levels differs from full detail.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImageError {
    /// Pixels in the frame.
    pub pixels: usize,
    /// Pixels whose nearest object differs (another object, or background where there was one, or the
    /// reverse): what a flat-shaded frame changes.
    pub pixels_changed: usize,
    /// Mean over every pixel of the absolute colour difference, as a fraction of full scale (0 to 1), with
    /// each object in its [`ObjectColor`] (grey without one) and the background black.
    pub colour_error: f64,
    /// Mean over the pixels both frames cover of the relative difference of view distance.
    pub depth_error: f64,
}

impl ImageError {
    /// `pixels_changed` as a fraction of `pixels`.
    pub fn changed_fraction(&self) -> f64 {
        self.pixels_changed as f64 / self.pixels.max(1) as f64
    }

    /// Sums `other` into this, weighting each frame's means by its pixels: the error over a camera path.
    pub fn add(&mut self, other: &ImageError) {
        let total = (self.pixels + other.pixels).max(1) as f64;
        self.colour_error = (self.colour_error * self.pixels as f64 + other.colour_error * other.pixels as f64) / total;
        self.depth_error = (self.depth_error * self.pixels as f64 + other.depth_error * other.pixels as f64) / total;
        self.pixels += other.pixels;
        self.pixels_changed += other.pixels_changed;
    }
}

/// `full` (full detail) against `lod` (the chosen levels), two renderings of the same objects from the same
/// view; `colours[i]` is object `i`'s colour.
///
/// # Panics
/// If the two renderings differ in size.
pub fn compare(full: &IdBuffer, lod: &IdBuffer, colours: &[[u8; 4]]) -> ImageError {
    assert_eq!((full.width(), full.height()), (lod.width(), lod.height()), "two renderings of one frame");
    let colour = |object: u32| {
        if object == NO_OBJECT { [0; 4] } else { colours.get(object as usize).copied().unwrap_or([128; 4]) }
    };
    let mut error = ImageError { pixels: full.objects().len(), ..ImageError::default() };
    let (mut colour_sum, mut depth_sum, mut both) = (0.0, 0.0, 0usize);
    for (i, (&a, &b)) in full.objects().iter().zip(lod.objects()).enumerate() {
        if a != b {
            error.pixels_changed += 1;
            let (ca, cb) = (colour(a), colour(b));
            colour_sum += (0..3).map(|c| (ca[c] as f64 - cb[c] as f64).abs()).sum::<f64>() / (3.0 * 255.0);
        }
        if a != NO_OBJECT && b != NO_OBJECT {
            // Depths are 1/w: view distances are their reciprocals.
            let (da, db) = (full.depths()[i], lod.depths()[i]);
            depth_sum += ((1.0 / db - 1.0 / da) / (1.0 / da)).abs();
            both += 1;
        }
    }
    error.colour_error = colour_sum / error.pixels.max(1) as f64;
    error.depth_error = depth_sum / both.max(1) as f64;
    error
}

/// Each chain's full-detail mesh: what [`cullet::mesh::MeshRef`]s name at full detail.
pub fn full_detail_meshes(library: &LodLibrary) -> Vec<Mesh> {
    (0..library.chain_count() as u32)
        .filter_map(|chain| library.mesh_of(chain, 0))
        .map(|mesh| library.meshes()[mesh as usize].clone())
        .collect()
}

/// The objects of `world` in store-slot order, each drawing the level its [`LodSelection`] chose from
/// `library` (a dropped object draws nothing); objects without levels as [`reference_objects`] draws them
/// from `full_detail` ([`full_detail_meshes`] of `library`).
pub fn lod_reference_objects<'a>(
    world: &World,
    library: &'a LodLibrary,
    full_detail: &'a [Mesh],
) -> Vec<ReferenceObject<'a>> {
    let selection = world.resource::<LodSelection>();
    let mut objects = reference_objects(world, full_detail);
    for (slot, object) in objects.iter_mut().enumerate() {
        match selection.mesh_of(slot, library) {
            Some(mesh) => object.mesh = Cow::Borrowed(&library.meshes()[mesh as usize]),
            None if selection.dropped().contains(slot) => object.mesh = Cow::Owned(Mesh::default()),
            None => {}
        }
    }
    objects
}

/// The image error of `world`'s last frame (culled with [`cullet::lod::install`]'s selection) from its
/// [`Camera`]: every object exactly at full detail against every object at its chosen level, both at
/// `reference`'s resolution. Levels are chosen for a frame [`cullet::lod::LodSettings::viewport_height`]
/// tall; judge at that height for the error in the same pixels.
pub fn judge_lod(world: &World, library: &LodLibrary, reference: &ReferenceSettings) -> ImageError {
    let camera = world.resource::<Camera>();
    let full_detail = full_detail_meshes(library);
    let lod = lod_reference_objects(world, library, &full_detail);
    let full = reference_objects(world, &full_detail);
    let colours: Vec<[u8; 4]> = world
        .resource::<BoundsStore>()
        .entities()
        .iter()
        .map(|&entity| world.get::<ObjectColor>(entity).map_or([128, 128, 128, 255], |c| c.0))
        .collect();
    compare(&render_ids(camera, &full, reference), &render_ids(camera, &lod, reference), &colours)
}
