//! Which resident Gaussians pruning removes, found on the GPU
//! (`glsl/prune_mask.comp`): one bit a row crosses the host link instead of
//! each row's scales and opacity, and the scan can be submitted right after
//! Stage II, so that the wait that ends Stage II is the one that reads it.

use crate::map::LocalWindow;
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Readback, Submission};
use latentam_shaders::{bind, push, PRUNE_MASK};

/// Invocations per workgroup of `glsl/prune_mask.comp`.
const THREADS: u64 = 256;

/// A scan of the window for the Gaussians pruning removes, submitted and
/// not yet read.
pub(crate) struct PruneScan {
    /// Until waited for.
    submission: Option<Submission>,
    mask: Readback,
    /// Rows of the window when it was recorded: the scan is of that
    /// window, whose rows do not move until the next sync.
    rows: usize,
    /// The bounds it applied.
    bounds: (f32, f32),
}

/// The logit of `min_opacity` and the logarithm of `max_scale`: the bounds
/// the kernel compares the stored parameters against.
pub(crate) fn prune_bounds(min_opacity: f32, max_scale: f32) -> (f32, f32) {
    let o = min_opacity.clamp(1e-7, 1.0 - 1e-7);
    ((o / (1.0 - o)).ln(), max_scale.max(1e-9).ln())
}

impl PruneScan {
    /// Records and submits the scan of `window`'s rows against
    /// [`prune_bounds`]`(min_opacity, max_scale)` on the compute queue,
    /// after everything submitted before it; `None` for an empty window.
    pub(crate) fn submit(
        ctx: &Context,
        window: &LocalWindow,
        mask: &mut Option<Buffer>,
        min_opacity: f32,
        max_scale: f32,
    ) -> Result<Option<PruneScan>> {
        let rows = window.len();
        if rows == 0 {
            return Ok(None);
        }
        let words = rows.div_ceil(32) as u64;
        if mask.as_ref().is_none_or(|m| m.bytes() < words * 4) {
            // Sized for the window's capacity: allocated once.
            let capacity = window.capacity().max(rows as u64);
            *mask = Some(Buffer::device(
                ctx,
                "pager/prune_mask",
                capacity.div_ceil(32) * 4,
            )?);
        }
        let mask = mask.as_ref().expect("allocated above");
        let rows32 = u32::try_from(rows)
            .map_err(|_| Error::bad_input("prune scan", "a window past 2^32 rows"))?;
        let bounds = prune_bounds(min_opacity, max_scale);
        let fields = window.params().fields();
        let mut rec = ctx.recorder()?;
        rec.dispatch_linear(
            &PRUNE_MASK,
            words.div_ceil(THREADS) as u32,
            bind::PruneMaskBuffers {
                log_scales: fields[1],
                opacity_logits: fields[4],
                mask,
            },
            &push::PruneMask {
                rows: rows32,
                words: words as u32,
                min_logit: bounds.0,
                max_log_scale: bounds.1,
            },
        )?;
        let readback = rec.download(mask, 0, words * 4)?;
        Ok(Some(PruneScan {
            submission: Some(rec.submit()?),
            mask: readback,
            rows,
            bounds,
        }))
    }

    /// Waits for the scan: one host wait, which also ends what was
    /// submitted before it on the compute queue (Stage II).
    pub(crate) fn wait(&mut self) -> Result<()> {
        match self.submission.take() {
            Some(s) => s.wait(),
            None => Ok(()),
        }
    }

    /// The rows marked, in order (waiting first if not waited for); `None`
    /// when the window no longer has the rows it scanned or the bounds
    /// differ.
    pub(crate) fn rows(mut self, rows_now: usize, bounds: (f32, f32)) -> Result<Option<Vec<u32>>> {
        self.wait()?;
        if rows_now != self.rows || bounds != self.bounds {
            return Ok(None);
        }
        let mask = self.mask.read::<u32>()?;
        Ok(Some(marked_rows(&mask, self.rows)))
    }
}

/// The rows `< rows` whose bit is set in `mask` (bit `b` of word `w` is
/// row `32w + b`), in order.
pub(super) fn marked_rows(mask: &[u32], rows: usize) -> Vec<u32> {
    let mut out = Vec::new();
    for (w, &word) in mask.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            let b = bits.trailing_zeros();
            let r = w as u32 * 32 + b;
            if (r as usize) < rows {
                out.push(r);
            }
            bits &= bits - 1;
        }
    }
    out
}
