//! Whole rows moved by index (kernels `glsl/rows.comp` and
//! `glsl/rows_move.comp`; CPU reference `latentam_reference::rows`): the
//! GPU side of paging a window by block. The rows of the blocks that leave
//! are gathered into one outbox for one download, the rows left behind are
//! moved down into the holes (compaction), and a reader's rows are gathered
//! the same way. Words move as bits, so any 32-bit field (floats, counts)
//! moves exactly.

use latentam_shaders::{bind, push, ROWS_GATHER, ROWS_MOVE, ROWS_SCATTER};

use crate::{Buffer, Recorder};
use latentam_base::{Error, Result};

/// Invocations per workgroup of the row kernels (`THREADS` in
/// `glsl/rows.comp` and `glsl/rows_move.comp`).
const THREADS: u64 = 256;

/// A list of row indices: `count` `u32`s from index `first` of `index`.
///
/// ```no_run
/// # use latentam_gpu::{Context, ops::RowList};
/// # fn f(ctx: &Context) -> latentam_base::Result<()> {
/// let index = ctx.upload_new("rows", &[7u32, 2, 40, 5])?;
/// let last_two = RowList { index: &index, first: 2, count: 2 }; // rows 40 and 5
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy)]
pub struct RowList<'a> {
    /// The index buffer.
    pub index: &'a Buffer,
    /// Where the list starts, in indices.
    pub first: u32,
    /// How many rows it names.
    pub count: u32,
}

/// Where packed rows lie in a staging buffer: from 32-bit word `word` of
/// `buffer`, one row after another.
#[derive(Clone, Copy)]
pub struct Packed<'a> {
    /// The staging buffer (a device buffer).
    pub buffer: &'a Buffer,
    /// The first word.
    pub word: u64,
}

/// Records `staging[word + i * width + j] = data[rows[i] * width + j]` for
/// every row `i` of the list and every word `j < width`. Every index must
/// name a row of `data` (the kernel does not check: the caller builds the
/// lists); an index may repeat.
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context, ops::{gather_rows, Packed, RowList}};
/// # fn f(ctx: &Context, means: &Buffer) -> latentam_base::Result<()> {
/// let leaving = ctx.upload_new("leaving rows", &[7u32, 2, 40])?;
/// let outbox = Buffer::device(ctx, "outbox", 3 * 3 * 4)?;
/// let rows = RowList { index: &leaving, first: 0, count: 3 };
/// let mut rec = ctx.recorder()?;
/// gather_rows(&mut rec, means, 3, rows, Packed { buffer: &outbox, word: 0 })?; // xyz rows
/// rec.submit()?.wait()?;
/// # Ok(())
/// # }
/// ```
pub fn gather_rows<'a>(
    rec: &mut Recorder<'a>,
    data: &'a Buffer,
    width: u32,
    rows: RowList<'a>,
    staging: Packed<'a>,
) -> Result<()> {
    record(rec, true, data, width, rows, staging)
}

/// Records `data[rows[i] * width + j] = staging[word + i * width + j]` for
/// every row `i` of the list and every word `j < width`. Every index must
/// name a row of `data`, and no row twice (the writes of one row listed
/// twice would race).
pub fn scatter_rows<'a>(
    rec: &mut Recorder<'a>,
    data: &'a Buffer,
    width: u32,
    rows: RowList<'a>,
    staging: Packed<'a>,
) -> Result<()> {
    record(rec, false, data, width, rows, staging)
}

/// Records the move of row `from[i]` of `data` to row `to[i]`, for every
/// `i` of two lists of the same length, within one buffer and without
/// staging. No row may be both a source and a destination and no
/// destination may repeat (checked by the caller, who builds the lists:
/// a window's compaction takes sources at or above the rows it keeps and
/// destinations below). `to` must follow `from` in the same index buffer.
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context, ops::{move_rows, RowList}};
/// # fn f(ctx: &Context, means: &Buffer) -> latentam_base::Result<()> {
/// // Rows 9 and 8 fill the holes at rows 1 and 4.
/// let index = ctx.upload_new("moves", &[9u32, 8, 1, 4])?;
/// let mut rec = ctx.recorder()?;
/// move_rows(&mut rec, means, 3, RowList { index: &index, first: 0, count: 2 })?;
/// rec.submit()?.wait()?;
/// # Ok(())
/// # }
/// ```
pub fn move_rows<'a>(
    rec: &mut Recorder<'a>,
    data: &'a Buffer,
    width: u32,
    from_then_to: RowList<'a>,
) -> Result<()> {
    let RowList {
        index,
        first,
        count,
    } = from_then_to;
    if count == 0 || width == 0 {
        return Ok(());
    }
    // Two lists: the sources, then the destinations.
    let words = check_rows(data, width, from_then_to, 2)?;
    rec.dispatch_linear(
        &ROWS_MOVE,
        words.div_ceil(THREADS) as u32,
        bind::RowsMoveBuffers { data, index },
        &push::RowsMove {
            count,
            width,
            list: first,
        },
    )
}

/// Checks `rows` (`lists` lists of `rows.count` indices one after
/// another) against their buffers, and that the words to move fit the
/// kernels' 32-bit counts; returns the words of one list's rows.
fn check_rows(data: &Buffer, width: u32, rows: RowList<'_>, lists: u64) -> Result<u64> {
    let count = rows.count;
    let words = count as u64 * width as u64;
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
    rows.index.ensure_bytes(
        (rows.first as u64 + lists * count as u64) * 4,
        "row indices",
    )?;
    Ok(words)
}

fn record<'a>(
    rec: &mut Recorder<'a>,
    gather: bool,
    data: &'a Buffer,
    width: u32,
    rows: RowList<'a>,
    staging: Packed<'a>,
) -> Result<()> {
    let RowList {
        index,
        first,
        count,
    } = rows;
    if count == 0 || width == 0 {
        return Ok(());
    }
    let words = check_rows(data, width, rows, 1)?;
    let word = u32::try_from(staging.word)
        .ok()
        .filter(|w| (*w as u64 + words) <= u32::MAX as u64)
        .ok_or_else(|| {
            Error::bad_input(
                "rows to move",
                format!("staging from word {}: past 2^32 words", staging.word),
            )
        })?;
    staging
        .buffer
        .ensure_bytes((word as u64 + words) * 4, "rows staging")?;
    let kernel = if gather { &ROWS_GATHER } else { &ROWS_SCATTER };
    rec.dispatch_linear(
        kernel,
        words.div_ceil(THREADS) as u32,
        bind::RowsBuffers {
            data,
            staging: staging.buffer,
            index,
        },
        &push::Rows {
            count,
            width,
            first: word,
            list: first,
        },
    )
}
