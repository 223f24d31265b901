//! Structural similarity, the L_SSIM of paper Eq. 7 (kernels `glsl/ssim_*.comp`, driven by
//! `engine/core/src/loss/image.rs`), in f64, computed directly with the 2-D
//! window rather than the GPU's separable passes.
//!
//! Per pixel and channel, with an 11×11 Gaussian window (σ = 1.5,
//! normalised) and zero padding outside the image:
//!
//! ```text
//! μx = Σ w·x,  μy = Σ w·y,  σx² = Σ w·x² − μx²,  σy² = Σ w·y² − μy²,  σxy = Σ w·xy − μx·μy
//! SSIM = (2μxμy + C1)(2σxy + C2) / ((μx² + μy² + C1)(σx² + σy² + C2)),  C1 = 0.01², C2 = 0.03²
//! ```

/// Window half-width (the window is 2·RADIUS + 1 wide).
pub const RADIUS: i64 = 5;
/// Window standard deviation.
pub const SIGMA: f64 = 1.5;
/// Stabiliser of the mean term, (0.01 · data range)².
pub const C1: f64 = 0.01 * 0.01;
/// Stabiliser of the variance term, (0.03 · data range)².
pub const C2: f64 = 0.03 * 0.03;

/// The normalised 1-D window; the 2-D window is its outer product.
pub fn window() -> [f64; 11] {
    let mut w = [0.0; 11];
    for (i, v) in w.iter_mut().enumerate() {
        let k = i as f64 - RADIUS as f64;
        *v = (-k * k / (2.0 * SIGMA * SIGMA)).exp();
    }
    let s: f64 = w.iter().sum();
    w.map(|v| v / s)
}

/// Mean SSIM over the pixels and channels of two `width` × `height` images
/// with `channels` interleaved channels, and its gradient with respect to
/// `x` (same layout).
pub fn ssim(x: &[f64], y: &[f64], width: usize, height: usize, channels: usize) -> (f64, Vec<f64>) {
    let w1 = window();
    let tap = |du: i64, dv: i64| w1[(du + RADIUS) as usize] * w1[(dv + RADIUS) as usize];
    let at = |img: &[f64], u: i64, v: i64, c: usize| -> f64 {
        if u < 0 || v < 0 || u >= width as i64 || v >= height as i64 {
            0.0
        } else {
            img[(v as usize * width + u as usize) * channels + c]
        }
    };
    let count = (width * height * channels) as f64;
    let mut total = 0.0;
    let mut grad = vec![0.0; x.len()];
    for v in 0..height as i64 {
        for u in 0..width as i64 {
            for c in 0..channels {
                let (mut mx, mut my, mut exx, mut eyy, mut exy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for dv in -RADIUS..=RADIUS {
                    for du in -RADIUS..=RADIUS {
                        let t = tap(du, dv);
                        let (a, b) = (at(x, u + du, v + dv, c), at(y, u + du, v + dv, c));
                        mx += t * a;
                        my += t * b;
                        exx += t * a * a;
                        eyy += t * b * b;
                        exy += t * a * b;
                    }
                }
                let (sx, sy, sxy) = (exx - mx * mx, eyy - my * my, exy - mx * my);
                let num_m = 2.0 * mx * my + C1;
                let num_s = 2.0 * sxy + C2;
                let den_m = mx * mx + my * my + C1;
                let den_s = sx + sy + C2;
                let m = num_m * num_s / (den_m * den_s);
                total += m;
                // ∂m with respect to the window sums Σw·x, Σw·x², Σw·xy.
                let dm_dmx = 2.0 * my * num_s / (den_m * den_s) - m * 2.0 * mx / den_m;
                let dm_dsx = -m / den_s;
                let dm_dsxy = 2.0 * num_m / (den_m * den_s);
                let d_mean = dm_dmx - 2.0 * mx * dm_dsx - my * dm_dsxy;
                for dv in -RADIUS..=RADIUS {
                    for du in -RADIUS..=RADIUS {
                        let (qu, qv) = (u + du, v + dv);
                        if qu < 0 || qv < 0 || qu >= width as i64 || qv >= height as i64 {
                            continue;
                        }
                        let t = tap(du, dv);
                        let q = (qv as usize * width + qu as usize) * channels + c;
                        grad[q] += t * (d_mean + 2.0 * x[q] * dm_dsx + y[q] * dm_dsxy) / count;
                    }
                }
            }
        }
    }
    (total / count, grad)
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;

    #[test]
    fn window_is_normalised_and_matches_published_taps() {
        let w = window();
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        // The taps of fused-ssim's published constant table (`cGauss`).
        for (got, want) in w.iter().zip([
            0.0010284, 0.0075988, 0.0360008, 0.1093607, 0.2130055, 0.2660117,
        ]) {
            assert!((got - want).abs() < 1e-7, "{got} vs {want}");
        }
    }

    #[test]
    fn identical_images_have_ssim_one_and_zero_gradient() {
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let x: Vec<f64> = (0..9 * 7 * 3).map(|_| r.random_range(0.0..1.0)).collect();
        let (s, g) = ssim(&x, &x, 9, 7, 3);
        assert!((s - 1.0).abs() < 1e-12);
        assert!(g.iter().all(|v| v.abs() < 1e-12));
    }

    #[test]
    fn gradient_matches_central_differences() {
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(6);
        let (w, h, c) = (13, 8, 2);
        let x: Vec<f64> = (0..w * h * c).map(|_| r.random_range(0.0..1.0)).collect();
        let y: Vec<f64> = (0..w * h * c).map(|_| r.random_range(0.0..1.0)).collect();
        let (_, grad) = ssim(&x, &y, w, h, c);
        let step = 1e-6;
        for i in 0..x.len() {
            let (mut a, mut b) = (x.clone(), x.clone());
            a[i] += step;
            b[i] -= step;
            let fd = (ssim(&a, &y, w, h, c).0 - ssim(&b, &y, w, h, c).0) / (2.0 * step);
            assert!(
                (fd - grad[i]).abs() < 1e-7 + 1e-5 * fd.abs(),
                "x[{i}]: {} vs {fd}",
                grad[i]
            );
        }
    }
}
