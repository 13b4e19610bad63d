//! The exact visible set: every object's real triangles rasterized into an object-ID and triangle-ID buffer at
//! full resolution.
//!
//! Coverage is tested at pixel centres with exact edge functions and the top-left fill rule, so two triangles
//! sharing an edge cover each pixel centre on it exactly once, as on a GPU. Depth is `1/w` in f64, affine in
//! screen space and so interpolated exactly; the nearest surface wins, and of two at exactly the same depth
//! the one drawn first (lower object index, then lower triangle index), as a `LESS` depth test would keep.
//! Geometry is clipped to the near plane and to a finite far plane; back faces are skipped unless
//! [`ReferenceSettings::cull_back_faces`] is off.

use crate::triangle::{Faces, ReferenceView, ScreenTriangle, world_triangle};
use cullet::VisibleSet;
use cullet::frustum::LightView;
use cullet::mesh::Mesh;
use cullet::{Camera, LocalBounds};
use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use std::borrow::Cow;

/// Marks a pixel no object covers.
pub const NO_OBJECT: u32 = u32::MAX;
/// Rows a rayon task renders; bands never share a pixel.
pub(crate) const BAND_ROWS: u32 = 16;

/// One object to render: its mesh in local space and its world transform.
#[derive(Clone, Debug)]
pub struct ReferenceObject<'a> {
    /// The triangles the object draws (counter-clockwise front faces).
    pub mesh: Cow<'a, Mesh>,
    /// Local-to-world transform.
    pub transform: Affine3A,
}

impl<'a> ReferenceObject<'a> {
    /// An object drawing `mesh` at `transform`.
    pub fn new(mesh: &'a Mesh, transform: Affine3A) -> Self {
        Self { mesh: Cow::Borrowed(mesh), transform }
    }

    /// An object with no mesh of its own, judged by its bounding box drawn as a closed box: the most an
    /// object inside those bounds could cover.
    pub fn from_bounds(bounds: &LocalBounds, transform: Affine3A) -> Self {
        let mesh = Mesh::unit_cube(1).scaled(bounds.half_extent * 2.0, bounds.center);
        Self { mesh: Cow::Owned(mesh), transform }
    }
}

/// Resolution and face culling of the reference rendering.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReferenceSettings {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Skip triangles facing away from the camera, as the engine's draw pass does.
    pub cull_back_faces: bool,
}

impl Default for ReferenceSettings {
    /// 1920x1080, back faces culled.
    fn default() -> Self {
        Self { width: 1920, height: 1080, cull_back_faces: true }
    }
}

/// Per pixel, row-major from the top: the nearest surface's object index (into the rendered slice, or
/// [`NO_OBJECT`]), triangle index within that object's mesh, and depth `1/w` (larger is nearer, 0 for none).
#[derive(Clone, Debug, Default)]
pub struct IdBuffer {
    width: u32,
    height: u32,
    objects: usize,
    object: Vec<u32>,
    triangle: Vec<u32>,
    depth: Vec<f64>,
}

impl IdBuffer {
    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Object index per pixel.
    pub fn objects(&self) -> &[u32] {
        &self.object
    }

    /// Triangle index (within its object's mesh) per pixel; meaningless where the object is [`NO_OBJECT`].
    pub fn triangles(&self) -> &[u32] {
        &self.triangle
    }

    /// Depth `1/w` per pixel.
    pub fn depths(&self) -> &[f64] {
        &self.depth
    }

    /// The object at pixel `(x, y)`, or [`NO_OBJECT`].
    pub fn object_at(&self, x: u32, y: u32) -> u32 {
        self.object[(y * self.width + x) as usize]
    }

    /// The exact visible set and each visible object's pixel count.
    pub fn visibility(&self) -> ExactVisibility {
        let mut pixels = vec![0u32; self.objects];
        for &object in &self.object {
            if object != NO_OBJECT {
                pixels[object as usize] += 1;
            }
        }
        let mut visible = VisibleSet::new(self.objects);
        let pixels = pixels
            .into_iter()
            .enumerate()
            .filter(|&(_, count)| count > 0)
            .map(|(object, count)| {
                visible.set(object, true);
                (object as u32, count)
            })
            .collect();
        ExactVisibility { visible, pixels }
    }

    /// Visible triangles as sorted, distinct `(object, triangle)` pairs.
    pub fn visible_triangles(&self) -> Vec<(u32, u32)> {
        let mut pairs: Vec<(u32, u32)> = self
            .object
            .iter()
            .zip(&self.triangle)
            .filter(|(object, _)| **object != NO_OBJECT)
            .map(|(&object, &triangle)| (object, triangle))
            .collect();
        pairs.sort_unstable();
        pairs.dedup();
        pairs
    }
}

/// What a frame's exact rendering says about objects, small enough to keep for a whole camera path.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ExactVisibility {
    /// Objects that own at least one pixel.
    pub visible: VisibleSet,
    /// `(object, pixels it owns)` for each visible object, by object index.
    pub pixels: Vec<(u32, u32)>,
}

impl ExactVisibility {
    /// Pixels that change if only the objects in `kept` are drawn: those whose nearest object is not kept.
    /// (Where the nearest object is kept, it stays the nearest of a subset, with the same tie order.)
    pub fn pixels_lost(&self, kept: &VisibleSet) -> usize {
        self.pixels.iter().filter(|(object, _)| !kept.contains(*object as usize)).map(|&(_, n)| n as usize).sum()
    }
}

/// Renders `objects` as `camera` sees them; object `i` of the slice is ID `i` in the result. Objects whose
/// bounds lie wholly outside one clip plane are skipped before their triangles are touched (an exact test on
/// the mesh's box corners in f64).
pub fn render_ids(camera: &Camera, objects: &[ReferenceObject<'_>], settings: &ReferenceSettings) -> IdBuffer {
    let view = ReferenceView::new(camera, settings.width, settings.height);
    let faces = if settings.cull_back_faces { Faces::Front } else { Faces::Both };
    render_view(&view, faces, objects)
}

/// Renders `objects` as a light view's shadow map of `size` x `size` texels sees them (object `i` of the slice
/// is ID `i`): both faces of every triangle, as a shadow map draws them; a lamp's face clipped to its near
/// and far planes; a sun's cascade orthographic, clipped to its far plane only (its map clamps the depth of
/// what lies nearer the light), nearest to the light winning. An object owning no texel changes no texel of
/// the map: every texel's nearest depth is some other object's.
pub fn render_light_view(light_view: &LightView, objects: &[ReferenceObject<'_>], size: u32) -> IdBuffer {
    render_view(&ReferenceView::of_light_view(light_view, size), Faces::Both, objects)
}

/// Renders `objects` through `view`, drawing `faces`.
fn render_view(view: &ReferenceView, faces: Faces, objects: &[ReferenceObject<'_>]) -> IdBuffer {
    let triangles: Vec<(u32, u32, ScreenTriangle)> = objects
        .par_iter()
        .enumerate()
        .flat_map_iter(|(index, object)| {
            let mut out = Vec::new();
            let Some(bounds) = object.mesh.local_bounds() else { return out };
            if !view.may_see_box(&object.transform, bounds.center, bounds.half_extent) {
                return out;
            }
            let transform = object.transform.as_daffine3();
            for (triangle, corners) in object.mesh.indices.chunks_exact(3).enumerate() {
                let Some(local) = corner_positions(&object.mesh, corners) else { continue };
                view.project(world_triangle(&transform, local), faces, |screen| {
                    out.push((index as u32, triangle as u32, screen));
                });
            }
            out
        })
        .collect();

    let (width, height) = (view.width, view.height);
    let pixels = (width * height) as usize;
    let mut buffer = IdBuffer {
        width,
        height,
        objects: objects.len(),
        object: vec![NO_OBJECT; pixels],
        triangle: vec![0; pixels],
        depth: vec![0.0; pixels],
    };
    let bins = bin_by_band(triangles.iter().map(|(_, _, t)| t), height);
    let band_pixels = (width * BAND_ROWS) as usize;
    buffer
        .object
        .par_chunks_mut(band_pixels)
        .zip(buffer.triangle.par_chunks_mut(band_pixels))
        .zip(buffer.depth.par_chunks_mut(band_pixels))
        .zip(bins.par_iter())
        .enumerate()
        .for_each(|(band, (((object_ids, triangle_ids), depths), bin))| {
            let y0 = band as u32 * BAND_ROWS;
            let y1 = (y0 + BAND_ROWS).min(height);
            for &index in bin {
                let (object, triangle, screen) = &triangles[index as usize];
                screen.cover(width, (y0, y1), |x, y, depth| {
                    let pixel = ((y - y0) * width + x) as usize;
                    if depth > depths[pixel] {
                        depths[pixel] = depth;
                        object_ids[pixel] = *object;
                        triangle_ids[pixel] = *triangle;
                    }
                });
            }
        });
    buffer
}

/// For each band of [`BAND_ROWS`] rows, the indices of the triangles that may touch it, in input order.
pub(crate) fn bin_by_band<'a>(triangles: impl Iterator<Item = &'a ScreenTriangle>, height: u32) -> Vec<Vec<u32>> {
    let mut bins = vec![Vec::new(); height.div_ceil(BAND_ROWS) as usize];
    for (index, triangle) in triangles.enumerate() {
        let (y0, y1) = triangle.rows(height);
        if y0 < y1 {
            for bin in &mut bins[(y0 / BAND_ROWS) as usize..y1.div_ceil(BAND_ROWS) as usize] {
                bin.push(index as u32);
            }
        }
    }
    bins
}

/// The three corners of a triangle, or `None` when an index is out of range.
fn corner_positions(mesh: &Mesh, corners: &[u32]) -> Option<[Vec3; 3]> {
    let corner = |i: usize| mesh.positions.get(corners[i] as usize).copied();
    Some([corner(0)?, corner(1)?, corner(2)?])
}
