//! Photometric (L1 + SSIM) and depth L1 losses on rendered images, with
//! their gradients (kernels `glsl/image_l1.comp` and the four SSIM passes
//! `glsl/ssim_stats_h.comp` → `ssim_map_v.comp` → `ssim_grad_h.comp` →
//! `ssim_grad_v.comp`; CPU references `latentam_reference::loss::image_l1_depth`
//! and `latentam_reference::ssim`).
//!
//! SSIM uses the separable 11×11 window: the forward is a horizontal then a
//! vertical pass over the five statistics, the backward the same two passes
//! over the three derivative maps (the zero-padded symmetric window is its
//! own adjoint).

use latentam_shaders::{push, IMAGE_L1, SSIM_GRAD_H, SSIM_GRAD_V, SSIM_MAP_V, SSIM_STATS_H};

use super::LossWeights;
use crate::splat::BatchLayout;
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Readback, Recorder};
use latentam_shaders::bind;

const THREADS: u64 = 256;

/// Whether a measured depth takes part in the depth loss (positive and
/// finite; 0 is the "no measurement" value of depth cameras).
pub fn depth_is_valid(z: f32) -> bool {
    z > 0.0 && z.is_finite()
}

/// The weighted terms of the last evaluation; they sum to the image part of
/// the objective (averaged over the batch's views).
///
/// ```no_run
/// # fn f(readback: &latentam_core::loss::ImageLossReadback) -> latentam_core::Result<()> {
/// let v = readback.values()?;
/// println!("L1 {:.4} + SSIM {:.4} + depth {:.4} = {:.4}", v.l1, v.ssim, v.depth, v.total());
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ImageLossValues {
    /// λ_rgb · λ_I1 · mean |Î − I|.
    pub l1: f64,
    /// λ_rgb · λ_I2 · (1 − SSIM).
    pub ssim: f64,
    /// λ_d · mean over valid pixels of |Ẑ − Z|.
    pub depth: f64,
}

impl ImageLossValues {
    /// Sum of the terms.
    pub fn total(&self) -> f64 {
        self.l1 + self.ssim + self.depth
    }
}

/// Downloads of the partial sums of one evaluation.
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context};
/// # use latentam_core::loss::ImageLoss;
/// # use latentam_core::splat::BatchLayout;
/// # fn f(ctx: &Context, loss: &ImageLoss, layout: &BatchLayout, rendered: &Buffer, target: &Buffer, valid: &[u64], grad: &Buffer) -> latentam_core::Result<()> {
/// let mut rec = ctx.recorder()?;
/// loss.record(&mut rec, layout, rendered, target, valid, grad)?;
/// let readback = loss.record_readback(&mut rec)?;
/// rec.submit()?.wait()?;
/// let total = readback.values()?.total();
/// # Ok(())
/// # }
/// ```
pub struct ImageLossReadback {
    l1: Readback,
    ssim: Readback,
    depth: Readback,
}

impl ImageLossReadback {
    /// The loss terms, once the submission has completed.
    pub fn values(&self) -> Result<ImageLossValues> {
        let sum =
            |r: &Readback| -> Result<f64> { Ok(r.read::<f32>()?.iter().map(|&v| v as f64).sum()) };
        Ok(ImageLossValues {
            l1: sum(&self.l1)?,
            ssim: sum(&self.ssim)?,
            depth: sum(&self.depth)?,
        })
    }
}

/// Evaluates the image losses of a batch of rendered views against their
/// targets and writes ∂L/∂(R, G, B, depth) per pixel.
///
/// Each view's loss is `λ_rgb (λ_I1 · mean|Î − I| + λ_I2 (1 − SSIM)) +
/// λ_d · mean_valid |Ẑ − Z|`, and the batch loss is the mean over views.
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context, ContextOptions};
/// use latentam_core::loss::{ImageLoss, LossWeights};
/// use latentam_core::splat::{BatchLayout, Camera};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let layout = BatchLayout::for_cameras(&[Camera::at_origin(64, 48)])?;
/// let loss = ImageLoss::new(&ctx, 64 * 48, 1, LossWeights::default())?;
/// let rendered = ctx.upload_new("rendered", &vec![[0.5f32, 0.5, 0.5, 2.0]; 64 * 48])?;
/// let target = ctx.upload_new("target", &vec![[0.4f32, 0.5, 0.6, 2.1]; 64 * 48])?;
/// let grad = Buffer::device(&ctx, "grad", 64 * 48 * 16)?;
/// let mut rec = ctx.recorder()?;
/// loss.record(&mut rec, &layout, &rendered, &target, &[64 * 48], &grad)?;
/// let values = loss.record_readback(&mut rec)?;
/// rec.submit()?.wait()?;
/// println!("{:?}", values.values()?);
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct ImageLoss {
    max_view_pixels: u64,
    max_views: u32,
    weights: LossWeights,
    /// Per-workgroup slots of one view in the partial-sum buffers.
    l1_slots: u64,
    ssim_slots: u64,
    stats: Buffer,
    dmap: Buffer,
    blurred: Buffer,
    l1_partial: Buffer,
    depth_partial: Buffer,
    ssim_partial: Buffer,
}

impl ImageLoss {
    /// Workspace for batches of up to `max_views` views of up to
    /// `max_view_pixels` pixels each.
    pub fn new(
        ctx: &Context,
        max_view_pixels: u64,
        max_views: u32,
        weights: LossWeights,
    ) -> Result<Self> {
        let p = max_view_pixels.max(1);
        let l1_slots = p.div_ceil(THREADS);
        let ssim_slots = (3 * p).div_ceil(THREADS);
        let views = max_views.max(1) as u64;
        let buf = |name: &str, bytes: u64| {
            Buffer::device(ctx, &format!("pixels/image_loss_{name}"), bytes)
        };
        Ok(Self {
            max_view_pixels,
            max_views,
            weights,
            l1_slots,
            ssim_slots,
            stats: buf("ssim_stats", p * 3 * 5 * 4)?,
            dmap: buf("ssim_dmap", p * 3 * 3 * 4)?,
            blurred: buf("ssim_blurred", p * 3 * 3 * 4)?,
            l1_partial: buf("l1_partial", views * l1_slots * 4)?,
            depth_partial: buf("depth_partial", views * l1_slots * 4)?,
            ssim_partial: buf("ssim_partial", views * ssim_slots * 4)?,
        })
    }

    /// Records the losses of every view of `layout`: `rendered` and
    /// `target` hold 4 floats per batch pixel (R, G, B, depth; a target depth
    /// that is not [`depth_is_valid`] is ignored), `valid_depth_pixels[v]` is
    /// the number of valid target depths of view v, and `grad` receives
    /// ∂L/∂rendered (every pixel of the batch is written).
    pub fn record<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        layout: &BatchLayout,
        rendered: &'a Buffer,
        target: &'a Buffer,
        valid_depth_pixels: &[u64],
        grad: &'a Buffer,
    ) -> Result<()> {
        let views = layout.views.len();
        self.record_part(
            rec,
            layout,
            rendered,
            target,
            valid_depth_pixels,
            grad,
            views,
        )
    }

    /// [`Self::record`] for a part of a batch of `batch_views` views (the
    /// loss is the mean over all of them): the values and gradients of the
    /// parts sum to those of the whole batch.
    #[allow(clippy::too_many_arguments)]
    pub fn record_part<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        layout: &BatchLayout,
        rendered: &'a Buffer,
        target: &'a Buffer,
        valid_depth_pixels: &[u64],
        grad: &'a Buffer,
        batch_views: usize,
    ) -> Result<()> {
        let views = layout.views.len();
        if batch_views < views {
            return Err(Error::bad_input(
                "image loss views",
                format!("a part of {views} views of a batch of {batch_views}"),
            ));
        }
        if views > self.max_views as usize || valid_depth_pixels.len() != views {
            return Err(Error::bad_input(
                "image loss views",
                format!(
                    "{views} views with {} valid-depth counts; sized for {} views",
                    valid_depth_pixels.len(),
                    self.max_views
                ),
            ));
        }
        let need = layout.pixels * 16;
        for b in [rendered, target, grad] {
            b.ensure_bytes(need, "image loss")?;
        }
        for b in [&self.l1_partial, &self.depth_partial, &self.ssim_partial] {
            rec.fill_u32(b, 0);
        }
        let w = &self.weights;
        let inv_views = 1.0 / batch_views.max(1) as f64;
        for (v, slot) in layout.views.iter().enumerate() {
            let pixels = slot.width as u64 * slot.height as u64;
            if pixels > self.max_view_pixels {
                return Err(Error::bad_input(
                    format!("view {v}"),
                    format!(
                        "{pixels} pixels; the image loss was sized for {}",
                        self.max_view_pixels
                    ),
                ));
            }
            if valid_depth_pixels[v] > pixels {
                return Err(Error::bad_input(
                    format!("view {v}"),
                    format!(
                        "{} valid depths out of {pixels} pixels",
                        valid_depth_pixels[v]
                    ),
                ));
            }
            let per_colour = inv_views / (3 * pixels) as f64;
            let w_depth = if valid_depth_pixels[v] > 0 {
                w.depth as f64 * inv_views / valid_depth_pixels[v] as f64
            } else {
                0.0
            };
            let first_pixel = slot.first_pixel as u32;
            rec.dispatch_linear(
                &IMAGE_L1,
                pixels.div_ceil(THREADS) as u32,
                bind::ImageL1Buffers {
                    rendered,
                    target,
                    grad,
                    l1_partial: &self.l1_partial,
                    depth_partial: &self.depth_partial,
                },
                &push::ImageL1 {
                    pixels: pixels as u32,
                    first_pixel,
                    partial_offset: (v as u64 * self.l1_slots) as u32,
                    w_rgb: (w.rgb as f64 * w.rgb_l1 as f64 * per_colour) as f32,
                    w_depth: w_depth as f32,
                },
            )?;
            let p = push::Ssim {
                width: slot.width,
                height: slot.height,
                first_pixel,
                partial_offset: (v as u64 * self.ssim_slots) as u32,
                weight: (w.rgb as f64 * w.ssim as f64 * per_colour) as f32,
            };
            let groups = (3 * pixels).div_ceil(THREADS) as u32;
            self.record_ssim(rec, rendered, target, grad, groups, &p)?;
        }
        Ok(())
    }

    /// The SSIM term of one view: windowed statistics along rows, then
    /// columns with the map and its partial sums; the gradient back the same
    /// way (kernels `glsl/ssim_*.comp`).
    fn record_ssim<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        rendered: &'a Buffer,
        target: &'a Buffer,
        grad: &'a Buffer,
        groups: u32,
        p: &push::Ssim,
    ) -> Result<()> {
        rec.dispatch_linear(
            &SSIM_STATS_H,
            groups,
            bind::SsimStatsHBuffers {
                rendered,
                target,
                stats: &self.stats,
            },
            p,
        )?;
        rec.dispatch_linear(
            &SSIM_MAP_V,
            groups,
            bind::SsimMapVBuffers {
                stats: &self.stats,
                dmap: &self.dmap,
                partial: &self.ssim_partial,
            },
            p,
        )?;
        rec.dispatch_linear(
            &SSIM_GRAD_H,
            groups,
            bind::SsimGradHBuffers {
                dmap: &self.dmap,
                blurred: &self.blurred,
            },
            p,
        )?;
        rec.dispatch_linear(
            &SSIM_GRAD_V,
            groups,
            bind::SsimGradVBuffers {
                blurred: &self.blurred,
                rendered,
                target,
                grad,
            },
            p,
        )?;
        Ok(())
    }

    /// Records downloads of the partial sums of the last [`Self::record`].
    pub fn record_readback<'a>(&'a self, rec: &mut Recorder<'a>) -> Result<ImageLossReadback> {
        Ok(ImageLossReadback {
            l1: rec.download(&self.l1_partial, 0, self.l1_partial.bytes())?,
            ssim: rec.download(&self.ssim_partial, 0, self.ssim_partial.bytes())?,
            depth: rec.download(&self.depth_partial, 0, self.depth_partial.bytes())?,
        })
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::splat::Camera;
    use latentam_gpu::testing::{rng, with_context};
    use latentam_reference::{loss::image_l1_depth, ssim::ssim};

    #[test]
    fn image_losses_match_reference() {
        let mut r = rng("image_losses_match_reference");
        with_context(|ctx| {
            let sizes = [(37u32, 29u32), (16, 16), (7, 5), (50, 21)];
            let cams: Vec<Camera> = sizes
                .iter()
                .map(|&(w, h)| Camera::at_origin(w, h))
                .collect();
            let layout = BatchLayout::for_cameras(&cams).unwrap();
            let n = layout.pixels as usize;
            let rendered: Vec<[f32; 4]> = (0..n)
                .map(|_| {
                    let c = [
                        r.random_range(0.0..1.0),
                        r.random_range(0.0..1.0),
                        r.random_range(0.0..1.0),
                    ];
                    [c[0], c[1], c[2], r.random_range(0.5..4.0)]
                })
                .collect();
            // Targets near the render (so SSIM is far from both 0 and 1), with
            // invalid depths: 0, NaN, infinity, negative.
            let target: Vec<[f32; 4]> = rendered
                .iter()
                .map(|p| {
                    let mut t = *p;
                    for c in t.iter_mut().take(3) {
                        *c = (*c + r.random_range(-0.2..0.2)).clamp(0.0, 1.0);
                    }
                    t[3] = match r.random_range(0..10) {
                        0 => 0.0,
                        1 => f32::NAN,
                        2 => f32::INFINITY,
                        3 => -1.0,
                        _ => t[3] + r.random_range(-0.3..0.3),
                    };
                    t
                })
                .collect();
            let valid: Vec<u64> = layout
                .views
                .iter()
                .map(|s| {
                    let a = s.first_pixel as usize;
                    let b = a + (s.width * s.height) as usize;
                    target[a..b].iter().filter(|t| depth_is_valid(t[3])).count() as u64
                })
                .collect();
            let weights = LossWeights::default();
            let loss = ImageLoss::new(ctx, 50 * 29, 4, weights).unwrap();
            let rb = ctx.upload_new("test/rendered", &rendered).unwrap();
            let tb = ctx.upload_new("test/target", &target).unwrap();
            let gb = Buffer::device(ctx, "test/grad", n as u64 * 16).unwrap();
            let mut rec = ctx.recorder().unwrap();
            rec.fill_u32(&gb, 0x7fc0_0000);
            loss.record(&mut rec, &layout, &rb, &tb, &valid, &gb)
                .unwrap();
            let values = loss.record_readback(&mut rec).unwrap();
            rec.submit().unwrap().wait().unwrap();
            let got = ctx.download::<[f32; 4]>(&gb).unwrap();
            let got_values = values.values().unwrap();

            let views = layout.views.len() as f64;
            let mut want_values = ImageLossValues::default();
            for (v, s) in layout.views.iter().enumerate() {
                let (a, pixels) = (s.first_pixel as usize, (s.width * s.height) as usize);
                let (w_rgb, w_ssim) = (
                    (weights.rgb * weights.rgb_l1) as f64 / (views * 3.0 * pixels as f64),
                    (weights.rgb * weights.ssim) as f64 / views,
                );
                let w_depth = weights.depth as f64 / (views * valid[v] as f64);
                let (l1, depth, mut grad) = image_l1_depth(
                    &rendered[a..a + pixels],
                    &target[a..a + pixels],
                    w_rgb,
                    w_depth,
                );
                let rgb = |img: &[[f32; 4]]| -> Vec<f64> {
                    img[a..a + pixels]
                        .iter()
                        .flat_map(|p| p[..3].iter().map(|&c| c as f64))
                        .collect()
                };
                let (mean, dmean) = ssim(
                    &rgb(&rendered),
                    &rgb(&target),
                    s.width as usize,
                    s.height as usize,
                    3,
                );
                want_values.l1 += l1;
                want_values.depth += depth;
                want_values.ssim += w_ssim * (1.0 - mean);
                for (p, g) in grad.iter_mut().enumerate() {
                    for c in 0..3 {
                        g[c] -= w_ssim * dmean[p * 3 + c];
                    }
                }
                let scale = grad.iter().flatten().fold(0.0f64, |m, g| m.max(g.abs()));
                for (p, g) in grad.iter().enumerate() {
                    for c in 0..4 {
                        let x = got[a + p][c] as f64;
                        assert!(
                            (x - g[c]).abs() <= 1e-4 * scale,
                            "view {v} pixel {p} channel {c}: {x} vs {}",
                            g[c]
                        );
                    }
                }
            }
            for (name, g, w) in [
                ("l1", got_values.l1, want_values.l1),
                ("ssim", got_values.ssim, want_values.ssim),
                ("depth", got_values.depth, want_values.depth),
            ] {
                assert!(
                    (g - w).abs() <= 1e-4 * w.abs().max(1e-3),
                    "{name}: {g} vs {w}"
                );
            }
        });
    }

    #[test]
    fn bad_batches_are_rejected() {
        with_context(|ctx| {
            let cam = Camera::at_origin(8, 8);
            let layout = BatchLayout::for_cameras(&[cam, cam]).unwrap();
            let b = Buffer::device(ctx, "test/b", 128 * 16).unwrap();
            let one_view = ImageLoss::new(ctx, 64, 1, LossWeights::default()).unwrap();
            let loss = ImageLoss::new(ctx, 64, 2, LossWeights::default()).unwrap();
            let small = ImageLoss::new(ctx, 32, 2, LossWeights::default()).unwrap();
            let mut rec = ctx.recorder().unwrap();
            assert!(one_view
                .record(&mut rec, &layout, &b, &b, &[1, 1], &b)
                .is_err());
            assert!(loss.record(&mut rec, &layout, &b, &b, &[1], &b).is_err());
            assert!(loss
                .record(&mut rec, &layout, &b, &b, &[65, 1], &b)
                .is_err());
            assert!(small
                .record(&mut rec, &layout, &b, &b, &[1, 1], &b)
                .is_err());
            assert!(loss.record(&mut rec, &layout, &b, &b, &[1, 1], &b).is_ok());
        });
    }
}
