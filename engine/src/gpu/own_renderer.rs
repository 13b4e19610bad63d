//! A renderer of the app's own that draws each frame's survivors into its own targets while the culler records
//! the frame ([`super::GpuCuller::run_into`], [`super::GpuCuller::run_world_into`]). With two-phase occlusion
//! the renderer draws the early phase, the culler merges the renderer's depth with the CPU pyramid and culls
//! the late phase against it, and the renderer draws the late phase over the early one (its occluder step
//! first, where it runs, with the depth merged again in between), all in the frame's one submission.

use super::indirect::DrawBuffers;
use super::{GpuContext, GpuError};

/// A renderer that draws the culler's survivors itself, into a depth texture of its own.
///
/// Each draw it records reads [`DrawBuffers`] as [`DrawBuffers::record`] does: the positions as vertex buffer,
/// the compacted indices, one multi-draw-indirect-count, the instances and the view at group 0 (see the
/// `own_render_pass` example). Depth is tested and written in the camera's
/// [`DepthConvention`](crate::camera::DepthConvention).
pub trait OwnRenderer {
    /// The depth texture the draws write. Where the frame runs in two phases, the culler reads it after the
    /// early phase's draw (and after each later one), so it must be `Depth32Float` or `Depth32FloatStencil8`,
    /// one sample, of the culler's target size ([`super::GpuCuller::resize`]), with
    /// [`wgpu::TextureUsages::TEXTURE_BINDING`].
    fn depth(&self) -> &wgpu::Texture;

    /// Records the draw of `buffers` into `encoder`: clearing the targets first where `clear` (the frame's
    /// first draw), else drawing over what earlier draws of the frame left. A frame of one phase calls it once
    /// (once per batch where its candidates need several), a frame of two phases once for each phase and once
    /// more for the late phase's occluder step where it runs ([`super::GpuGating::min_late_occluder_share`]).
    fn draw(&mut self, context: &GpuContext, encoder: &mut wgpu::CommandEncoder, buffers: DrawBuffers<'_>, clear: bool);
}

/// Checks that two-phase occlusion's merge can read `depth` as the depth of `target` (width, height) frames.
///
/// # Errors
/// [`GpuError::RendererDepth`] saying what does not fit.
pub(crate) fn check_depth(depth: &wgpu::Texture, target: (u32, u32)) -> Result<(), GpuError> {
    let size = (depth.width(), depth.height());
    let problem =
        if !matches!(depth.format(), wgpu::TextureFormat::Depth32Float | wgpu::TextureFormat::Depth32FloatStencil8) {
            format!("its format is {:?}, not Depth32Float or Depth32FloatStencil8", depth.format())
        } else if size != target {
            format!("it is {}x{}, the culler's targets {}x{} (GpuCuller::resize)", size.0, size.1, target.0, target.1)
        } else if !depth.usage().contains(wgpu::TextureUsages::TEXTURE_BINDING) {
            "it lacks the TEXTURE_BINDING usage".to_owned()
        } else if depth.sample_count() != 1 || depth.dimension() != wgpu::TextureDimension::D2 {
            "it is not a two-dimensional texture of one sample".to_owned()
        } else {
            return Ok(());
        };
    Err(GpuError::RendererDepth(problem))
}
