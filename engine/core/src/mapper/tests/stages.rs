//! Stage I and II on a small synthetic keyframe: the losses fall, a
//! batch streamed in chunks steps as the whole batch at once, and the
//! window and batches fit a small binding limit.

use glam::DVec3;

use super::fixtures::*;
use crate::latent::{LatentHead, LatentHeadConfig};
use crate::loss::LossWeights;
use crate::map::{seed_from_frame, GlobalMap, LocalWindow, SeedingConfig};
use crate::mapper::*;
use crate::optim::GaussianLearningRates;
use latentam_gpu::testing::with_context;
use latentam_io::Frame;

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
                kept_views: 4,
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
            .stage_one(ctx, &window, Some(&head), &batch, &[])
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
                .stage_one(ctx, &window, Some(&head), &batch, &[])
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
        assert!(trainer
            .stage_one(ctx, &window, Some(&head), &[], &[])
            .is_err());
        let three: Vec<&KeyframeRecord> = vec![&records[0]; 3];
        assert!(trainer
            .stage_one(ctx, &window, Some(&head), &three, &[])
            .is_err());
    });
}

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
    let plan = window.plan(&global, DVec3::ZERO, 5.0, 0.0);
    let mut rec = ctx.recorder().unwrap();
    let outbox = window
        .record_sync(&mut rec, &plan, &global, &[], None)
        .unwrap();
    assert!(outbox.is_empty(), "nothing was resident to write back");
    rec.submit().unwrap().wait().unwrap();
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
        // Kept keyframes: chunks pooled before the last take their region
        // rows again from the GPU copy Stage I made of them while pooling.
        let keys: Vec<ReplayKey> = records.iter().map(|_| ReplayKey::fresh()).collect();
        let run_keyed = |chunk_pixels: u64, attach: bool, keys: &[ReplayKey]| {
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
                    kept_views: 4,
                },
                DIM as u32,
            )
            .unwrap();
            let report = trainer
                .stage_one(ctx, &window, Some(&head), &batch, keys)
                .unwrap();
            let uploads = trainer.kept_targets().uploads();
            assert_eq!(uploads, 4, "each view's colour once, kept or not");
            let n = window.len() as u64;
            let grads = trainer.gradients().download(ctx, n).unwrap();
            let w = ctx.download::<f32>(head.w()).unwrap();
            let d = ctx.download::<f32>(head.atoms()).unwrap();
            (report, grads, w, d)
        };
        let run = |chunk_pixels: u64, attach: bool| run_keyed(chunk_pixels, attach, &[]);
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
            let (kept, g_kept, _, _) = run_keyed(1, attach, &keys);
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
            for r in [&streamed, &pairs, &kept] {
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
            for other in [&g_streamed, &g_pairs, &g_kept] {
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
            limit / crate::mapper::budget::largest_row_bytes(4)
        );
        assert_eq!(
            w.capacity, w.buffer_limit_rows,
            "the limit, not the budget, bounds it"
        );
        assert!(mapper.stats().keyframes == 4);
    });
}
