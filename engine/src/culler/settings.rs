//! What one view is culled with: the frustum switch, the occlusion buffer and the adaptive gating.

use crate::camera::Camera;
use crate::depth::ScreenView;
use crate::detail::DetailSettings;
use crate::raster::RasterMode;
use bevy_ecs::prelude::*;

/// How the pipeline skips work a scene does not need. Gating only ever skips a stage (keeping everything that
/// stage would have tested) or reuses a result whose inputs did not change, so it cannot add false negatives.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveSettings {
    /// Reuse last frame's frustum and occlusion results when no bounds changed, the camera is the same and so
    /// are the settings; when only a few objects without occluders moved, re-test just those
    /// ([`crate::pipeline::CullStats::retested`]).
    pub reuse_unchanged: bool,
    /// The occlusion stage is skipped once it has removed less than this fraction of the frustum survivors for
    /// [`AdaptiveSettings::low_benefit_frames`] frames in a row (an open field), then run again to re-probe
    /// every [`AdaptiveSettings::reprobe_every`] frames. 0 never skips.
    pub min_occlusion_benefit: f32,
    /// The same for each light view's occlusion ([`super::LightOcclusionSettings`]), as a fraction of the view's
    /// casters: a higher bar than the camera's, since a hidden caster saves a shadow map less than a hidden
    /// object saves the frame (docs/design.md measures what light views hide under a high and a low sun). 0
    /// never skips.
    pub min_light_occlusion_benefit: f32,
    /// See `min_occlusion_benefit`.
    pub low_benefit_frames: u32,
    /// See `min_occlusion_benefit`.
    pub reprobe_every: u32,
    /// Occluders whose object the occlusion stage hid last frame are not selected: they would most likely be
    /// hidden again, and the triangle budget goes to the ones in front (temporal coherence). Off by default:
    /// on the city's fly-through at 30 frames a second it saved 5% of the CPU stages' time but left the GPU
    /// 5% more triangles (an occluder hidden last frame may show this frame), so it does not pay.
    pub skip_hidden_occluders: bool,
    /// The frustum stage tests first, for each block of 8 objects, the plane that rejected the whole block last
    /// frame ([`crate::frustum::PlaneCoherence`]). The same result either way.
    pub plane_coherence: bool,
}

impl Default for AdaptiveSettings {
    /// Reuse of unchanged frames; occlusion skipped after 8 frames under 1% removed (a light view's under
    /// 10%), re-probed every 30 frames;
    /// plane coherence on; hidden occluders are still selected.
    fn default() -> Self {
        Self {
            reuse_unchanged: true,
            min_occlusion_benefit: 0.01,
            min_light_occlusion_benefit: 0.1,
            low_benefit_frames: 8,
            reprobe_every: 30,
            skip_hidden_occluders: false,
            plane_coherence: true,
        }
    }
}

impl AdaptiveSettings {
    /// No gating at all: every stage runs every frame (the fixed pipeline, for comparison).
    pub fn fixed() -> Self {
        Self {
            reuse_unchanged: false,
            min_occlusion_benefit: 0.0,
            min_light_occlusion_benefit: 0.0,
            low_benefit_frames: u32::MAX,
            reprobe_every: 0,
            skip_hidden_occluders: false,
            plane_coherence: false,
        }
    }
}

/// Settings of the software occlusion stage.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct OcclusionSettings {
    /// Whether the stage runs at all; when off, every frustum survivor stays visible.
    pub enabled: bool,
    /// Depth-buffer width in texels.
    pub width: u32,
    /// Depth-buffer height in texels.
    pub height: u32,
    /// How texels are sampled ([`RasterMode`]): conservative (default), pixel centres or masked blocks at the
    /// viewport's size (or below it, for [`OcclusionSettings::frame`]), or fast.
    pub mode: RasterMode,
    /// Most occluder triangles rasterized per frame. The default, 4096, sits on the measured run-time-against-
    /// error Pareto front (docs/tradeoff.md).
    pub triangle_budget: usize,
    /// The resolution (width, height) of the frame the kept objects are drawn at, where known (`None` by
    /// default). With it, a [`RasterMode::PixelCentres`] or [`RasterMode::Masked`] buffer smaller than the frame
    /// is conservative for it: each buffer pixel stands for the frame's pixel centres in its square
    /// ([`ScreenView::for_frame`]). Without it, those modes are conservative at their own resolution only.
    pub frame: Option<(u32, u32)>,
}

impl OcclusionSettings {
    /// Whether these settings never hide an object a rendering of `viewport` (width, height) pixels shows: the
    /// stage is off, its mode is conservative at that size ([`RasterMode::is_conservative_for`]), or it samples
    /// pixel centres for that very frame ([`OcclusionSettings::frame`]) at a buffer no larger.
    pub fn is_conservative_for(&self, viewport: (u32, u32)) -> bool {
        let buffer = (self.width, self.height);
        let sampled_for_it = self.mode.samples_pixel_centres()
            && self.frame == Some(viewport)
            && buffer.0 <= viewport.0
            && buffer.1 <= viewport.1;
        !self.enabled || self.mode.is_conservative_for(buffer, viewport) || sampled_for_it
    }

    /// The settings to use where the frame's size (width, height, pixels) is known: a masked buffer standing
    /// for its pixels ([`OcclusionSettings::frame`]), the frame divided by the smallest whole number that
    /// leaves at most 960x540 samples (rounded up: the frame's own size up to there, half of 1920x1080, a
    /// quarter of 3840x2160), with 5120 occluder triangles: on the judged fly-through it culls more of what is
    /// hidden than [`OcclusionSettings::default`] in the same CPU time, with no object wrongly hidden
    /// (docs/tradeoff.md); a whole divisor keeps the buffer's samples from reaching as far
    /// ([`ScreenView::for_frame`]). The default cannot be this, as it does not know the frame.
    ///
    /// ```
    /// use cullet::culler::OcclusionSettings;
    /// let settings = OcclusionSettings::for_frame(1920, 1080);
    /// assert_eq!((settings.width, settings.height), (960, 540));
    /// assert!(settings.is_conservative_for((1920, 1080)));
    /// assert_eq!(OcclusionSettings::for_frame(640, 360).width, 640);
    /// ```
    pub fn for_frame(width: u32, height: u32) -> Self {
        let samples = |divisor: u32| u64::from(width.div_ceil(divisor)) * u64::from(height.div_ceil(divisor));
        let estimate = (samples(1) as f64 / FRAME_BUFFER_SAMPLES as f64).sqrt() as u32;
        let divisor = (estimate.max(1)..).find(|&divisor| samples(divisor) <= FRAME_BUFFER_SAMPLES).unwrap_or(1);
        Self {
            width: width.div_ceil(divisor),
            height: height.div_ceil(divisor),
            mode: RasterMode::Masked,
            triangle_budget: 5120,
            frame: Some((width, height)),
            ..Self::default()
        }
    }

    /// These settings for a frame of `width` x `height` pixels, as when a window or viewport is resized, so that
    /// they stay conservative for the frame drawn. Settings whose buffer [`OcclusionSettings::for_frame`] chose
    /// for the old frame get its choice for the new one (their switch and triangle budget kept). Any other
    /// pixel-centre or masked buffer ([`RasterMode::samples_pixel_centres`]) keeps its relation to the frame:
    /// one that is the old [`OcclusionSettings::frame`] divided by a whole number and rounded up becomes the
    /// new frame divided by that number, any other its share of the new frame (rounded up), and one with no
    /// frame becomes the new frame's size. A conservative or fast buffer keeps its size (the first is
    /// conservative at any frame size, the second at none). `frame` becomes the new size. A frame with no
    /// pixels draws nothing: the settings are returned as they are.
    ///
    /// ```
    /// use cullet::culler::OcclusionSettings;
    /// use cullet::raster::RasterMode;
    /// let resized = OcclusionSettings::for_frame(1920, 1080).resized_to(3840, 2160);
    /// assert_eq!((resized.width, resized.height, resized.frame), (960, 540, Some((3840, 2160))));
    /// assert!(resized.is_conservative_for((3840, 2160)));
    /// let sixth = OcclusionSettings { width: 640, height: 360, mode: RasterMode::Masked, ..resized };
    /// assert_eq!(sixth.resized_to(1920, 1080).width, 320);
    /// ```
    pub fn resized_to(self, width: u32, height: u32) -> Self {
        if width == 0 || height == 0 {
            return self;
        }
        let old = self.frame.unwrap_or((self.width, self.height));
        let chosen = Self::for_frame(old.0, old.1);
        if self.frame.is_some() && (self.width, self.height, self.mode) == (chosen.width, chosen.height, chosen.mode) {
            let (enabled, triangle_budget) = (self.enabled, self.triangle_budget);
            return Self { enabled, triangle_budget, ..Self::for_frame(width, height) };
        }
        let mut resized = Self { frame: Some((width, height)), ..self };
        if self.mode.samples_pixel_centres() {
            (resized.width, resized.height) =
                (resized_axis(self.width, old.0, width), resized_axis(self.height, old.1, height));
        }
        resized
    }

    /// The view the stage rasterizes and tests through for `camera`: the buffer's size, standing for
    /// [`OcclusionSettings::frame`]'s pixels where that is given.
    pub fn view(&self, camera: &Camera) -> ScreenView {
        let view = ScreenView::new(camera, self.width, self.height);
        self.frame.map_or(view, |frame| view.for_frame(frame))
    }
}

/// The most samples [`OcclusionSettings::for_frame`] gives its buffer: 960x540, the half of 1920x1080 chosen on
/// the judged fly-through (docs/tradeoff.md).
const FRAME_BUFFER_SAMPLES: u64 = 960 * 540;

/// A buffer's size along one axis for a frame resized from `old` to `new` pixels (see
/// [`OcclusionSettings::resized_to`]): `new / k` rounded up where `buffer` is `old / k` rounded up for a whole
/// `k` (so half stays half, as whole-number ratios sample better), otherwise `buffer`'s share of `new`.
fn resized_axis(buffer: u32, old: u32, new: u32) -> u32 {
    if buffer == 0 || old == 0 {
        return new;
    }
    let divisor = (f64::from(old) / f64::from(buffer)).round().max(1.0) as u32;
    if old.div_ceil(divisor) == buffer {
        new.div_ceil(divisor)
    } else {
        let share = (u64::from(new) * u64::from(buffer)).div_ceil(u64::from(old));
        u32::try_from(share).unwrap_or(u32::MAX).max(1)
    }
}

impl Default for OcclusionSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            width: 256,
            height: 144,
            mode: RasterMode::Conservative,
            triangle_budget: 4096,
            frame: None,
        }
    }
}

/// The most texels an occlusion buffer may have ([`OcclusionSettings::validate`]): 4096x4096, 64 MiB of
/// depths.
pub const MAX_OCCLUSION_SAMPLES: u64 = 4096 * 4096;

/// The longest side of an occlusion buffer, in texels ([`OcclusionSettings::validate`]).
pub const MAX_OCCLUSION_SIDE: u32 = 16384;

/// Why occlusion settings cannot be used.
#[derive(thiserror::Error, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SettingsError {
    /// The buffer has no texels.
    #[error("the occlusion buffer {width}x{height} has no texels")]
    EmptyBuffer {
        /// Its width.
        width: u32,
        /// Its height.
        height: u32,
    },
    /// The buffer is larger than [`MAX_OCCLUSION_SIDE`] a side or [`MAX_OCCLUSION_SAMPLES`] in all.
    #[error(
        "the occlusion buffer {width}x{height} is too large: at most {MAX_OCCLUSION_SIDE} texels a side and \
         {MAX_OCCLUSION_SAMPLES} in all"
    )]
    BufferTooLarge {
        /// Its width.
        width: u32,
        /// Its height.
        height: u32,
    },
    /// The frame the buffer stands for ([`OcclusionSettings::frame`]) has no pixels.
    #[error("the frame {0}x{1} the occlusion buffer stands for has no pixels")]
    EmptyFrame(u32, u32),
}

impl OcclusionSettings {
    /// Whether these settings can be used: a buffer of at least one texel, at most [`MAX_OCCLUSION_SIDE`] a
    /// side and [`MAX_OCCLUSION_SAMPLES`] in all, standing for a frame with pixels. A view culled with
    /// invalid settings skips the occlusion stage and says why ([`super::ViewStats::occlusion_error`]).
    ///
    /// # Errors
    /// [`SettingsError`] says which bound is broken.
    ///
    /// ```
    /// use cullet::culler::{OcclusionSettings, SettingsError};
    /// assert!(OcclusionSettings::default().validate().is_ok());
    /// let huge = OcclusionSettings { width: 100_000, height: 100_000, ..OcclusionSettings::default() };
    /// assert!(matches!(huge.validate(), Err(SettingsError::BufferTooLarge { .. })));
    /// ```
    pub fn validate(&self) -> Result<(), SettingsError> {
        let (width, height) = (self.width, self.height);
        if width == 0 || height == 0 {
            return Err(SettingsError::EmptyBuffer { width, height });
        }
        if width.max(height) > MAX_OCCLUSION_SIDE || u64::from(width) * u64::from(height) > MAX_OCCLUSION_SAMPLES {
            return Err(SettingsError::BufferTooLarge { width, height });
        }
        match self.frame {
            Some((frame_width, frame_height)) if frame_width == 0 || frame_height == 0 => {
                Err(SettingsError::EmptyFrame(frame_width, frame_height))
            }
            _ => Ok(()),
        }
    }
}

/// What one view is culled with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewSettings {
    /// Whether the frustum stage culls; off, it keeps every object (for comparison and debugging).
    pub frustum: bool,
    /// The occlusion stage.
    pub occlusion: OcclusionSettings,
    /// What may be skipped or reused where it cannot pay off.
    pub adaptive: AdaptiveSettings,
    /// Detail culling after the frustum (lossy; off by default): inside the occlusion test where that runs,
    /// a pass of its own where it does not.
    pub detail: DetailSettings,
}

impl Default for ViewSettings {
    /// Both stages, with [`OcclusionSettings::default`] and [`AdaptiveSettings::default`]; no detail culling.
    fn default() -> Self {
        let (occlusion, adaptive) = (OcclusionSettings::default(), AdaptiveSettings::default());
        Self { frustum: true, occlusion, adaptive, detail: DetailSettings::default() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pixel-centre or masked buffer below the frame is conservative for the frame it stands for, and only
    /// for it; no larger than it; and its view moves each test inward by what the frame's pixel centres reach.
    #[test]
    fn sample_centre_buffers_below_the_frame_are_conservative_for_that_frame() {
        let frame = (1920, 1080);
        let masked = OcclusionSettings {
            width: 960,
            height: 540,
            mode: RasterMode::Masked,
            frame: Some(frame),
            ..OcclusionSettings::default()
        };
        assert!(masked.is_conservative_for(frame));
        assert!(!masked.is_conservative_for((2560, 1440)));
        assert!(!OcclusionSettings { frame: None, ..masked }.is_conservative_for(frame));
        assert!(!OcclusionSettings { width: 2560, height: 1440, ..masked }.is_conservative_for(frame));
        let fast = OcclusionSettings { mode: RasterMode::Fast, ..masked };
        assert!(!fast.is_conservative_for(frame));
        let camera = Camera::looking_at(glam::Vec3::ZERO, glam::Vec3::NEG_Z);
        assert_eq!(masked.view(&camera).sample_reach, [0.25, 0.25]);
        // At two thirds, a frame pixel centre can lie on a buffer pixel's edge.
        let two_thirds = OcclusionSettings { width: 1280, height: 720, ..masked };
        assert_eq!(two_thirds.view(&camera).sample_reach, [0.5, 0.5]);
        let third = OcclusionSettings { width: 640, height: 360, ..masked };
        assert!(third.view(&camera).sample_reach.iter().all(|r| (r - 1.0 / 3.0).abs() < 1e-12));
        let own_size = OcclusionSettings { width: 1920, height: 1080, ..masked };
        assert_eq!(own_size.view(&camera).sample_reach, [0.0, 0.0]);
        assert_eq!(OcclusionSettings::default().view(&camera).sample_reach, [0.0, 0.0]);
    }

    /// The frame's settings take the frame's own size up to 960x540 samples, a whole divisor of it beyond.
    #[test]
    fn settings_for_a_frame_divide_it_by_the_smallest_whole_number_that_fits() {
        let size = |(width, height)| {
            let settings = OcclusionSettings::for_frame(width, height);
            assert!(settings.is_conservative_for((width, height)), "{width}x{height}");
            (settings.width, settings.height)
        };
        assert_eq!(size((640, 360)), (640, 360));
        assert_eq!(size((960, 540)), (960, 540));
        assert_eq!(size((961, 540)), (481, 270));
        assert_eq!(size((1920, 1080)), (960, 540));
        assert_eq!(size((2560, 1440)), (854, 480));
        assert_eq!(size((3840, 2160)), (960, 540));
        assert_eq!(size((1, 1)), (1, 1));
        let (width, height) = size((u32::MAX, u32::MAX));
        assert!(u64::from(width) * u64::from(height) <= FRAME_BUFFER_SAMPLES);
    }

    /// A resized frame gets the buffer the frame's settings would choose where they chose it; keeps any other
    /// pixel-centre or masked buffer in the same relation to it (and conservative for it); leaves a
    /// conservative buffer's size alone; and ignores a frame with no pixels.
    #[test]
    fn resized_settings_follow_the_frame() {
        let chosen =
            OcclusionSettings { enabled: false, triangle_budget: 77, ..OcclusionSettings::for_frame(1281, 721) };
        for (width, height) in [(1920, 1080), (1281, 721), (640, 360), (7, 3), (u32::MAX, 100)] {
            let resized = chosen.resized_to(width, height);
            let expected = OcclusionSettings {
                enabled: false,
                triangle_budget: 77,
                ..OcclusionSettings::for_frame(width, height)
            };
            assert_eq!(resized, expected);
            assert_eq!(resized.resized_to(1281, 721), chosen);
        }
        // A quarter of the frame stays a quarter; two thirds, no whole divisor, keeps its share.
        let quarter = OcclusionSettings { width: 480, height: 270, ..OcclusionSettings::for_frame(1920, 1080) };
        let resized = quarter.resized_to(1281, 721);
        assert_eq!((resized.width, resized.height, resized.frame), (321, 181, Some((1281, 721))));
        assert!(resized.is_conservative_for((1281, 721)));
        let two_thirds = OcclusionSettings { width: 1280, height: 720, ..quarter };
        let resized = two_thirds.resized_to(960, 540);
        assert_eq!((resized.width, resized.height), (640, 360));
        assert!(resized.is_conservative_for((960, 540)));
        // With no frame, the buffer was the frame's own size.
        let own_size = OcclusionSettings { mode: RasterMode::PixelCentres, ..OcclusionSettings::default() };
        let resized = own_size.resized_to(1920, 1080);
        assert_eq!((resized.width, resized.height, resized.frame), (1920, 1080, Some((1920, 1080))));
        assert_eq!(resized.view(&Camera::looking_at(glam::Vec3::ZERO, glam::Vec3::NEG_Z)).sample_reach, [0.0; 2]);
        let conservative = OcclusionSettings::default().resized_to(640, 360);
        assert_eq!((conservative.width, conservative.height, conservative.frame), (256, 144, Some((640, 360))));
        assert_eq!(chosen.resized_to(0, 720), chosen);
    }
}
