//! A frame's route through the mapper: keyframes map a moving camera,
//! with embeddings or without, refused frames change nothing, a hurried
//! keyframe stays consistent, and guesses a later keyframe contradicts
//! go.

use glam::DVec3;

use super::fixtures::*;
use crate::map::SeedingConfig;
use crate::mapper::*;
use latentam_gpu::testing::with_context;
use latentam_io::DepthData;

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
        assert_eq!(mapper.pager.global().len(), added_total);
        assert!(mapper.dictionary.head().unwrap().atom_count() >= 2);
        // Every Gaussian of the map is in the window (it is large enough),
        // once.
        let window = mapper.pager.window().unwrap();
        let keys: std::collections::HashSet<_> = window.keys().iter().copied().collect();
        assert_eq!(keys.len(), window.len());
        assert_eq!(keys.len(), mapper.pager.global().len());
        let psnr = psnr_of_first_keyframe(ctx, &mapper);
        eprintln!(
            "PSNR of keyframe 0: {psnr_after_first:.1} dB after it, {psnr:.1} dB after 8 keyframes ({} Gaussians)",
            mapper.pager.global().len()
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
    let window = mapper.pager.window().unwrap();
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
        assert!(mapper.dictionary.head().is_none());
        assert!(!mapper.pager.global().is_empty());
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
        assert_eq!(mapper.dictionary.head().unwrap().config().dim, DIM as u32);
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
        let before = (mapper.stats().frames, mapper.pager.global().len());
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
            assert_eq!((mapper.stats().frames, mapper.pager.global().len()), before);
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
        m.pager
            .global()
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
            let window = mapper.pager.window().unwrap();
            assert_eq!(window.len(), mapper.pager.global().len());
            assert!(window
                .keys()
                .iter()
                .all(|&k| mapper.pager.global().get(k).is_some()));
        }
    });
}

/// Maps `keyframes` frames with `cfg`, then checks that a query scores
/// every Gaussian finitely and that the map saves (a diverged one would
/// not). Returns the mapper and the query's embedding.
fn map_query_and_save(
    ctx: &latentam_gpu::Context,
    cfg: MapperConfig,
    keyframes: i64,
) -> (Mapper, Vec<f32>) {
    let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
    for i in 0..keyframes {
        let mut f = keyframe(DVec3::new(0.05 * i as f64, 0.0, 0.0));
        f.stamp_ns = i;
        mapper.integrate(f).unwrap();
    }
    let mut word = vec![0.0f32; DIM];
    word[3] = 1.0;
    let scores = mapper.cosines(&word).unwrap();
    assert!(!scores.is_empty() && scores.iter().all(|s| s.is_finite()));
    let path = std::env::temp_dir().join(format!(
        "latentam-limits-{}-{}",
        std::process::id(),
        std::thread::current()
            .name()
            .unwrap_or("test")
            .replace("::", "-")
    ));
    mapper.save_file(&path).unwrap();
    std::fs::remove_file(&path).ok();
    (mapper, word)
}

/// Every floating-point setting at the ends of its documented range, and
/// each just past them: the map, its queries and its save stay finite at
/// the ends, and validation refuses what lies past them.
#[test]
fn float_settings_at_their_limits_keep_every_output_finite() {
    use crate::latent::{TextQuery, MAX_TEMPERATURE, MIN_TEMPERATURE};
    use crate::map::{MAX_DEPTH_ERROR, MAX_SCALE_FACTOR};
    let at = |temperature, depth_error, scale_factor, opacity| MapperConfig {
        temperature,
        seeding: SeedingConfig {
            depth_error,
            scale_factor,
            opacity,
            ..SeedingConfig::default()
        },
        ..small_map_config()
    };
    for past in [
        at(MIN_TEMPERATURE / 2.0, 0.05, 0.75, 0.9),
        at(1e-45, 0.05, 0.75, 0.9),
        at(MAX_TEMPERATURE * 2.0, 0.05, 0.75, 0.9),
        at(0.05, MAX_DEPTH_ERROR * 2.0, 0.75, 0.9),
        at(0.05, 0.05, MAX_SCALE_FACTOR * 2.0, 0.9),
        at(0.05, 0.05, 0.0, 0.9),
    ] {
        assert!(
            past.validate().is_err(),
            "{:?}",
            (past.temperature, past.seeding)
        );
    }
    with_context(|ctx| {
        let limits = [
            at(MIN_TEMPERATURE, 0.0, 1e-6, 0.0),
            at(MAX_TEMPERATURE, MAX_DEPTH_ERROR, MAX_SCALE_FACTOR, 1.0),
        ];
        for cfg in limits {
            let (mut mapper, word) = map_query_and_save(ctx, cfg, 3);
            let vocabulary = latentam_io::Vocabulary {
                names: vec!["a".into(), "b".into()],
                ids: vec![0, 1],
                dim: DIM as u32,
                vectors: [word.clone(), word.iter().rev().copied().collect()].concat(),
                model: "test".into(),
            };
            for temperature in [MIN_TEMPERATURE, MAX_TEMPERATURE] {
                let q = TextQuery::vocabulary_word(&vocabulary, "a", temperature).unwrap();
                let p = mapper.relevance(&q, Scored::Gaussians).unwrap();
                assert!(p.iter().all(|p| p.is_finite() && (0.0..=1.0).contains(p)));
            }
        }
    });
}

/// Every learning rate at the top of its range (10): Adam's steps are
/// bounded by the rate whatever the gradients, so the map, its queries
/// and its save stay finite.
#[test]
fn learning_rates_at_their_maximum_keep_every_output_finite() {
    use crate::optim::GaussianLearningRates;
    // MAX_LEARNING_RATE (optim) and MAX_LATENT_LR (config) are both 10.
    let top = 10.0;
    let cfg = MapperConfig {
        latent_lr: top,
        learning_rates: GaussianLearningRates {
            means: top,
            log_scales: top,
            quats: top,
            colors: top,
            opacity: top,
            queries: top,
        },
        stage_two_iterations: 20,
        ..small_map_config()
    };
    assert!(cfg.validate().is_ok());
    with_context(|ctx| _ = map_query_and_save(ctx, cfg, 4));
}

/// Relevance of every Gaussian goes through the mapper's index of their
/// attention (built on the first query, dropped by the next keyframe):
/// it matches every Gaussian decoded in full on the GPU, before and after
/// a keyframe changes the map, with random query embeddings.
#[test]
fn relevance_through_the_index_matches_the_decoder_and_follows_keyframes() {
    use crate::latent::TextQuery;
    use rand::{Rng, SeedableRng};
    with_context(|ctx| {
        let (mut mapper, _) = map_query_and_save(ctx, small_map_config(), 3);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(54);
        let mut check = |mapper: &mut Mapper| {
            let e: Vec<f32> = (0..DIM).map(|_| rng.random_range(-1.0..1.0)).collect();
            let q = TextQuery::embedding(e);
            let fast = mapper.relevance(&q, Scored::Gaussians).unwrap();
            let exact = mapper.relevance_decoded(&q).unwrap();
            assert_eq!(fast.len(), mapper.stats().gaussians);
            assert_eq!(fast.len(), exact.len());
            let worst = fast
                .iter()
                .zip(&exact)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            assert!(worst < 1e-2, "index off the decoder by {worst}");
            fast
        };
        check(&mut mapper);
        let before = mapper.stats().gaussians;
        let mut f = keyframe(DVec3::new(0.3, 0.0, 0.1));
        f.stamp_ns = 10;
        mapper.integrate(f).unwrap();
        assert!(
            mapper.relevance_index.is_none(),
            "a keyframe keeps a stale index"
        );
        check(&mut mapper);
        assert!(mapper.relevance_index.is_some());
        eprintln!("{before} -> {} Gaussians", mapper.stats().gaussians);
    });
}

#[test]
fn replayed_keyframes_upload_their_targets_once_when_kept_on_the_gpu() {
    with_context(|ctx| {
        let run = |replay_on_gpu| {
            let cfg = MapperConfig {
                replay: 3,
                history_cell: 0.0,
                replay_on_gpu,
                ..small_map_config()
            };
            let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
            let mut uploaded = 0;
            for i in 0..6 {
                let mut f = keyframe(DVec3::new(0.05 * i as f64, 0.0, 0.0));
                f.stamp_ns = i;
                if let Integrated::Keyframe(k) = mapper.integrate(&f).unwrap() {
                    uploaded += k.gpu_work.uploaded_bytes;
                }
            }
            let trainer = mapper.trainer.as_ref().unwrap();
            let uploads = trainer.kept_targets().uploads();
            (uploads, uploaded, psnr_of_first_keyframe(ctx, &mapper))
        };
        // Every keyframe trains with up to 3 of the earlier ones: 1, 2, 3,
        // 4, 4, 4 views.
        let (none, none_bytes, none_psnr) = run(0);
        assert_eq!(none, 18, "uploaded at every step when nothing is kept");
        let (all, all_bytes, all_psnr) = run(32);
        assert_eq!(all, 6, "each keyframe uploaded once, as it trains first");
        let (two, _, _) = run(2);
        assert!((7..18).contains(&two), "two slots for four views: {two}");
        // Twelve views of 48×36 pixels at 5 bytes a pixel (colour and
        // depth alone) crossed no more.
        assert!(
            none_bytes - all_bytes >= 12 * 5 * (W * H) as u64,
            "{none_bytes} → {all_bytes} bytes"
        );
        // Targets expand from either copy through the same kernel: the
        // same training up to float atomics' summation order.
        assert!(
            (none_psnr - all_psnr).abs() < 0.5,
            "{none_psnr} vs {all_psnr}"
        );
    });
}
