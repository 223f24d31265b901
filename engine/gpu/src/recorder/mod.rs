//! Command recording: the one way to dispatch a kernel. The recorder binds
//! buffers by the kernel's declared bindings, inserts the memory barriers that
//! read-after-write and write-after-read hazards need, writes profiler
//! timestamps, and submits with a timeline-semaphore signal.

use std::collections::HashSet;
use std::marker::PhantomData;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use ash::vk;
use latentam_shaders::{BindingSet, Kernel, KernelDef};

use super::buffer::{Buffer, BufferKind, Readback};
use super::context::{Context, Device, Queue};
use super::objects::ObjectKind;
use super::retire::Retired;
use latentam_base::{Error, Result, VkContext};

mod dispatch;
mod submission;
mod sync_point;
mod timestamps;
mod transfers;

pub use submission::{GpuSpan, Submission};
pub use sync_point::SyncPoint;
use timestamps::{QueryBlock, QUERIES_PER_POOL};

const SETS_PER_POOL: u32 = 64;
const MAX_BINDINGS: u32 = 16;

/// Which queue a recorder submits to.
///
/// ```
/// use latentam_gpu::QueueKind;
///
/// // `Context::recorder` records for the compute queue, `Context::transfer_recorder`
/// // for the transfer queue.
/// let kind = QueueKind::Transfer;
/// assert_ne!(kind, QueueKind::Compute);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum QueueKind {
    /// The compute queue: kernels and copies.
    Compute,
    /// The dedicated transfer queue when the device has one (copies only),
    /// otherwise the compute queue.
    Transfer,
}

/// How many workgroups a dispatch runs: known now, or read by the GPU from
/// a buffer (x, y, z at a byte offset) when it runs.
#[derive(Clone, Copy)]
enum Groups<'a> {
    Direct([u32; 3]),
    Indirect(&'a Buffer, u64),
}

/// Records GPU work. Buffers used by recorded commands are borrowed for the
/// recorder's lifetime, so they cannot be dropped before submission; after
/// submission their deferred destruction keeps them alive until the GPU is
/// done.
///
/// ```no_run
/// # use latentam_gpu::*;
/// let ctx = Context::new(ContextOptions::default())?;
/// let buf = Buffer::device(&ctx, "example/buf", 1024)?;
/// let mut rec = ctx.recorder()?;
/// rec.fill_u32(&buf, 0);
/// rec.submit()?.wait()?;
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
pub struct Recorder<'a> {
    dev: Arc<Device>,
    transfer: bool,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    desc_pools: Vec<vk::DescriptorPool>,
    sets_left: u32,
    written: HashSet<vk::Buffer>,
    read: HashSet<vk::Buffer>,
    /// Staging buffers the recorded copies use, released (into deferred
    /// destruction) only once the work is submitted.
    keep: Vec<Arc<Buffer>>,
    queries: Vec<QueryBlock>,
    labels: Vec<(&'static str, u32, u32)>,
    waits: Vec<SyncPoint>,
    host_reads: bool,
    readbacks: Vec<Arc<AtomicU64>>,
    span_start: Option<u32>,
    /// A clock calibration's own batch: neither its submission nor its
    /// wait is the caller's work, so neither is counted or traced.
    calibration: bool,
    /// Set by [`Recorder::overlap_other_queue`]: the batch does not wait for
    /// the other queue's earlier submissions.
    overlaps_other_queue: bool,
    /// Set by [`Recorder::detach`]: the other queue's later batches do not
    /// wait for this one either.
    detached: bool,
    /// Whether a command touching a buffer has been recorded yet.
    touched: bool,
    /// The work the caller stated for the next dispatch
    /// ([`Recorder::work_of_next`]).
    next_work: Option<latentam_shaders::Work>,
    _borrows: PhantomData<&'a Buffer>,
}

impl Context {
    /// Starts recording work for the compute queue.
    pub fn recorder(&self) -> Result<Recorder<'_>> {
        Recorder::new(self, QueueKind::Compute)
    }

    /// Starts recording copies for the transfer queue (the compute queue on
    /// devices without a dedicated one).
    pub fn transfer_recorder(&self) -> Result<Recorder<'_>> {
        Recorder::new(self, QueueKind::Transfer)
    }

    /// Creates a device buffer holding `data` (uploads and waits).
    pub fn upload_new<T: bytemuck::Pod>(&self, name: &str, data: &[T]) -> Result<Buffer> {
        let buf = Buffer::device(self, name, std::mem::size_of_val(data) as u64)?;
        self.upload(&buf, 0, data)?;
        Ok(buf)
    }

    /// Writes `data` at byte `offset` of `buf` (uploads and waits).
    pub fn upload<T: bytemuck::Pod>(&self, buf: &Buffer, offset: u64, data: &[T]) -> Result<()> {
        let mut rec = self.recorder()?;
        rec.upload(buf, offset, data)?;
        rec.submit()?.wait()
    }

    /// Reads a whole device buffer as `T`s (waits).
    pub fn download<T: bytemuck::Pod>(&self, buf: &Buffer) -> Result<Vec<T>> {
        let mut rec = self.recorder()?;
        let rb = rec.download(buf, 0, buf.bytes())?;
        rec.submit()?.wait()?;
        rb.read()
    }
}

impl<'a> Recorder<'a> {
    fn new(ctx: &'a Context, kind: QueueKind) -> Result<Self> {
        let dev = ctx.dev.clone();
        dev.collect();
        let transfer = kind == QueueKind::Transfer && dev.transfer.is_some();
        let family = if transfer {
            dev.transfer
                .as_ref()
                .map(|q| q.family)
                .unwrap_or(dev.compute.family)
        } else {
            dev.compute.family
        };
        // SAFETY: valid create/alloc infos; the pool is retired with the
        // recorder or its submission.
        unsafe {
            let pool = dev
                .raw
                .create_command_pool(
                    &vk::CommandPoolCreateInfo::default()
                        .queue_family_index(family)
                        .flags(vk::CommandPoolCreateFlags::TRANSIENT),
                    None,
                )
                .vk("vkCreateCommandPool")?;
            let cmd = match dev.raw.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(pool)
                    .level(vk::CommandBufferLevel::PRIMARY)
                    .command_buffer_count(1),
            ) {
                Ok(c) => c[0],
                Err(e) => {
                    dev.raw.destroy_command_pool(pool, None);
                    return Err(e).vk("vkAllocateCommandBuffers");
                }
            };
            if let Err(e) = dev.raw.begin_command_buffer(
                cmd,
                &vk::CommandBufferBeginInfo::default()
                    .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
            ) {
                dev.raw.destroy_command_pool(pool, None);
                return Err(e).vk("vkBeginCommandBuffer");
            }
            dev.objects.created(ObjectKind::CommandPool);
            Ok(Self {
                dev,
                transfer,
                pool,
                cmd,
                desc_pools: Vec::new(),
                sets_left: 0,
                written: HashSet::new(),
                read: HashSet::new(),
                keep: Vec::new(),
                queries: Vec::new(),
                labels: Vec::new(),
                waits: Vec::new(),
                host_reads: false,
                readbacks: Vec::new(),
                span_start: None,
                calibration: false,
                overlaps_other_queue: false,
                detached: false,
                touched: false,
                next_work: None,
                _borrows: PhantomData,
            })
        }
    }

    /// [`Context::kernel_builds`] from a recorder.
    pub fn kernel_builds(&self, kernel: &'static Kernel) -> Result<bool> {
        let dev = &self.dev;
        dev.pipelines.builds(&dev.raw, dev.pipeline_cache, kernel)
    }

    /// The device this recorder records for.
    pub fn info(&self) -> &super::DeviceInfo {
        &self.dev.info
    }

    /// Lets this batch run beside what was submitted to the other queue
    /// before it, instead of after it (the default, see
    /// [`Recorder::submit`]). Only for a batch that touches no buffer that
    /// work reads or writes: Stage II beside the window's paging, say.
    /// Later batches of either queue still wait for both.
    pub fn overlap_other_queue(&mut self) {
        self.overlaps_other_queue = true;
    }

    /// Detaches this batch from the other queue both ways: it runs beside
    /// what that queue was given before it (as with
    /// [`Recorder::overlap_other_queue`]), and that queue's later batches
    /// do not wait for it either. A batch that needs its results waits for
    /// it by name ([`Recorder::wait_for`] with its
    /// [`Submission::sync_point`]). Only for a batch that touches no buffer
    /// the other queue's work reads or writes meanwhile: uploading the
    /// next window sync's arrivals into a staging buffer of their own while
    /// Stage I trains, say. Batches of its own queue still run after it.
    ///
    /// ```no_run
    /// # use latentam_gpu::*;
    /// # fn f(ctx: &Context, inbox: &Buffer, rows: &Buffer, data: &[u32]) -> latentam_gpu::Result<()> {
    /// let mut upload = ctx.transfer_recorder()?;
    /// upload.detach();
    /// upload.upload(inbox, 0, data)?;
    /// let uploaded = upload.submit()?;
    /// // ... compute work that does not wait for the upload ...
    /// let mut rec = ctx.recorder()?;
    /// rec.wait_for(uploaded.sync_point());
    /// rec.copy(inbox, 0, rows, 0, inbox.bytes())?;
    /// rec.submit()?.wait()?;
    /// # Ok(())
    /// # }
    /// ```
    pub fn detach(&mut self) {
        self.overlaps_other_queue = true;
        self.detached = true;
    }

    /// Makes this batch wait (on the GPU) for `point` before it starts.
    pub fn wait_for(&mut self, point: SyncPoint) {
        self.waits.push(point);
    }

    /// Inserts a barrier if the next command touches a buffer in a
    /// conflicting way with commands since the last barrier.
    ///
    /// The first such command also gets a barrier: it orders this batch
    /// after every batch submitted before it to the same queue, whose
    /// writes it may read (separate submissions to one queue may overlap
    /// and need not see each other's writes without one, even when the
    /// host waited for the earlier batch).
    fn track(&mut self, reads: &[vk::Buffer], writes: &[vk::Buffer]) {
        if !self.touched {
            self.touched = true;
            self.barrier();
        }
        let hazard = reads.iter().any(|b| self.written.contains(b))
            || writes
                .iter()
                .any(|b| self.written.contains(b) || self.read.contains(b));
        if hazard {
            self.barrier();
        }
        self.read.extend(reads.iter().copied());
        self.written.extend(writes.iter().copied());
    }

    /// Forgets what the batch touched since its last barrier, so that the
    /// next command gets none: plants a hazard for the test that checks
    /// synchronization validation sees one.
    #[cfg(test)]
    pub(crate) fn forget_hazards(&mut self) {
        self.written.clear();
        self.read.clear();
    }

    /// A full memory barrier between all compute and transfer work recorded
    /// before and after it. The recorder inserts these itself; call it only
    /// around work it cannot see.
    pub fn barrier(&mut self) {
        // A transfer-only queue has no shader stages: its barriers name the
        // transfer stage and transfer accesses alone (naming shader accesses
        // there is invalid, and drivers may ignore the whole barrier).
        let (src_access, dst_access, src, dst) = if self.transfer {
            (
                vk::AccessFlags::TRANSFER_WRITE,
                vk::AccessFlags::TRANSFER_READ | vk::AccessFlags::TRANSFER_WRITE,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::TRANSFER,
            )
        } else {
            let work = vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER;
            (
                vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE,
                vk::AccessFlags::SHADER_READ
                    | vk::AccessFlags::SHADER_WRITE
                    | vk::AccessFlags::TRANSFER_READ
                    | vk::AccessFlags::TRANSFER_WRITE
                    | vk::AccessFlags::INDIRECT_COMMAND_READ,
                work,
                // Indirect dispatches read their counts at DRAW_INDIRECT.
                work | vk::PipelineStageFlags::DRAW_INDIRECT,
            )
        };
        let mb = [vk::MemoryBarrier::default()
            .src_access_mask(src_access)
            .dst_access_mask(dst_access)];
        // SAFETY: recording into our own command buffer.
        unsafe {
            self.dev.raw.cmd_pipeline_barrier(
                self.cmd,
                src,
                dst,
                vk::DependencyFlags::empty(),
                &mb,
                &[],
                &[],
            )
        };
        self.written.clear();
        self.read.clear();
    }

    fn timestamp(&mut self, stage: vk::PipelineStageFlags) -> Option<u32> {
        self.dev.profiler.as_ref()?;
        self.write_query(stage)
    }

    /// Writes a timestamp into the recorder's query pools; `None` where
    /// this queue cannot write (or reset) timestamps.
    fn write_query(&mut self, stage: vk::PipelineStageFlags) -> Option<u32> {
        if self.queue().timestamp_bits == 0 {
            return None;
        }
        // Only graphics and compute queues can reset a query pool in a
        // command buffer; elsewhere it must be reset from the host.
        if self.transfer && !self.dev.host_query_reset {
            return None;
        }
        let need_new = self
            .queries
            .last()
            .is_none_or(|q| q.used == QUERIES_PER_POOL);
        if need_new {
            // SAFETY: valid create info; the pool is reset before first use
            // and retired with the submission.
            let pool = unsafe {
                self.dev.raw.create_query_pool(
                    &vk::QueryPoolCreateInfo::default()
                        .query_type(vk::QueryType::TIMESTAMP)
                        .query_count(QUERIES_PER_POOL),
                    None,
                )
            };
            let pool = match pool {
                Ok(p) => p,
                Err(e) => {
                    log::warn!("timestamps disabled for this batch: vkCreateQueryPool: {e}");
                    return None;
                }
            };
            // SAFETY: the pool is new and unused by any submission.
            unsafe {
                if self.dev.host_query_reset {
                    self.dev.raw.reset_query_pool(pool, 0, QUERIES_PER_POOL);
                } else {
                    self.dev
                        .raw
                        .cmd_reset_query_pool(self.cmd, pool, 0, QUERIES_PER_POOL);
                }
            }
            self.dev.objects.created(ObjectKind::QueryPool);
            self.queries.push(QueryBlock { pool, used: 0 });
        }
        let block = self.queries.len() - 1;
        let q = self.queries.last_mut()?;
        let idx = q.used;
        q.used += 1;
        // SAFETY: the query was reset above.
        unsafe {
            self.dev
                .raw
                .cmd_write_timestamp(self.cmd, stage, q.pool, idx)
        };
        Some(block as u32 * QUERIES_PER_POOL + idx)
    }

    /// Marks this batch as a profiler clock calibration (see
    /// `Context::calibrate_host_clock`).
    pub(crate) fn for_calibration(&mut self) {
        self.calibration = true;
    }

    /// Times this batch on the GPU: a timestamp is written now and one when
    /// the batch ends, read by [`Submission::wait_span`]. Call it first,
    /// before recording the work to be timed. No effect on queues without
    /// timestamps.
    pub fn start_span(&mut self) {
        if self.span_start.is_none() {
            self.span_start = self.write_query(vk::PipelineStageFlags::TOP_OF_PIPE);
        }
    }

    fn queue(&self) -> &Queue {
        self.dev.queue(self.transfer)
    }

    /// The other queue's batch this one waits for without being told.
    /// With two queues, a batch waits for everything submitted earlier to
    /// the other queue: submission order is dependency order across queues
    /// (and the semaphore makes the other queue's writes visible). To
    /// overlap two batches, submit the one that must not wait first, with
    /// [`Recorder::overlap_other_queue`]. A semaphore's value counts
    /// batches in submission order, so waiting for the other queue's last
    /// attached batch leaves a later detached one ([`Recorder::detach`])
    /// free to run on.
    pub(crate) fn implicit_wait(&self) -> Option<SyncPoint> {
        if self.dev.transfer.is_none() || self.overlaps_other_queue {
            return None;
        }
        let other = self
            .dev
            .queue(!self.transfer)
            .attached
            .load(Ordering::SeqCst);
        (other > 0).then_some(SyncPoint {
            transfer: !self.transfer,
            value: other,
        })
    }

    /// Ends recording and submits. The returned [`Submission`] can be waited
    /// on, or its [`SyncPoint`] passed to another recorder.
    pub fn submit(mut self) -> Result<Submission> {
        let span = match self.span_start {
            Some(s) => self
                .write_query(vk::PipelineStageFlags::BOTTOM_OF_PIPE)
                .map(|e| (s, e)),
            None => None,
        };
        if self.host_reads {
            let mb = [vk::MemoryBarrier::default()
                .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                .dst_access_mask(vk::AccessFlags::HOST_READ)];
            // SAFETY: recording into our own command buffer.
            unsafe {
                self.dev.raw.cmd_pipeline_barrier(
                    self.cmd,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::PipelineStageFlags::HOST,
                    vk::DependencyFlags::empty(),
                    &mb,
                    &[],
                    &[],
                )
            };
        }
        // SAFETY: ending our own command buffer.
        unsafe { self.dev.raw.end_command_buffer(self.cmd) }.vk("vkEndCommandBuffer")?;
        if !self.calibration {
            self.dev.calls.submitted();
        }

        let dev = self.dev.clone();
        let transfer = self.transfer;
        if let Some(point) = self.implicit_wait() {
            self.waits.push(point);
        }
        let mut wait_sems = Vec::new();
        let mut wait_values = Vec::new();
        for w in &self.waits {
            wait_sems.push(dev.queue(w.transfer).timeline);
            wait_values.push(w.value);
        }
        let wait_stages = vec![vk::PipelineStageFlags::ALL_COMMANDS; wait_sems.len()];
        let q = dev.queue(transfer);
        let cmds = [self.cmd];
        let signal = [q.timeline];
        let value = {
            let guard = q.queue.lock().unwrap_or_else(|p| p.into_inner());
            let value = q.submitted.load(Ordering::SeqCst) + 1;
            let values = [value];
            let mut ti = vk::TimelineSemaphoreSubmitInfo::default()
                .wait_semaphore_values(&wait_values)
                .signal_semaphore_values(&values);
            let submit = vk::SubmitInfo::default()
                .wait_semaphores(&wait_sems)
                .wait_dst_stage_mask(&wait_stages)
                .command_buffers(&cmds)
                .signal_semaphores(&signal)
                .push_next(&mut ti);
            if latentam_base::faults::device_lost() {
                return Err(Error::DeviceLost {
                    call: "vkQueueSubmit",
                });
            }
            // SAFETY: the command buffer is complete; the queue is externally
            // synchronised by `guard`.
            unsafe { dev.raw.queue_submit(*guard, &[submit], vk::Fence::null()) }
                .vk("vkQueueSubmit")?;
            q.submitted.store(value, Ordering::SeqCst);
            if !self.detached {
                q.attached.store(value, Ordering::SeqCst);
            }
            value
        };
        for r in self.readbacks.drain(..) {
            r.store(value, Ordering::SeqCst);
        }
        // Everything the batch used is retired behind this submission.
        let pool = std::mem::replace(&mut self.pool, vk::CommandPool::null());
        dev.retire(Retired::CommandPool(pool));
        for p in self.desc_pools.drain(..) {
            dev.retire(Retired::DescriptorPool(p));
        }
        self.keep.clear();
        Ok(Submission {
            dev,
            point: SyncPoint { transfer, value },
            queries: std::mem::take(&mut self.queries),
            labels: std::mem::take(&mut self.labels),
            span,
            calibration: self.calibration,
        })
    }
}

impl Drop for Recorder<'_> {
    fn drop(&mut self) {
        // Only reached without submission (or after it, with nothing left).
        if self.pool != vk::CommandPool::null() {
            self.dev.retire(Retired::CommandPool(self.pool));
        }
        for p in self.desc_pools.drain(..) {
            self.dev.retire(Retired::DescriptorPool(p));
        }
        for q in self.queries.drain(..) {
            self.dev.retire(Retired::QueryPool(q.pool));
        }
    }
}
