//! Exclusive prefix sum of u32 of any length (kernels `scan_blocks` and
//! `scan_add` in `glsl/scan.comp`; CPU reference `latentam_reference::scan`).

use latentam_shaders::{push, SCAN_ADD, SCAN_BLOCKS};

use crate::{Buffer, Context, Recorder};
use latentam_base::{Error, Result};
use latentam_shaders::bind;

/// Elements scanned per workgroup.
pub const SCAN_BLOCK: u64 = latentam_shaders::shared::SCAN_BLOCK as u64;

/// A reusable exclusive scan for up to `max_len` elements: owns the
/// block-total buffers of every level, so recording allocates nothing.
///
/// ```
/// # use latentam_gpu::{Context, ops::PrefixScan};
/// # let ctx = Context::new(Default::default())?;
/// let counts = ctx.upload_new("example/counts", &[2u32, 0, 3])?;
/// let scan = PrefixScan::new(&ctx, 3)?;
/// let mut rec = ctx.recorder()?;
/// scan.record(&mut rec, &counts, 3)?;
/// rec.submit()?.wait()?;
/// assert_eq!(ctx.download::<u32>(&counts)?, vec![0, 2, 2]);
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
pub struct PrefixScan {
    max_len: u64,
    levels: Vec<Buffer>,
}

impl PrefixScan {
    /// Allocates the level buffers for scans of up to `max_len` elements.
    pub fn new(ctx: &Context, max_len: u64) -> Result<Self> {
        let mut levels = Vec::new();
        let mut len = max_len;
        loop {
            let blocks = len.div_ceil(SCAN_BLOCK).max(1);
            levels.push(Buffer::device(
                ctx,
                &format!("scan/level{}", levels.len()),
                blocks * 4,
            )?);
            if blocks <= 1 {
                break;
            }
            len = blocks;
        }
        Ok(Self { max_len, levels })
    }

    /// Largest supported length.
    pub fn max_len(&self) -> u64 {
        self.max_len
    }

    /// Replaces `data[..n]` by its exclusive prefix sum (wrapping on
    /// overflow).
    pub fn record<'a>(&'a self, rec: &mut Recorder<'a>, data: &'a Buffer, n: u64) -> Result<()> {
        if n > self.max_len {
            return Err(Error::bad_input(
                "prefix scan",
                format!(
                    "{n} elements exceed this PrefixScan's capacity {}",
                    self.max_len
                ),
            ));
        }
        if n * 4 > data.bytes() {
            return Err(Error::bad_input(
                "prefix scan",
                format!(
                    "{n} u32 overflow `{}` ({} bytes)",
                    data.name(),
                    data.bytes()
                ),
            ));
        }
        self.level(rec, data, n, 0)
    }

    fn level<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        data: &'a Buffer,
        n: u64,
        level: usize,
    ) -> Result<()> {
        if n == 0 {
            return Ok(());
        }
        let blocks = n.div_ceil(SCAN_BLOCK);
        let sums = &self.levels[level];
        let p = push::Scan { n: n as u32 };
        rec.dispatch_linear(
            &SCAN_BLOCKS,
            blocks as u32,
            bind::ScanBuffers { data, sums },
            &p,
        )?;
        if blocks > 1 {
            self.level(rec, sums, blocks, level + 1)?;
            let p = push::Scan { n: n as u32 };
            rec.dispatch_linear(
                &SCAN_ADD,
                blocks as u32,
                bind::ScanBuffers { data, sums },
                &p,
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::testing::{rng, with_context};
    use latentam_reference::scan::exclusive_scan_u32;

    fn check(ctx: &Context, data: &[u32]) {
        let n = data.len() as u64;
        let buf = ctx.upload_new("test/data", data).unwrap();
        let scan = PrefixScan::new(ctx, n).unwrap();
        let mut rec = ctx.recorder().unwrap();
        scan.record(&mut rec, &buf, n).unwrap();
        rec.submit().unwrap().wait().unwrap();
        let got = ctx.download::<u32>(&buf).unwrap();
        let want = exclusive_scan_u32(data);
        if let Some(i) = (0..data.len()).find(|&i| got[i] != want[i]) {
            panic!(
                "n = {n}: first mismatch at {i}: got {}, want {}",
                got[i], want[i]
            );
        }
    }

    #[test]
    fn scan_matches_reference_on_random_lengths() {
        let mut r = rng("scan_matches_reference_on_random_lengths");
        with_context(|ctx| {
            // Edge lengths around the block size, plus random ones covering
            // one, two and three levels.
            let mut lengths = vec![0u64, 1, 2, 1023, 1024, 1025, 2048, 1024 * 1024 + 1];
            for _ in 0..4 {
                lengths.push(r.random_range(1..3_000_000));
            }
            for n in lengths {
                let data: Vec<u32> = (0..n).map(|_| r.random_range(0..1000)).collect();
                check(ctx, &data);
            }
        });
    }

    #[test]
    fn scan_wraps_like_u32() {
        with_context(|ctx| check(ctx, &[u32::MAX, 2, u32::MAX, 7]));
    }

    #[test]
    fn scan_rejects_lengths_past_capacity() {
        with_context(|ctx| {
            let buf = Buffer::device(ctx, "test/data", 64).unwrap();
            let scan = PrefixScan::new(ctx, 8).unwrap();
            let big = PrefixScan::new(ctx, 100).unwrap();
            let mut rec = ctx.recorder().unwrap();
            assert!(scan.record(&mut rec, &buf, 9).is_err());
            assert!(scan.record(&mut rec, &buf, 8).is_ok());
            assert!(big.record(&mut rec, &buf, 17).is_err(), "buffer too small");
        });
    }
}
