//! Drawing for debug views and comparisons, apart from culling: the scene drawn whole, recoloured, from a
//! camera other than the culling one, and shadow maps drawn with no GPU culling. The game's views and the
//! tests use it through [`GpuCuller::debug`]; nothing here changes what a culled frame draws.

use super::draw::RenderedImage;
use super::frame::{GpuCullSettings, GpuCuller, SunCasters, sun_casters};
use super::output::GpuFrameOutput;
use super::shadow::Cascade;
use super::{GpuContext, GpuError};
use crate::camera::Camera;
use crate::depth::DepthBuffer;
use bevy_ecs::prelude::*;

/// A [`GpuCuller`]'s scene and targets borrowed for debug drawing ([`GpuCuller::debug`]).
pub struct DebugDraw<'a> {
    culler: &'a mut GpuCuller,
}

impl GpuCuller {
    /// Debug drawing with this culler's scene and targets: see [`DebugDraw`].
    pub fn debug(&mut self) -> DebugDraw<'_> {
        DebugDraw { culler: self }
    }
}

impl DebugDraw<'_> {
    /// [`GpuCuller::run`] culling for `camera` but drawing the survivors as `draw_camera` sees them: with
    /// culling frozen at one camera, flying another shows what was culled.
    ///
    /// # Errors
    /// As [`GpuCuller::run`].
    pub fn run_from(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        draw_camera: &Camera,
        visible: &[u32],
        depth: &DepthBuffer,
        settings: &GpuCullSettings,
    ) -> Result<GpuFrameOutput, GpuError> {
        self.culler.run_views(context, camera, draw_camera, visible, depth, settings, None, None)
    }

    /// [`GpuCuller::run_world`] drawing from `draw_camera` (see [`DebugDraw::run_from`]).
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    ///
    /// # Panics
    /// As [`GpuCuller::run_world`].
    pub fn run_world_from(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        draw_camera: &Camera,
        settings: &GpuCullSettings,
    ) -> Result<GpuFrameOutput, GpuError> {
        self.culler.run_world_from(context, world, draw_camera, settings, None)
    }

    /// Draws every object of `world` with no culling, each in the colour `color_of(slot)` gives it (its own
    /// for `None`), as `camera` sees it: for debug views, such as tinting each object by the stage that culled
    /// it. The next [`GpuCuller::run_world`] restores every object's own colour.
    pub fn recolored(
        &mut self,
        context: &GpuContext,
        world: &mut World,
        camera: &Camera,
        color_of: impl Fn(usize) -> Option<[u8; 4]>,
    ) {
        self.culler.recolored = true;
        self.culler.sync_instances(context, world, |slot, instance| match color_of(slot) {
            Some(color) => instance.with_color(Some(color)),
            None => instance,
        });
        self.culler.draw_all(context, camera, false);
    }

    /// Draws every cluster of every instance with no culling at all, for comparison, and reads the image;
    /// `reversed` draws them in the opposite order, which shows where the image depends on draw order
    /// (coplanar surfaces of different objects at exactly the same depth).
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost.
    pub fn unculled(&self, context: &GpuContext, camera: &Camera, reversed: bool) -> Result<RenderedImage, GpuError> {
        self.culler.draw_all(context, camera, reversed);
        self.culler.read_image(context)
    }

    /// Draws the shadow maps of `world`'s sun cascades with no culling on the GPU: every cluster of the
    /// casters each light view kept, for a draw from `draw_origin`. For comparison with the culled maps
    /// [`GpuCuller::run_world`] draws (the next frame draws culled maps again); `world` as for it.
    pub fn shadows_unculled(&mut self, context: &GpuContext, world: &World, draw_origin: glam::Vec3) {
        let suns = sun_casters(world).unwrap_or_default();
        let cascades: Vec<Cascade<'_>> = suns.iter().map(SunCasters::cascade).collect();
        self.culler.shadows.draw_unculled(context, &self.culler.scene, &cascades, draw_origin);
    }
}
