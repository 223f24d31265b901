//! Seeding: on the measured surface once per voxel, thin images, only
//! unexplained pixels, region queries, depth holes filled.

use super::*;
use crate::splat::PixelGrid;
use latentam_base::random::SplitMix;
use latentam_reference::grid::gather_grid;

#[test]
fn seeds_lie_on_the_measured_surface_once_per_voxel() {
    let frame = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    let mut map = GlobalMap::new(0.01);
    let config = SeedingConfig {
        opacity: 0.5,
        scale_factor: 0.5,
        hole_fill_radius: 0,
        border_fill_radius: 0,
        ..SeedingConfig::default()
    };
    let seeds = seed_from_frame(&frame, None, &map, &config, 1, None);
    // Stride 2 from pixel 1: 16 × 12 candidates, minus the 2 × 2 without depth;
    // at 2 m a 2-pixel step is 10 cm, so every candidate has its own voxel.
    assert_eq!(seeds.len(), 16 * 12 - 4);
    for g in &seeds {
        assert!((g.mean[2] - 2.0).abs() < 1e-5, "{:?}", g.mean);
        let u = (g.mean[0] as f64 / 2.0 * 40.0 + 15.5).round() as u32;
        let v = (g.mean[1] as f64 / 2.0 * 40.0 + 11.5).round() as u32;
        assert_eq!(frame.color.rgb(u, v).map(|c| c as f32 / 255.0), g.color);
        // σ = 0.5 × 2 px × 2 m / 40 px = 5 cm; opacity 0.5.
        assert!((g.log_scale[0] - 0.05f32.ln()).abs() < 1e-5);
        assert_eq!(g.opacity_logit, 0.0);
        assert_eq!(g.quat, [1.0, 0.0, 0.0, 0.0]);
        assert!(
            g.query.iter().any(|&q| q != 0.0),
            "queries are never all zero"
        );
    }
    assert_eq!(
        seed_from_frame(&frame, None, &map, &config, 1, None),
        seeds,
        "deterministic"
    );
    for g in &seeds {
        map.insert(*g).unwrap();
    }
    // Everything is now occupied: the same view adds nothing.
    assert!(seed_from_frame(&frame, None, &map, &config, 1, None).is_empty());
}

/// An image thinner than half the seeding stride (one row, one column, a
/// single pixel) still seeds its pixels on the stride grid from its edge.
#[test]
fn images_thinner_than_half_a_stride_are_seeded() {
    let full = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    for (w, h) in [(W, 1), (1, H), (1, 1), (3, 2)] {
        let mut frame = full.clone();
        // The bottom-right corner of the wall, where every pixel has depth.
        let keep = |x: u32, y: u32| x >= W - w && y >= H - h;
        let idx = (0..W * H).filter(|&i| keep(i % W, i / W));
        frame.color.data = idx
            .clone()
            .flat_map(|i| full.color.data[3 * i as usize..3 * i as usize + 3].to_vec())
            .collect();
        frame.depth.data = DepthData::Units {
            values: vec![2000; (w * h) as usize],
            metres_per_unit: 0.001,
        };
        (frame.color.width, frame.color.height) = (w, h);
        (frame.depth.width, frame.depth.height) = (w, h);
        frame.intrinsics.width = w;
        frame.intrinsics.height = h;
        frame.intrinsics.cx = (w as f64 - 1.0) / 2.0;
        frame.intrinsics.cy = (h as f64 - 1.0) / 2.0;
        frame.check().unwrap();
        for stride in [2, 4] {
            let config = SeedingConfig {
                stride,
                hole_fill_radius: 0,
                border_fill_radius: 0,
                ..SeedingConfig::default()
            };
            let map = GlobalMap::new(0.001);
            let seeds = seed_from_frame(&frame, None, &map, &config, 1, None);
            // Candidates from min(stride / 2, side - 1), every stride pixels.
            let count = |side: u32| (side - (stride / 2).min(side - 1)).div_ceil(stride);
            assert_eq!(
                seeds.len() as u32,
                count(w) * count(h),
                "{w}×{h}, stride {stride}"
            );
        }
    }
}

/// Seeding reads the render only at its candidate pixels, so a render read
/// back at those alone (what the mapper reads back) seeds exactly what the
/// whole image does, at any stride.
#[test]
fn a_render_of_the_candidate_pixels_alone_seeds_what_the_whole_image_does() {
    let frame = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    let map = GlobalMap::new(0.01);
    let n = (W * H) as usize;
    let mut rng = SplitMix(0x5eed_c0fe);
    // Random coverage: about half the pixels explained (alpha near 1,
    // depth near the wall's 2 m), the rest holes, faint or misplaced.
    let alpha: Vec<f32> = (0..n).map(|_| rng.uniform()).collect();
    let depth: Vec<f32> = alpha
        .iter()
        .map(|&a| a * (1.8 + 0.4 * rng.uniform()))
        .collect();
    for stride in [1, 2, 3, 5] {
        let config = SeedingConfig {
            stride,
            ..SeedingConfig::default()
        };
        let k = frame.intrinsics;
        let grid = config.candidate_grid(0.5 * (k.fx + k.fy), W, H);
        let (cols, cells) = (grid.cols(W), grid.cells(W, H) as u32);
        let whole = ViewCoverage {
            grid: PixelGrid::ALL,
            alpha: &alpha,
            depth: &depth,
            partial: false,
            complete_within: None,
            exposure: 1.0,
        };
        let grid_alpha = gather_grid(&alpha, W, grid.stride, grid.start, cols, cells);
        let grid_depth = gather_grid(&depth, W, grid.stride, grid.start, cols, cells);
        let candidates = ViewCoverage {
            grid,
            alpha: &grid_alpha,
            depth: &grid_depth,
            ..whole
        };
        let want = seed_from_frame(&frame, Some(whole), &map, &config, 3, None);
        let got = seed_from_frame(&frame, Some(candidates), &map, &config, 3, None);
        assert!(!want.is_empty(), "stride {stride}: something to seed");
        assert!(
            want.len() < cells as usize,
            "stride {stride}: some candidates explained"
        );
        assert_eq!(got, want, "stride {stride}");
    }
}

#[test]
fn only_unexplained_pixels_are_seeded_and_new_seeds_inherit_neighbour_queries() {
    let frame = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    let map = GlobalMap::new(0.01);
    let n = (W * H) as usize;
    // The map explains the left half (alpha 1, depth right), not the right
    // half (alpha 0), and gets the depth wrong in the bottom rows.
    let alpha: Vec<f32> = (0..n)
        .map(|i| if (i as u32 % W) < W / 2 { 1.0 } else { 0.0 })
        .collect();
    let depth: Vec<f32> = (0..n)
        .map(|i| {
            if i as u32 / W >= H - 4 {
                3.0 * alpha[i]
            } else {
                2.0 * alpha[i]
            }
        })
        .collect();
    let rendered = ViewCoverage {
        grid: PixelGrid::ALL,
        partial: false,
        complete_within: None,
        alpha: &alpha,
        depth: &depth,
        exposure: 1.0,
    };
    let seeds = seed_from_frame(
        &frame,
        Some(rendered),
        &map,
        &SeedingConfig::default(),
        1,
        None,
    );
    // Right half: 8 × 12 candidates; left half bottom 4 rows: 8 × 2.
    assert_eq!(seeds.len(), 8 * 12 + 8 * 2);
    // A frame taken at twice the map's exposure seeds the colours the map
    // holds at its own: halved.
    let brighter = ViewCoverage {
        exposure: 2.0,
        ..rendered
    };
    let config = SeedingConfig::default();
    let dimmed = seed_from_frame(&frame, Some(brighter), &map, &config, 1, None);
    assert_eq!(dimmed.len(), seeds.len());
    for (d, s) in dimmed.iter().zip(&seeds) {
        assert_eq!(d.mean, s.mean);
        for c in 0..3 {
            assert!((2.0 * d.color[c] - s.color[c]).abs() < 1e-6);
        }
    }

    // A dense wall (stride 1 at 0.4 m: 1 cm between pixels): seeds next to
    // existing Gaussians copy their query.
    let near = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 400);
    let dense = SeedingConfig {
        stride: 4,
        refill_alpha: 1.0,
        ..SeedingConfig::default()
    };
    let mut map = GlobalMap::new(0.01);
    let first = seed_from_frame(&near, None, &map, &dense, 1, None);
    for g in &first {
        map.insert(*g).unwrap();
    }
    let moved = wall_frame(DVec3::new(0.011, 0.0, 0.0), DQuat::IDENTITY, 400);
    let second = seed_from_frame(&moved, None, &map, &dense, 2, None);
    assert!(!second.is_empty());
    for g in &second {
        let key = map.key_of(DVec3::from(g.mean.map(f64::from))).unwrap();
        if let Some(n) = key.neighbourhood().find_map(|k| map.get(k)) {
            assert_eq!(g.query, n.query);
        }
    }
}

#[test]
fn mapped_surface_beyond_the_window_is_not_seeded_again() {
    // A wall 0.6 m away (seeds 3 cm apart), mapped from one pose; seen
    // again from 1.5 cm aside (new pixels land in new voxels) with nothing
    // rendered (alpha 0).
    let config = SeedingConfig::default();
    let mut map = GlobalMap::new(0.01);
    let first = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 600);
    for g in seed_from_frame(&first, None, &map, &config, 1, None) {
        map.insert(g).unwrap();
    }
    let again = wall_frame(DVec3::new(0.015, 0.0, 0.0), DQuat::IDENTITY, 600);
    let n = (W * H) as usize;
    let (alpha, depth) = (vec![0.0f32; n], vec![0.0f32; n]);
    let coverage = |complete_within| ViewCoverage {
        grid: PixelGrid::ALL,
        alpha: &alpha,
        depth: &depth,
        partial: false,
        complete_within,
        exposure: 1.0,
    };
    // The render held everything within 5 m: the wall is unexplained there,
    // so it is seeded (holes in a complete render are real).
    let inside = Some((DVec3::ZERO, 5.0));
    let reseeded = seed_from_frame(&again, Some(coverage(inside)), &map, &config, 2, None).len();
    assert!(reseeded > 50, "{reseeded}");
    // Only what is within 0.3 m was resident: the wall's Gaussians may be
    // paged out, and its surface is mapped, so only the strip the first
    // view did not see (past its edge) is seeded.
    let outside = Some((DVec3::ZERO, 0.3));
    let seeded = seed_from_frame(&again, Some(coverage(outside)), &map, &config, 2, None);
    assert!(
        seeded.len() * 5 < reseeded,
        "{} of {reseeded}",
        seeded.len()
    );
    let edge = (W as f64 / 2.0) / 40.0 * 0.6;
    assert!(seeded.iter().all(|g| g.mean[0] as f64 > edge - 0.04));
    // A render that covers it but with the wrong depth (alpha 0.6, above
    // `refill_alpha`) is not a hole: mapped surface is not seeded again,
    // rendered or not.
    assert!(config.refill_alpha <= 0.6);
    let faint = vec![0.6f32; n];
    let partly = ViewCoverage {
        grid: PixelGrid::ALL,
        alpha: &faint,
        depth: &depth,
        partial: false,
        complete_within: inside,
        exposure: 1.0,
    };
    let again_seeded = seed_from_frame(&again, Some(partly), &map, &config, 2, None);
    assert_eq!(again_seeded.len(), seeded.len());
}

#[test]
fn seeds_in_a_region_start_from_its_query_and_others_as_before() {
    let frame = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    let map = GlobalMap::new(0.01);
    let config = SeedingConfig::default();
    // A 4 × 3 label image over the 32 × 24 view: region 0 is the left
    // half, region 1 (no query: e.g. a zero embedding) the top right
    // quarter, the rest no region.
    let labels = [0, 0, 1, 1, 0, 0, 9, 9, 0, 0, 9, 9];
    let q0 = [0.5f32; crate::splat::QUERY_DIM];
    let queries = [Some(q0), None];
    let regions = RegionQueries {
        width: 4,
        height: 3,
        labels: &labels,
        queries: &queries,
    };
    let plain = seed_from_frame(&frame, None, &map, &config, 1, None);
    let seeded = seed_from_frame(&frame, None, &map, &config, 1, Some(&regions));
    assert_eq!(plain.len(), seeded.len());
    let mut from_region = 0;
    for (a, b) in plain.iter().zip(&seeded) {
        assert_eq!(a.mean, b.mean);
        let u = (b.mean[0] as f64 / 2.0 * 40.0 + 15.5).round();
        if u < 16.0 {
            assert_eq!(b.query, q0, "left half: region 0's query");
            from_region += 1;
        } else {
            assert_eq!(a.query, b.query, "no query for this pixel: as before");
        }
    }
    assert_eq!(from_region, 8 * 12, "with the borrowed-depth pixels");
}

#[test]
fn pixels_without_depth_borrow_it_from_the_nearest_ring_within_the_radius() {
    // The top-left 4 × 4 block has no depth. Its candidates (stride 2 from
    // pixel 1) are (1, 1), (3, 1), (1, 3) and (3, 3): the last three have
    // valid depth one pixel away, (1, 1) only three pixels away.
    let frame = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    let map = GlobalMap::new(0.01);
    // (The block touches the image's corner: a border hole too.)
    let with = |radius| SeedingConfig {
        hole_fill_radius: radius,
        border_fill_radius: radius,
        ..SeedingConfig::default()
    };
    let count = |radius| seed_from_frame(&frame, None, &map, &with(radius), 1, None).len();
    assert_eq!(count(0), 16 * 12 - 4);
    assert_eq!(count(1), 16 * 12 - 1);
    assert_eq!(count(2), 16 * 12 - 1);
    assert_eq!(count(3), 16 * 12);
    for g in seed_from_frame(&frame, None, &map, &with(3), 1, None) {
        assert!((g.mean[2] - 2.0).abs() < 1e-5, "on the wall: {:?}", g.mean);
    }
    // The median of the ring: a hole ringed by three pixels at 1 m and
    // five at 3 m takes 3 m.
    let mut frame = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 3000);
    if let latentam_io::DepthData::Units { values, .. } = &mut frame.depth.data {
        for y in 0..H {
            for x in 0..W {
                let i = (y * W + x) as usize;
                if (10..=12).contains(&x) && (10..=12).contains(&y) {
                    values[i] = if (x, y) == (11, 11) {
                        0
                    } else if y == 10 {
                        1000
                    } else {
                        3000
                    };
                }
            }
        }
    }
    let at_hole = seed_from_frame(&frame, None, &map, &with(1), 1, None)
        .into_iter()
        .find(|g| {
            let u = g.mean[0] as f64 / g.mean[2] as f64 * 40.0 + 15.5;
            let v = g.mean[1] as f64 / g.mean[2] as f64 * 40.0 + 11.5;
            (u - 11.0).abs() < 1e-3 && (v - 11.0).abs() < 1e-3
        })
        .expect("the hole pixel is seeded");
    assert!((at_hole.mean[2] - 3.0).abs() < 1e-5, "{:?}", at_hole.mean);
}

#[test]
fn holes_that_reach_the_image_edge_are_filled_further_than_inner_ones() {
    // No depth in the 12 rightmost columns, as where registered depth does
    // not reach the colour camera's border.
    let mut frame = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    if let DepthData::Units { values, .. } = &mut frame.depth.data {
        for (i, v) in values.iter_mut().enumerate() {
            if i as u32 % W >= W - 12 {
                *v = 0;
            }
        }
    }
    let map = GlobalMap::new(0.01);
    let seeds = |border_fill_radius| {
        let config = SeedingConfig {
            stride: 1,
            hole_fill_radius: 4,
            border_fill_radius,
            ..SeedingConfig::default()
        };
        seed_from_frame(&frame, None, &map, &config, 1, None)
    };
    // Filled up to 4 columns into the band as an inner hole would be...
    let inner = seeds(0);
    assert_eq!(inner.len(), (W * H - 8 * H) as usize);
    // ... and all the way with the border's radius, on the wall's plane.
    let border = seeds(32);
    assert_eq!(border.len(), (W * H) as usize);
    assert!(border.iter().all(|g| (g.mean[2] - 2.0).abs() < 1e-4));
}
