//! Tests of the attention decoder: against the f64 reference, gradients
//! against finite differences of the GPU forward, no regions, bad sizes.

use rand::Rng;

use super::*;
use latentam_gpu::testing::{rng, with_context};
use latentam_reference::decoder as reference;

struct Problem {
    n: usize,
    atoms: usize,
    dim: usize,
    tau: f32,
    q: Vec<f32>,
    w: Vec<f32>,
    d: Vec<f32>,
    /// ∂L/∂F̂.
    g: Vec<f32>,
}

impl Problem {
    /// Random queries and projection; half of the atoms are noisy copies
    /// of the projected queries' directions so that some attention rows
    /// are peaked (logits near 1/τ) and others flat.
    fn random(r: &mut impl Rng, n: usize, atoms: usize, dim: usize, tau: f32) -> Self {
        let s = QUERY_DIM;
        let q: Vec<f32> = (0..n * s).map(|_| r.random_range(-1.0..1.0)).collect();
        let w: Vec<f32> = (0..s * dim).map(|_| r.random_range(-1.0..1.0)).collect();
        let mut d: Vec<f32> = (0..atoms * dim)
            .map(|_| r.random_range(-1.0..1.0))
            .collect();
        for i in 0..n.min(atoms / 2) {
            let e: Vec<f64> = (0..dim)
                .map(|j| {
                    (0..s)
                        .map(|p| q[i * s + p] as f64 * w[p * dim + j] as f64)
                        .sum()
                })
                .collect();
            let norm = e.iter().map(|v| v * v).sum::<f64>().sqrt();
            for j in 0..dim {
                d[i * dim + j] = (e[j] / norm) as f32 * 3.0
                    + 0.3 * r.random_range(-1.0f32..1.0) / (dim as f32).sqrt();
            }
        }
        let g = (0..n * dim).map(|_| r.random_range(-1.0..1.0)).collect();
        Self {
            n,
            atoms,
            dim,
            tau,
            q,
            w,
            d,
            g,
        }
    }

    fn shape(&self) -> reference::DecoderShape {
        reference::DecoderShape {
            n: self.n,
            query_dim: QUERY_DIM,
            dim: self.dim,
            atoms: self.atoms,
            tau: self.tau as f64,
            eps: 1e-6,
        }
    }
}

struct GpuResult {
    output: Vec<f32>,
    grad_q: Vec<f32>,
    grad_w: Vec<f32>,
    grad_d: Vec<f32>,
}

fn run(ctx: &Context, p: &Problem) -> GpuResult {
    let cfg = DecoderConfig {
        max_regions: p.n.max(1) as u32,
        max_atoms: p.atoms as u32,
        dim: p.dim as u32,
        temperature: p.tau,
        eps: 1e-6,
    };
    let dec = AttentionDecoder::new(ctx, cfg).unwrap();
    let q = ctx.upload_new("test/q", &p.q).unwrap();
    let w = ctx.upload_new("test/w", &p.w).unwrap();
    let d = ctx.upload_new("test/d", &p.d).unwrap();
    let g = ctx.upload_new("test/g", &p.g).unwrap();
    let (n, k, df) = (p.n as u64, p.atoms as u64, p.dim as u64);
    let gq = Buffer::device(ctx, "test/gq", (n.max(1) * QUERY_DIM as u64) * 4).unwrap();
    let gw = Buffer::device(ctx, "test/gw", QUERY_DIM as u64 * df * 4).unwrap();
    let gd = Buffer::device(ctx, "test/gd", k * df * 4).unwrap();
    let params = DecoderParams {
        w: &w,
        atoms: &d,
        atom_count: p.atoms as u32,
    };
    let mut rec = ctx.recorder().unwrap();
    for b in [dec.output(), &gq, &gw, &gd] {
        rec.fill_u32(b, 0x7fc0_0000); // NaN: every output must be written
    }
    dec.record_forward(&mut rec, params, &q, p.n as u32)
        .unwrap();
    let grads = DecoderGrads {
        queries: Some(&gq),
        w: &gw,
        atoms: &gd,
    };
    dec.record_backward(&mut rec, params, &q, p.n as u32, &g, grads)
        .unwrap();
    rec.submit().unwrap().wait().unwrap();
    let take = |b: &Buffer, len: u64| ctx.download::<f32>(b).unwrap()[..len as usize].to_vec();
    GpuResult {
        output: take(dec.output(), n * df),
        grad_q: take(&gq, n * QUERY_DIM as u64),
        grad_w: take(&gw, QUERY_DIM as u64 * df),
        grad_d: take(&gd, k * df),
    }
}

/// max |got − want| ≤ rel · max(max |want|, floor).
fn assert_close(what: &str, got: &[f32], want: &[f64], rel: f64, floor: f64) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = max_abs(want).max(floor).max(1e-12);
    for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g as f64 - w).abs() <= rel * scale,
            "{what}[{i}] = {g}, want {w} (tolerance {})",
            rel * scale
        );
    }
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

#[test]
fn decoder_matches_reference_on_random_shapes() {
    let mut r = rng("decoder_matches_reference_on_random_shapes");
    with_context(|ctx| {
        let mut shapes = vec![
            (1usize, 1usize, 64usize, 0.05f32),
            (7, 37, 65, 0.05),
            (200, 300, 768, 0.05),
            (33, 130, 129, 0.2),
            (20, 50, 1536, 0.05),
        ];
        shapes.push((
            r.random_range(1..80),
            r.random_range(1..200),
            r.random_range(64..300),
            0.05,
        ));
        for (n, atoms, dim, tau) in shapes {
            let p = Problem::random(&mut r, n, atoms, dim, tau);
            let got = run(ctx, &p);
            let s = p.shape();
            let fwd = reference::forward(&s, &p.q, &p.w, &p.d);
            let g: Vec<f64> = p.g.iter().map(|&v| v as f64).collect();
            let want = reference::backward(&s, &p.q, &p.w, &p.d, &fwd, &g);
            let case = format!("n={n} K={atoms} d_f={dim} tau={tau}");
            assert_close(&format!("{case}: F"), &got.output, &fwd.output, 1e-4, 1e-6);
            // ∂L/∂D = Aᵀ·∂L/∂F̂ is the direct path; ∂L/∂Q and ∂L/∂W pass
            // through the 1/τ softmax backward, which nearly vanishes
            // when the attention saturates, leaving them tiny and their
            // f32 rounding (set by the upstream scale) large relative
            // to them. Their tolerance is therefore relative to the
            // larger of their own size and 1e-4 of ∂L/∂D's (seen: max
            // ∂L/∂Q 4e-6 against ∂L/∂D 1 at n=7, K=37, d_f=65, with
            // errors up to 9e-8). Unsaturated shapes keep the check
            // tight, and finite differences check ∂L/∂Q separately.
            let upstream = 1e-4 * max_abs(&want.d);
            assert_close(
                &format!("{case}: dQ"),
                &got.grad_q,
                &want.queries,
                5e-3,
                upstream,
            );
            assert_close(&format!("{case}: dW"), &got.grad_w, &want.w, 5e-3, upstream);
            assert_close(&format!("{case}: dD"), &got.grad_d, &want.d, 5e-3, 1e-6);
        }
    });
}

/// The GPU gradient against central differences of the GPU forward pass,
/// along a random direction of each parameter (a directional derivative
/// averages out f32 rounding that single-entry differences would not).
#[test]
fn decoder_gradients_match_gpu_finite_differences() {
    let mut r = rng("decoder_gradients_match_gpu_finite_differences");
    with_context(|ctx| {
        let p = Problem::random(&mut r, 9, 40, 96, 0.05);
        let base = run(ctx, &p);
        let loss = |p: &Problem| -> f64 {
            let out = run(ctx, p).output;
            out.iter()
                .zip(&p.g)
                .map(|(&a, &b)| a as f64 * b as f64)
                .sum()
        };
        for which in ["Q", "W", "D"] {
            let (values, grad) = match which {
                "Q" => (&p.q, &base.grad_q),
                "W" => (&p.w, &base.grad_w),
                _ => (&p.d, &base.grad_d),
            };
            let dir: Vec<f32> = (0..values.len())
                .map(|_| r.random_range(-1.0..1.0))
                .collect();
            let analytic: f64 = grad
                .iter()
                .zip(&dir)
                .map(|(&g, &u)| g as f64 * u as f64)
                .sum();
            let h = 2e-3f32;
            let shifted = |sign: f32| {
                let mut q = Problem {
                    q: p.q.clone(),
                    w: p.w.clone(),
                    d: p.d.clone(),
                    g: p.g.clone(),
                    ..p
                };
                let v = match which {
                    "Q" => &mut q.q,
                    "W" => &mut q.w,
                    _ => &mut q.d,
                };
                for (x, u) in v.iter_mut().zip(&dir) {
                    *x += sign * h * u;
                }
                loss(&q)
            };
            let fd = (shifted(1.0) - shifted(-1.0)) / (2.0 * h as f64);
            assert!(
                (fd - analytic).abs() <= 0.02 * analytic.abs().max(fd.abs()) + 1e-2,
                "{which}: directional derivative {analytic} vs finite difference {fd}"
            );
        }
    });
}

#[test]
fn no_regions_give_zero_parameter_gradients() {
    with_context(|ctx| {
        let mut r = rng("no_regions_give_zero_parameter_gradients");
        let p = Problem::random(&mut r, 0, 5, 64, 0.05);
        let got = run(ctx, &p);
        assert!(got.grad_w.iter().all(|&v| v == 0.0));
        assert!(got.grad_d.iter().all(|&v| v == 0.0));
    });
}

#[test]
fn bad_sizes_are_rejected() {
    with_context(|ctx| {
        let cfg = DecoderConfig {
            max_regions: 4,
            max_atoms: 8,
            dim: 64,
            ..Default::default()
        };
        assert!(AttentionDecoder::new(
            ctx,
            DecoderConfig {
                temperature: 0.0,
                ..cfg
            }
        )
        .is_err());
        assert!(AttentionDecoder::new(ctx, DecoderConfig { dim: 0, ..cfg }).is_err());
        let dec = AttentionDecoder::new(ctx, cfg).unwrap();
        let b = Buffer::device(ctx, "test/b", 4 * 64 * 32).unwrap();
        let mut rec = ctx.recorder().unwrap();
        let p = |atom_count| DecoderParams {
            w: &b,
            atoms: &b,
            atom_count,
        };
        assert!(dec.record_forward(&mut rec, p(0), &b, 4).is_err());
        assert!(dec.record_forward(&mut rec, p(9), &b, 4).is_err());
        assert!(dec.record_forward(&mut rec, p(8), &b, 5).is_err());
    });
}
