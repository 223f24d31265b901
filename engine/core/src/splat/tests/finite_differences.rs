//! Gradients against finite differences: the reference's own, and the
//! GPU's against its forward.

use super::*;

/// Σ upstream · outputs, in f64, for a rendered batch.
fn linear_loss(images: &[reference::Image], up: &[ImageGrads]) -> f64 {
    let mut l = 0.0;
    for (img, g) in images.iter().zip(up) {
        for i in 0..img.alpha.len() {
            l += img.alpha[i] * g.alpha[i];
            for k in 0..CHANNELS {
                l += img.channels[i][k] * g.channels[i][k];
            }
        }
    }
    l
}

/// Parameter `k` (0..49 over all kinds) of a Gaussian, mutably.
fn param(g: &mut Gaussian, k: usize) -> &mut f64 {
    match k {
        0..=2 => &mut g.mean[k],
        3..=5 => &mut g.log_scale[k - 3],
        6..=9 => &mut g.quat[k - 6],
        10..=12 => &mut g.color[k - 10],
        13 => &mut g.opacity_logit,
        _ => &mut g.query[k - 14],
    }
}

/// The same parameter of a host set.
fn param_f32(h: &mut HostGaussians, gi: usize, k: usize) -> &mut f32 {
    match k {
        0..=2 => &mut h.means[gi][k],
        3..=5 => &mut h.log_scales[gi][k - 3],
        6..=9 => &mut h.quats[gi][k - 6],
        10..=12 => &mut h.colors[gi][k - 10],
        13 => &mut h.opacity_logits[gi],
        _ => &mut h.queries[gi][k - 14],
    }
}

const PARAMS: usize = 14 + QUERY_DIM;

#[test]
fn reference_backward_matches_its_finite_differences() {
    let mut r = rng("reference_backward_matches_its_finite_differences");
    let cams: Vec<Camera> = [(24, 20), (19, 17)]
        .iter()
        .map(|&(w, h)| random_camera(&mut r, w, h, 3.0))
        .collect();
    let host = random_gaussians(&mut r, 40, (-2.5, -1.2), (-1.0, 3.0));
    let gs = Gaussian::all(&host);
    let bg = [0.2, 0.4, 0.6];
    let up = random_upstream(&mut r, &cams);
    let render_all = |gs: &[Gaussian]| -> Vec<reference::Image> {
        cams.iter().map(|c| reference::render(gs, c, bg)).collect()
    };
    // With the query gradients detached, geometry sees the loss without the
    // query channels.
    let mut up_geom = up.clone();
    for g in &mut up_geom {
        for c in &mut g.channels {
            c[4..].iter_mut().for_each(|v| *v = 0.0);
        }
    }
    for detach in [false, true] {
        let grads = reference::backward(&gs, &cams, bg, &up, detach).grads;
        // A step can still move a pixel across the 1/255 cut-off, a jump the
        // analytic gradient rightly ignores; it is rare at this step, so a
        // couple of the ~3000 entries may disagree.
        let h = 1e-6;
        let mut outliers = Vec::new();
        let mut checked = 0;
        for gi in 0..gs.len() {
            if !cams
                .iter()
                .any(|c| reference::project(&gs[gi], c).is_some())
            {
                continue;
            }
            checked += 1;
            for k in 0..PARAMS {
                let geometry = !(10..=12).contains(&k) && k < 14;
                let loss_up = if detach && geometry { &up_geom } else { &up };
                let central = |h: f64| {
                    let mut plus = gs.clone();
                    *param(&mut plus[gi], k) += h;
                    let mut minus = gs.clone();
                    *param(&mut minus[gi], k) -= h;
                    (linear_loss(&render_all(&plus), loss_up)
                        - linear_loss(&render_all(&minus), loss_up))
                        / (2.0 * h)
                };
                let fd = central(h);
                let mut g = grads[gi];
                let an = *param(&mut g, k);
                let disagrees = |fd: f64| (fd - an).abs() > 1e-5 + 1e-4 * fd.abs().max(an.abs());
                // A jump within the step (a cut-off or a depth-order swap)
                // adds jump / 2h to the difference: a step ten times shorter
                // either leaves it out (and agrees) or makes it ten times
                // larger. A wrong gradient does neither.
                let jump = disagrees(fd) && {
                    let fine = central(h / 10.0);
                    !disagrees(fine) || fine.abs() > 3.0 * fd.abs()
                };
                if disagrees(fd) && !jump {
                    outliers.push(format!(
                        "Gaussian {gi} parameter {k}: finite difference {fd}, analytic {an}"
                    ));
                }
            }
        }
        assert!(
            outliers.len() <= 2,
            "detach={detach}: {} gradients disagree with finite differences:\n{}",
            outliers.len(),
            outliers.join("\n")
        );
        assert!(checked > 10, "too few visible Gaussians ({checked})");
    }
}

#[test]
fn backward_matches_finite_differences_of_the_gpu_forward() {
    with_context(|ctx| {
        let mut r = rng("backward_matches_finite_differences_of_the_gpu_forward");
        let cams: Vec<Camera> = [(32, 24), (27, 21)]
            .iter()
            .map(|&(w, h)| random_camera(&mut r, w, h, 3.0))
            .collect();
        // Few, large, fairly opaque Gaussians: smooth in their parameters
        // apart from the 1/255 fringe, whose effect stays around 1 %.
        let n = 12;
        let host = random_gaussians(&mut r, n, (-1.6, -1.0), (0.5, 1.5));
        // Geometry is checked on RGB, depth and alpha alone: fewer channels,
        // smaller cut-off jumps and less f32 noise. (The query channels' path
        // to geometry is checked against the reference, itself checked
        // against finite differences.)
        let up_full = random_upstream(&mut r, &cams);
        let mut up_geom = up_full.clone();
        for g in &mut up_geom {
            for c in &mut g.channels {
                c[4..].iter_mut().for_each(|v| *v = 0.0);
            }
        }
        let buf = upload(ctx, &host);
        let grads = GaussianBuffers::new(ctx, "test_grads", n as u64).unwrap();
        let mut raster = Rasterizer::new(ctx);
        raster.settings.detach_query_gradients = false;
        let mut analytic_for = |up: &[ImageGrads]| {
            raster.forward(&buf, n as u64, &cams).unwrap();
            upload_upstream(ctx, &raster, up);
            raster.backward(&buf, &grads).unwrap();
            Gaussian::all(&grads.download(ctx, n as u64).unwrap())
        };
        let analytic_full = analytic_for(&up_full);
        let analytic_geom = analytic_for(&up_geom);

        let gpu_loss = |raster: &mut Rasterizer, h: &HostGaussians, up: &[ImageGrads]| -> f64 {
            buf.upload(ctx, 0, h).unwrap();
            raster.forward(&buf, n as u64, &cams).unwrap();
            let imgs: Vec<reference::Image> = (0..cams.len())
                .map(|v| {
                    let d = raster.download_view(v).unwrap();
                    reference::Image {
                        width: d.width,
                        height: d.height,
                        channels: d
                            .rgbd
                            .iter()
                            .zip(&d.query)
                            .map(|(c, q)| {
                                let mut out = [0.0; CHANNELS];
                                for k in 0..4 {
                                    out[k] = c[k] as f64;
                                }
                                for k in 0..QUERY_DIM {
                                    out[4 + k] = q[k] as f64;
                                }
                                out
                            })
                            .collect(),
                        alpha: d.alpha.iter().map(|&a| a as f64).collect(),
                    }
                })
                .collect();
            linear_loss(&imgs, up)
        };
        // The loss jumps where a pixel crosses the 1/255 alpha cut-off or two
        // Gaussians swap depth order; the analytic gradient rightly ignores
        // those jumps, so steps stay small (f32 forward passes are precise
        // enough for that) and a few entries may still straddle a jump.
        // Colour and query do not move any cut-off: all must agree.
        let steps = [2e-5f32, 5e-5, 1e-4, 1e-3, 2e-4, 1e-3];
        let ranges = [0..3, 3..6, 6..10, 10..13, 13..14, 14..PARAMS];
        let names = [
            "mean",
            "log_scale",
            "quat",
            "color",
            "opacity_logit",
            "query",
        ];
        for (kind, (range, h)) in ranges.into_iter().zip(steps).enumerate() {
            let geometry = ![3, 5].contains(&kind);
            let (up, analytic) = if geometry {
                (&up_geom, &analytic_geom)
            } else {
                (&up_full, &analytic_full)
            };
            let mut fd = Vec::new();
            let mut an = Vec::new();
            for gi in 0..n {
                for k in range.clone() {
                    let mut plus = host.clone();
                    let mut minus = host.clone();
                    *param_f32(&mut plus, gi, k) += h;
                    *param_f32(&mut minus, gi, k) -= h;
                    let (xp, xm) = (*param_f32(&mut plus, gi, k), *param_f32(&mut minus, gi, k));
                    let lp = gpu_loss(&mut raster, &plus, up);
                    let lm = gpu_loss(&mut raster, &minus, up);
                    // The step actually taken, after f32 rounding.
                    fd.push((lp - lm) / (xp as f64 - xm as f64));
                    let mut g = analytic[gi];
                    an.push(*param(&mut g, k));
                }
            }
            let rms = (an.iter().map(|a| a * a).sum::<f64>() / an.len() as f64).sqrt();
            // Entries far off are jumps (or a broken term, if many); on the
            // rest, the least-squares slope of analytic against finite
            // differences must be 1, which averages the f32 noise out and
            // catches a gradient that is off by 5 % or more. Agreeing entries
            // are within ~3 % plus f32 noise of ~1 % of the RMS; a jump that
            // stayed below the cut would dominate the slope (a Gaussian whose
            // footprint crosses the alpha cut-off is 30-60 % off), so the cut
            // sits well under that.
            let far: Vec<usize> = (0..an.len())
                .filter(|&i| {
                    (an[i] - fd[i]).abs() > 0.1 * an[i].abs().max(fd[i].abs()) + 0.05 * rms
                })
                .collect();
            let allowed = if geometry { an.len() / 5 } else { 0 };
            assert!(
                far.len() <= allowed,
                "{}: {} of {} gradients disagree with finite differences of the GPU forward, \
                 e.g. entry {}: analytic {} vs {}",
                names[kind],
                far.len(),
                an.len(),
                far[0],
                an[far[0]],
                fd[far[0]]
            );
            let (mut num, mut den) = (0.0, 0.0);
            for i in (0..an.len()).filter(|i| !far.contains(i)) {
                num += an[i] * fd[i];
                den += fd[i] * fd[i];
            }
            let slope = num / den;
            assert!(
                (slope - 1.0).abs() < 0.05,
                "{}: analytic gradients are {slope} times the finite differences",
                names[kind]
            );
        }
    });
}
