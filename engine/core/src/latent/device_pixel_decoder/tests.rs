use rand::Rng;

use super::*;
use crate::latent::FactorisedDecoder;
use latentam_gpu::testing::{rng, with_context, with_options};
use latentam_gpu::ContextOptions;
use latentam_reference::decoder::{forward, DecoderShape};

/// A random decoder whose atoms lie near directions W can reach, and
/// queries of which some point at one atom (sharp attention, as in a
/// trained map) and the others anywhere (diffuse attention).
struct Case {
    k: usize,
    dim: usize,
    w: Vec<f32>,
    d: Vec<f32>,
    queries: Vec<[f32; QUERY_DIM]>,
    region: Vec<u32>,
    targets: Vec<f32>,
    texts: Vec<f32>,
}

fn case(r: &mut impl Rng, k: usize, dim: usize, n: usize) -> Case {
    let w: Vec<f32> = (0..QUERY_DIM * dim)
        .map(|_| r.random_range(-0.5..0.5))
        .collect();
    // Atom j = c_j W + noise, so that the query c_j decodes close to it.
    let codes: Vec<[f32; QUERY_DIM]> = (0..k)
        .map(|_| std::array::from_fn(|_| r.random_range(-1.0..1.0)))
        .collect();
    let mut d = vec![0.0f32; k * dim];
    for (j, c) in codes.iter().enumerate() {
        for x in 0..dim {
            let v: f32 = (0..QUERY_DIM).map(|i| c[i] * w[i * dim + x]).sum();
            d[j * dim + x] = v + r.random_range(-0.1..0.1);
        }
    }
    let queries = (0..n)
        .map(|i| {
            if i % 2 == 0 {
                let c = &codes[r.random_range(0..k)];
                std::array::from_fn(|x| c[x] * 3.0 + r.random_range(-0.05..0.05))
            } else {
                std::array::from_fn(|_| r.random_range(-1.0..1.0))
            }
        })
        .collect();
    let regions = 6;
    let mut targets: Vec<f32> = (0..regions * dim)
        .map(|_| r.random_range(-1.0..1.0))
        .collect();
    // The last region's target is all zero: it scores 0.
    targets[(regions - 1) * dim..].fill(0.0);
    let region = (0..n)
        .map(|_| {
            if r.random_bool(0.2) {
                NO_REGION
            } else {
                r.random_range(0..regions as u32)
            }
        })
        .collect();
    let texts = (0..5 * dim).map(|_| r.random_range(-1.0..1.0)).collect();
    Case {
        k,
        dim,
        w,
        d,
        queries,
        region,
        targets,
        texts,
    }
}

fn decoder(ctx: &Context, c: &Case) -> DevicePixelDecoder {
    let w = ctx.upload_new("w", &c.w).unwrap();
    let d = ctx.upload_new("d", &c.d).unwrap();
    DevicePixelDecoder::new(ctx, &w, &d, c.k as u32, c.dim as u32, 0.05, 1e-6).unwrap()
}

fn pixels<'a>(c: &'a Case, text_output: TextOutput) -> PixelsToDecode<'a> {
    PixelsToDecode {
        queries: &c.queries,
        region: &c.region,
        targets: &c.targets,
        texts: &c.texts,
        text_output,
    }
}

fn unit(v: &[f32]) -> Vec<f64> {
    let n = v.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt();
    v.iter()
        .map(|&x| if n > 0.0 { x as f64 / n } else { 0.0 })
        .collect()
}

#[test]
fn device_decoding_equals_the_explicit_and_the_factorised_decoder() {
    let mut r = rng("device_pixel_decoding");
    with_context(|ctx| {
        for (k, dim, n) in [(5usize, 24usize, 300usize), (405, 384, 64), (2000, 768, 24)] {
            let c = case(&mut r, k, dim, n);
            let mut dec = decoder(ctx, &c);
            let all = dec.decode(ctx, &pixels(&c, TextOutput::All)).unwrap();
            let best = dec.decode(ctx, &pixels(&c, TextOutput::Best)).unwrap();
            assert_eq!(
                all.norm, best.norm,
                "K = {k}: text output changes nothing else"
            );
            let shape = DecoderShape {
                n,
                query_dim: QUERY_DIM,
                dim,
                atoms: k,
                tau: 0.05,
                eps: 1e-6,
            };
            let flat: Vec<f32> = c.queries.iter().flatten().copied().collect();
            let want = forward(&shape, &flat, &c.w, &c.d);
            let cpu = FactorisedDecoder::new(&c.w, &c.d, dim, 0.05, 1e-6).unwrap();
            let cpu_targets = cpu.project(
                &c.targets
                    .chunks(dim)
                    .flat_map(unit)
                    .map(|x| x as f32)
                    .collect::<Vec<_>>(),
            );
            let texts: Vec<Vec<f64>> = c.texts.chunks(dim).map(unit).collect();
            let (mut a, mut used) = (vec![0.0f32; k], Vec::new());
            for p in 0..n {
                let e = &want.output[p * dim..(p + 1) * dim];
                let norm = e.iter().map(|x| x * x).sum::<f64>().sqrt();
                let tol = 1e-4 * norm.max(1.0);
                assert!(
                    (all.norm[p] as f64 - norm).abs() < tol,
                    "K = {k}, pixel {p}: ‖e‖ {} vs {norm}",
                    all.norm[p]
                );
                let want_dot = match c.region[p] {
                    NO_REGION => 0.0,
                    reg => {
                        let t = unit(&c.targets[reg as usize * dim..(reg as usize + 1) * dim]);
                        e.iter().zip(&t).map(|(x, y)| x * y).sum()
                    }
                };
                assert!(
                    (all.target_dot[p] as f64 - want_dot).abs() < tol,
                    "K = {k}, pixel {p}: ⟨e, t⟩"
                );
                let dots: Vec<f64> = texts
                    .iter()
                    .map(|t| e.iter().zip(t).map(|(x, y)| x * y).sum())
                    .collect();
                for (ci, &wd) in dots.iter().enumerate() {
                    let got = all.text_dots[p * texts.len() + ci] as f64;
                    assert!(
                        (got - wd).abs() < tol,
                        "K = {k}, pixel {p}, text {ci}: {got} vs {wd}"
                    );
                }
                // The best text, unless the explicit decoder's top two are
                // closer than the tolerance.
                let mut order: Vec<usize> = (0..dots.len()).collect();
                order.sort_by(|&x, &y| dots[y].total_cmp(&dots[x]));
                if dots[order[0]] - dots[order[1]] > tol {
                    assert_eq!(
                        best.best_text[p] as usize, order[0],
                        "K = {k}, pixel {p}: best text"
                    );
                }
                // The CPU factorised decoder agrees as closely.
                let q: [f32; QUERY_DIM] = c.queries[p];
                cpu.attention(&q, &mut a);
                let cpu_norm = cpu.norm(&a, &mut used) as f64;
                assert!(
                    (all.norm[p] as f64 - cpu_norm).abs() < tol,
                    "K = {k}, pixel {p}: CPU ‖e‖"
                );
                if c.region[p] != NO_REGION {
                    let reg = c.region[p] as usize;
                    let cpu_dot =
                        FactorisedDecoder::dot(&a, &cpu_targets[reg * k..(reg + 1) * k]) as f64;
                    assert!(
                        (all.target_dot[p] as f64 - cpu_dot).abs() < tol,
                        "K = {k}, pixel {p}: CPU ⟨e, t⟩"
                    );
                }
            }
        }
    });
}

#[test]
fn batches_split_at_the_binding_limit_give_the_same_pixels() {
    let mut r = rng("device_pixel_batches");
    let c = case(&mut r, 405, 64, 1000);
    let mut whole = None;
    with_context(|ctx| {
        let mut dec = decoder(ctx, &c);
        assert!(dec.batch_pixels() as usize >= c.queries.len());
        whole = Some(dec.decode(ctx, &pixels(&c, TextOutput::All)).unwrap());
    });
    let options = ContextOptions {
        max_buffer_bytes: Some(128 << 10),
        ..ContextOptions::default()
    };
    with_options(options, |ctx| {
        let mut dec = decoder(ctx, &c);
        assert!(
            (dec.batch_pixels() as usize) < c.queries.len() / 4,
            "{} pixels a batch",
            dec.batch_pixels()
        );
        let split = dec.decode(ctx, &pixels(&c, TextOutput::All)).unwrap();
        let whole = whole.take().unwrap();
        for (name, a, b) in [
            ("norm", &split.norm, &whole.norm),
            ("target_dot", &split.target_dot, &whole.target_dot),
            ("text_dots", &split.text_dots, &whole.text_dots),
        ] {
            assert_eq!(a.len(), b.len(), "{name}");
            for (x, y) in a.iter().zip(b.iter()) {
                assert!(
                    (x - y).abs() <= 1e-6 * y.abs().max(1.0),
                    "{name}: {x} vs {y}"
                );
            }
        }
    });
}

#[test]
fn bad_pixels_are_errors() {
    let mut r = rng("device_pixel_errors");
    let c = case(&mut r, 7, 16, 10);
    with_context(|ctx| {
        let mut dec = decoder(ctx, &c);
        let good = pixels(&c, TextOutput::Best);
        let far = vec![6u32; 10]; // 6 targets: rows 0..=5
        let mut nan = c.queries.clone();
        nan[3][7] = f32::NAN;
        let bad = [
            PixelsToDecode {
                region: &far,
                ..good
            },
            PixelsToDecode {
                region: &far[..3],
                ..good
            },
            PixelsToDecode {
                texts: &c.texts[..5],
                ..good
            },
            PixelsToDecode {
                queries: &nan,
                ..good
            },
        ];
        for pixels in &bad {
            assert!(dec.decode(ctx, pixels).is_err(), "{pixels:?}");
        }
        assert!(dec.decode(ctx, &good).is_ok());
        let w = ctx.upload_new("w", &c.w).unwrap();
        let d = ctx.upload_new("d", &c.d).unwrap();
        assert!(DevicePixelDecoder::new(ctx, &w, &d, 0, 16, 0.05, 1e-6).is_err());
        assert!(
            DevicePixelDecoder::new(ctx, &w, &d, 8, 16, 0.05, 1e-6).is_err(),
            "more atoms than the buffer holds"
        );
        assert!(DevicePixelDecoder::new(ctx, &w, &d, 7, 16, 0.0, 1e-6).is_err());
    });
}
