//! Points on a queue's timeline semaphore.

/// A point on a queue's timeline: "everything submitted up to here".
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context, staging: &latentam_gpu::Buffer, dst: &latentam_gpu::Buffer) -> latentam_gpu::Result<()> {
/// let mut copies = ctx.transfer_recorder()?;
/// copies.copy(staging, 0, dst, 0, staging.bytes())?;
/// let copied = copies.submit()?;
/// let mut rec = ctx.recorder()?;
/// rec.wait_for(copied.sync_point()); // the GPU waits; the host does not
/// let readback = rec.download(dst, 0, dst.bytes())?;
/// rec.submit()?.wait()?;
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SyncPoint {
    pub(crate) transfer: bool,
    pub(crate) value: u64,
}
