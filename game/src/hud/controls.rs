//! The settings a player changes most, as one value the keys and the HUD both edit; the game applies it to
//! the pipeline every frame.

use bevy_ecs::world::World;
use cullet::detail::DetailSettings;
use cullet::gpu::GpuCullSettings;
use cullet::lod::LodSettings;
use cullet::pipeline::FrustumSettings;

use cullet::culler::OcclusionSettings;

/// What the window shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum View {
    /// The culled scene as drawn.
    Shaded,
    /// Every object drawn, those the CPU stages culled tinted by the stage that culled them.
    Tinted,
    /// The software occlusion depth buffer.
    #[value(name = "buffer")]
    OcclusionBuffer,
    /// One level of its farthest-depth pyramid.
    Pyramid,
    /// Every object drawn, coloured by the level of detail it draws (with levels of detail on).
    Levels,
}

impl View {
    /// Every view, in the order V cycles through them.
    pub const ALL: [View; 5] = [View::Shaded, View::Tinted, View::OcclusionBuffer, View::Pyramid, View::Levels];

    /// The view after this one.
    pub fn next(self) -> Self {
        let index = Self::ALL.iter().position(|&view| view == self).unwrap_or(0);
        Self::ALL[(index + 1) % Self::ALL.len()]
    }

    /// Its name on screen.
    pub fn label(self) -> &'static str {
        match self {
            Self::Shaded => "shaded",
            Self::Tinted => "tinted by culling stage",
            Self::OcclusionBuffer => "occlusion buffer",
            Self::Pyramid => "occlusion pyramid",
            Self::Levels => "coloured by level of detail",
        }
    }
}

/// The pipeline's settings the player can change, and what the window shows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Controls {
    /// The frustum stage's settings.
    pub frustum: FrustumSettings,
    /// The occlusion stage's settings: on or off, buffer size, mode, occluder budget.
    pub occlusion: OcclusionSettings,
    /// Detail culling (lossy): objects projecting under its pixels dropped.
    pub detail: DetailSettings,
    /// Levels of detail (lossy), where the world has them ([`cullet::lod::install`]).
    pub lod: Option<LodSettings>,
    /// Which GPU tests run.
    pub gpu: GpuCullSettings,
    /// Culling frozen at the camera of the frame it was frozen in.
    pub frozen: bool,
    /// What the window shows.
    pub view: View,
    /// The pyramid level the pyramid view shows (clamped to the levels there are).
    pub pyramid_level: usize,
}

impl Controls {
    /// The controls as `world`'s pipeline has them, with the window's own state.
    pub fn of(world: &World, gpu: GpuCullSettings, frozen: bool, view: View, pyramid_level: usize) -> Self {
        Self {
            frustum: *world.resource::<FrustumSettings>(),
            occlusion: *world.resource::<OcclusionSettings>(),
            detail: world.get_resource::<DetailSettings>().copied().unwrap_or_default(),
            lod: world.get_resource::<LodSettings>().copied(),
            gpu,
            frozen,
            view,
            pyramid_level,
        }
    }

    /// Writes the CPU stages' settings into `world` where they differ from what it has. Settings left alone
    /// are not touched, so the pipeline still sees them unchanged and may reuse the last frame's result.
    pub fn apply(&self, world: &mut World) {
        if *world.resource::<FrustumSettings>() != self.frustum {
            world.insert_resource(self.frustum);
        }
        if *world.resource::<OcclusionSettings>() != self.occlusion {
            world.insert_resource(self.occlusion);
        }
        if world.get_resource::<DetailSettings>().copied().unwrap_or_default() != self.detail {
            world.insert_resource(self.detail);
        }
        if let Some(lod) = self.lod
            && world.get_resource::<LodSettings>() != Some(&lod)
        {
            world.insert_resource(lod);
        }
    }

    /// Whether the GPU cluster tests (normal cones and the HZB) are on.
    pub fn clusters_on(&self) -> bool {
        self.gpu.cluster_cone
    }

    /// Turns the conservative GPU cluster tests on or off together.
    pub fn set_clusters(&mut self, on: bool) {
        (self.gpu.cluster_cone, self.gpu.cluster_hzb) = (on, on);
    }

    /// Whether the GPU triangle tests are on.
    pub fn triangles_on(&self) -> bool {
        self.gpu.triangle_backface
    }

    /// Turns the conservative GPU triangle tests (back faces, viewport, small triangles) on or off together.
    pub fn set_triangles(&mut self, on: bool) {
        let gpu = &mut self.gpu;
        (gpu.triangle_backface, gpu.triangle_frustum, gpu.small_triangles) = (on, on, on);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hud::{Hud, HudFrame};
    use cullet::draw_cost::DrawSavings;
    use cullet::pipeline::CameraCuller;
    use cullet::raster::RasterMode;
    use cullet::scene::city::{CityParams, CityScene};
    use cullet::scene::flight::Flight;

    fn city_flight() -> Flight {
        let city = CityScene::generate(CityParams::with_objects(2000));
        let path = city.flythrough();
        let scene = city.scene;
        Flight::new(path, 16.0 / 9.0, 8, OcclusionSettings::default(), |world| {
            scene.spawn(world);
        })
    }

    #[test]
    fn a_change_made_through_the_hud_state_reaches_the_pipeline() {
        let mut flight = city_flight();
        let before = flight.run_frame(3);
        assert!(before.after_frustum < before.objects, "the frustum culls at first");
        let mut controls = Controls::of(&flight.world, GpuCullSettings::default(), false, View::Shaded, 0);
        controls.frustum.enabled = false;
        controls.occlusion.width = 512;
        controls.occlusion.height = 288;
        controls.occlusion.mode = RasterMode::Fast;
        controls.occlusion.triangle_budget = 300;
        controls.apply(&mut flight.world);
        assert_eq!(*flight.world.resource::<FrustumSettings>(), controls.frustum);
        assert_eq!(*flight.world.resource::<OcclusionSettings>(), controls.occlusion);
        // The next frame runs with them: nothing frustum-culled, a 512x288 buffer.
        let after = flight.run_frame(3);
        assert_eq!(after.after_frustum, after.objects);
        let state = flight.world.resource::<CameraCuller>();
        assert_eq!((state.depth().width(), state.depth().height()), (512, 288));
        // Detail culling goes into the world, and off again.
        controls.detail = DetailSettings { min_pixels: 2.0, viewport_height: 540 };
        controls.apply(&mut flight.world);
        assert_eq!(*flight.world.resource::<DetailSettings>(), controls.detail);
        controls.detail.min_pixels = 0.0;
        controls.apply(&mut flight.world);
        assert!(!flight.world.resource::<DetailSettings>().enabled());
        // And the GPU switches go where the game reads them.
        controls.set_clusters(false);
        controls.set_triangles(false);
        let gpu = controls.gpu;
        assert!(!gpu.cluster_cone && !gpu.cluster_hzb && !gpu.triangle_backface && !gpu.small_triangles);
    }

    #[test]
    fn the_hud_left_alone_changes_no_setting_and_leaves_the_pipeline_unchanged() {
        let mut flight = city_flight();
        let stats = flight.run_frame(0);
        let controls = Controls::of(&flight.world, GpuCullSettings::default(), false, View::Pyramid, 2);
        let frame = HudFrame {
            stats,
            gpu: None,
            savings: DrawSavings::default(),
            fps: 60.0,
            hud_time: Default::default(),
            following_path: true,
            buffer: (256, 144),
            pyramid: vec![(128, 72), (64, 36), (32, 18)],
            viewport: (1280, 720),
            light_views: Vec::new(),
        };
        let ctx = egui::Context::default();
        let mut hud = Hud::new(true);
        hud.help = true;
        let mut edited = controls;
        for _ in 0..3 {
            hud.record(frame.clone(), 1.0 / 60.0);
            let mut output = ctx.run_pass(egui::RawInput::default(), |ctx| {
                let covered = hud.ui(ctx, None, &mut edited);
                assert_eq!(covered.len(), 3, "figures, plots and help windows");
            });
            // Nothing paints here: the font texture is dropped unapplied.
            output.textures_delta.clear();
        }
        assert_eq!(edited, controls);
        // Applying unchanged controls does not touch the settings, so the pipeline may reuse its last result.
        flight.world.clear_trackers();
        edited.apply(&mut flight.world);
        assert!(!flight.world.is_resource_changed::<OcclusionSettings>());
        assert!(!flight.world.is_resource_changed::<FrustumSettings>());
        // Hidden, it builds nothing.
        hud.visible = false;
        let mut output = ctx.run_pass(egui::RawInput::default(), |ctx| {
            assert!(hud.ui(ctx, None, &mut edited).is_empty());
        });
        output.textures_delta.clear();
    }
}
