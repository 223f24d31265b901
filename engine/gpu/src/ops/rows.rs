//! Whole rows moved by index between a row-major buffer and a packed
//! staging buffer (kernels `glsl/rows.comp`; CPU reference
//! `latentam_reference::rows`): the GPU side of paging a window by block,
//! where the rows of the blocks that leave are gathered for one download
//! and those of the blocks that arrive are scattered from one upload.
//! Words move as bits, so any 32-bit field (floats, counts) moves exactly.

use latentam_shaders::{bind, push, KernelDef, ROWS_GATHER, ROWS_SCATTER};

use crate::{Buffer, Recorder};
use latentam_base::{Error, Result};

/// Invocations per workgroup of the row kernels (`THREADS` in
/// `glsl/rows.comp`).
const THREADS: u64 = 256;

/// Records `staging[i * width + j] = data[index[i] * width + j]` for the
/// first `count` indices of `index` and every word `j < width`. Every index
/// must name a row of `data` (the kernel does not check: the caller builds
/// the lists); an index may repeat.
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context};
/// # fn f(ctx: &Context, means: &Buffer) -> latentam_base::Result<()> {
/// let leaving = ctx.upload_new("leaving rows", &[7u32, 2, 40])?;
/// let out = Buffer::device(ctx, "outbox", 3 * 3 * 4)?;
/// let mut rec = ctx.recorder()?;
/// latentam_gpu::ops::gather_rows(&mut rec, means, &out, &leaving, 3, 3)?; // xyz rows
/// rec.submit()?.wait()?;
/// # Ok(())
/// # }
/// ```
pub fn gather_rows<'a>(
    rec: &mut Recorder<'a>,
    data: &'a Buffer,
    staging: &'a Buffer,
    index: &'a Buffer,
    count: u32,
    width: u32,
) -> Result<()> {
    record(rec, &ROWS_GATHER, data, staging, index, count, width)
}

/// Records `data[index[i] * width + j] = staging[i * width + j]` for the
/// first `count` indices of `index` and every word `j < width`. Every index
/// must name a row of `data`, and no row twice (the writes of one row
/// listed twice would race).
pub fn scatter_rows<'a>(
    rec: &mut Recorder<'a>,
    data: &'a Buffer,
    staging: &'a Buffer,
    index: &'a Buffer,
    count: u32,
    width: u32,
) -> Result<()> {
    record(rec, &ROWS_SCATTER, data, staging, index, count, width)
}

fn record<'a>(
    rec: &mut Recorder<'a>,
    kernel: &'static KernelDef<push::Rows, bind::Rows>,
    data: &'a Buffer,
    staging: &'a Buffer,
    index: &'a Buffer,
    count: u32,
    width: u32,
) -> Result<()> {
    if count == 0 || width == 0 {
        return Ok(());
    }
    let words = count as u64 * width as u64;
    // The kernel counts words in 32 bits.
    if words > u32::MAX as u64 || data.bytes() / 4 > u32::MAX as u64 {
        return Err(Error::bad_input(
            "rows to move",
            format!(
                "{count} rows of {width} words in a buffer of {} bytes: more than 2^32 words; \
                 move them in parts",
                data.bytes()
            ),
        ));
    }
    data.ensure_bytes(width as u64 * 4, "rows data")?;
    staging.ensure_bytes(words * 4, "rows staging")?;
    index.ensure_bytes(count as u64 * 4, "row indices")?;
    rec.dispatch_linear(
        kernel,
        words.div_ceil(THREADS) as u32,
        bind::RowsBuffers {
            data,
            staging,
            index,
        },
        &push::Rows { count, width },
    )
}
