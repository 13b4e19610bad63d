//! The HUD's CPU cost: building its UI with full plots (5 s of history) and tessellating it. The game spreads
//! a build over frames (10 a second at most, or on input; see `HudPainter`): egui's pass (begun, then the HUD's
//! parts, a frame each), then tessellating what it drew, then the upload. The pass and the tessellation are
//! timed here on their own, with warm caches and with the caches flushed first, as after a frame's culling and
//! draw; other frames draw the last build again.
//!
//! `cargo bench -p cullet-game --bench hud`

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use cullet::gpu::{GpuCounters, GpuCullSettings, GpuFrameOutput, GpuPassTimes};
use cullet::pipeline::{CullStats, FrustumSettings};

use cullet::culler::OcclusionSettings;
use cullet_game::hud::controls::{Controls, View};
use cullet_game::hud::{Hud, HudFrame};
use std::hint::black_box;
use std::time::Duration;

/// Frame `i`'s figures: every number changes, as in a fly-through.
fn figures(i: u64) -> HudFrame {
    let us = |base: u64, spread: u64| Duration::from_micros(base + (i * 37) % spread);
    let stats = CullStats {
        objects: 100_000,
        bounds_recomputed: 500 + (i % 40) as usize,
        after_frustum: 20_000 + (i * 13 % 3000) as usize,
        after_occlusion: 5_000 + (i * 7 % 900) as usize,
        bounds_time: us(100, 40),
        frustum_time: us(400, 90),
        raster_time: us(900, 200),
        occlusion_time: us(300, 60),
        occluders: 300,
        occluder_triangles: 4000,
        ..CullStats::default()
    };
    let counters = GpuCounters {
        clusters_in: 9000,
        clusters_out: 6000,
        triangles_in: 400_000,
        triangles_out: 250_000,
        draws: 5000,
        ..Default::default()
    };
    let pass_times = GpuPassTimes {
        hzb: us(20, 5),
        clusters: us(60, 10),
        triangles: us(200, 30),
        draw: us(900, 100),
        ..Default::default()
    };
    HudFrame {
        stats,
        gpu: Some(GpuFrameOutput { counters, pass_times: Some(pass_times), ..Default::default() }),
        savings: Default::default(),
        fps: 60.0 + (i % 10) as f32,
        hud_time: us(150, 30),
        following_path: true,
        buffer: (256, 144),
        pyramid: vec![(256, 144), (128, 72), (64, 36), (32, 18)],
        viewport: (1920, 1080),
        light_views: Vec::new(),
    }
}

fn hud(c: &mut Criterion) {
    let ctx = cullet_game::hud::context();
    let mut hud = Hud::new(true);
    let mut controls = Controls {
        frustum: FrustumSettings::default(),
        occlusion: OcclusionSettings::default(),
        detail: Default::default(),
        lod: Some(Default::default()),
        gpu: GpuCullSettings::default(),
        frozen: false,
        view: View::Shaded,
        pyramid_level: 0,
    };
    let input = || egui::RawInput {
        screen_rect: Some(egui::Rect::from_min_size(egui::Pos2::ZERO, egui::vec2(1920.0, 1080.0))),
        ..Default::default()
    };
    // Five seconds at 60 frames a second: the plots full.
    let mut frame = 0;
    for _ in 0..300 {
        frame += 1;
        hud.record(figures(frame), 1.0 / 60.0);
    }
    // egui's pass over the figures of a new frame, whole: the game spreads its parts over frames.
    let mut pass = |hud: &mut Hud, frame: u64| {
        hud.record(figures(frame), 0.1);
        let mut output = ctx.run_pass(input(), |ctx| {
            black_box(hud.ui(ctx, None, &mut controls));
        });
        output.textures_delta.clear();
        output
    };
    // A frame's culling and draw pass over far more memory than the last-level cache holds.
    let mut flush = vec![0u8; 64 << 20];
    let mut flush_caches = || {
        for byte in flush.iter_mut().step_by(64) {
            *byte = byte.wrapping_add(1);
        }
    };
    let mut group = c.benchmark_group("hud");
    group.bench_function("pass", |b| {
        b.iter(|| {
            frame += 1;
            black_box(pass(&mut hud, frame));
        })
    });
    group.bench_function("pass, caches flushed", |b| {
        b.iter_batched(
            &mut flush_caches,
            |()| {
                frame += 1;
                black_box(pass(&mut hud, frame));
            },
            BatchSize::PerIteration,
        )
    });
    // Tessellating one pass's shapes: the second frame.
    frame += 1;
    let drawn = pass(&mut hud, frame);
    let tessellate = |shapes| ctx.tessellate(shapes, drawn.pixels_per_point);
    group.bench_function("tessellate", |b| b.iter_batched(|| drawn.shapes.clone(), tessellate, BatchSize::SmallInput));
    group.bench_function("tessellate, caches flushed", |b| {
        let cold_shapes = || {
            let shapes = drawn.shapes.clone();
            flush_caches();
            shapes
        };
        b.iter_batched(cold_shapes, tessellate, BatchSize::PerIteration)
    });
    group.finish();
}

criterion_group!(benches, hud);
criterion_main!(benches);
