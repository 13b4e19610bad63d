//! The GPU pipeline on a real device (Mesa's lavapipe in CI): the HZB equals the CPU pyramid, cluster and
//! triangle culling equal their CPU twins, and the image drawn through all culling equals the image drawn
//! with none, pixel for pixel. Without an adapter these tests skip with a message, unless
//! `CULLET_REQUIRE_GPU` is set.

use cullet::Camera;
use cullet::camera::DepthConvention;
use cullet::depth::{DepthBuffer, DepthPyramid};
use cullet::gpu::cluster_cull::{ClusterVerdict, cull_cluster};
use cullet::gpu::draw::RenderedImage;
use cullet::gpu::hzb::Hzb;
use cullet::gpu::interface::{GpuView, VIEW_HZB, VIEW_PHASE_LATE, VIEW_SECOND_HZB};
use cullet::gpu::scene::instances_from_world;
use cullet::gpu::triangle_cull::{TriangleVerdict, cull_triangle};
use cullet::gpu::two_phase::merge_level0;
use cullet::gpu::{DrawBuffers, GpuContext, GpuError, OwnRenderer, STORAGE_BUFFERS_PER_STAGE};
use cullet::gpu::{GpuCounters, GpuCullSettings, GpuCuller, GpuFrameOutput, GpuGating, ReadBack};
use cullet::pipeline::{CameraCuller, CullStats};
use cullet_test_support::context_for_tests;

use cullet::culler::OcclusionSettings;
use cullet::raster::RasterMode;
use cullet::scene::city::{CityParams, CityScene};
use cullet::scene::flight::Flight;
use glam::Vec3;
use std::collections::HashMap;

const WIDTH: u32 = 320;
const HEIGHT: u32 = 180;

/// A city after one frame of the CPU stages from `camera`, and a GPU pipeline for it.
struct Setup {
    flight: Flight,
    culler: GpuCuller,
    /// Half the city's side.
    half: f32,
}

fn setup(context: &GpuContext, objects: usize) -> Setup {
    setup_with(context, objects, (WIDTH, HEIGHT), OcclusionSettings::default())
}

/// [`setup`] for a `size` frame with `occlusion` settings.
fn setup_with(context: &GpuContext, objects: usize, size: (u32, u32), occlusion: OcclusionSettings) -> Setup {
    setup_flying(context, objects, size, occlusion, 10)
}

/// [`setup_with`] for a fly-through of `frames` frames.
fn setup_flying(
    context: &GpuContext,
    objects: usize,
    size: (u32, u32),
    occlusion: OcclusionSettings,
    frames: u32,
) -> Setup {
    let city = CityScene::generate(CityParams::with_objects(objects));
    let flight = Flight::new(city.flythrough(), size.0 as f32 / size.1 as f32, frames, occlusion, |world| {
        city.spawn(world);
    });
    let culler = GpuCuller::for_world(context, &flight.world, &city.scene.meshes, size);
    Setup { flight, culler, half: city.half_size() }
}

impl Setup {
    /// Runs the CPU stages for `camera`, then the GPU passes; returns the GPU output and the CPU inputs.
    fn run(
        &mut self,
        context: &GpuContext,
        camera: Camera,
        settings: &GpuCullSettings,
    ) -> (GpuFrameOutput, Vec<u32>, DepthBuffer) {
        self.run_on(context, camera, settings, false)
    }

    /// [`Setup::run`], giving the GPU the frustum's survivors where `frustum_survivors`, the objects the CPU's
    /// occlusion test hid among them, rather than the occlusion test's.
    fn run_on(
        &mut self,
        context: &GpuContext,
        camera: Camera,
        settings: &GpuCullSettings,
        frustum_survivors: bool,
    ) -> (GpuFrameOutput, Vec<u32>, DepthBuffer) {
        self.flight.world.insert_resource(camera);
        self.flight.schedule.run(&mut self.flight.world);
        let state = self.flight.world.resource::<CameraCuller>();
        let survivors = match frustum_survivors {
            true => &self.flight.world.resource::<CameraCuller>().frustum_visible(),
            false => &state.visible(),
        };
        let visible: Vec<u32> = survivors.iter().map(|s| s as u32).collect();
        let depth = state.depth().clone();
        let output = self.culler.run(context, &camera, &visible, &depth, settings).expect("GPU frame");
        (output, visible, depth)
    }
}

/// Cameras that stress the pipeline: the city's benchmark views, one skimming a wall (near plane), one at a
/// screen edge along a street, and one looking straight down.
fn cameras(city_half: f32) -> Vec<(&'static str, Camera)> {
    let street = 40.0;
    let mut cams = vec![
        ("street", Camera::looking_at(Vec3::new(street, 1.8, street), Vec3::new(city_half, 2.0, street))),
        ("roofs", Camera::looking_at(Vec3::new(street, 80.0, street), Vec3::new(city_half, 0.0, city_half))),
        ("overview", Camera::looking_at(Vec3::new(0.0, city_half, -city_half), Vec3::ZERO)),
        ("down", Camera { up: Vec3::Z, ..Camera::looking_at(Vec3::new(10.0, 60.0, 10.0), Vec3::new(10.0, 0.0, 10.0)) }),
    ];
    // Skimming a building face: buildings stand inside blocks 64 wide around multiples of 80.
    let mut close = Camera::looking_at(Vec3::new(street - 7.7, 3.0, 5.0), Vec3::new(street - 7.7, 3.0, -60.0));
    close.near = 0.05;
    cams.push(("near wall", close));
    let mut wide = Camera::looking_at(Vec3::new(street, 2.0, -street), Vec3::new(city_half, 20.0, -street + 30.0));
    wide.fov_y = 100f32.to_radians();
    wide.far = Some(400.0);
    cams.push(("wide finite far", wide));
    cams
}

#[test]
fn hzb_equals_the_cpu_pyramid_for_odd_and_even_sizes() {
    let Some(context) = context_for_tests() else { return };
    let mut encoder_count = 0;
    for (width, height) in [(256, 144), (37, 23), (1, 1), (64, 1)] {
        let mut depth = DepthBuffer::new(width, height);
        // Deterministic pseudo-random depths, some zero.
        let texels: Vec<f32> = (0..width * height)
            .map(|i: u32| (i.wrapping_mul(2654435761) >> 8) as f32 / 16777216.0 * (i % 7).min(1) as f32)
            .collect();
        depth.texels_mut().copy_from_slice(&texels);
        let hzb = Hzb::new(&context, width, height);
        let mut encoder = context.device.create_command_encoder(&Default::default());
        hzb.build(&context, &depth, &mut encoder, None);
        context.queue.submit([encoder.finish()]);
        encoder_count += 1;
        let gpu = hzb.read(&context).unwrap();
        let mut cpu = DepthPyramid::default();
        cpu.build(&depth);
        assert_eq!(gpu.len(), cpu.level_count(), "{width}x{height}");
        for (level, texels) in gpu.iter().enumerate() {
            assert_eq!(texels.as_slice(), cpu.level(level).texels(), "{width}x{height} level {level}");
        }
    }
    assert_eq!(encoder_count, 4);
}

/// Compares the GPU's survivors with the CPU twin's. Every difference must be borderline: a decision that a
/// nudge of the camera by 1e-3 units flips on the CPU (GPU and CPU round differently, for instance where the
/// GPU fuses a multiply and an add). Returns the number of such differences (zero in most runs).
fn compare_sets<T: Ord + Clone + std::fmt::Debug>(
    camera: &str,
    what: &str,
    gpu: &[T],
    cpu: &[T],
    borderline: impl Fn(&T) -> bool,
) -> usize {
    let (mut gpu, mut cpu) = (gpu.to_vec(), cpu.to_vec());
    gpu.sort_unstable();
    cpu.sort_unstable();
    let only_gpu: Vec<&T> = gpu.iter().filter(|x| cpu.binary_search(x).is_err()).collect();
    let only_cpu: Vec<&T> = cpu.iter().filter(|x| gpu.binary_search(x).is_err()).collect();
    for item in only_gpu.iter().chain(&only_cpu) {
        assert!(
            borderline(item),
            "{camera}: {what} {item:?} kept by one side only (GPU-only {only_gpu:?}, CPU-only {only_cpu:?})"
        );
    }
    if !only_gpu.is_empty() || !only_cpu.is_empty() {
        println!("{camera}: {what}: {} borderline differences", only_gpu.len() + only_cpu.len());
    }
    only_gpu.len() + only_cpu.len()
}

/// Whether `decide` changes its answer when the camera moves by 1e-3 along some axis.
fn flips_when_nudged<V: PartialEq>(view: &GpuView, decide: impl Fn(&GpuView) -> V) -> bool {
    let base = decide(view);
    [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z].iter().any(|axis| {
        let mut nudged = *view;
        for (c, d) in nudged.camera.iter_mut().zip(axis.to_array().map(|a| a * 1e-3)) {
            *c += d;
        }
        decide(&nudged) != base
    })
}

/// Every cluster and triangle decision of the GPU equals the CPU twin's on every stress camera, up to
/// borderline decisions that rounding can flip (see [`compare_sets`]).
#[test]
fn cluster_and_triangle_culling_match_the_cpu_exactly() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 5000);
    // Every pass runs on every frame (no gating).
    setup.culler.set_gating(GpuGating::fixed());
    let half = setup.half;
    let settings = GpuCullSettings::default();
    let mut totals: HashMap<String, u64> = HashMap::new();
    for (name, camera) in cameras(half) {
        // The frustum's survivors: the CPU's occlusion test, finer than the HZB's 2x2 texels a cluster, leaves the
        // HZB next to nothing to cull among its own survivors.
        let (output, visible, _) = setup.run_on(&context, camera, &settings, true);
        let (gpu_clusters, gpu_indices) = setup.culler.read_survivors(&context).unwrap();
        let view = *setup.culler.last_view();
        let hzb: Vec<f32> = setup.culler.hzb().read(&context).unwrap().concat();
        let library = &setup.culler.scene().library;
        let instances = setup.culler.scene().instances();
        // Clusters.
        let mut expected_clusters = Vec::new();
        let mut cluster_counts: HashMap<ClusterVerdict, u32> = HashMap::new();
        let mut unstable_clusters = 0;
        for &slot in &visible {
            let instance = &instances[slot as usize];
            let first = library.meshes.get(instance.mesh as usize).map_or(0, |m| m.first_cluster);
            for (c, cluster) in library.clusters_of(instance.mesh).iter().enumerate() {
                let verdict = cull_cluster(&view, &hzb, instance, cluster);
                *cluster_counts.entry(verdict).or_default() += 1;
                unstable_clusters +=
                    usize::from(flips_when_nudged(&view, |v| cull_cluster(v, &hzb, instance, cluster)));
                if verdict == ClusterVerdict::Keep {
                    expected_clusters.push((slot, first + c as u32));
                }
            }
        }
        let borderline_clusters = compare_sets(name, "clusters", &gpu_clusters, &expected_clusters, |&(slot, c)| {
            let keep = |view: &GpuView| {
                cull_cluster(view, &hzb, &instances[slot as usize], &library.clusters[c as usize])
                    == ClusterVerdict::Keep
            };
            flips_when_nudged(&view, keep)
        });
        for (verdict, count) in &cluster_counts {
            let gpu = output.counters.clusters(*verdict);
            assert!(
                gpu.abs_diff(*count) as usize <= borderline_clusters + unstable_clusters,
                "{name}: clusters {verdict:?}: GPU {gpu}, CPU {count}"
            );
        }
        // Triangles of the surviving clusters.
        let mut expected_triangles = Vec::new();
        let mut triangle_counts: HashMap<TriangleVerdict, u32> = HashMap::new();
        let mut unstable_triangles = 0;
        for &(slot, cluster_index) in &expected_clusters {
            let cluster = &library.clusters[cluster_index as usize];
            for t in 0..cluster.triangle_count {
                let (instance, corners) = (&instances[slot as usize], library.triangle(cluster, t));
                let verdict = cull_triangle(&view, instance, corners);
                *triangle_counts.entry(verdict).or_default() += 1;
                unstable_triangles += usize::from(flips_when_nudged(&view, |v| cull_triangle(v, instance, corners)));
                if verdict == TriangleVerdict::Keep {
                    let first = (cluster.first_index + 3 * t) as usize;
                    expected_triangles.push([
                        library.indices[first],
                        library.indices[first + 1],
                        library.indices[first + 2],
                    ]);
                }
            }
        }
        let gpu_triangles: Vec<[u32; 3]> = gpu_indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
        let borderline_triangles = compare_sets(name, "triangles", &gpu_triangles, &expected_triangles, |corners| {
            // Find the triangle's cluster among the survivors to re-judge it.
            expected_clusters.iter().any(|&(slot, c)| {
                let cluster = &library.clusters[c as usize];
                (0..cluster.triangle_count).any(|t| {
                    let first = (cluster.first_index + 3 * t) as usize;
                    library.indices[first..first + 3] == corners[..]
                        && flips_when_nudged(&view, |view| {
                            cull_triangle(view, &instances[slot as usize], library.triangle(cluster, t))
                                == TriangleVerdict::Keep
                        })
                })
            })
        });
        for (verdict, count) in &triangle_counts {
            let gpu = output.counters.triangles(*verdict);
            // A borderline triangle may also change which test culls it.
            let slack = borderline_triangles + unstable_triangles;
            assert!(gpu.abs_diff(*count) as usize <= slack, "{name}: triangles {verdict:?}: GPU {gpu}, CPU {count}");
        }
        let c = output.counters;
        println!("{name}: {c:?}");
        assert_eq!(
            c.clusters_in,
            c.clusters_out + c.clusters_frustum + c.clusters_cone + c.clusters_hzb + c.clusters_small
        );
        assert_eq!(
            c.triangles_in,
            c.triangles_out + c.triangles_degenerate + c.triangles_backface + c.triangles_frustum + c.triangles_small
        );
        assert!(c.draws <= c.clusters_out);
        for (key, value) in [
            ("hzb", c.clusters_hzb),
            ("cone", c.clusters_cone),
            ("backface", c.triangles_backface),
            ("small", c.triangles_small),
        ] {
            *totals.entry(key.into()).or_default() += u64::from(value);
        }
    }
    // Not vacuous: every test removed something on some camera.
    for (key, value) in &totals {
        assert!(*value > 0, "no {key} culling on any camera");
    }
}

/// Pixels of the last frame's image that differ from the image drawn with no culling at all from `camera`:
/// depth anywhere, colour and object ID wherever they do not depend on draw order. Also returns how many
/// pixels the unculled image covers.
fn pixels_differing_from_unculled(context: &GpuContext, culler: &mut GpuCuller, camera: &Camera) -> (usize, usize) {
    let culled = culler.read_image(context).unwrap();
    image_differing_from_unculled(context, culler, camera, &culled)
}

/// [`pixels_differing_from_unculled`] for `culled`, an image drawn by a renderer of its own (colour compared
/// only where it has one).
fn image_differing_from_unculled(
    context: &GpuContext,
    culler: &mut GpuCuller,
    camera: &Camera,
    culled: &RenderedImage,
) -> (usize, usize) {
    let unculled = culler.debug().unculled(context, camera, false).unwrap();
    let reversed = culler.debug().unculled(context, camera, true).unwrap();
    assert_eq!(unculled.depth, reversed.depth, "depth must not depend on draw order");
    // Pixels where two objects' surfaces meet at exactly the same depth: which one shows depends on draw order
    // alone, and the culled draws come in the order the GPU appended them.
    let tie = |i: usize| unculled.object[i] != reversed.object[i];
    let color_differs = |i: usize| !culled.color.is_empty() && culled.color[i] != unculled.color[i];
    let differing = (0..culled.object.len())
        .filter(|&i| {
            culled.depth[i] != unculled.depth[i]
                || (!tie(i) && (culled.object[i] != unculled.object[i] || color_differs(i)))
        })
        .count();
    let covered = unculled.object.iter().filter(|&&o| o != cullet::gpu::draw::NO_OBJECT).count();
    (differing, covered)
}

/// The image drawn through the CPU stages and every GPU test equals the image drawn with no culling at all.
#[test]
fn culled_image_equals_unculled_image() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 5000);
    let half = setup.half;
    for (name, camera) in cameras(half) {
        let (output, _, _) = setup.run(&context, camera, &GpuCullSettings::default());
        let (differing, covered) = pixels_differing_from_unculled(&context, &mut setup.culler, &camera);
        println!("{name}: {differing} differing pixels, {covered} covered, {:?}", output.counters);
        assert!(covered > 0, "{name}: nothing drawn");
        assert_eq!(differing, 0, "{name}: culling changed {differing} pixels");
    }
}

/// The same with the masked buffer at the frame's own size, one whose sides 4x4 blocks do not divide: the HZB
/// primed from blocks (its last row and column reaching past the frame) hides nothing the frame shows.
#[test]
fn culled_image_equals_unculled_image_with_a_masked_buffer_at_an_odd_size() {
    let Some(context) = context_for_tests() else { return };
    let size = (333, 187);
    let occlusion =
        OcclusionSettings { width: size.0, height: size.1, mode: RasterMode::Masked, ..OcclusionSettings::default() };
    let mut setup = setup_with(&context, 5000, size, occlusion);
    let half = setup.half;
    for (name, camera) in cameras(half) {
        let camera = Camera { aspect: size.0 as f32 / size.1 as f32, ..camera };
        let (output, _, depth) = setup.run(&context, camera, &GpuCullSettings::default());
        assert_eq!((depth.width(), depth.height(), depth.texel_size()), (84, 47, 4), "{name}");
        let (differing, covered) = pixels_differing_from_unculled(&context, &mut setup.culler, &camera);
        println!("{name}: {differing} differing pixels, {covered} covered, {:?}", output.counters);
        assert!(covered > 0, "{name}: nothing drawn");
        assert_eq!(differing, 0, "{name}: culling changed {differing} pixels");
    }
}

/// Each way of skipping GPU passes (no cluster pass for a tiny frame or where it removes too little, no
/// triangle pass where it removes too little, both) draws the same image as no culling at all, and its
/// counters say what ran.
#[test]
fn skipped_gpu_passes_draw_the_same_image() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 2000);
    let half = setup.half;
    // Every frame counts as tiny, or as too little removed; a gated pass is skipped from the second frame.
    let tiny = GpuGating { tiny_scene_clusters: u32::MAX, ..GpuGating::fixed() };
    let no_clusters =
        GpuGating { min_cluster_benefit: 1.0, low_benefit_frames: 1, reprobe_every: u32::MAX, ..GpuGating::fixed() };
    let no_triangles =
        GpuGating { min_triangle_benefit: 1.0, low_benefit_frames: 1, reprobe_every: u32::MAX, ..GpuGating::fixed() };
    let both = GpuGating { tiny_scene_clusters: u32::MAX, ..no_triangles };
    let variants =
        [("tiny", tiny), ("no cluster pass", no_clusters), ("no triangle pass", no_triangles), ("both", both)];
    for (label, adaptive) in variants {
        setup.culler.set_gating(adaptive);
        let mut tested = 0;
        for (frame, (name, camera)) in cameras(half).into_iter().enumerate() {
            let (output, visible, _) = setup.run(&context, camera, &GpuCullSettings::default());
            let (differing, covered) = pixels_differing_from_unculled(&context, &mut setup.culler, &camera);
            let c = output.counters;
            println!("{label}, {name}: {differing} differing of {covered} covered, {output:?}");
            assert!(covered > 0, "{label}, {name}: nothing drawn");
            assert_eq!(differing, 0, "{label}, {name}: {differing} pixels changed");
            let gated = adaptive.min_cluster_benefit > 0.0 && frame > 0;
            assert_eq!(output.cluster_pass_skipped, adaptive.tiny_scene_clusters > 0 || gated, "{label}, {name}");
            let library = &setup.culler.scene().library;
            let instances = setup.culler.scene().instances();
            let candidates: Vec<_> =
                visible.iter().flat_map(|&s| library.clusters_of(instances[s as usize].mesh)).collect();
            if output.cluster_pass_skipped {
                assert_eq!((c.clusters_in, c.clusters_out), (candidates.len() as u32, candidates.len() as u32));
            }
            if output.triangle_pass_skipped {
                tested += 1;
                assert_eq!(c.triangles_in, 0, "{label}, {name}");
                assert_eq!(c.draws, c.clusters_out, "{label}, {name}: one draw per surviving cluster");
                let (survivors, indices) = setup.culler.read_survivors(&context).unwrap();
                assert_eq!(indices.len() as u32, 3 * c.triangles_out);
                let drawn: u32 = survivors.iter().map(|&(_, k)| library.clusters[k as usize].triangle_count).sum();
                assert_eq!(drawn, c.triangles_out);
            }
        }
        let expect_skipped = if adaptive.min_triangle_benefit > 0.0 { cameras(half).len() - 1 } else { 0 };
        assert_eq!(tested, expect_skipped, "{label}: frames without the triangle pass");
    }
}

/// Each pass is skipped after `low_benefit_frames` frames under its threshold and re-probed every
/// `reprobe_every` frames; a pass that removes enough is never skipped.
#[test]
fn each_pass_is_skipped_and_reprobed() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 1000);
    let camera = cameras(setup.half)[0].1;
    let low = GpuGating { low_benefit_frames: 2, reprobe_every: 3, ..GpuGating::fixed() };
    let cluster_skipped: fn(&GpuFrameOutput) -> bool = |o| o.cluster_pass_skipped;
    let triangle_skipped: fn(&GpuFrameOutput) -> bool = |o| o.triangle_pass_skipped;
    for (pass, gating, skipped) in [
        ("cluster", GpuGating { min_cluster_benefit: 1.0, ..low }, cluster_skipped),
        ("triangle", GpuGating { min_triangle_benefit: 1.0, ..low }, triangle_skipped),
    ] {
        setup.culler.set_gating(gating);
        let pattern: Vec<bool> =
            (0..10).map(|_| skipped(&setup.run(&context, camera, &GpuCullSettings::default()).0)).collect();
        // Two low frames, three skipped, then the re-probe starts the count again.
        let expected = [false, false, true, true, true, false, false, true, true, true];
        assert_eq!(pattern, expected, "{pass} pass");
    }
    // The default threshold (40%) keeps the triangle pass on the street, where it removes more.
    setup.culler.set_gating(GpuGating::default());
    let outputs: Vec<GpuFrameOutput> =
        (0..20).map(|_| setup.run(&context, camera, &GpuCullSettings::default()).0).collect();
    assert!(outputs.iter().all(|o| !o.triangle_pass_skipped));
    let c = outputs[0].counters;
    println!(
        "street: {} of {} clusters and {} of {} triangles removed",
        c.clusters_in - c.clusters_out,
        c.clusters_in,
        c.triangles_in - c.triangles_out,
        c.triangles_in
    );
}

/// Per-instance data is written only where the store changed (the moving cars), and the GPU copy always
/// equals the world.
#[test]
fn only_changed_instances_are_uploaded() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 5000);
    let moving = {
        let world = &mut setup.flight.world;
        world.query::<&cullet::scene::Velocity>().iter(world).count()
    };
    assert!(moving > 0);
    let settings = GpuCullSettings::default();
    setup.flight.run_frame(0);
    setup.culler.run_world(&context, &mut setup.flight.world, &settings).unwrap();
    for frame in 1..4 {
        setup.flight.run_frame(frame);
        setup.culler.run_world(&context, &mut setup.flight.world, &settings).unwrap();
        assert_eq!(setup.culler.scene().instances_written_last_update, moving, "frame {frame}");
        let expected = instances_from_world(&setup.flight.world);
        let bytes = context.read_buffer(&setup.culler.scene().instances, (expected.len() * 64) as u64).unwrap();
        assert_eq!(bytemuck::cast_slice::<u8, cullet::gpu::scene::GpuInstance>(&bytes), &expected[..], "frame {frame}");
    }
}

/// A frame with more candidate triangles than one storage binding holds is culled and drawn in batches: the
/// image and every counter equal those of one batch.
#[test]
fn frames_split_into_batches_draw_the_same_image() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 3000);
    let camera = cameras(setup.half)[2].1;
    let (whole, _, _) = setup.run(&context, camera, &GpuCullSettings::default());
    let image = setup.culler.read_image(&context).unwrap();
    // About 40 000 triangles a batch: the overview's candidates need several.
    setup.culler.limit_batches(12 * 60_000);
    let (batched, _, _) = setup.run(&context, camera, &GpuCullSettings::default());
    let batched_image = setup.culler.read_image(&context).unwrap();
    assert!(whole.counters.triangles_in > 100_000, "{:?}", whole.counters);
    assert_eq!(whole.counters, batched.counters);
    assert_eq!(image.depth, batched_image.depth);
    let differing = image.object.iter().zip(&batched_image.object).filter(|(a, b)| a != b).count();
    // Only exact depth ties between objects may resolve differently (draw order changes).
    assert!(differing < image.object.len() / 1000, "{differing} pixels differ");
}

/// A visible slot that is not an instance of the scene is an error, not a panic, and runs nothing: the next
/// frame culls as usual.
#[test]
fn an_out_of_range_slot_is_an_error() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 500);
    let camera = cameras(setup.half)[0].1;
    let depth = DepthBuffer::default();
    let settings = GpuCullSettings::default();
    let instances = setup.culler.scene().instances().len();
    let refused = setup.culler.run(&context, &camera, &[0, instances as u32], &depth, &settings);
    assert!(
        matches!(refused, Err(cullet::gpu::GpuError::SlotOutOfRange { slot, instances: n }) if slot as usize == n),
        "{refused:?}"
    );
    let (output, _, _) = setup.run(&context, camera, &settings);
    assert!(output.counters.draws > 0);
}

/// Each sun cascade is a view of its own on the GPU, culled by the cluster and triangle passes in the camera's
/// submission: every cascade's map equals, texel for texel, the map drawn from every cluster of the same
/// casters, while its counters show clusters and triangles removed. With a storage binding too small for a
/// cascade's candidates it is drawn whole, and its map is still the same.
#[test]
fn sun_cascades_culled_on_the_gpu_draw_the_same_shadow_maps() {
    use cullet::frustum::LightSource;
    use cullet::pipeline::{LightViews, LightViewsVisible};
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 5000);
    let camera = cameras(setup.half)[0].1;
    let sun = LightSource::Sun { direction: Vec3::new(0.35, -1.0, 0.25), splits: vec![0.1, 12.0, 40.0, 120.0, 400.0] };
    let world = &mut setup.flight.world;
    world.insert_resource(LightViews(vec![sun]));
    world.insert_resource(camera);
    setup.flight.schedule.run(world);
    world.clear_trackers();
    let casters: Vec<u32> = world.resource::<LightViewsVisible>().0.iter().map(|v| v.visible.count() as u32).collect();
    let maps = |culler: &GpuCuller| -> Vec<Vec<f32>> {
        (0..casters.len()).map(|i| culler.shadow_maps().read_layer(&context, i).unwrap()).collect()
    };
    let output = setup.culler.run_world(&context, world, &GpuCullSettings::default()).unwrap();
    let culled = maps(&setup.culler);
    setup.culler.debug().shadows_unculled(&context, world, camera.position);
    let whole = maps(&setup.culler);
    assert_eq!(output.light_views.len(), 4);
    for (index, counters) in output.light_views.iter().enumerate() {
        println!("cascade {index}: {counters:?}");
        assert_eq!(counters.instances, casters[index]);
        let drawn = culled[index].iter().filter(|&&depth| depth < 1.0).count();
        let differing = culled[index].iter().zip(&whole[index]).filter(|(a, b)| a != b).count();
        assert!(drawn > 1000, "cascade {index} drew {drawn} texels");
        assert_eq!(differing, 0, "culling changed {differing} texels of cascade {index}");
    }
    let removed = |f: fn(&GpuCounters) -> (u32, u32)| output.light_views.iter().map(|c| f(c).0 - f(c).1).sum::<u32>();
    assert!(removed(|c| (c.clusters_in, c.clusters_out)) > 0, "{:?}", output.light_views);
    assert!(removed(|c| (c.triangles_in, c.triangles_out)) > 0, "{:?}", output.light_views);

    // A binding too small for the larger cascades' candidates (about 1,300 triangles): those are drawn whole,
    // the others still culled, with the same maps.
    setup.culler.limit_batches(12 * 2_000);
    let output = setup.culler.run_world(&context, world, &GpuCullSettings::default()).unwrap();
    let drawn_whole = |c: &&GpuCounters| c.clusters_in == c.clusters_out && c.triangles_in == c.triangles_out;
    let large = output.light_views.iter().filter(|c| c.triangles_in > 1_300);
    assert!(large.clone().count() > 0 && large.clone().all(|c| drawn_whole(&c)), "{:?}", output.light_views);
    assert_eq!(maps(&setup.culler), whole, "cascades drawn whole differ");
}

/// The sun cascades' culled casters feed real shadow maps: with `LightViews` the draw darkens some pixels and
/// brightens none, every pixel shows the same object at the same depth, and the culled image still equals the
/// unculled one (both shaded with the same maps).
#[test]
fn sun_cascades_draw_shadows_from_their_culled_casters() {
    use cullet::frustum::LightSource;
    use cullet::pipeline::LightViews;
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 5000);
    let camera = cameras(setup.half)[0].1;
    let frame = |setup: &mut Setup| {
        setup.flight.world.insert_resource(camera);
        setup.flight.schedule.run(&mut setup.flight.world);
        setup.flight.world.clear_trackers();
        setup.culler.run_world(&context, &mut setup.flight.world, &GpuCullSettings::default()).unwrap();
        setup.culler.read_image(&context).unwrap()
    };
    let plain = frame(&mut setup);
    let sun = LightSource::Sun { direction: Vec3::new(0.35, -1.0, 0.25), splits: vec![0.1, 12.0, 40.0, 120.0, 400.0] };
    setup.flight.world.insert_resource(LightViews(vec![sun]));
    let shadowed = frame(&mut setup);
    assert_eq!(setup.culler.read_image(&context).unwrap().object, plain.object);
    assert_eq!(shadowed.depth, plain.depth, "shadows moved a surface");
    let luma = |c: [u8; 4]| u32::from(c[0]) + u32::from(c[1]) + u32::from(c[2]);
    let darker = (0..plain.color.len()).filter(|&i| luma(shadowed.color[i]) < luma(plain.color[i])).count();
    let brighter = (0..plain.color.len()).filter(|&i| luma(shadowed.color[i]) > luma(plain.color[i])).count();
    println!("shadows darkened {darker} of {} pixels", plain.color.len());
    assert!(darker > plain.color.len() / 100, "no shadow drawn: {darker} pixels darker");
    assert_eq!(brighter, 0, "a shadow brightened {brighter} pixels");
    let (differing, _) = pixels_differing_from_unculled(&context, &mut setup.culler, &camera);
    assert_eq!(differing, 0, "culling changed {differing} shaded pixels");

    // Every object as a caster of every cascade: the image must not change, as the casters the light views
    // dropped cannot shadow anything the camera sees.
    setup.flight.world.insert_resource(camera);
    setup.flight.schedule.run(&mut setup.flight.world);
    setup.flight.world.clear_trackers();
    let objects = setup.flight.world.resource::<cullet::BoundsStore>().len();
    for view in &mut setup.flight.world.resource_mut::<cullet::pipeline::LightViewsVisible>().0 {
        view.visible = cullet::VisibleSet::all(objects);
    }
    setup.culler.run_world(&context, &mut setup.flight.world, &GpuCullSettings::default()).unwrap();
    let all_casters = setup.culler.read_image(&context).unwrap();
    let changed = (0..plain.color.len()).filter(|&i| all_casters.color[i] != shadowed.color[i]).count();
    println!("all objects as casters changed {changed} pixels");
    assert_eq!(changed, 0, "casters the light views dropped shadow {changed} pixels");
}

/// Every pass fits in a device that allows only the storage buffers per shader stage the engine asks an adapter
/// for: wgpu refuses a pipeline that binds more (its default error handler panics), so a pass grown past
/// `STORAGE_BUFFERS_PER_STAGE` fails here rather than on a user's adapter with that few. One fewer is refused
/// when the context is opened, with an error that says so.
#[test]
fn every_pass_fits_the_storage_buffers_asked_of_the_adapter() {
    let Some(_) = context_for_tests() else { return };
    let allowing =
        |count: u32| move |limits: wgpu::Limits| wgpu::Limits { max_storage_buffers_per_shader_stage: count, ..limits };
    let context = GpuContext::new_with_limits(allowing(STORAGE_BUFFERS_PER_STAGE)).expect("a device with that many");
    let mut setup = setup(&context, 2000);
    let camera = cameras(setup.half)[0].1;
    let (output, _, _) = setup.run(&context, camera, &GpuCullSettings::default());
    assert!(output.counters.draws > 0, "nothing drawn");
    match GpuContext::new_with_limits(allowing(STORAGE_BUFFERS_PER_STAGE - 1)) {
        Err(error @ GpuError::Unsupported { .. }) => assert!(error.to_string().contains("storage buffers"), "{error}"),
        Err(error) => panic!("refused for another reason: {error}"),
        Ok(_) => panic!("a device with too few storage buffers was opened"),
    }
}

/// Counters read a frame late ([`ReadBack::Late`]): each frame returns the previous frame's counters, exactly
/// those a culler that waits returned for it, draws the same image (the same depths; objects differing only
/// at exact depth ties, as between any two runs) and leaves the same survivors; switched back, a frame returns
/// its own again.
#[test]
fn counters_read_a_frame_late_are_the_previous_frames() {
    let Some(context) = context_for_tests() else { return };
    let (mut waits, mut late) = (setup(&context, 3000), setup(&context, 3000));
    // Passes never skipped: the gates would learn a frame later in one than in the other.
    waits.culler.set_gating(GpuGating::fixed());
    late.culler.set_gating(GpuGating::fixed());
    late.culler.set_read_back(ReadBack::Late);
    let settings = GpuCullSettings::default();
    let mut previous: Option<GpuFrameOutput> = None;
    for frame in 0..5 {
        waits.flight.run_frame(frame);
        late.flight.run_frame(frame);
        let own = waits.culler.run_world(&context, &mut waits.flight.world, &settings).unwrap();
        let lagged = late.culler.run_world(&context, &mut late.flight.world, &settings).unwrap();
        assert!(!own.counters_late && lagged.counters_late);
        let expected = previous.as_ref().map_or(GpuCounters::default(), |output| output.counters);
        assert_eq!(lagged.counters, expected, "frame {frame}");
        let (image, late_image) =
            (waits.culler.read_image(&context).unwrap(), late.culler.read_image(&context).unwrap());
        assert!(image.depth == late_image.depth, "frame {frame}: depths differ");
        // Only exact depth ties between objects may resolve differently: the GPU appends draws in any order.
        let differing = image.object.iter().zip(&late_image.object).filter(|(a, b)| a != b).count();
        assert!(differing < image.object.len() / 1000, "frame {frame}: {differing} pixels differ");
        let sorted = |(mut clusters, indices): cullet::gpu::Survivors| {
            clusters.sort_unstable();
            (clusters, indices.len())
        };
        let survivors = sorted(waits.culler.read_survivors(&context).unwrap());
        assert_eq!(survivors, sorted(late.culler.read_survivors(&context).unwrap()), "frame {frame}");
        previous = Some(own);
    }
    late.culler.set_read_back(ReadBack::Wait);
    waits.flight.run_frame(5);
    late.flight.run_frame(5);
    let own = waits.culler.run_world(&context, &mut waits.flight.world, &settings).unwrap();
    let again = late.culler.run_world(&context, &mut late.flight.world, &settings).unwrap();
    assert!(!again.counters_late);
    assert_eq!(again.counters, own.counters);
}

/// Flies `flight` for `frames` frames in two phases, cutting to each of `cuts` (a frame index and a camera off
/// the path), checking every frame's image against the unculled one: no pixel may differ. `between` runs before
/// each frame (to resize, spawn or despawn). Returns each frame's phase counters.
fn fly_two_phase(
    context: &GpuContext,
    (flight, culler): (&mut Flight, &mut GpuCuller),
    frames: u32,
    cuts: &[(u32, Camera)],
    mut between: impl FnMut(u32, &mut Flight, &mut GpuCuller),
) -> Vec<cullet::gpu::PhaseCounters> {
    let settings = GpuCullSettings { two_phase: true, ..GpuCullSettings::default() };
    let mut phases_per_frame = Vec::new();
    for frame in 0..frames {
        between(frame, flight, culler);
        match cuts.iter().find(|(at, _)| *at == frame) {
            Some(&(_, camera)) => flight.run_with_camera(camera, 0.0),
            None => flight.run_frame(frame),
        };
        let output = culler.run_world(context, &mut flight.world, &settings).expect("GPU frame");
        let phases = output.phases.expect("a frame of two phases");
        let (early, late) = (phases.early, phases.late);
        assert_eq!(output.counters.triangles_out, early.triangles_out + late.triangles_out);
        // The late phase keeps every cluster drawn early but those the merged HZB hides, and tests every one.
        assert!(late.clusters_drawn_early <= early.clusters_out, "frame {frame}: {phases:?}");
        let culled = late.clusters_frustum + late.clusters_cone + late.clusters_hzb + late.clusters_small;
        assert_eq!(late.clusters_in, culled + late.clusters_out + late.clusters_drawn_early, "frame {frame}");
        if let Some(step) = phases.late_occluders {
            // The occluder step counts only the clusters it draws, and the rest never draw them again.
            assert_eq!((step.clusters_in, step.clusters_hzb), (step.clusters_out, 0), "frame {frame}");
            assert!(step.triangles_out <= late.triangles_out, "frame {frame}");
        }
        let camera = *flight.world.resource::<Camera>();
        let (differing, covered) = pixels_differing_from_unculled(context, culler, &camera);
        assert!(covered > 0, "frame {frame}: nothing drawn");
        assert_eq!(differing, 0, "frame {frame}: two-phase culling changed {differing} pixels; {phases:?}");
        phases_per_frame.push(phases);
    }
    phases_per_frame
}

/// Two-phase occlusion draws exactly the unculled image on the city, with the software occluders on and off,
/// over the fly-through with moving cars, camera cuts (beside a wall, across the city, straight down), a
/// window resize, and objects despawned and spawned; on the frames that follow the path the early phase draws
/// most of what is seen, and the late phase's HZB removes clusters.
#[test]
fn two_phase_draws_the_unculled_image_through_cuts_resizes_and_spawns() {
    let Some(context) = context_for_tests() else { return };
    for occluders in [true, false] {
        let occlusion = OcclusionSettings { enabled: occluders, ..OcclusionSettings::default() };
        // Frames of the fly-through at 15 a second.
        let mut setup = setup_flying(&context, 3000, (WIDTH, HEIGHT), occlusion, 300);
        let city = CityScene::generate(CityParams::with_objects(3000));
        let views = cameras(setup.half);
        let cuts = [(4, views[4].1), (5, views[2].1), (9, views[3].1)];
        let flying = (&mut setup.flight, &mut setup.culler);
        let phases = fly_two_phase(&context, flying, 13, &cuts, |frame, flight, culler| match frame {
            3 => culler.resize(&context, WIDTH + 37, HEIGHT + 21),
            7 => {
                let store = flight.world.resource::<cullet::bounds::BoundsStore>();
                let entities: Vec<_> = store.entities().iter().step_by(15).copied().collect();
                for entity in entities {
                    flight.world.despawn(entity);
                }
            }
            8 => {
                let mut moved = city.scene.clone();
                moved.objects.truncate(100);
                for object in &mut moved.objects {
                    object.transform.translation += glam::Vec3A::new(3.0, 0.0, 2.0);
                }
                moved.spawn(&mut flight.world);
            }
            _ => {}
        });
        for (frame, phases) in phases.iter().enumerate() {
            println!("occluders {occluders}, frame {frame}: {phases:?}");
        }
        // Frames after a frame on the path draw most early; those after a despawn (whose emptied slots are refilled
        // by other objects, which lose their visibility) and a spawn still draw more early than late.
        for (frame, share) in [(1, 4), (2, 4), (7, 1), (8, 1), (11, 4), (12, 4)] {
            let (early, late) = (phases[frame].early, phases[frame].late);
            assert!(early.triangles_out > share * late.triangles_out, "occluders {occluders}, frame {frame}");
        }
        assert!(phases.iter().map(|p| p.late.clusters_hzb).sum::<u32>() > 0, "occluders {occluders}");
        let step_drew = |frame: usize| phases[frame].late_occluders.is_some_and(|step| step.clusters_out > 0);
        assert!(cuts.iter().all(|&(frame, _)| step_drew(frame as usize)), "occluders {occluders}: {phases:?}");
    }
}

/// Two-phase occlusion draws exactly the unculled image on the shared third-party scenes, which have no artist
/// occluders (truck_town's sixty objects, zdm2's one mesh, where only clusters can be culled), over their
/// orbits with a cut to the far side; on the frames that follow the orbit the early phase draws most of it.
#[test]
fn two_phase_draws_the_unculled_image_on_the_shared_scenes() {
    let Some(context) = context_for_tests() else { return };
    for name in ["zdm2/zdm2.glb", "truck_town/town_model.gltf"] {
        let Some(loaded) = cullet_test_support::shared_scene(name) else { return };
        let scene = loaded.scene;
        let path = scene.orbit_path();
        let aspect = WIDTH as f32 / HEIGHT as f32;
        let far_side = path.camera_at(0.5 * path.duration(), aspect);
        let mut flight = Flight::new(path, aspect, 120, OcclusionSettings::default(), |world| {
            scene.spawn(world);
        });
        let mut culler = GpuCuller::for_world(&context, &flight.world, &scene.meshes, (WIDTH, HEIGHT));
        let phases = fly_two_phase(&context, (&mut flight, &mut culler), 8, &[(4, far_side)], |_, _, _| {});
        for (frame, phases) in phases.iter().enumerate() {
            println!("{name}, frame {frame}: {phases:?}");
        }
        for frame in [2, 3, 6, 7] {
            let (early, late) = (phases[frame].early, phases[frame].late);
            assert!(early.triangles_out > 4 * late.triangles_out, "{name}, frame {frame}");
        }
    }
}

/// A renderer of the test's own: each object's store slot and its depth, drawn as the culler's draw does
/// (`draw.wgsl`'s vertex stage), into textures of its own.
struct SlotRenderer {
    pipeline: wgpu::RenderPipeline,
    object: wgpu::Texture,
    depth: wgpu::Texture,
    /// The depth each draw clears to.
    empty_depth: f32,
}

const SLOT_SHADER: &str = "
@group(0) @binding(1) var<storage, read> instances: array<Instance>;

struct Varyings {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) instance: u32,
}

@vertex
fn vs(@location(0) position: vec3<f32>, @builtin(instance_index) instance: u32) -> Varyings {
    var clip = view.clip_from_relative * vec4<f32>(relative_point(instances[instance], position, view.camera.xyz), 1.0);
    if (view.depth_from_negative_one != 0u) {
        clip.z = (clip.z + clip.w) * 0.5;
    }
    return Varyings(clip, instance);
}

@fragment
fn fs(in: Varyings) -> @location(0) u32 {
    return in.instance;
}
";

impl SlotRenderer {
    /// Targets of `size` (width, height) for frames drawn in the `depth` convention, the depth texture made as
    /// `depth_format` with `depth_usage` besides being drawn into.
    fn new(
        context: &GpuContext,
        size: (u32, u32),
        depth: DepthConvention,
        (depth_format, depth_usage): (wgpu::TextureFormat, wgpu::TextureUsages),
    ) -> Self {
        let device = &context.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("slots"),
            source: wgpu::ShaderSource::Wgsl(cullet::gpu::shader_source(SLOT_SHADER).into()),
        });
        let reversed = depth == DepthConvention::Reversed;
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("slots"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                buffers: &[Some(cullet::gpu::indirect::POSITION_LAYOUT)],
            },
            primitive: wgpu::PrimitiveState { cull_mode: Some(wgpu::Face::Back), ..Default::default() },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: depth_format,
                depth_write_enabled: Some(true),
                depth_compare: Some(if reversed {
                    wgpu::CompareFunction::Greater
                } else {
                    wgpu::CompareFunction::Less
                }),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::TextureFormat::R32Uint.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let texture = |format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some("slots"),
                size: wgpu::Extent3d { width: size.0, height: size.1, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: usage | wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
                view_formats: &[],
            })
        };
        Self {
            pipeline,
            object: texture(wgpu::TextureFormat::R32Uint, wgpu::TextureUsages::empty()),
            depth: texture(depth_format, depth_usage),
            empty_depth: if reversed { 0.0 } else { 1.0 },
        }
    }

    /// What it drew: object IDs and depth, no colour.
    fn read(&self, context: &GpuContext) -> RenderedImage {
        let object = context.read_texture(&self.object, wgpu::TextureAspect::All, 4).unwrap();
        let depth = context.read_texture(&self.depth, wgpu::TextureAspect::DepthOnly, 4).unwrap();
        RenderedImage {
            width: self.object.width(),
            height: self.object.height(),
            color: Vec::new(),
            object: bytemuck::cast_slice(&object).to_vec(),
            depth: bytemuck::cast_slice(&depth).to_vec(),
        }
    }
}

impl OwnRenderer for SlotRenderer {
    fn depth(&self) -> &wgpu::Texture {
        &self.depth
    }

    fn draw(
        &mut self,
        context: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        buffers: DrawBuffers<'_>,
        clear: bool,
    ) {
        let group = buffers.bind_group(context, &self.pipeline.get_bind_group_layout(0));
        let (object, depth) =
            (self.object.create_view(&Default::default()), self.depth.create_view(&Default::default()));
        let no_object = f64::from(cullet::gpu::draw::NO_OBJECT);
        let (object_load, depth_load) = match clear {
            true => {
                let cleared = wgpu::Color { r: no_object, g: 0.0, b: 0.0, a: 0.0 };
                (wgpu::LoadOp::Clear(cleared), wgpu::LoadOp::Clear(self.empty_depth))
            }
            false => (wgpu::LoadOp::Load, wgpu::LoadOp::Load),
        };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("slots"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &object,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: object_load, store: wgpu::StoreOp::Store },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &depth,
                depth_ops: Some(wgpu::Operations { load: depth_load, store: wgpu::StoreOp::Store }),
                stencil_ops: None,
            }),
            ..Default::default()
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        buffers.record(context, &mut pass);
    }
}

/// A renderer drawing both phases into its own depth: with the software occluders off, the late phase hides
/// clusters only through the depth the renderer drew early (the culler's own targets are never drawn), and the
/// renderer's image equals the unculled one through the fly-through, cuts and a resize, in every depth
/// convention. A depth texture the merge cannot read is refused before anything runs.
#[test]
fn a_renderer_of_its_own_draws_both_phases_into_its_depth() {
    let Some(context) = context_for_tests() else { return };
    let occlusion = OcclusionSettings { enabled: false, ..OcclusionSettings::default() };
    let settings = GpuCullSettings { two_phase: true, ..GpuCullSettings::default() };
    let readable = (wgpu::TextureFormat::Depth32Float, wgpu::TextureUsages::TEXTURE_BINDING);
    for convention in [DepthConvention::Reversed, DepthConvention::Standard, DepthConvention::NegativeOneToOne] {
        let mut setup = setup_flying(&context, 3000, (WIDTH, HEIGHT), occlusion, 300);
        let views = cameras(setup.half);
        let mut renderer = SlotRenderer::new(&context, (WIDTH, HEIGHT), convention, readable);
        let mut late_hidden = 0;
        for frame in 0..10 {
            let size = if frame < 6 { (WIDTH, HEIGHT) } else { (WIDTH + 37, HEIGHT + 21) };
            if frame == 6 {
                setup.culler.resize(&context, size.0, size.1);
                renderer = SlotRenderer::new(&context, size, convention, readable);
            }
            let camera = match frame {
                4 => views[2].1,
                _ => setup.flight.path.camera_at(frame as f32 * setup.flight.frame_delta(), 1.0),
            };
            let camera = Camera { depth: convention, aspect: size.0 as f32 / size.1 as f32, ..camera };
            setup.flight.run_with_camera(camera, setup.flight.frame_delta());
            let world = &mut setup.flight.world;
            let output = setup.culler.run_world_into(&context, world, &settings, &mut renderer).expect("GPU frame");
            let phases = output.phases.expect("a frame of two phases");
            late_hidden += phases.late.clusters_hzb;
            let image = renderer.read(&context);
            let (differing, covered) = image_differing_from_unculled(&context, &mut setup.culler, &camera, &image);
            println!("{convention:?}, frame {frame}: {differing} differing of {covered} covered; {phases:?}");
            assert!(covered > 0, "{convention:?}, frame {frame}: nothing drawn");
            assert_eq!(differing, 0, "{convention:?}, frame {frame}: {phases:?}");
        }
        assert!(late_hidden > 0, "{convention:?}: the late phase hid nothing behind the renderer's depth");
    }

    // Depth textures the merge cannot read.
    let mut setup = setup(&context, 500);
    setup.flight.run_frame(0);
    let reversed = DepthConvention::Reversed;
    let wrong = [
        SlotRenderer::new(&context, (WIDTH, HEIGHT), reversed, (wgpu::TextureFormat::Depth24Plus, readable.1)),
        SlotRenderer::new(&context, (WIDTH + 1, HEIGHT), reversed, readable),
        SlotRenderer::new(&context, (WIDTH, HEIGHT), reversed, (readable.0, wgpu::TextureUsages::empty())),
    ];
    for mut renderer in wrong {
        let result = setup.culler.run_world_into(&context, &mut setup.flight.world, &settings, &mut renderer);
        assert!(matches!(result, Err(GpuError::RendererDepth(_))), "{:?}", result.map(|output| output.counters));
    }
    // In one phase the depth is not read: any depth does.
    let mut renderer =
        SlotRenderer::new(&context, (WIDTH, HEIGHT), reversed, (wgpu::TextureFormat::Depth24Plus, readable.1));
    let one_phase = GpuCullSettings::default();
    setup.culler.run_world_into(&context, &mut setup.flight.world, &one_phase, &mut renderer).expect("one phase");
}

/// Two-phase occlusion's passes against their CPU twins on still cameras, once the late phase draws nothing
/// and the image's depth is the early phase's: the merged pyramid's level 0 is the CPU merge of
/// that depth with the CPU pyramid's level 0, and the late phase's cluster counters are the CPU cluster test
/// of every candidate against the merged pyramid (up to decisions that a 1e-3 nudge of the camera flips); in
/// every depth convention, and drawing the unculled image.
#[test]
fn two_phase_passes_match_their_cpu_twins() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 3000);
    setup.culler.set_gating(GpuGating::fixed());
    let settings = GpuCullSettings { two_phase: true, ..GpuCullSettings::default() };
    let conventions = [DepthConvention::Reversed, DepthConvention::Standard, DepthConvention::NegativeOneToOne];
    let stills = conventions.iter().flat_map(|&depth| {
        cameras(setup.half)
            .into_iter()
            .map(move |(name, camera)| (format!("{name}, {depth:?}"), Camera { depth, ..camera }))
    });
    for (name, camera) in stills.collect::<Vec<_>>() {
        // A still camera draws everything early within a few frames (what the first frame's late phase drew,
        // and then what that hid of the first frame's early draws, settle).
        let late_draws = |output: &GpuFrameOutput| {
            let p = output.phases.expect("two phases");
            println!(
                "{name}: early {} clusters, {} draws; late {} clusters, {} draws, hzb {}, drawn early {}",
                p.early.clusters_out,
                p.early.draws,
                p.late.clusters_out,
                p.late.draws,
                p.late.clusters_hzb,
                p.late.clusters_drawn_early
            );
            p.late.draws
        };
        let settled =
            (0..6).map(|_| setup.run(&context, camera, &settings)).find(|(output, ..)| late_draws(output) == 0);
        let Some((output, visible, _)) = settled else { panic!("{name}: the late phase drew in every frame") };
        let phases = output.phases.expect("two phases");
        // The merge.
        let image = setup.culler.read_image(&context).unwrap();
        let merged = setup.culler.merged_hzb().expect("a merged pyramid");
        let levels = merged.read(&context).unwrap();
        let cpu = setup.culler.hzb();
        let cpu_level0 = &cpu.read(&context).unwrap()[0];
        let depth = (image.depth.as_slice(), image.width, image.height);
        let expected = merge_level0(depth, Some((cpu_level0, cpu.levels[0], cpu.screen_size)), &camera);
        let differing = expected.iter().zip(&levels[0]).filter(|(a, b)| (*a - *b).abs() > 1e-6 * a.abs()).count();
        assert_eq!(differing, 0, "{name}: merged texels differ from the CPU twin's");
        // The late phase's cluster tests, against the merged pyramid and the CPU's copied after it.
        let view = *setup.culler.last_late_view().expect("a late phase");
        assert_eq!(
            view.flags & (VIEW_PHASE_LATE | VIEW_HZB | VIEW_SECOND_HZB),
            VIEW_PHASE_LATE | VIEW_HZB | VIEW_SECOND_HZB
        );
        let bytes = context.read_buffer(&merged.buffer, merged.buffer.size()).unwrap();
        let hzb: &[f32] = bytemuck::cast_slice(&bytes);
        let (library, instances) = (&setup.culler.scene().library, setup.culler.scene().instances());
        let mut counts: HashMap<ClusterVerdict, u32> = HashMap::new();
        let mut unstable = 0;
        for &slot in &visible {
            let instance = &instances[slot as usize];
            for cluster in library.clusters_of(instance.mesh) {
                *counts.entry(cull_cluster(&view, hzb, instance, cluster)).or_default() += 1;
                unstable += usize::from(flips_when_nudged(&view, |v| cull_cluster(v, hzb, instance, cluster)));
            }
        }
        let late = phases.late;
        let gpu = [
            (ClusterVerdict::Keep, late.clusters_out + late.clusters_drawn_early),
            (ClusterVerdict::Frustum, late.clusters_frustum),
            (ClusterVerdict::Cone, late.clusters_cone),
            (ClusterVerdict::Hzb, late.clusters_hzb),
        ];
        for (verdict, gpu) in gpu {
            let cpu = counts.get(&verdict).copied().unwrap_or(0);
            assert!(gpu.abs_diff(cpu) as usize <= unstable, "{name}: {verdict:?}: GPU {gpu}, CPU {cpu}");
        }
        println!("{name}: late phase {counts:?}, {unstable} unstable");
        let (differing, _) = pixels_differing_from_unculled(&context, &mut setup.culler, &camera);
        assert_eq!(differing, 0, "{name}: two-phase culling changed {differing} pixels");
    }
}

/// Two-phase occlusion that hides less than its share (the camera looking straight down on the city hides
/// little, and the share asked is all) runs in one phase after `low_benefit_frames` frames of two, is
/// re-probed after `reprobe_every` (the first frame of two phases after frames of one has nothing marked and is
/// not counted), and every frame draws the unculled image.
#[test]
fn two_phase_under_its_benefit_is_gated_off_and_reprobed() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 3000);
    let gating =
        GpuGating { low_benefit_frames: 3, reprobe_every: 4, min_two_phase_benefit: 1.0, ..GpuGating::default() };
    setup.culler.set_gating(gating);
    let (_, down) = cameras(setup.half).into_iter().find(|(name, _)| *name == "down").expect("a camera looking down");
    let settings = GpuCullSettings { two_phase: true, ..GpuCullSettings::default() };
    let mut in_two_phases = Vec::new();
    for frame in 0..14 {
        let (output, ..) = setup.run(&context, down, &settings);
        in_two_phases.push(output.phases.is_some());
        let (differing, _) = pixels_differing_from_unculled(&context, &mut setup.culler, &down);
        assert_eq!(differing, 0, "frame {frame}");
    }
    let expected = [true, true, true, true, false, false, false, false, true, true, true, true, false, false];
    assert_eq!(in_two_phases, expected);
}

/// Runs `frame` of a camera standing at a point of the fly-through, still or turning 0.4 radians a frame on
/// the spot, with `settings`, and checks that it draws the unculled image.
fn turn_on_the_spot(
    context: &GpuContext,
    setup: &mut Setup,
    (still, frame): (bool, u32),
    settings: &GpuCullSettings,
) -> (GpuFrameOutput, CullStats) {
    let camera = setup.flight.path.camera_at(1.0, setup.flight.aspect);
    let turn = if still { 0.0 } else { 0.4 * frame as f32 };
    let camera = Camera { forward: glam::Quat::from_rotation_y(turn) * camera.forward, ..camera };
    let stats = setup.flight.run_with_camera(camera, 0.0);
    let output = setup.culler.run_world(context, &mut setup.flight.world, settings).expect("GPU frame");
    let camera = *setup.flight.world.resource::<Camera>();
    let (differing, _) = pixels_differing_from_unculled(context, &mut setup.culler, &camera);
    assert_eq!(differing, 0, "still {still}, frame {frame}");
    (output, stats)
}

/// Beside two phases, the CPU occluder stage runs only where it pays (`GpuGating::min_occluder_benefit`): on
/// a still camera the frame's own depth hides all the CPU buffer does, and the stage is skipped but for its
/// probes; turning fast on the spot, where what the last frame saw covers only part of this one, it saves
/// triangles and runs but for its probes. Every frame draws the unculled image.
#[test]
fn the_occluder_stage_runs_beside_two_phases_only_where_it_pays() {
    let Some(context) = context_for_tests() else { return };
    let gating = GpuGating { min_occluder_benefit: 0.05, reprobe_every: 6, ..GpuGating::fixed() };
    let settings = GpuCullSettings { two_phase: true, ..GpuCullSettings::default() };
    for still in [true, false] {
        let mut setup = setup_flying(&context, 3000, (WIDTH, HEIGHT), OcclusionSettings::default(), 300);
        setup.flight.world.insert_resource(gating);
        let mut ran = Vec::new();
        for frame in 0..26 {
            let (output, stats) = turn_on_the_spot(&context, &mut setup, (still, frame), &settings);
            let occluders = setup.flight.world.resource::<CameraCuller>().stats().occluders;
            println!(
                "still {still}, frame {frame}: {occluders} occluders, {} drawn, {stats:?}",
                output.counters.triangles_out
            );
            ran.push(occluders > 0);
        }
        let ran_after_the_first_probes = ran[10..].iter().filter(|&&ran| ran).count();
        match still {
            true => assert!(ran_after_the_first_probes <= 4, "{ran:?}"),
            false => assert!(ran_after_the_first_probes >= 12, "{ran:?}"),
        }
    }
}

/// The late phase's occluder step runs only where it draws its share of the frame
/// (`GpuGating::min_late_occluder_share`): on a still camera, once the early phase draws everything, it draws
/// nothing and is skipped but for its probes; turning fast on the spot, it draws the large clusters coming into
/// view first and runs every frame. Every frame draws the unculled image.
#[test]
fn the_late_occluder_step_runs_only_where_it_draws() {
    let Some(context) = context_for_tests() else { return };
    let gating =
        GpuGating { min_late_occluder_share: 0.01, low_benefit_frames: 3, reprobe_every: 6, ..GpuGating::fixed() };
    let settings = GpuCullSettings { two_phase: true, ..GpuCullSettings::default() };
    for still in [true, false] {
        let mut setup = setup_flying(&context, 3000, (WIDTH, HEIGHT), OcclusionSettings::default(), 300);
        setup.flight.world.insert_resource(gating);
        let mut ran = Vec::new();
        for frame in 0..20 {
            let (output, _) = turn_on_the_spot(&context, &mut setup, (still, frame), &settings);
            let step = output.phases.expect("two phases").late_occluders;
            println!("still {still}, frame {frame}: {step:?} of {} drawn", output.counters.triangles_out);
            ran.push(step.is_some());
        }
        assert!(ran[0], "{ran:?}");
        let ran_after_the_first_frames = ran[4..].iter().filter(|&&ran| ran).count();
        match still {
            true => assert!(ran_after_the_first_frames <= 6, "{ran:?}"),
            false => assert_eq!(ran_after_the_first_frames, 16, "{ran:?}"),
        }
    }
}

/// Two-phase occlusion's marks (`2f` and `2f + 1` for frame `f`) are cleared before they would wrap around, so
/// that no stale mark reads as drawn early this frame: frames across the wrap draw the unculled image, the
/// first after it all late.
#[test]
fn two_phase_marks_start_again_before_they_wrap() {
    let Some(context) = context_for_tests() else { return };
    let mut setup = setup(&context, 2000);
    let camera = cameras(setup.half)[0].1;
    let settings = GpuCullSettings { two_phase: true, ..GpuCullSettings::default() };
    setup.run(&context, camera, &settings);
    setup.culler.set_two_phase_frame(u32::MAX / 2 - 4);
    let mut early_draws = Vec::new();
    for frame in 0..6 {
        let (output, ..) = setup.run(&context, camera, &settings);
        early_draws.push(output.phases.expect("two phases").early.draws);
        let (differing, _) = pixels_differing_from_unculled(&context, &mut setup.culler, &camera);
        assert_eq!(differing, 0, "frame {frame}");
    }
    // The jump leaves no mark of the frame before: all late. Frames u32::MAX / 2 - 2 and - 1 draw early; then
    // the marks are cleared and the count starts again, all late once more.
    let drew_early: Vec<bool> = early_draws.iter().map(|&draws| draws > 0).collect();
    assert_eq!(drew_early, [false, true, true, false, true, true], "{early_draws:?}");
}

#[test]
fn levels_of_detail_draw_fewer_triangles_and_nearly_the_same_image() {
    use cullet::lod::{self, ChainSettings, LodLibrary, LodSettings};
    let Some(context) = context_for_tests() else { return };
    let ((width, height), frames) = ((640, 360), 6);
    let city = CityScene::generate(CityParams::with_objects(3_000));
    let library = LodLibrary::build(&city.scene.meshes, &ChainSettings::default());
    let fly = |lod: Option<LodSettings>| {
        let aspect = width as f32 / height as f32;
        let mut flight = Flight::new(city.flythrough(), aspect, frames, OcclusionSettings::default(), |world| {
            city.spawn(world);
        });
        if let Some(settings) = lod {
            lod::install(&mut flight.world, &mut flight.schedule, library.clone(), settings);
        }
        let mut culler = GpuCuller::for_world(&context, &flight.world, &city.scene.meshes, (width, height));
        let (mut triangles, mut images) = (0u64, Vec::new());
        for frame in 0..frames {
            flight.run_frame(frame);
            let output = culler.run_world(&context, &mut flight.world, &GpuCullSettings::default()).unwrap();
            triangles += output.counters.triangles_out as u64;
            images.push(culler.read_image(&context).unwrap().object);
        }
        (triangles, images)
    };
    let ((full, full_images), (drawn, lod_images)) = (fly(None), fly(Some(LodSettings::pixels(1.0, height))));
    assert!(drawn * 2 <= full, "{drawn} of {full} triangles drawn");
    // Under a budget that drops objects, a dropped object draws nothing on the GPU either.
    let budget = LodSettings { triangle_budget: Some(drawn / frames as u64 / 4), ..LodSettings::pixels(1.0, height) };
    let (budgeted, _) = fly(Some(budget));
    assert!(budgeted * 3 <= drawn, "{budgeted} triangles under the budget, {drawn} without");
    for (frame, (a, b)) in full_images.iter().zip(&lod_images).enumerate() {
        let changed = a.iter().zip(b).filter(|(a, b)| a != b).count();
        assert!(changed * 200 <= a.len(), "frame {frame}: {changed} pixels changed");
    }
}
