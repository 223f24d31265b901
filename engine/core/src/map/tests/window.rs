//! The local window: paging whole blocks of Gaussians between the global
//! map and the GPU, against a plain reference (every Gaussian's current
//! value, wherever it lives).

use std::collections::{HashMap, HashSet};

use bytemuck::Zeroable;
use glam::DVec3;
use rand::Rng;

use crate::map::{gaussian_at, Companion, Gaussian, GlobalMap, LocalWindow, VoxelKey};
use crate::splat::HostGaussians;
use latentam_gpu::testing::{rng, with_context, with_options};
use latentam_gpu::{Buffer, ContextOptions, TransferQueue};

/// Gaussians along a 20 m corridor, one every ~2 cm, each with a
/// recognisable opacity and query (1 cm voxels: blocks of 0.64 m).
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

/// Distance from `centre` to the nearest point of `key`'s block.
fn block_distance(global: &GlobalMap, key: VoxelKey, centre: DVec3) -> f64 {
    let b = GlobalMap::block_of(key);
    let edge = global.voxel_size() * crate::map::BLOCK_VOXELS as f64;
    let min = DVec3::new(b.x as f64, b.y as f64, b.z as f64) * edge;
    centre.clamp(min, min + edge).distance(centre)
}

/// Stands for a training step: every resident changed on the GPU, the
/// reference following.
fn train(
    ctx: &latentam_gpu::Context,
    window: &LocalWindow,
    truth: &mut HashMap<VoxelKey, Gaussian>,
    changed_keys: &mut HashSet<VoxelKey>,
    rng: &mut impl Rng,
) {
    let host = window.params().download(ctx, window.len() as u64).unwrap();
    let mut changed = HostGaussians::default();
    for (row, key) in window.keys().iter().enumerate() {
        let mut g = gaussian_at(&host, row);
        g.opacity_logit += 0.5;
        g.quat[1] = rng.random();
        truth.insert(*key, g);
        changed_keys.insert(*key);
        crate::map::push_gaussian(&mut changed, &g);
    }
    window.params().upload(ctx, 0, &changed).unwrap();
}

fn bits(g: &Gaussian) -> Vec<u32> {
    bytemuck::cast_slice::<Gaussian, u32>(std::slice::from_ref(g)).to_vec()
}

/// On the device's own queues, and on the transfer path rehearsed on the
/// compute family (see `TransferQueue::SameFamily`), so that its recording
/// and synchronisation run under validation on any device.
#[test]
fn random_walks_of_block_plans_keep_every_gaussian_in_one_place() {
    for transfer_queue in [TransferQueue::Auto, TransferQueue::SameFamily] {
        let options = ContextOptions {
            transfer_queue,
            ..ContextOptions::default()
        };
        with_options(options, random_walks);
    }
}

fn random_walks(ctx: &latentam_gpu::Context) {
    let mut rng = rng("random_walks_of_block_plans");
    let (radius, margin) = (1.5, 0.3);
    // What the walks exercised, over all of them.
    let (mut moved, mut fetched, mut written, mut dropped_clean) = (0, 0, 0, 0);
    for walk in 0..3 {
        let mut global = corridor(&mut rng);
        let total = global.len();
        // The reference: every Gaussian's value as training left it.
        let mut truth: HashMap<VoxelKey, Gaussian> = global.iter().map(|(k, g)| (k, *g)).collect();
        // Small enough that some walks overflow it.
        let capacity = [400, 250, 120][walk];
        let mut window = LocalWindow::new(ctx, capacity).unwrap();
        // A companion row per Gaussian: 2 words tagging its key.
        let companion = Buffer::device(ctx, "test/companion", capacity * 8).unwrap();
        let tag = |k: VoxelKey| [k.x as f32, k.y as f32];
        let mut x = rng.random_range(0.0..20.0);
        let mut jump = 0.0;
        // Residents changed since their block's last copy to the host.
        let mut changed_keys: HashSet<VoxelKey> = HashSet::new();
        for step in 0..14 {
            // Random steps; every fourth sync a jump there and back (the
            // blocks it brings in arrive after a training step and leave
            // before the next, so they leave clean, without a write-back);
            // and a short step that keeps most of the window, so that rows
            // from the tail fill holes.
            let inward = if x < 10.0 { 1.0 } else { -1.0 };
            x = match step % 4 {
                1 => {
                    jump = 4.0 * inward;
                    x + jump
                }
                2 => x - jump,
                3 => x + 0.7 * inward,
                _ => (x + rng.random_range(-2.5..2.5f64)).clamp(-1.0, 21.0),
            };
            let centre = DVec3::new(x, 0.0, 1.0);
            let plan = window.plan(&global, centre, radius, margin);
            let before: HashSet<VoxelKey> = window.keys().iter().copied().collect();
            // As the mapper does, every third sync is planned before a
            // training step and carried out after it: what that step
            // changed must be written back all the same.
            if step % 3 == 2 {
                train(ctx, &window, &mut truth, &mut changed_keys, &mut rng);
                window.mark_trained();
            }
            let leaving_dirty: HashSet<u32> = plan
                .evict
                .iter()
                .copied()
                .filter(|&r| changed_keys.contains(&window.keys()[r as usize]))
                .collect();
            dropped_clean += plan.evict.len() - leaving_dirty.len();
            moved += plan
                .evict
                .iter()
                .filter(|&&r| (r as usize) < plan.keep)
                .count();
            fetched += plan.fetch.len();
            written += leaving_dirty.len();

            // Every other sync has its arrivals uploaded ahead, on a
            // detached transfer batch the moves wait for by name.
            let (staged, upload) = if step % 2 == 1 {
                let mut rec = ctx.transfer_recorder().unwrap();
                rec.detach();
                let staged = window.record_arrivals(&mut rec, &plan, &global).unwrap();
                (Some(staged), Some(rec.submit().unwrap()))
            } else {
                (None, None)
            };
            let mut rec = ctx.recorder().unwrap();
            if let Some(u) = &upload {
                rec.wait_for(u.sync_point());
            }
            let rows = [Companion {
                buffer: &companion,
                row_bytes: 8,
            }];
            let outbox = window
                .record_sync(&mut rec, &plan, &global, &rows, staged)
                .unwrap();
            let moves = rec.submit().unwrap();
            let mut rec = ctx.transfer_recorder().unwrap();
            let pending = window.record_outbox(&mut rec, outbox).unwrap();
            rec.submit().unwrap().wait().unwrap();
            // The download waited for the moves on the GPU.
            assert!(moves.is_done());
            moves.finished_span().unwrap();
            if let Some(u) = upload {
                assert!(u.is_done());
                u.finished_span().unwrap();
            }
            // Those of changed blocks: a block is written back whole, so
            // the test's set (every resident at a training step) is the
            // window's.
            assert_eq!(pending.apply(&mut global).unwrap(), leaving_dirty.len());
            changed_keys.retain(|k| window.holds(*k));

            // Whole blocks: a resident block has every Gaussian of its
            // block in the window, and each key is resident once.
            let resident: HashSet<VoxelKey> = window.keys().iter().copied().collect();
            assert_eq!(resident.len(), window.len(), "a key twice in the window");
            assert!(window.len() as u64 <= capacity);
            let blocks: HashSet<VoxelKey> =
                resident.iter().map(|&k| GlobalMap::block_of(k)).collect();
            assert_eq!(blocks.len(), window.blocks());
            for &b in &blocks {
                assert!(
                    global.block_keys(b).all(|k| resident.contains(&k)),
                    "block {b:?} is whole"
                );
            }
            // What is resident lies within the radius and margin; what
            // lies within the radius is resident unless it did not fit.
            for (key, _) in global.iter() {
                let d = block_distance(&global, key, centre);
                if resident.contains(&key) {
                    assert!(d <= radius + margin + 1e-9, "{key:?} at {d} m stayed");
                } else if plan.over_capacity == 0 {
                    assert!(d > radius, "{key:?} at {d} m left out with room to spare");
                }
            }

            // The GPU holds the truth for residents, the global map for
            // the others, bit for bit; companion rows moved with their
            // Gaussian, arriving ones start at zero.
            let host = window.params().download(ctx, window.len() as u64).unwrap();
            let comp: Vec<[f32; 2]> =
                bytemuck::cast_slice(&ctx.download::<f32>(&companion).unwrap()).to_vec();
            for (row, key) in window.keys().iter().enumerate() {
                assert_eq!(
                    bits(&gaussian_at(&host, row)),
                    bits(&truth[key]),
                    "row {row}"
                );
                if before.contains(key) {
                    assert_eq!(comp[row], tag(*key), "row {row} kept its companion");
                } else {
                    assert_eq!(comp[row], [0.0, 0.0], "row {row} is new");
                }
            }
            for (key, g) in global.iter() {
                if !resident.contains(&key) {
                    assert_eq!(bits(g), bits(&truth[&key]), "{key:?} on the host");
                }
            }

            // "Train" every other step: change every resident on the GPU.
            if step % 2 == 0 {
                train(ctx, &window, &mut truth, &mut changed_keys, &mut rng);
                window.mark_trained();
            }
            let tags: Vec<[f32; 2]> = window.keys().iter().map(|k| tag(*k)).collect();
            ctx.upload(&companion, 0, &tags).unwrap();
        }
        // A write-back makes the host copy equal the GPU's, bit for bit,
        // and leaves nothing dirty.
        let mut rec = ctx.recorder().unwrap();
        let pending = window.record_write_back(&mut rec).unwrap();
        rec.submit().unwrap().wait().unwrap();
        pending.apply(&mut global).unwrap();
        assert!(window.dirty_rows().is_empty());
        assert_eq!(global.len(), total);
        for (key, g) in global.iter() {
            assert_eq!(bits(g), bits(&truth[&key]), "{key:?} after the write-back");
        }
        // Far away, every block leaves, and nothing is written back twice.
        let plan = window.plan(&global, DVec3::new(100.0, 0.0, 0.0), radius, margin);
        assert_eq!(plan.fetch.len(), 0);
        assert_eq!(plan.evict.len(), window.len());
        let mut rec = ctx.recorder().unwrap();
        let outbox = window
            .record_sync(&mut rec, &plan, &global, &[], None)
            .unwrap();
        assert!(outbox.is_empty(), "nothing changed since the write-back");
        rec.submit().unwrap().wait().unwrap();
        assert!(window.is_empty() && window.blocks() == 0);
    }
    assert!(
        moved > 0 && fetched > 0 && written > 0 && dropped_clean > 0,
        "moved {moved}, fetched {fetched}, written {written}, dropped clean {dropped_clean}"
    );
}

#[test]
fn a_full_window_takes_the_nearest_whole_blocks_and_bad_plans_are_errors() {
    with_context(|ctx| {
        let mut rng = rng("a_full_window");
        let global = corridor(&mut rng);
        let cap = 50;
        let mut window = LocalWindow::new(ctx, cap).unwrap();
        let centre = DVec3::new(5.0, 0.0, 1.0);
        let plan = window.plan(&global, centre, 3.0, 0.0);
        assert!(plan.over_capacity > 0);
        assert!(plan.fetch.len() as u64 <= cap);
        // Whole blocks, and every block within the radius left out would
        // not have fitted beside those taken.
        let taken: HashSet<VoxelKey> = plan.fetch.iter().map(|&k| GlobalMap::block_of(k)).collect();
        assert_eq!(taken.len(), plan.blocks_in);
        let per_block = |b: VoxelKey| global.block_len(b);
        assert_eq!(
            taken.iter().map(|&b| per_block(b)).sum::<usize>(),
            plan.fetch.len()
        );
        let mut left_out = 0;
        for (d2, b, n) in global.blocks_near(centre, 3.0) {
            assert!(d2 <= 9.0);
            if !taken.contains(&b) {
                assert!(
                    plan.fetch.len() + n > cap as usize,
                    "block {b:?} of {n} fitted"
                );
                left_out += n;
            }
        }
        assert_eq!(left_out, plan.over_capacity);
        // The nearest block comes in, and blocks come nearest first.
        let nearest = global.blocks_near(centre, 3.0)[0].1;
        assert!(taken.contains(&nearest));

        // Arrivals staged for one plan do not serve another.
        let other = window.plan(&global, DVec3::new(15.0, 0.0, 1.0), 3.0, 0.0);
        let mut rec = ctx.recorder().unwrap();
        let staged = window.record_arrivals(&mut rec, &other, &global).unwrap();
        rec.submit().unwrap().wait().unwrap();
        let mut rec = ctx.recorder().unwrap();
        let e = window
            .record_sync(&mut rec, &plan, &global, &[], Some(staged))
            .unwrap_err();
        assert!(matches!(e, crate::Error::BadInput { .. }), "{e}");
        drop(rec);
        let mut bad = plan.clone();
        bad.fetch.push(VoxelKey {
            x: 1 << 20,
            y: 0,
            z: 0,
        });
        let mut rec = ctx.recorder().unwrap();
        assert!(window
            .record_sync(&mut rec, &bad, &global, &[], None)
            .is_err());
        drop(rec);
        // Fill it, then plans whose rows are out of order, not resident, or
        // written back without leaving are refused.
        let mut rec = ctx.recorder().unwrap();
        let _ = window
            .record_sync(&mut rec, &plan, &global, &[], None)
            .unwrap();
        rec.submit().unwrap().wait().unwrap();
        let n = window.len() as u32;
        let refused = [
            window.plan_removal(vec![3, 1]),
            window.plan_removal(vec![n]),
            crate::map::SyncPlan {
                generation: 7,
                ..window.plan_removal(vec![1])
            },
        ];
        for plan in refused {
            let mut rec = ctx.recorder().unwrap();
            let e = window
                .record_sync(&mut rec, &plan, &global, &[], None)
                .unwrap_err();
            assert!(matches!(e, crate::Error::BadInput { .. }), "{e}");
        }
        let odd = Buffer::device(ctx, "test/odd", cap * 6).unwrap();
        let mut rec = ctx.recorder().unwrap();
        let rows = [Companion {
            buffer: &odd,
            row_bytes: 6,
        }];
        let removal = window.plan_removal(vec![0]);
        assert!(window
            .record_sync(&mut rec, &removal, &global, &rows, None)
            .is_err());
        drop(rec);
        assert!(LocalWindow::new(ctx, 0).is_err());
    });
}
