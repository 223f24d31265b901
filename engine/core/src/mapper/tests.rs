//! Stage I and II on a small synthetic keyframe: the losses fall.

use glam::{DQuat, DVec3};

use super::*;
use crate::latent::{LatentHead, LatentHeadConfig};
use crate::loss::LossWeights;
use crate::map::{
    seed_from_frame, GlobalMap, KeyframeConfig, KeyframePolicy, LocalWindow, SeedingConfig,
};
use crate::optim::GaussianLearningRates;
use latentam_gpu::testing::with_context;
use latentam_io::{
    encode_floats, CameraPose, ColorImage, DepthData, DepthImage, Dtype, EmbeddingLayout,
    Embeddings, Frame, Intrinsics, LabelImage, PixelFormat,
};

const W: u32 = 48;
const H: u32 = 36;
const DIM: usize = 32;

/// A wall 1.5 m ahead: red left half (region 0), blue right half with a
/// gradient (region 1), each with its own target embedding.
pub(super) fn keyframe(eye: DVec3) -> Frame {
    let n = (W * H) as usize;
    let mut rgb = Vec::with_capacity(n * 3);
    let mut labels = Vec::with_capacity(n);
    for i in 0..n as u32 {
        let (u, v) = (i % W, i / W);
        if u < W / 2 {
            rgb.extend([200, 40, 30]);
            labels.push(0);
        } else {
            rgb.extend([20, (v * 6) as u8, 220]);
            labels.push(1);
        }
    }
    let mut vectors = vec![0.0f32; 2 * DIM];
    vectors[3] = 1.0;
    vectors[DIM + 17] = 1.0;
    Frame {
        stamp_ns: 0,
        pose: CameraPose {
            rotation: DQuat::IDENTITY,
            translation: eye,
        },
        intrinsics: Intrinsics {
            width: W,
            height: H,
            fx: 50.0,
            fy: 50.0,
            cx: 23.5,
            cy: 17.5,
        },
        color: ColorImage {
            width: W,
            height: H,
            format: PixelFormat::Rgb8,
            data: rgb,
        },
        depth: DepthImage {
            width: W,
            height: H,
            data: DepthData::Units {
                values: vec![1500; n],
                metres_per_unit: 0.001,
            },
        },
        embeddings: Some(Embeddings {
            layout: EmbeddingLayout::Regions(LabelImage {
                width: W,
                height: H,
                labels,
            }),
            count: 2,
            dim: DIM as u32,
            dtype: Dtype::F32,
            data: encode_floats(&vectors, Dtype::F32),
            model: "test".into(),
        }),
        semantic: None,
    }
}

/// Keyframe selection that takes every frame, so a test's frames all train.
fn every_frame_a_keyframe() -> KeyframeConfig {
    KeyframeConfig {
        policy: KeyframePolicy::Interval(1),
        ..Default::default()
    }
}

#[test]
fn stage_one_and_two_reduce_the_image_and_feature_losses() {
    with_context(|ctx| {
        let frames = [keyframe(DVec3::ZERO), keyframe(DVec3::new(0.1, 0.0, 0.0))];
        let records: Vec<KeyframeRecord> = frames.iter().map(KeyframeRecord::from_frame).collect();
        // The map seeded from the first keyframe with every colour greyed
        // out, so there is something to learn.
        let (window, head) = training_fixture(ctx, &frames);
        assert!(window.len() > 1000);

        let mut trainer = Trainer::new(
            ctx,
            TrainerConfig {
                capacity: window.capacity(),
                max_view_pixels: (W * H) as u64,
                max_views: 2,
                chunk_pixels: DEFAULT_CHUNK_PIXELS,
                max_regions: 16,
                min_region_pixels: 4,
                weights: LossWeights::default(),
                learning_rates: GaussianLearningRates {
                    colors: 0.02,
                    ..GaussianLearningRates::default()
                },
                attach_feature_gradients: false,
                blend_layout: crate::splat::BlendLayout::Auto,
            },
            DIM as u32,
        )
        .unwrap();
        let batch: Vec<&KeyframeRecord> = records.iter().collect();
        let queries_before = window
            .params()
            .download(ctx, window.len() as u64)
            .unwrap()
            .queries;
        let first = trainer
            .stage_one(ctx, &window, Some(&head), &batch)
            .unwrap();
        assert_eq!(first.regions, 4, "two regions in each of two views");
        assert!(
            first.image.total() > 0.0 && first.feature > 0.0,
            "{first:?}"
        );
        let stage_two_first = trainer.stage_two(ctx, Some(&head), 5).unwrap();
        let mut last = first;
        let mut stage_two_last = stage_two_first;
        for _ in 0..40 {
            last = trainer
                .stage_one(ctx, &window, Some(&head), &batch)
                .unwrap();
            stage_two_last = trainer.stage_two(ctx, Some(&head), 5).unwrap();
        }
        assert!(
            last.image.total() < 0.6 * first.image.total(),
            "image loss {:?} → {:?}",
            first.image,
            last.image
        );
        assert!(
            last.feature < 0.5 * first.feature,
            "feature loss {} → {}",
            first.feature,
            last.feature
        );
        assert!(
            stage_two_last < stage_two_first,
            "Stage II {stage_two_first} → {stage_two_last}"
        );
        assert!(last.image.total().is_finite() && last.feature.is_finite());
        eprintln!(
            "image {:.4} → {:.4}, feature {:.4} → {:.4}, Stage II {:.4} → {:.4}",
            first.image.total(),
            last.image.total(),
            first.feature,
            last.feature,
            stage_two_first,
            stage_two_last
        );
        // The feature loss reached the Gaussians' queries through pooling and
        // the rasterizer.
        let queries_after = window
            .params()
            .download(ctx, window.len() as u64)
            .unwrap()
            .queries;
        let changed = queries_before
            .iter()
            .zip(&queries_after)
            .filter(|(a, b)| a.iter().zip(b.iter()).any(|(x, y)| (x - y).abs() > 1e-4))
            .count();
        assert!(
            changed > window.len() / 2,
            "{changed} of {} queries moved",
            window.len()
        );

        // Batches are checked.
        assert!(trainer.stage_one(ctx, &window, Some(&head), &[]).is_err());
        let three: Vec<&KeyframeRecord> = vec![&records[0]; 3];
        assert!(trainer
            .stage_one(ctx, &window, Some(&head), &three)
            .is_err());
    });
}

#[test]
fn the_online_loop_maps_a_moving_camera_with_and_without_embeddings() {
    with_context(|ctx| {
        let cfg = MapperConfig {
            keyframes: every_frame_a_keyframe(),
            seeding: SeedingConfig {
                stride: 2,
                ..SeedingConfig::default()
            },
            window_capacity: Some(8192),
            replay: 2,
            history_cell: 0.0,
            atoms: 16,
            max_regions: 64,
            min_region_pixels: 4,
            ..MapperConfig::default()
        };
        let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
        let mut added_total = 0;
        let mut psnr_after_first = 0.0;
        for i in 0..8 {
            let mut f = keyframe(DVec3::new(0.05 * i as f64, 0.0, 0.0));
            f.stamp_ns = i as i64;
            if i % 3 == 1 {
                f.embeddings = None;
            }
            match mapper.integrate(&f).unwrap() {
                Integrated::Keyframe(k) => {
                    added_total += k.added;
                    assert!(k.stage_one.image.total().is_finite());
                    // Every dispatch of a keyframe has its work counted
                    // (a kernel whose `@cost` is `caller` has its
                    // dispatching code state it).
                    let w = k.gpu_work;
                    assert_eq!(w.uncounted_dispatches, 0, "keyframe {i}: {w:?}");
                    assert!(
                        w.flops > 0.0 && w.bytes > 0.0 && w.uploaded_bytes > 0,
                        "{w:?}"
                    );
                }
                Integrated::Skipped => panic!("every frame is a keyframe here"),
            }
            if i == 0 {
                psnr_after_first = psnr_of_first_keyframe(ctx, &mapper);
            }
        }
        assert_eq!(mapper.history().len(), 8);
        assert_eq!(mapper.trajectory().len(), 8);
        let work = &mapper.stats().gpu_work;
        for stage in ["adam_step", "project_backward", "softmax", "kmeans_update"] {
            assert!(
                work.kernels.get(stage).is_some_and(|k| k.flops > 0.0),
                "{stage}: {work:?}"
            );
        }
        assert_eq!(mapper.global().len(), added_total);
        assert!(mapper.head().unwrap().atom_count() >= 2);
        // Every Gaussian of the map is in the window (it is large enough),
        // once.
        let window = mapper.window().unwrap();
        let keys: std::collections::HashSet<_> = window.keys().iter().copied().collect();
        assert_eq!(keys.len(), window.len());
        assert_eq!(keys.len(), mapper.global().len());
        let psnr = psnr_of_first_keyframe(ctx, &mapper);
        eprintln!(
            "PSNR of keyframe 0: {psnr_after_first:.1} dB after it, {psnr:.1} dB after 8 keyframes ({} Gaussians)",
            mapper.global().len()
        );
        assert!(
            psnr > 15.0 && psnr > psnr_after_first + 1.0,
            "PSNR {psnr_after_first:.1} → {psnr:.1} dB"
        );
    });
}

/// PSNR of the map's rendering of the first keyframe against its image.
fn psnr_of_first_keyframe(ctx: &latentam_gpu::Context, mapper: &Mapper) -> f64 {
    let first = mapper.history().get(0).unwrap();
    let mut raster = crate::splat::Rasterizer::new(ctx);
    let window = mapper.window().unwrap();
    raster
        .forward(window.params(), window.len() as u64, &[first.camera])
        .unwrap();
    let img = raster.download_view(0).unwrap();
    let target = first.target_rgbd();
    let mse: f64 = img
        .rgbd
        .iter()
        .zip(&target)
        .map(|(p, t)| {
            (0..3)
                .map(|c| (p[c].clamp(0.0, 1.0) as f64 - t[c] as f64).powi(2))
                .sum::<f64>()
        })
        .sum::<f64>()
        / (3 * target.len()) as f64;
    -10.0 * mse.log10()
}

#[test]
fn frames_without_embeddings_map_geometry_and_colour_only() {
    with_context(|ctx| {
        let cfg = MapperConfig {
            keyframes: every_frame_a_keyframe(),
            window_capacity: Some(8192),
            replay: 2,
            ..MapperConfig::default()
        };
        let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
        for i in 0..4 {
            let mut f = keyframe(DVec3::new(0.05 * i as f64, 0.0, 0.0));
            f.stamp_ns = i as i64;
            f.embeddings = None;
            let Integrated::Keyframe(k) = mapper.integrate(&f).unwrap() else {
                panic!("every frame is a keyframe here");
            };
            assert!(k.stage_one.image.total().is_finite());
            assert_eq!(k.stage_one.regions, 0);
        }
        assert!(mapper.head().is_none());
        assert!(!mapper.global().is_empty());
        // No per-pixel feature buffer (query images or their gradients)
        // was ever allocated, and no latent head.
        let mem = ctx.memory_report();
        for part in ["features", "latent", "decoder", "kmeans"] {
            assert!(
                !mem.by_category.contains_key(part),
                "`{part}` buffers allocated: {:?}",
                mem.by_category.keys().collect::<Vec<_>>()
            );
        }
        assert!(mem.by_category["pixels"].peak > 0);
    });
}

/// A window seeded from `frames[0]` with grey colours (all of the map), and
/// a head whose dictionary was initialised from its regions: the same
/// state each call.
fn training_fixture(ctx: &latentam_gpu::Context, frames: &[Frame]) -> (LocalWindow, LatentHead) {
    let mut global = GlobalMap::new(0.01);
    let seeding = SeedingConfig {
        stride: 1,
        ..SeedingConfig::default()
    };
    for mut g in seed_from_frame(&frames[0], None, &global, &seeding, 1, None) {
        g.color = [0.5; 3];
        global.insert(g);
    }
    let mut window = LocalWindow::new(ctx, 4096).unwrap();
    let plan = window.plan(&global, DVec3::ZERO, 5.0);
    let mut rec = ctx.transfer_recorder().unwrap();
    let pending = window.record_sync(&mut rec, &plan, &global, &[]).unwrap();
    rec.submit().unwrap().wait().unwrap();
    pending.apply(&mut global).unwrap();
    assert_eq!(window.len(), global.len());
    let head = LatentHead::new(
        ctx,
        LatentHeadConfig {
            dim: DIM as u32,
            atoms: 16,
            max_regions: 16,
            seed: 3,
            ..Default::default()
        },
    )
    .unwrap();
    let first = KeyframeRecord::from_frame(&frames[0]);
    let targets = ctx
        .upload_new("test/regions", &first.regions.as_ref().unwrap().vectors)
        .unwrap();
    let mut rec = ctx.recorder().unwrap();
    head.record_dictionary_update(&mut rec, &targets, None, 2)
        .unwrap();
    rec.submit().unwrap().wait().unwrap();
    (window, head)
}

#[test]
fn streamed_stage_one_equals_the_batched_step() {
    with_context(|ctx| {
        let frames = [
            keyframe(DVec3::ZERO),
            keyframe(DVec3::new(0.1, 0.0, 0.0)),
            keyframe(DVec3::new(-0.05, 0.05, 0.1)),
            keyframe(DVec3::new(0.0, -0.08, -0.05)),
        ];
        let mut records: Vec<KeyframeRecord> =
            frames.iter().map(KeyframeRecord::from_frame).collect();
        // A view without regions: it takes part in the image losses only.
        records[1].regions = None;
        let batch: Vec<&KeyframeRecord> = records.iter().collect();
        let run = |chunk_pixels: u64, attach: bool| {
            let (window, head) = training_fixture(ctx, &frames);
            let mut trainer = Trainer::new(
                ctx,
                TrainerConfig {
                    capacity: window.capacity(),
                    max_view_pixels: (W * H) as u64,
                    max_views: 4,
                    chunk_pixels,
                    max_regions: 16,
                    min_region_pixels: 4,
                    weights: LossWeights::default(),
                    learning_rates: GaussianLearningRates::default(),
                    attach_feature_gradients: attach,
                    blend_layout: crate::splat::BlendLayout::Auto,
                },
                DIM as u32,
            )
            .unwrap();
            let report = trainer
                .stage_one(ctx, &window, Some(&head), &batch)
                .unwrap();
            let n = window.len() as u64;
            let grads = trainer.gradients().download(ctx, n).unwrap();
            let w = ctx.download::<f32>(head.w()).unwrap();
            let d = ctx.download::<f32>(head.atoms()).unwrap();
            (report, grads, w, d)
        };
        // Attached, the feature loss also reaches opacity and geometry.
        let detached_opacity = run(u64::MAX, false).1.opacity_logits;
        let attached_opacity = run(u64::MAX, true).1.opacity_logits;
        let moved = detached_opacity
            .iter()
            .zip(&attached_opacity)
            .filter(|(a, b)| (*a - *b).abs() > 1e-3 * a.abs().max(1e-6))
            .count();
        assert!(
            moved > detached_opacity.len() / 10,
            "attaching changed {moved} of {} opacity gradients",
            detached_opacity.len()
        );
        for attach in [false, true] {
            let (whole, g_whole, w_whole, d_whole) = run(u64::MAX, attach);
            let (streamed, g_streamed, w_streamed, d_streamed) = run(1, attach);
            // Two views a chunk: one chunk with and one without a region-free view.
            let (pairs, g_pairs, _, _) = run(2 * (W * H) as u64, attach);
            assert_eq!((whole.chunks, whole.forward_passes), (1, 1));
            assert_eq!(streamed.chunks, 4);
            // Three chunks with regions rendered twice except the last pooled;
            // the region-free chunk once.
            assert_eq!(streamed.forward_passes, 3 + 2 + 1);
            assert_eq!((pairs.chunks, pairs.forward_passes), (2, 3));
            assert_eq!(whole.regions, 6);
            assert_eq!((streamed.regions, pairs.regions), (6, 6));
            assert_eq!(whole.raster, streamed.raster);
            let close = |a: f64, b: f64, what: &str| {
                assert!(
                    (a - b).abs() <= 1e-5 * a.abs().max(b.abs()) + 1e-9,
                    "{what}: {a} vs {b}"
                );
            };
            for r in [&streamed, &pairs] {
                close(whole.image.l1, r.image.l1, "L1");
                close(whole.image.ssim, r.image.ssim, "SSIM");
                close(whole.image.depth, r.image.depth, "depth");
                close(whole.feature, r.feature, "feature loss");
            }
            assert!(whole.feature > 0.0 && whole.image.total() > 0.0);
            // The summed gradients agree field by field.
            let fields = |h: &crate::splat::HostGaussians| -> Vec<(&str, Vec<f32>)> {
                vec![
                    ("means", h.means.iter().flatten().copied().collect()),
                    (
                        "log_scales",
                        h.log_scales.iter().flatten().copied().collect(),
                    ),
                    ("quats", h.quats.iter().flatten().copied().collect()),
                    ("opacity", h.opacity_logits.clone()),
                    ("colors", h.colors.iter().flatten().copied().collect()),
                    ("queries", h.queries.iter().flatten().copied().collect()),
                ]
            };
            let largest = fields(&g_whole)
                .iter()
                .flat_map(|(_, v)| v.iter())
                .fold(0.0f32, |m, x| m.max(x.abs()));
            for other in [&g_streamed, &g_pairs] {
                for ((name, a), (_, b)) in fields(&g_whole).into_iter().zip(fields(other)) {
                    // Fields with only rounding noise (the rotations of round
                    // Gaussians) are compared at the scale of the others.
                    let scale = a
                        .iter()
                        .fold(0.0f32, |m, x| m.max(x.abs()))
                        .max(1e-3 * largest);
                    let worst = a
                        .iter()
                        .zip(&b)
                        .map(|(x, y)| (x - y).abs())
                        .fold(0.0f32, f32::max);
                    assert!(
                        worst <= 2e-4 * scale,
                        "{name}: differs by {worst} (scale {scale})"
                    );
                }
            }
            // The decoder stepped on the same pooled queries.
            for (a, b) in [(&w_whole, &w_streamed), (&d_whole, &d_streamed)] {
                let worst = a
                    .iter()
                    .zip(b)
                    .map(|(x, y)| (x - y).abs())
                    .fold(0.0, f32::max);
                assert!(worst <= 1e-5, "W or D differs by {worst}");
            }
        }
    });
}

#[test]
fn the_window_and_batches_stay_within_a_small_binding_limit() {
    // A device that binds at most 1 MiB per buffer: the window is sized to
    // the limit (not to the budget), Stage I streams one view at a time,
    // and mapping proceeds; no buffer exceeds the limit (each is checked
    // when it is created).
    let limit = 1 << 20;
    let o = latentam_gpu::ContextOptions {
        max_buffer_bytes: Some(limit),
        ..latentam_gpu::ContextOptions::default()
    };
    latentam_gpu::testing::with_options(o, |ctx| {
        assert_eq!(ctx.info().max_buffer_bytes(), limit);
        let cfg = MapperConfig {
            keyframes: every_frame_a_keyframe(),
            gpu_budget: Some(1 << 30),
            replay: 3,
            // K² similarities must fit a buffer too.
            atoms: 64,
            ..MapperConfig::default()
        };
        let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
        for i in 0..4 {
            let mut f = keyframe(DVec3::new(0.03 * i as f64, 0.0, 0.0));
            f.stamp_ns = i as i64;
            let Integrated::Keyframe(k) = mapper.integrate(&f).unwrap() else {
                panic!("every frame is a keyframe here");
            };
            assert!(k.stage_one.image.total().is_finite());
        }
        let w = mapper.stats().window.unwrap();
        assert_eq!(
            w.buffer_limit_rows,
            limit / super::budget::largest_row_bytes(4)
        );
        assert_eq!(
            w.capacity, w.buffer_limit_rows,
            "the limit, not the budget, bounds it"
        );
        assert!(mapper.stats().keyframes == 4);
    });
}

#[test]
fn embeddings_arriving_after_the_first_keyframes_train_the_head() {
    with_context(|ctx| {
        let cfg = MapperConfig {
            keyframes: every_frame_a_keyframe(),
            window_capacity: Some(8192),
            replay: 2,
            atoms: 16,
            max_regions: 64,
            min_region_pixels: 4,
            ..MapperConfig::default()
        };
        let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
        for i in 0..4 {
            let mut f = keyframe(DVec3::new(0.04 * i as f64, 0.0, 0.0));
            f.stamp_ns = i as i64;
            if i < 2 {
                f.embeddings = None;
            }
            let Integrated::Keyframe(k) = mapper.integrate(&f).unwrap() else {
                panic!("every frame is a keyframe here");
            };
            // The workspace was sized before any embedding: the region
            // targets still take the later ones.
            assert_eq!(k.stage_one.regions > 0, i >= 2, "keyframe {i}");
            assert!(k.stage_one.feature.is_finite());
        }
        assert_eq!(mapper.head().unwrap().config().dim, DIM as u32);
    });
}

#[test]
fn refused_frames_leave_the_map_as_it_was_and_a_broken_one_is_not_saved() {
    with_context(|ctx| {
        let cfg = MapperConfig {
            keyframes: every_frame_a_keyframe(),
            window_capacity: Some(8192),
            ..MapperConfig::default()
        };
        let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
        let at = |i: u32| {
            let mut f = keyframe(DVec3::new(0.05 * i as f64, 0.0, 0.0));
            f.stamp_ns = i as i64;
            f
        };
        mapper.integrate(at(0)).unwrap();
        let before = (mapper.stats().frames, mapper.global().len());
        let selector = mapper.selector.state();
        // Another dimension, another model, a NaN pose, garbage
        // intrinsics: refused before anything changes.
        let mut other_dim = at(1);
        let e = other_dim.embeddings.as_mut().unwrap();
        e.dim = 16;
        e.count = 4;
        let mut other_model = at(1);
        other_model.embeddings.as_mut().unwrap().model = "another".into();
        let mut nan_pose = at(1);
        nan_pose.pose.translation.x = f64::NAN;
        let mut bad_k = at(1);
        bad_k.intrinsics.fx = -1.0;
        for (frame, why) in [
            (other_dim, "16-d embeddings, the map's are 32-d"),
            (other_model, "model `another`"),
            (nan_pose, "not a rigid transform"),
            (bad_k, "not a pinhole camera"),
        ] {
            let e = mapper.integrate(&frame).unwrap_err().to_string();
            assert!(e.contains(why), "{e}");
            assert_eq!((mapper.stats().frames, mapper.global().len()), before);
            assert_eq!(mapper.selector.state(), selector);
            assert!(!mapper.is_broken());
        }
        // Mapping goes on as if they had never come.
        assert!(matches!(
            mapper.integrate(at(1)).unwrap(),
            Integrated::Keyframe(_)
        ));
        assert_eq!(mapper.stats().keyframes, 2);
        // A keyframe that failed part-way: neither saved nor mapped on.
        mapper.progress.keyframe_started(2);
        let path = std::env::temp_dir().join(format!("latentam-broken-{}", std::process::id()));
        let e = mapper.save_file(&path).unwrap_err().to_string();
        assert!(e.contains("failed") && e.contains("last save"), "{e}");
        assert!(!path.exists());
        assert!(mapper.integrate(at(2)).is_err());
    });
}

#[test]
fn a_hurried_keyframe_skips_its_remaining_steps_and_stays_consistent() {
    use std::sync::atomic::{AtomicBool, Ordering};
    static STOP: AtomicBool = AtomicBool::new(false);
    with_context(|ctx| {
        let cfg = MapperConfig {
            keyframes: every_frame_a_keyframe(),
            window_capacity: Some(8192),
            stage_two_iterations: 20,
            ..MapperConfig::default()
        };
        let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
        mapper.set_hurry_flag(&STOP);
        let at = |i: u32| {
            let mut f = keyframe(DVec3::new(0.05 * i as f64, 0.0, 0.0));
            f.stamp_ns = i as i64;
            f
        };
        let stage_two = |k: Integrated| match k {
            Integrated::Keyframe(k) => k.stage_two,
            Integrated::Skipped => panic!("every frame is a keyframe here"),
        };
        assert!(stage_two(mapper.integrate(at(0)).unwrap()) > 0.0);
        STOP.store(true, Ordering::SeqCst);
        // Stage II skipped (no feature loss measured), the keyframe counted.
        assert_eq!(stage_two(mapper.integrate(at(1)).unwrap()), 0.0);
        STOP.store(false, Ordering::SeqCst);
        assert_eq!(mapper.stats().keyframes, 2);
        assert!(!mapper.is_broken());
        assert!(stage_two(mapper.integrate(at(2)).unwrap()) > 0.0);
    });
}

/// Holes filled from their neighbours are guesses: where a later keyframe
/// measures their pixels further away, the guessed Gaussians float in front
/// of the real surface and are removed; where it measures them where they
/// are, they stay.
#[test]
fn guessed_surface_that_a_later_keyframe_contradicts_is_removed() {
    const BAND: u32 = 10;
    let with_depth = |right_mm: u16| {
        let mut f = keyframe(DVec3::ZERO);
        f.embeddings = None;
        if let DepthData::Units { values, .. } = &mut f.depth.data {
            for (i, v) in values.iter_mut().enumerate() {
                if i as u32 % W >= W - BAND {
                    *v = right_mm;
                }
            }
        }
        f
    };
    // The band's Gaussians: in front of 2 m, right of the band's edge.
    let band = |m: &Mapper| {
        let edge = (W - BAND) as f32 - 0.5;
        m.global()
            .iter()
            .filter(|(_, g)| g.mean[2] < 2.0 && g.mean[0] / g.mean[2] * 50.0 + 23.5 > edge)
            .count()
    };
    with_context(|ctx| {
        for (later_mm, kept) in [(3000, false), (1500, true)] {
            let cfg = MapperConfig {
                keyframes: every_frame_a_keyframe(),
                window_capacity: Some(8192),
                prune_interval: 1,
                ..MapperConfig::default()
            };
            let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
            // No depth in the band, which reaches the image's edge: filled
            // from the wall beside it.
            mapper.integrate(with_depth(0)).unwrap();
            let guessed = band(&mapper);
            assert!(guessed >= (BAND / 2 * H / 2) as usize, "{guessed} guesses");
            assert_eq!(mapper.seeder.guesses(), guessed);
            let mut later = with_depth(later_mm);
            later.stamp_ns = 1;
            mapper.integrate(&later).unwrap();
            if kept {
                assert_eq!(band(&mapper), guessed, "measured where guessed");
                assert!(mapper.seeder.guesses() == 0, "confirmed");
            } else {
                assert_eq!(band(&mapper), 0, "the guesses in front are gone");
            }
            let window = mapper.window().unwrap();
            assert_eq!(window.len(), mapper.global().len());
            assert!(window
                .keys()
                .iter()
                .all(|&k| mapper.global().get(k).is_some()));
        }
    });
}
