//! Buffers sized by the largest batch so far.

use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context};

/// A buffer that grows (by 25 % headroom) when a batch needs more.
pub(super) struct Grow {
    pub(super) name: &'static str,
    pub(super) buf: Option<Buffer>,
}

impl Grow {
    pub(super) const fn new(name: &'static str) -> Self {
        Self { name, buf: None }
    }

    pub(super) fn ensure(&mut self, ctx: &Context, bytes: u64) -> Result<()> {
        let bytes = bytes.max(4);
        if self.buf.as_ref().is_some_and(|b| b.bytes() >= bytes) {
            return Ok(());
        }
        let limit = ctx.info().max_buffer_bytes();
        if bytes > limit {
            return Err(Error::Unsupported(format!(
                "`{}` needs {bytes} bytes, over the device's largest storage buffer ({limit}); \
                 render fewer views or Gaussians per batch",
                self.name
            )));
        }
        self.buf = None;
        // `limit` is a multiple of 16, so padding to whole words stays within it.
        let padded = (bytes + bytes / 4).min(limit).div_ceil(4) * 4;
        self.buf = Some(Buffer::device(ctx, self.name, padded)?);
        Ok(())
    }

    pub(super) fn get(&self) -> &Buffer {
        self.buf
            .as_ref()
            .expect("buffer sized by `ensure` before recording")
    }
}
