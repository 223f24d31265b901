//! Stable GPU key-value radix sort (kernels `radix_histogram` and
//! `radix_scatter` in `shaders/wgsl/radix_sort.wgsl`; CPU reference
//! `latentam_reference::sort`).

use latentam_shaders::{push, RADIX_HISTOGRAM, RADIX_SCATTER};

use super::scan::PrefixScan;
use crate::{Buffer, Context, Recorder};
use latentam_base::{Error, Result};
use latentam_shaders::bind;

/// Elements per workgroup (THREADS × ITEMS in the kernel).
pub const SORT_BLOCK: u64 = 2048;
/// Key bits consumed per pass.
pub const RADIX_BITS: u32 = 4;
const RADIX: u64 = 1 << RADIX_BITS;

/// A reusable sorter for up to `max_len` (u32 key, u32 value) pairs. Owns the
/// ping-pong buffers and the histogram scan, so recording allocates nothing.
///
/// ```
/// # use latentam_gpu::{Context, ops::RadixSorter};
/// # let ctx = Context::new(Default::default())?;
/// let keys = ctx.upload_new("example/keys", &[3u32, 1, 2, 1])?;
/// let vals = ctx.upload_new("example/vals", &[0u32, 1, 2, 3])?;
/// let sorter = RadixSorter::new(&ctx, 4)?;
/// let mut rec = ctx.recorder()?;
/// sorter.record(&mut rec, &keys, &vals, 4, 32)?;
/// rec.submit()?.wait()?;
/// assert_eq!(ctx.download::<u32>(&vals)?, vec![1, 3, 2, 0]); // stable
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
pub struct RadixSorter {
    max_len: u64,
    keys_alt: Buffer,
    vals_alt: Buffer,
    hist: Buffer,
    scan: PrefixScan,
}

impl RadixSorter {
    /// Allocates scratch for sorting up to `max_len` pairs.
    pub fn new(ctx: &Context, max_len: u64) -> Result<Self> {
        let blocks = max_len.div_ceil(SORT_BLOCK).max(1);
        Ok(Self {
            max_len,
            keys_alt: Buffer::device(ctx, "sort/keys_alt", max_len * 4)?,
            vals_alt: Buffer::device(ctx, "sort/vals_alt", max_len * 4)?,
            hist: Buffer::device(ctx, "sort/histogram", blocks * RADIX * 4)?,
            scan: PrefixScan::new(ctx, blocks * RADIX)?,
        })
    }

    /// Largest supported length.
    pub fn max_len(&self) -> u64 {
        self.max_len
    }

    /// Sorts `keys[..n]` with `values[..n]` in place by the low `key_bits`
    /// bits of the keys (1..=32; fewer bits, fewer passes), stably.
    pub fn record<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        keys: &'a Buffer,
        values: &'a Buffer,
        n: u64,
        key_bits: u32,
    ) -> Result<()> {
        if n > self.max_len || keys.bytes() < n * 4 || values.bytes() < n * 4 {
            return Err(Error::bad_input(
                "radix sort",
                format!(
                    "sorting {n} pairs in `{}`/`{}` ({}/{} bytes) with a sorter for {}",
                    keys.name(),
                    values.name(),
                    keys.bytes(),
                    values.bytes(),
                    self.max_len
                ),
            ));
        }
        if !(1..=32).contains(&key_bits) {
            return Err(Error::bad_input(
                "key_bits",
                format!("must be in 1..=32, got {key_bits}"),
            ));
        }
        if n <= 1 {
            return Ok(());
        }
        let blocks = n.div_ceil(SORT_BLOCK);
        let passes = key_bits.div_ceil(RADIX_BITS);
        let mut src = (keys, values);
        let mut dst = (&self.keys_alt, &self.vals_alt);
        for pass in 0..passes {
            let p = push::RadixSort {
                n: n as u32,
                shift: pass * RADIX_BITS,
                num_blocks: blocks as u32,
                bits: (key_bits - pass * RADIX_BITS).min(RADIX_BITS),
            };
            rec.dispatch_linear(
                &RADIX_HISTOGRAM,
                blocks as u32,
                bind::RadixHistogramBuffers {
                    keys_in: src.0,
                    hist: &self.hist,
                },
                &p,
            )?;
            self.scan.record(rec, &self.hist, blocks * RADIX)?;
            rec.dispatch_linear(
                &RADIX_SCATTER,
                blocks as u32,
                bind::RadixScatterBuffers {
                    keys_in: src.0,
                    hist: &self.hist,
                    vals_in: src.1,
                    keys_out: dst.0,
                    vals_out: dst.1,
                },
                &p,
            )?;
            std::mem::swap(&mut src, &mut dst);
        }
        if passes % 2 == 1 {
            rec.copy(&self.keys_alt, 0, keys, 0, n * 4)?;
            rec.copy(&self.vals_alt, 0, values, 0, n * 4)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::testing::{rng, with_context};
    use latentam_reference::sort::sort_pairs;

    fn check(ctx: &Context, keys: &[u32], key_bits: u32) {
        let n = keys.len() as u64;
        let vals: Vec<u32> = (0..n as u32).collect();
        let kb = ctx.upload_new("test/keys", keys).unwrap();
        let vb = ctx.upload_new("test/vals", &vals).unwrap();
        let sorter = RadixSorter::new(ctx, n).unwrap();
        let mut rec = ctx.recorder().unwrap();
        sorter.record(&mut rec, &kb, &vb, n, key_bits).unwrap();
        rec.submit().unwrap().wait().unwrap();
        let (want_k, want_v) = sort_pairs(keys, &vals, key_bits);
        let got_k = ctx.download::<u32>(&kb).unwrap();
        let got_v = ctx.download::<u32>(&vb).unwrap();
        if let Some(i) = (0..keys.len()).find(|&i| got_k[i] != want_k[i] || got_v[i] != want_v[i]) {
            panic!(
                "n={n} bits={key_bits}: mismatch at {i}: got ({}, {}), want ({}, {})",
                got_k[i], got_v[i], want_k[i], want_v[i]
            );
        }
    }

    #[test]
    fn sort_matches_reference_and_is_stable() {
        let mut r = rng("sort_matches_reference_and_is_stable");
        with_context(|ctx| {
            for n in [0usize, 1, 2, 3, 2047, 2048, 2049, 100_000] {
                // Few distinct keys, so stability is exercised.
                let keys: Vec<u32> = (0..n)
                    .map(|_| r.random_range(0..50) * 0x0101_0101)
                    .collect();
                check(ctx, &keys, 32);
            }
            let n = r.random_range(300_000..700_000);
            let keys: Vec<u32> = (0..n).map(|_| r.random()).collect();
            check(ctx, &keys, 32);
        });
    }

    #[test]
    fn sort_by_low_bits_only() {
        let mut r = rng("sort_by_low_bits_only");
        with_context(|ctx| {
            for bits in [1u32, 4, 13, 16, 31] {
                let keys: Vec<u32> = (0..50_000).map(|_| r.random()).collect();
                check(ctx, &keys, bits);
            }
        });
    }

    #[test]
    fn sort_of_eight_million_keys() {
        let mut r = rng("sort_of_eight_million_keys");
        with_context(|ctx| {
            let keys: Vec<u32> = (0..8_388_608).map(|_| r.random()).collect();
            check(ctx, &keys, 32);
        });
    }
}
