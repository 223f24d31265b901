//! Tests of the per-pixel metrics: against the explicit reference, exact
//! maps and swapped words, device decoding, and inputs of the wrong size.

use rand::Rng;

use super::*;
use crate::mapper::class_iou::mean_iou;
use latentam_gpu::testing::rng;
use latentam_reference::decoder::DecoderShape;
use latentam_reference::metrics as reference;

/// A random decoder and view of `n` pixels: 5 regions, the last
/// without a target, a fifth of the pixels in none; true classes 1..=6,
/// of which the vocabulary names 1..=4.
struct RandomView {
    w: Vec<f32>,
    d: Vec<f32>,
    queries: Vec<[f32; QUERY_DIM]>,
    targets: Vec<f32>,
    region: Vec<u32>,
    truth: Vec<u16>,
    ids: [u16; 4],
    texts: Vec<f32>,
}

fn random_view(r: &mut impl Rng, n: usize, dim: usize, k: usize) -> RandomView {
    let mut values = |count: usize, half: f32| -> Vec<f32> {
        (0..count).map(|_| r.random_range(-half..half)).collect()
    };
    let w = values(QUERY_DIM * dim, 0.5);
    let d = values(k * dim, 1.0);
    let mut targets = values(5 * dim, 1.0);
    targets[4 * dim..].fill(0.0);
    let ids = [1u16, 2, 3, 4];
    let texts = values(ids.len() * dim, 1.0);
    let queries = (0..n)
        .map(|_| std::array::from_fn(|_| r.random_range(-1.0..1.0)))
        .collect();
    let region = (0..n)
        .map(|_| {
            if r.random_bool(0.2) {
                NO_REGION
            } else {
                r.random_range(0..5)
            }
        })
        .collect();
    let truth = (0..n).map(|_| r.random_range(0..7)).collect();
    RandomView {
        w,
        d,
        queries,
        targets,
        region,
        truth,
        ids,
        texts,
    }
}

#[test]
fn per_pixel_metrics_match_the_explicit_reference() {
    let mut r = rng("per_pixel_metrics");
    let (w_px, h_px, dim, k) = (11usize, 7usize, 24usize, 9usize);
    let n = w_px * h_px;
    let RandomView {
        w,
        d,
        queries,
        targets,
        region,
        truth,
        ids,
        texts,
    } = random_view(&mut r, n, dim, k);
    let dec = FactorisedDecoder::new(&w, &d, dim, 0.05, 1e-6).unwrap();
    let inputs = PixelInputs {
        width: w_px,
        height: h_px,
        queries: &queries,
        region: &region,
        targets: &targets,
        truth: &truth,
        vocabulary: Some((&ids, &texts)),
        stride: 1,
    };
    let got = pixel_metrics(&dec, &inputs).unwrap();
    let shape = DecoderShape {
        n,
        query_dim: QUERY_DIM,
        dim,
        atoms: k,
        tau: 0.05,
        eps: 1e-6,
    };
    let flat: Vec<f32> = queries.iter().flatten().copied().collect();
    let want = reference::pixel_metrics(
        &shape,
        &flat,
        &w,
        &d,
        &region,
        &targets,
        &truth,
        Some((&ids, &texts)),
    );
    assert_eq!(got.cosine_pixels, want.cosine_pixels);
    assert!(got.cosine_pixels > 0);
    let tol = 1e-4 * got.cosine_pixels as f64;
    assert!(
        (got.cosine_loss_sum - want.cosine_loss_sum).abs() < tol,
        "{} vs {}",
        got.cosine_loss_sum,
        want.cosine_loss_sum
    );
    let counts: BTreeMap<u16, [u64; 3]> = got
        .class_iou
        .iter()
        .map(|(&c, n)| (c, [n.intersection, n.union, n.truth]))
        .collect();
    assert_eq!(counts, want.classes);
    assert!(
        counts.keys().all(|c| ids.contains(c)),
        "only vocabulary classes"
    );
    // A stride evaluates a subset.
    let half = pixel_metrics(
        &dec,
        &PixelInputs {
            stride: 2,
            ..inputs
        },
    )
    .unwrap();
    assert!(half.cosine_pixels < got.cosine_pixels && half.cosine_pixels > 0);
}

type Atoms = Vec<f32>;

/// The exact scene's W: query channel c decodes to atom c (8-d).
fn exact_w() -> Vec<f32> {
    let dim = 8;
    let mut w = vec![0.0f32; QUERY_DIM * dim];
    for c in 0..4 {
        w[c * dim + c] = 5.0;
    }
    w
}

/// A 4-class scene the map reproduces exactly: class c's pixels render
/// a query that decodes to atom c, which is also the class's target
/// and text embedding.
fn exact_scene() -> (
    FactorisedDecoder,
    Vec<[f32; QUERY_DIM]>,
    Vec<u32>,
    Vec<u16>,
    Atoms,
) {
    let (dim, k) = (8usize, 4usize);
    let mut d = vec![0.0f32; k * dim];
    for c in 0..k {
        d[c * dim + c] = 1.0;
    }
    let dec = FactorisedDecoder::new(&exact_w(), &d, dim, 0.05, 1e-6).unwrap();
    // 4 × 3 pixels: column c is class c + 1 (region c), the last row
    // class 9, which no query word names.
    let (width, height) = (4usize, 3usize);
    let mut queries = Vec::new();
    let mut region = Vec::new();
    let mut truth = Vec::new();
    for y in 0..height {
        for x in 0..width {
            let mut q = [0.0f32; QUERY_DIM];
            q[x] = 1.0;
            queries.push(q);
            region.push(x as u32);
            truth.push(if y == 2 { 9 } else { x as u16 + 1 });
        }
    }
    (dec, queries, region, truth, d)
}

#[test]
fn an_exact_map_scores_perfectly_and_swapped_words_fail_exactly_their_classes() {
    let (dec, queries, region, truth, d) = exact_scene();
    let ids = [1u16, 2, 3, 4];
    let run = |texts: &[f32], truth: &[u16]| {
        pixel_metrics(
            &dec,
            &PixelInputs {
                width: 4,
                height: 3,
                queries: &queries,
                region: &region,
                targets: &d,
                truth,
                vocabulary: Some((&ids, texts)),
                stride: 1,
            },
        )
        .unwrap()
    };
    let exact = run(&d, &truth);
    assert_eq!(exact.cosine_pixels, 12);
    assert!(
        exact.cosine_loss().unwrap() < 1e-6,
        "{:?}",
        exact.cosine_loss()
    );
    assert_eq!(mean_iou(&exact.class_iou), Some(1.0));
    // Class 9's row is not evaluated: the counts are those of a view
    // without it.
    let mut no_nine = truth.clone();
    no_nine.iter_mut().filter(|t| **t == 9).for_each(|t| *t = 0);
    assert_eq!(run(&d, &no_nine).class_iou, exact.class_iou);
    assert!(!exact.class_iou.contains_key(&9));
    // Words 2 and 3 swapped: those two classes fail, the others do not.
    let mut swapped = d.clone();
    let dim = 8;
    for i in 0..dim {
        swapped.swap(dim + i, 2 * dim + i);
    }
    let s = run(&swapped, &truth);
    let iou = |c: u16| s.class_iou[&c].iou();
    assert_eq!((iou(1), iou(2), iou(3), iou(4)), (1.0, 0.0, 0.0, 1.0));
}

#[test]
fn device_decoding_gives_the_host_metrics() {
    let mut r = rng("device_pixel_metrics");
    let (w_px, h_px, dim, k) = (40usize, 30usize, 48usize, 37usize);
    let RandomView {
        w,
        d,
        queries,
        targets,
        mut region,
        truth,
        ids,
        texts,
    } = random_view(&mut r, w_px * h_px, dim, k);
    // Some pixels in region 5, past the targets: no target.
    region.iter_mut().step_by(7).for_each(|g| *g = 5);
    let host = FactorisedDecoder::new(&w, &d, dim, 0.05, 1e-6).unwrap();
    latentam_gpu::testing::with_context(|ctx| {
        let wb = ctx.upload_new("w", &w).unwrap();
        let db = ctx.upload_new("d", &d).unwrap();
        let mut device =
            DevicePixelDecoder::new(ctx, &wb, &db, k as u32, dim as u32, 0.05, 1e-6).unwrap();
        for stride in [1, 3] {
            let inputs = PixelInputs {
                width: w_px,
                height: h_px,
                queries: &queries,
                region: &region,
                targets: &targets,
                truth: &truth,
                vocabulary: Some((&ids, &texts)),
                stride,
            };
            let want = pixel_metrics(&host, &inputs).unwrap();
            let got = pixel_metrics_on_device(ctx, &mut device, &inputs).unwrap();
            assert_eq!(got.cosine_pixels, want.cosine_pixels);
            let tol = 1e-4 * want.cosine_pixels as f64;
            assert!((got.cosine_loss_sum - want.cosine_loss_sum).abs() < tol);
            assert!((got.l2_sum - want.l2_sum).abs() < tol);
            // Classes: the same pixels counted; a near-tie may fall
            // the other way in one decoder's rounding.
            let truths = |m: &PixelMetrics| -> u64 { m.class_iou.values().map(|c| c.truth).sum() };
            assert_eq!(truths(&got), truths(&want));
            let moved: u64 = want
                .class_iou
                .iter()
                .map(|(c, x)| x.intersection.abs_diff(got.class_iou[c].intersection))
                .sum();
            assert!(moved * 200 <= truths(&want), "{moved} pixels changed class");
        }
        // The exact scene scores exactly on the device too.
        let (dec, q, reg, tr, atoms) = exact_scene();
        let wb = ctx.upload_new("w", &exact_w()).unwrap();
        let db = ctx.upload_new("d", &atoms).unwrap();
        let mut device = DevicePixelDecoder::new(ctx, &wb, &db, 4, 8, 0.05, 1e-6).unwrap();
        let inputs = PixelInputs {
            width: 4,
            height: 3,
            queries: &q,
            region: &reg,
            targets: &atoms,
            truth: &tr,
            vocabulary: Some((&ids, &atoms)),
            stride: 1,
        };
        let got = pixel_metrics_on_device(ctx, &mut device, &inputs).unwrap();
        assert_eq!(
            got.class_iou,
            pixel_metrics(&dec, &inputs).unwrap().class_iou
        );
        assert_eq!(mean_iou(&got.class_iou), Some(1.0));
        assert!(got.cosine_loss().unwrap() < 1e-6);
    });
}

#[test]
fn inputs_of_the_wrong_size_are_errors() {
    let (dec, queries, region, truth, d) = exact_scene();
    let v = PixelInputs {
        width: 5,
        height: 3,
        queries: &queries,
        region: &region,
        targets: &d,
        truth: &truth,
        vocabulary: None,
        stride: 1,
    };
    assert!(pixel_metrics(&dec, &v).is_err());
}
