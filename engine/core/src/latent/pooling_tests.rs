//! Tests of region pooling: regions from label images, and the pooled rows
//! and their gradients against the f64 reference.

use rand::Rng;

use super::*;
use crate::splat::Camera;
use latentam_gpu::testing::{rng, with_context};
use latentam_reference::pooling as reference;

fn layout(sizes: &[(u32, u32)]) -> BatchLayout {
    let cams: Vec<Camera> = sizes
        .iter()
        .map(|&(w, h)| Camera::at_origin(w, h))
        .collect();
    BatchLayout::for_cameras(&cams).unwrap()
}

fn random_labels(r: &mut impl Rng, w: u32, h: u32, count: u32) -> Vec<u16> {
    (0..w * h)
        .map(|_| {
            if r.random_bool(0.15) {
                NO_REGION_LABEL
            } else {
                r.random_range(0..count) as u16
            }
        })
        .collect()
}

/// A label image as given: labels, width, height, region count.
type LabelInput = (Vec<u16>, u32, u32, u32);

/// Two views of odd sizes, label images coarser and finer than the views.
fn random_regions(r: &mut impl Rng) -> (BatchLayout, Regions, Vec<LabelInput>) {
    let layout = layout(&[(37, 29), (20, 16), (9, 5)]);
    let mut regions = Regions::new(&layout, 5);
    let mut inputs = Vec::new();
    for (view, (lw, lh, count)) in [(13u32, 7u32, 12u32), (40, 32, 9)].into_iter().enumerate() {
        let labels = random_labels(r, lw, lh, count);
        let img = LabelImage {
            width: lw,
            height: lh,
            labels: &labels,
        };
        regions.add_labels(view, img, count).unwrap();
        inputs.push((labels, lw, lh, count));
    }
    (layout, regions, inputs)
}

#[test]
fn regions_follow_the_label_images() {
    let mut r = rng("regions_follow_the_label_images");
    let (layout, regions, inputs) = random_regions(&mut r);
    assert_eq!(regions.rows_per_view().len(), 3);
    assert_eq!(regions.rows_per_view()[2], 0);
    for (vr, (labels, lw, lh, count)) in regions.views().iter().zip(&inputs) {
        let slot = layout.views[vr.view];
        // Label of every view pixel by integer arithmetic: the label
        // pixel whose span contains the pixel centre.
        let mut members = vec![Vec::new(); *count as usize];
        for v in 0..slot.height {
            for u in 0..slot.width {
                let lu = (2 * u + 1) * lw / (2 * slot.width);
                let lv = (2 * v + 1) * lh / (2 * slot.height);
                let l = labels[(lv * lw + lu) as usize];
                if l != NO_REGION_LABEL {
                    members[l as usize].push(slot.first_pixel as u32 + v * slot.width + u);
                }
            }
        }
        let kept: Vec<u32> = (0..*count)
            .filter(|&l| members[l as usize].len() >= 5)
            .collect();
        assert_eq!(vr.sources, kept);
        let small = members
            .iter()
            .filter(|m| !m.is_empty() && m.len() < 5)
            .count();
        let empty = members.iter().filter(|m| m.is_empty()).count();
        assert_eq!((vr.too_small as usize, vr.empty as usize), (small, empty));
        for (i, &src) in vr.sources.iter().enumerate() {
            let row = (vr.first_row + i as u32) as usize;
            let (a, b) = (regions.offsets()[row], regions.offsets()[row + 1]);
            let mut got = regions.pixels()[a as usize..b as usize].to_vec();
            got.sort();
            assert_eq!(got, members[src as usize], "region {src}");
            assert!(got
                .iter()
                .all(|&p| regions.pixel_region()[p as usize] == row as u32));
        }
    }
    let in_regions = regions
        .pixel_region()
        .iter()
        .filter(|&&r| r != NO_REGION)
        .count();
    assert_eq!(in_regions, regions.pixels().len());
}

/// The region of every pixel of a `w × h` view under `source`, by
/// integer arithmetic (the source cell whose span holds the pixel centre).
fn brute_force_regions(source: RegionSource, w: u32, h: u32) -> Vec<u32> {
    let mut out = Vec::new();
    for v in 0..h {
        for u in 0..w {
            out.push(match source {
                RegionSource::Grid { rows, cols } => {
                    ((2 * v + 1) * rows / (2 * h)) * cols + (2 * u + 1) * cols / (2 * w)
                }
                RegionSource::Labels { image, .. } => {
                    let lu = (2 * u + 1) * image.width / (2 * w);
                    let lv = (2 * v + 1) * image.height / (2 * h);
                    match image.labels[(lv * image.width + lu) as usize] {
                        NO_REGION_LABEL => NO_REGION,
                        l => l as u32,
                    }
                }
            });
        }
    }
    out
}

#[test]
fn counted_regions_match_the_pixels_on_random_sizes() {
    let mut r = rng("counted_regions_match_the_pixels_on_random_sizes");
    for _ in 0..200 {
        let (w, h) = (r.random_range(1..70u32), r.random_range(1..50u32));
        let (lw, lh) = (r.random_range(1..90u32), r.random_range(1..60u32));
        let count = r.random_range(1..40u32);
        let min = r.random_range(0..12u32);
        let labels = random_labels(&mut r, lw, lh, count);
        let source = if r.random_bool(0.3) {
            RegionSource::Grid {
                rows: lh.min(9),
                cols: lw.min(9),
            }
        } else {
            RegionSource::Labels {
                image: LabelImage {
                    width: lw,
                    height: lh,
                    labels: &labels,
                },
                count,
            }
        };
        let counts = RegionCounts::of(source, w, h, min).unwrap();
        let truth = brute_force_regions(source, w, h);
        let mut sizes = vec![0u32; source.count() as usize];
        for &l in truth.iter().filter(|&&l| l != NO_REGION) {
            sizes[l as usize] += 1;
        }
        let kept: Vec<u32> = (0..source.count())
            .filter(|&l| sizes[l as usize] >= min.max(1))
            .collect();
        assert_eq!(counts.sources, kept, "{w}x{h} over {lw}x{lh}");
        let kept_sizes: Vec<u32> = kept.iter().map(|&l| sizes[l as usize]).collect();
        assert_eq!(counts.sizes, kept_sizes);
        assert_eq!(
            counts.empty as usize,
            sizes.iter().filter(|&&n| n == 0).count()
        );
        assert_eq!(
            counts.too_small as usize,
            sizes.iter().filter(|&&n| n > 0 && n < min.max(1)).count()
        );
        let mut rows = Vec::new();
        counts
            .for_each_pixel(source, |i, row| {
                assert_eq!(i, rows.len());
                rows.push(row);
            })
            .unwrap();
        let want: Vec<u32> = truth
            .iter()
            .map(|&l| match kept.iter().position(|&k| k == l) {
                Some(row) => row as u32,
                None => NO_REGION,
            })
            .collect();
        assert_eq!(rows, want);

        // The same view second in a batch: its rows without pixels are
        // those of the pixel lists.
        let layout = layout(&[(5, 3), (w, h)]);
        let mut lists = Regions::new(&layout, min);
        lists.add_grid(0, 1, 2).unwrap();
        lists.add(1, source).unwrap();
        let mut without = RegionRows::new(&layout);
        without
            .add(
                0,
                &RegionCounts::of(RegionSource::Grid { rows: 1, cols: 2 }, 5, 3, min).unwrap(),
            )
            .unwrap();
        let view = without.add(1, &counts).unwrap().clone();
        assert_eq!(without.offsets(), lists.offsets());
        assert_eq!(without.views(), lists.views());
        assert_eq!(without.members(), lists.pixels().len() as u64);
        let mut local = Vec::new();
        view.for_each_pixel(w, h, source, |_, row| local.push(row))
            .unwrap();
        assert_eq!(local, rows);
    }
}

#[test]
fn counts_of_another_view_or_source_are_refused() {
    let layout = layout(&[(8, 6)]);
    let grid = RegionSource::Grid { rows: 2, cols: 3 };
    let mut rows = RegionRows::new(&layout);
    let wrong = RegionCounts::of(grid, 6, 8, 1).unwrap();
    assert!(rows.add(0, &wrong).is_err());
    assert!(rows.is_empty() && rows.views().is_empty() && rows.offsets() == [0]);
    let counts = RegionCounts::of(grid, 8, 6, 1).unwrap();
    assert!(rows.add(1, &counts).is_err(), "no view 1");
    rows.add(0, &counts).unwrap();
    assert!(rows.add(0, &counts).is_err(), "view 0 twice");
    assert_eq!(rows.len(), 6);
    // Six regions counted; a source of four cannot be the one.
    let smaller = RegionSource::Grid { rows: 2, cols: 2 };
    assert!(counts.for_each_pixel(smaller, |_, _| {}).is_err());
    let labels = [0u16, 1, 7, NO_REGION_LABEL];
    let bad = RegionSource::Labels {
        image: LabelImage {
            width: 2,
            height: 2,
            labels: &labels,
        },
        count: 3,
    };
    assert!(RegionCounts::of(bad, 8, 6, 1)
        .unwrap_err()
        .to_string()
        .contains("label 7"));
    assert!(RegionCounts::of(RegionSource::Grid { rows: 0, cols: 3 }, 8, 6, 1).is_err());
}

#[test]
fn feature_grid_cells_become_regions() {
    let layout = layout(&[(16, 12)]);
    let mut regions = Regions::new(&layout, 1);
    let v = regions.add_grid(0, 3, 4).unwrap().clone();
    assert_eq!(v.sources, (0..12).collect::<Vec<_>>());
    assert!(regions.offsets().windows(2).all(|w| w[1] - w[0] == 16));
    // Pixel (5, 9) lies in cell row 2, column 1.
    assert_eq!(regions.pixel_region()[9 * 16 + 5], 2 * 4 + 1);
}

#[test]
fn bad_label_images_are_rejected_without_change() {
    let layout = layout(&[(8, 8), (8, 8)]);
    let mut regions = Regions::new(&layout, 1);
    let labels = vec![0u16, 1, 2, 3];
    let img = LabelImage {
        width: 2,
        height: 2,
        labels: &labels,
    };
    let err = regions.add_labels(0, img, 3).unwrap_err().to_string();
    assert!(err.contains("label 3"), "{err}");
    assert!(regions.is_empty() && regions.views().is_empty());
    let short = LabelImage {
        width: 3,
        height: 2,
        labels: &labels,
    };
    assert!(regions.add_labels(0, short, 4).is_err());
    assert!(regions.add_labels(2, img, 4).is_err());
    regions.add_labels(1, img, 4).unwrap();
    assert!(regions.add_labels(0, img, 4).is_err(), "views out of order");
    assert!(regions.add_grid(1, 0, 3).is_err());
}

#[test]
fn pooling_matches_reference_and_its_backward_is_the_adjoint() {
    let mut r = rng("pooling_matches_reference_and_its_backward_is_the_adjoint");
    with_context(|ctx| {
        let (layout, regions, _) = random_regions(&mut r);
        let pixels = layout.pixels as usize;
        let c = QUERY_DIM;
        let image: Vec<f32> = (0..pixels * c).map(|_| r.random_range(-1.0..1.0)).collect();
        let n = regions.len() as usize;
        // Rows 0..first of the pooled rows belong to other chunks of the
        // batch: they must be neither written nor read.
        for first in [0usize, 7] {
            let grad: Vec<f32> = (0..(first + n) * c)
                .map(|i| {
                    if i < first * c {
                        f32::NAN
                    } else {
                        r.random_range(-1.0..1.0)
                    }
                })
                .collect();
            let pool = RegionPooling::new(ctx, 64, layout.pixels).unwrap();
            let ib = ctx.upload_new("test/image", &image).unwrap();
            let gb = ctx.upload_new("test/grad_pooled", &grad).unwrap();
            let gi = Buffer::device(ctx, "test/grad_image", (pixels * c * 4) as u64).unwrap();
            let mut rec = ctx.recorder().unwrap();
            pool.record_upload_at(&mut rec, &regions, first as u32)
                .unwrap();
            rec.fill_u32(pool.pooled(), 0x7fc0_0000);
            rec.fill_u32(&gi, 0x7fc0_0000);
            pool.record_forward(&mut rec, &ib).unwrap();
            pool.record_backward(&mut rec, &gb, &gi).unwrap();
            rec.submit().unwrap().wait().unwrap();
            let all = ctx.download::<f32>(pool.pooled()).unwrap();
            assert!(
                all[..first * c].iter().all(|v| v.is_nan()),
                "rows before {first}"
            );
            let pooled = &all[first * c..(first + n) * c];
            let grad = &grad[first * c..];
            let back = ctx.download::<f32>(&gi).unwrap();
            let want = reference::pool(&image, c, regions.offsets(), regions.pixels());
            let want_back =
                reference::pool_backward(grad, c, regions.offsets(), regions.pixels(), pixels);
            for i in 0..n * c {
                assert!((pooled[i] as f64 - want[i]).abs() < 1e-5, "pooled[{i}]");
            }
            for i in 0..pixels * c {
                assert!((back[i] as f64 - want_back[i]).abs() < 1e-6, "grad[{i}]");
            }
            // <pool(x), y> = <x, pool^T(y)>: the backward is the exact adjoint.
            let lhs: f64 = pooled
                .iter()
                .zip(grad)
                .map(|(&a, &b)| a as f64 * b as f64)
                .sum();
            let rhs: f64 = image
                .iter()
                .zip(&back)
                .map(|(&a, &b)| a as f64 * b as f64)
                .sum();
            assert!(
                (lhs - rhs).abs() <= 1e-4 * lhs.abs().max(1.0),
                "{lhs} vs {rhs}"
            );
        }
    });
}

#[test]
fn oversized_uploads_are_rejected() {
    let mut r = rng("oversized_uploads_are_rejected");
    with_context(|ctx| {
        let (layout, regions, _) = random_regions(&mut r);
        let small = RegionPooling::new(ctx, 2, layout.pixels).unwrap();
        let few_pixels = RegionPooling::new(ctx, 64, 100).unwrap();
        let exact = RegionPooling::new(ctx, regions.len(), layout.pixels).unwrap();
        let mut rec = ctx.recorder().unwrap();
        assert!(small.record_upload(&mut rec, &regions).is_err());
        assert!(few_pixels.record_upload(&mut rec, &regions).is_err());
        assert!(exact.record_upload(&mut rec, &regions).is_ok());
        assert!(exact.record_upload_at(&mut rec, &regions, 1).is_err());
    });
}
