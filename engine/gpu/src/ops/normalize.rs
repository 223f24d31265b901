//! Row normalisation with an epsilon on the norm and its vector-Jacobian
//! product (kernels `glsl/normalize_rows.comp`,
//! `glsl/normalize_rows_backward.comp`; CPU reference
//! `latentam_reference::normalize`).

use latentam_shaders::{push, NORMALIZE_ROWS, NORMALIZE_ROWS_BACKWARD};

use crate::{Buffer, Recorder};
use latentam_base::Result;
use latentam_shaders::bind;

/// Records `y[r, :] = x[r, :] / (‖x[r, :]‖ + eps)` and `norm[r] = ‖x[r, :]‖` for
/// a rows × cols row-major matrix.
pub fn normalize_rows<'a>(
    rec: &mut Recorder<'a>,
    x: &'a Buffer,
    y: &'a Buffer,
    norm: &'a Buffer,
    rows: u32,
    cols: u32,
    eps: f32,
) -> Result<()> {
    let elems = rows as u64 * cols as u64 * 4;
    x.ensure_bytes(elems, "normalize_rows input")?;
    y.ensure_bytes(elems, "normalize_rows output")?;
    norm.ensure_bytes(rows as u64 * 4, "normalize_rows norms")?;
    let p = push::NormalizeRows { rows, cols, eps };
    rec.dispatch_linear(
        &NORMALIZE_ROWS,
        rows,
        bind::NormalizeRowsBuffers { x, y, norm },
        &p,
    )
}

/// Records dx = beta·dx + ∂L/∂x for y = [`normalize_rows`]`(x)` given y, the
/// norms and g = ∂L/∂y (beta = 0 never reads dx).
#[allow(clippy::too_many_arguments)]
pub fn normalize_rows_backward<'a>(
    rec: &mut Recorder<'a>,
    y: &'a Buffer,
    norm: &'a Buffer,
    g: &'a Buffer,
    dx: &'a Buffer,
    rows: u32,
    cols: u32,
    eps: f32,
    beta: f32,
) -> Result<()> {
    let elems = rows as u64 * cols as u64 * 4;
    for (b, what) in [(y, "y"), (g, "gradient"), (dx, "output")] {
        b.ensure_bytes(elems, &format!("normalize_rows_backward {what}"))?;
    }
    norm.ensure_bytes(rows as u64 * 4, "normalize_rows_backward norms")?;
    let p = push::NormalizeRowsBackward {
        rows,
        cols,
        eps,
        beta,
    };
    rec.dispatch_linear(
        &NORMALIZE_ROWS_BACKWARD,
        rows,
        bind::NormalizeRowsBackwardBuffers { y, norm, g, dx },
        &p,
    )
}
