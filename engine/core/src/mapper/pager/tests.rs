//! The pager against a plain reference: after every move each Gaussian is
//! in one place, what training changed on the GPU reaches the global map
//! when its block leaves or the window is written back, and reading the
//! map without a write-back sees the same.

use bytemuck::Zeroable;
use glam::DVec3;

use super::*;
use crate::map::Gaussian;
use crate::mapper::budget::WindowBudget;
use latentam_gpu::testing::with_context;

const CAPACITY: u64 = 64;

fn pager(ctx: &Context) -> Pager {
    // 1 cm voxels: blocks of 0.64 m, small against the 2 m radius.
    let mut pager = Pager::new(
        0.01,
        PagerSettings {
            radius: 2.0,
            sync_distance: 0.5,
            host_budget: 0,
        },
    );
    let budget = WindowBudget {
        budget: 1 << 30,
        reserved: 0,
        bytes_per_row: 1,
        capacity: CAPACITY,
        buffer_limit_rows: CAPACITY,
    };
    pager.open_window(ctx, budget).unwrap();
    pager
}

/// Gaussians every 10 cm along x from `from` metres, with distinct colours.
fn insert_line(pager: &mut Pager, from: f32, count: usize) -> Vec<VoxelKey> {
    (0..count)
        .map(|i| {
            let g = Gaussian {
                mean: [from + 0.1 * i as f32, 0.0, 0.0],
                color: [i as f32 / count as f32, 0.5, from],
                opacity_logit: 2.0,
                log_scale: [(0.01f32).ln(); 3],
                ..Gaussian::zeroed()
            };
            pager.global_mut().insert(g).expect("free voxel")
        })
        .collect()
}

/// Every Gaussian as (mean, colour, opacity) bits, sorted: two readings of
/// a map are equal when these are.
fn fingerprint(h: &HostGaussians) -> Vec<[u32; 7]> {
    let mut v: Vec<[u32; 7]> = (0..h.means.len())
        .map(|i| {
            let (m, c) = (h.means[i], h.colors[i]);
            [m[0], m[1], m[2], c[0], c[1], c[2], h.opacity_logits[i]].map(f32::to_bits)
        })
        .collect();
    v.sort_unstable();
    v
}

fn global_fingerprint(pager: &Pager) -> Vec<[u32; 7]> {
    let mut host = HostGaussians::default();
    for (_, g) in pager.global().iter() {
        push_gaussian(&mut host, g);
    }
    fingerprint(&host)
}

/// Each resident once, each a Gaussian of the global map, within the
/// window's capacity.
fn check_one_place(pager: &Pager) {
    let window = pager.window().unwrap();
    let resident: KeySet = window.keys().iter().copied().collect();
    assert_eq!(resident.len(), window.len(), "a Gaussian resident twice");
    assert!(window.len() as u64 <= CAPACITY);
    assert!(resident.iter().all(|&k| pager.global().contains(k)));
}

/// Stands for a training step: every resident's colour changed on the GPU.
fn train(ctx: &Context, pager: &mut Pager, step: f32) {
    let window = pager.window().unwrap();
    let n = window.len() as u64;
    let mut host = window.params().download(ctx, n).unwrap();
    for c in &mut host.colors {
        c[1] += step;
    }
    window.params().upload(ctx, 0, &host).unwrap();
    pager.mark_trained();
}

#[test]
fn new_gaussians_are_appended_while_they_fit_and_page_the_window_when_not() {
    with_context(|ctx| {
        let mut pager = pager(ctx);
        let first = insert_line(&mut pager, 0.0, 40);
        assert!(pager
            .make_resident(ctx, &first, &[], DVec3::ZERO)
            .unwrap()
            .is_none());
        assert_eq!(pager.resident(), 40);
        let extent = pager.extent();
        assert!(
            !extent.partial && extent.complete_within.is_none(),
            "{extent:?}"
        );

        // 40 more do not fit the 24 free rows: the window is re-centred at
        // 5 m, keeping the blocks within 2 m.
        let second = insert_line(&mut pager, 4.0, 40);
        let centre = DVec3::new(5.0, 0.0, 0.0);
        assert!(pager
            .make_resident(ctx, &second, &[], centre)
            .unwrap()
            .is_some());
        // Nothing waited yet: the global map lacks what left until the
        // sync is settled.
        let settled = pager.settle(None).unwrap();
        assert_eq!(settled.len(), 1);
        let report = settled[0].0;
        assert!(report.before_stage_one);
        assert!(report.blocks_in > 0 && report.blocks_out > 0, "{report:?}");
        check_one_place(&pager);
        let window = pager.window().unwrap();
        let block_diagonal = 0.64 * 3f64.sqrt();
        for &key in window.keys() {
            let m = pager.global().get(key).unwrap().mean;
            assert!(
                (m[0] as f64 - 5.0).abs() <= 2.0 + block_diagonal,
                "{m:?} resident"
            );
        }
        for (key, g) in pager.global().iter() {
            if (g.mean[0] as f64 - 5.0).abs() <= 2.0 {
                assert!(window.holds(key), "{:?} within 2 m is resident", g.mean);
            }
        }
        assert_eq!(pager.last_sync(), Some(centre));
        assert_eq!(pager.global().len(), 80);
        // Renders of the window now show the map within 2 m of 5 m only.
        let extent = pager.extent();
        assert_eq!(extent.complete_within, Some((centre, 2.0)));
        assert!(!extent.partial, "everything within 2 m fit");
    });
}

#[test]
fn reading_the_map_without_a_write_back_equals_a_write_back_then_reading() {
    with_context(|ctx| {
        let mut pager = pager(ctx);
        let keys = insert_line(&mut pager, 0.0, 50);
        pager.make_resident(ctx, &keys, &[], DVec3::ZERO).unwrap();
        let before = global_fingerprint(&pager);
        train(ctx, &mut pager, 0.25);
        let now = fingerprint(&pager.gaussians_now(ctx).unwrap());
        assert_ne!(now, before, "training changed the resident rows");
        assert_eq!(
            global_fingerprint(&pager),
            before,
            "gaussians_now wrote back"
        );
        pager.flush(ctx).unwrap();
        assert_eq!(global_fingerprint(&pager), now);
        // Nothing trained since: a second flush and a reading change nothing.
        pager.flush(ctx).unwrap();
        assert_eq!(fingerprint(&pager.gaussians_now(ctx).unwrap()), now);
    });
}

#[test]
fn following_the_camera_writes_leaving_rows_back_and_stays_consistent() {
    with_context(|ctx| {
        let mut pager = pager(ctx);
        let keys = insert_line(&mut pager, 0.0, 100); // 0 to 9.9 m
        let mut centre = DVec3::ZERO;
        pager
            .make_resident(ctx, &keys[..CAPACITY as usize], &[], centre)
            .unwrap();
        pager.settle(None).unwrap();
        for step in 1..8 {
            train(ctx, &mut pager, 0.01 * step as f32);
            let expected = fingerprint(&pager.gaussians_now(ctx).unwrap());
            centre.x += 1.3;
            let prepared = pager.prepare(ctx, centre).unwrap().expect("moved 1.3 m");
            pager.follow(ctx, prepared, &[]).unwrap();
            let settled = pager.settle(None).unwrap();
            assert_eq!(settled.len(), 1);
            let report = settled[0].0;
            check_one_place(&pager);
            // Only what left was copied back, all of it trained.
            assert_eq!(report.written_back, report.evicted, "step {step}");
            assert!(report.written_back < CAPACITY as usize);
            assert_eq!(
                fingerprint(&pager.gaussians_now(ctx).unwrap()),
                expected,
                "step {step}"
            );
            assert_eq!(pager.global().len(), 100);
            // Within the sync distance nothing moves.
            assert!(pager
                .prepare(ctx, centre + DVec3::new(0.2, 0.0, 0.0))
                .unwrap()
                .is_none());
        }
        // A write-back makes the global map what the readings saw.
        let now = fingerprint(&pager.gaussians_now(ctx).unwrap());
        pager.flush(ctx).unwrap();
        assert_eq!(global_fingerprint(&pager), now);
    });
}

#[test]
fn pruning_removes_faint_residents_and_superseded_guesses_everywhere() {
    with_context(|ctx| {
        let mut pager = pager(ctx);
        let keys = insert_line(&mut pager, 0.0, 80);
        pager
            .make_resident(ctx, &keys[..40], &[], DVec3::ZERO)
            .unwrap();
        // New Gaussians come in alone.
        let resident = pager.resident();
        assert_eq!(resident, 40);
        // Residents 0..5 fade out on the GPU.
        let window = pager.window().unwrap();
        let faint: Vec<VoxelKey> = window.keys()[..5].to_vec();
        let mut host = window.params().download(ctx, resident as u64).unwrap();
        host.opacity_logits[..5].fill(-20.0);
        window.params().upload(ctx, 0, &host).unwrap();
        pager.mark_trained();
        // One superseded guess resident, one paged out.
        let superseded: KeySet = [keys[20], keys[60]].into_iter().collect();
        let removed = pager.prune(ctx, &[], superseded, 0.005, 0.5, None).unwrap();
        assert_eq!(removed, 7);
        assert_eq!(pager.global().len(), 73);
        for key in faint.iter().chain([&keys[20], &keys[60]]) {
            assert!(!pager.global().contains(*key));
        }
        check_one_place(&pager);
        assert_eq!(pager.resident(), resident - 6);
        // The rows left are those that were not pruned, each its own.
        let host = pager
            .window()
            .unwrap()
            .params()
            .download(ctx, resident as u64 - 6)
            .unwrap();
        for (row, key) in pager.window().unwrap().keys().iter().enumerate() {
            assert_eq!(host.means[row], pager.global().get(*key).unwrap().mean);
        }
    });
}

/// The pruning scan on the GPU (`glsl/prune_mask.comp`) marks exactly the
/// rows the CPU reference does, on random residents with faint, large
/// and NaN parameters (63 rows: a partial last word), and a scan submitted
/// early is read only for the window and bounds it scanned.
#[test]
fn the_pruning_scan_marks_what_the_reference_does() {
    use latentam_base::random::SplitMix;
    use latentam_reference::prune::prune_mask;
    with_context(|ctx| {
        let mut pager = pager(ctx);
        let keys = insert_line(&mut pager, 0.0, 63);
        pager.make_resident(ctx, &keys, &[], DVec3::ZERO).unwrap();
        let window = pager.window().unwrap();
        let n = window.len();
        assert_eq!(n, 63);
        let mut host = window.params().download(ctx, n as u64).unwrap();
        let mut rng = SplitMix(0x9e3779b9);
        for r in 0..n {
            host.opacity_logits[r] = 12.0 * rng.uniform() - 8.0;
            host.log_scales[r] = [0, 1, 2].map(|_| 3.0 * rng.uniform() - 2.5);
        }
        host.opacity_logits[7] = f32::NAN;
        // Opaque, so that only their scales can mark them.
        host.opacity_logits[8..=10].fill(5.0);
        host.log_scales[8] = [f32::NAN, -3.0, -3.0];
        host.log_scales[9] = [f32::NAN; 3];
        host.log_scales[10] = [f32::NAN, 5.0, f32::NAN];
        window.params().upload(ctx, 0, &host).unwrap();
        for (min_opacity, max_scale) in [(0.005, 0.5), (0.3, 1.5), (0.9, 0.05)] {
            let bounds = prune_bounds(min_opacity, max_scale);
            let mask = prune_mask(&host.log_scales, &host.opacity_logits, bounds.0, bounds.1);
            let want = prune_scan::marked_rows(&mask, n);
            let scan = pager
                .submit_prune_scan(ctx, min_opacity, max_scale)
                .unwrap()
                .unwrap();
            let got = scan.rows(n, bounds).unwrap();
            assert_eq!(got.as_ref(), Some(&want), "bounds {bounds:?}");
            assert!(want.contains(&7) && want.contains(&10), "NaN rules");
            assert!(!want.contains(&8) && !want.contains(&9), "NaN rules");
            assert!(
                !want.is_empty() && want.len() < n,
                "{bounds:?}: some marked"
            );
            // Another window size or other bounds: not read.
            let scan = pager
                .submit_prune_scan(ctx, min_opacity, max_scale)
                .unwrap();
            assert_eq!(scan.unwrap().rows(n - 1, bounds).unwrap(), None);
            let scan = pager
                .submit_prune_scan(ctx, min_opacity, max_scale)
                .unwrap();
            let other = prune_bounds(min_opacity * 0.5, max_scale);
            assert_eq!(scan.unwrap().rows(n, other).unwrap(), None);
        }
        // Bits past the rows stay clear.
        assert_eq!(prune_scan::marked_rows(&[u32::MAX, u32::MAX], 40).len(), 40);
    });
}
