//! The local window: paging Gaussians between the global map and the GPU.

use std::collections::HashSet;

use bytemuck::Zeroable;
use glam::DVec3;
use rand::Rng;

use crate::map::{gaussian_at, Companion, Gaussian, GlobalMap, LocalWindow, VoxelKey};
use latentam_gpu::testing::{rng, with_context, with_options};
use latentam_gpu::{Buffer, ContextOptions, TransferQueue};

/// Gaussians along a 20 m corridor, one every ~2 cm, each with a
/// recognisable opacity and query.
fn corridor(rng: &mut impl Rng) -> GlobalMap {
    let mut map = GlobalMap::new(0.01);
    for i in 0..1000 {
        let x = i as f32 * 0.02 + rng.random_range(0.0..0.005f32);
        let g = Gaussian {
            mean: [x, rng.random_range(-0.5..0.5), rng.random_range(0.0..2.0)],
            opacity_logit: i as f32,
            query: std::array::from_fn(|c| (i * 32 + c) as f32),
            ..Gaussian::zeroed()
        };
        map.insert(g);
    }
    map
}

/// On the device's own queues, and on the transfer path rehearsed on
/// the compute family (see `TransferQueue::SameFamily`), so that its
/// recording and synchronisation run under validation on any device.
#[test]
fn paging_follows_the_camera_keeps_state_and_writes_back_by_key() {
    for transfer_queue in [TransferQueue::Auto, TransferQueue::SameFamily] {
        let options = ContextOptions {
            transfer_queue,
            ..ContextOptions::default()
        };
        with_options(options, paging_follows_the_camera);
    }
}

fn paging_follows_the_camera(ctx: &latentam_gpu::Context) {
    {
        let mut rng = rng("paging_follows_the_camera");
        let mut global = corridor(&mut rng);
        let total = global.len();
        let capacity = 160;
        let mut window = LocalWindow::new(ctx, capacity).unwrap();
        // A companion row per Gaussian: 2 floats tagging its key.
        let companion = Buffer::device(ctx, "test/companion", capacity * 8).unwrap();
        let tag = |k: VoxelKey| [k.x as f32, k.y as f32];
        let radius = 1.5;
        let (mut kept, mut moved, mut fetched) = (0, 0, 0);
        for step in 0..16 {
            let centre = DVec3::new(step as f64 * 0.6, 0.0, 1.0);
            let plan = window.plan(&global, centre, radius);
            kept += plan.keep;
            fetched += plan.fetch.len();
            moved += plan
                .evict
                .iter()
                .filter(|&&r| (r as usize) < plan.keep)
                .count();
            let keep_before: HashSet<VoxelKey> = window.keys().iter().copied().collect();
            let mut rec = ctx.transfer_recorder().unwrap();
            let pending = window
                .record_sync(
                    &mut rec,
                    &plan,
                    &global,
                    &[Companion {
                        buffer: &companion,
                        row_bytes: 8,
                    }],
                )
                .unwrap();
            rec.submit().unwrap().wait().unwrap();
            pending.apply(&mut global).unwrap();

            // The window holds exactly the nearest Gaussians within the radius.
            let mut want: Vec<(f64, VoxelKey)> = global
                .iter()
                .map(|(k, g)| (DVec3::from(g.mean.map(f64::from)).distance(centre), k))
                .filter(|(d, _)| *d <= radius)
                .collect();
            want.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            want.truncate(capacity as usize);
            let got: HashSet<VoxelKey> = window.keys().iter().copied().collect();
            assert_eq!(got.len(), window.len(), "no key twice in the window");
            assert_eq!(
                got,
                want.iter().map(|w| w.1).collect::<HashSet<_>>(),
                "step {step}"
            );

            // Every row holds its key's Gaussian, and companion rows moved
            // with their Gaussian (fetched rows start at zero).
            let host = window.params().download(ctx, window.len() as u64).unwrap();
            let comp: Vec<[f32; 2]> =
                bytemuck::cast_slice(&ctx.download::<f32>(&companion).unwrap()).to_vec();
            for (row, key) in window.keys().iter().enumerate() {
                assert_eq!(
                    gaussian_at(&host, row),
                    *global.get(*key).unwrap(),
                    "row {row}"
                );
                if keep_before.contains(key) {
                    assert_eq!(comp[row], tag(*key), "row {row} kept its companion");
                } else {
                    assert_eq!(comp[row], [0.0, 0.0], "row {row} is new");
                }
            }

            // "Optimise": change every resident on the GPU and tag the
            // companions; the next sync must write the changes back.
            let mut changed = host.clone();
            for o in &mut changed.opacity_logits {
                *o += 0.5;
            }
            window.params().upload(ctx, 0, &changed).unwrap();
            let tags: Vec<[f32; 2]> = window.keys().iter().map(|k| tag(*k)).collect();
            ctx.upload(&companion, 0, &tags).unwrap();
        }
        assert!(
            kept > 0 && moved > 0 && fetched > 0,
            "kept {kept}, moved {moved}, fetched {fetched}"
        );
        // Final write-back: the global map has every Gaussian exactly once,
        // with the window's changes.
        let plan = window.plan(&global, DVec3::new(100.0, 0.0, 0.0), radius);
        assert_eq!(plan.fetch.len(), 0);
        let resident: Vec<VoxelKey> = window.keys().to_vec();
        let mut rec = ctx.transfer_recorder().unwrap();
        let pending = window.record_sync(&mut rec, &plan, &global, &[]).unwrap();
        rec.submit().unwrap().wait().unwrap();
        let before: Vec<f32> = resident
            .iter()
            .map(|k| global.get(*k).unwrap().opacity_logit)
            .collect();
        pending.apply(&mut global).unwrap();
        assert!(window.is_empty());
        assert_eq!(global.len(), total);
        for (k, b) in resident.iter().zip(before) {
            assert_eq!(global.get(*k).unwrap().opacity_logit, b + 0.5);
        }
        // Every Gaussian visited was changed by exactly 0.5 per sync it
        // was resident for, so all opacities are i + 0.5·m.
        for (_, g) in global.iter() {
            let frac = (g.opacity_logit * 2.0).fract();
            assert_eq!(frac, 0.0, "{}", g.opacity_logit);
        }
    }
}

#[test]
fn a_full_window_keeps_the_nearest_and_bad_plans_are_errors() {
    with_context(|ctx| {
        let mut rng = rng("a_full_window");
        let global = corridor(&mut rng);
        let mut window = LocalWindow::new(ctx, 50).unwrap();
        let plan = window.plan(&global, DVec3::new(5.0, 0.0, 1.0), 3.0);
        assert_eq!(plan.fetch.len(), 50);
        assert!(plan.over_capacity > 0);
        let centre = DVec3::new(5.0, 0.0, 1.0);
        let far = plan
            .fetch
            .iter()
            .map(|k| DVec3::from(global.get(*k).unwrap().mean.map(f64::from)).distance(centre))
            .fold(0.0, f64::max);
        let nearer_left_out = global
            .within(centre, 3.0)
            .into_iter()
            .filter(|k| !plan.fetch.contains(k))
            .any(|k| {
                DVec3::from(global.get(k).unwrap().mean.map(f64::from)).distance(centre) < far
            });
        assert!(!nearer_left_out, "the nearest 50 come in");
        let mut bad = plan.clone();
        bad.fetch.push(VoxelKey {
            x: 1 << 20,
            y: 0,
            z: 0,
        });
        let mut rec = ctx.transfer_recorder().unwrap();
        assert!(window.record_sync(&mut rec, &bad, &global, &[]).is_err());
        assert!(LocalWindow::new(ctx, 0).is_err());
    });
}
