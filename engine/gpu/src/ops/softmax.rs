//! Row softmax with a scale and its vector-Jacobian product (kernels
//! `softmax` in `glsl/softmax.comp` and `softmax_backward` in
//! `glsl/softmax_backward.comp`; CPU reference `latentam_reference::softmax`).

use latentam_shaders::{push, SOFTMAX, SOFTMAX_BACKWARD};

use crate::{Buffer, Recorder};
use latentam_base::Result;
use latentam_shaders::bind;

/// Records y[r, :] = softmax(scale · x[r, :]) for a rows × cols row-major
/// matrix. `x` and `y` may be the same buffer only if the caller accepts
/// that rows are overwritten in place (they are read fully before written).
pub fn row_softmax<'a>(
    rec: &mut Recorder<'a>,
    x: &'a Buffer,
    y: &'a Buffer,
    rows: u32,
    cols: u32,
    scale: f32,
) -> Result<()> {
    let need = rows as u64 * cols as u64 * 4;
    x.ensure_bytes(need, "softmax input")?;
    y.ensure_bytes(need, "softmax output")?;
    rec.dispatch_linear(
        &SOFTMAX,
        rows,
        bind::SoftmaxBuffers { x, y },
        &push::Softmax { rows, cols, scale },
    )
}

/// Records the backward pass of [`row_softmax`] in place: given
/// a = softmax(scale · s) in `a` and ∂L/∂a in `grad`, overwrites `grad` with
/// ∂L/∂s = scale · a ⊙ (∂L/∂a − Σⱼ aⱼ ∂L/∂aⱼ).
pub fn row_softmax_backward<'a>(
    rec: &mut Recorder<'a>,
    a: &'a Buffer,
    grad: &'a Buffer,
    rows: u32,
    cols: u32,
    scale: f32,
) -> Result<()> {
    let need = rows as u64 * cols as u64 * 4;
    a.ensure_bytes(need, "softmax backward")?;
    grad.ensure_bytes(need, "softmax backward")?;
    rec.dispatch_linear(
        &SOFTMAX_BACKWARD,
        rows,
        bind::SoftmaxBackwardBuffers { a, g: grad },
        &push::SoftmaxBackward { rows, cols, scale },
    )
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::testing::{rng, with_context};
    use latentam_reference::softmax::row_softmax as reference;

    #[test]
    fn softmax_matches_reference_on_random_rows() {
        let mut r = rng("softmax_matches_reference_on_random_rows");
        with_context(|ctx| {
            // Cosine logits / 0.05 span [-20, 20], as in the decoder.
            for (rows, cols) in [
                (1u32, 1u32),
                (3, 255),
                (7, 256),
                (5, 257),
                (200, 2000),
                (2, 5000),
            ] {
                let x: Vec<f32> = (0..rows * cols)
                    .map(|_| r.random_range(-1.0..1.0))
                    .collect();
                let xb = ctx.upload_new("test/x", &x).unwrap();
                let yb = Buffer::device(ctx, "test/y", (rows * cols * 4) as u64).unwrap();
                let mut rec = ctx.recorder().unwrap();
                rec.fill_u32(&yb, 0x7fc0_0000);
                row_softmax(&mut rec, &xb, &yb, rows, cols, 20.0).unwrap();
                rec.submit().unwrap().wait().unwrap();
                let got = ctx.download::<f32>(&yb).unwrap();
                let want = reference(&x, rows as usize, cols as usize, 20.0);
                for i in 0..(rows * cols) as usize {
                    let tol = 1e-5 * want[i].max(1e-3) * 10.0 + 1e-7;
                    assert!(
                        (got[i] as f64 - want[i]).abs() <= tol,
                        "{rows}x{cols}: y[{i}] = {} want {}",
                        got[i],
                        want[i]
                    );
                }
            }
        });
    }
}
