//! GPU buffers. Kernels only ever see device-local storage buffers; data moves
//! in and out through explicit host-visible staging buffers, so the same code
//! is correct on discrete GPUs where device memory is not mappable.

use std::sync::Arc;

use ash::vk;
use gpu_allocator::vulkan::{AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;

use super::context::{Context, Device};
use super::objects::ObjectKind;
use super::retire::Retired;
use latentam_base::{Error, Result, VkContext};

/// Where a buffer lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BufferKind {
    /// Device-local storage buffer.
    Device,
    /// Host-visible, written by the CPU, read by transfers.
    Upload,
    /// Host-visible, written by transfers, read by the CPU.
    Readback,
}

/// A Vulkan buffer and its memory. Dropping it frees both once the GPU has
/// finished every submission made before the drop.
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context, ContextOptions};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let buf = Buffer::device(&ctx, "example/weights", 4 * 256)?;
/// assert_eq!(buf.len_of::<f32>(), 256);
/// ctx.upload(&buf, 0, &[1.0f32; 256])?;
/// assert_eq!(ctx.download::<f32>(&buf)?[0], 1.0);
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
pub struct Buffer {
    dev: Arc<Device>,
    pub(crate) raw: vk::Buffer,
    allocation: Option<gpu_allocator::vulkan::Allocation>,
    bytes: u64,
    allocated: u64,
    name: String,
    kind: BufferKind,
}

impl std::fmt::Debug for Buffer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Buffer")
            .field("name", &self.name)
            .field("bytes", &self.bytes)
            .finish()
    }
}

/// The accounting category of a buffer: its name up to the first `/`.
fn category(name: &str) -> &str {
    name.split('/').next().unwrap_or(name)
}

/// Refuses a buffer larger than the device binds or allocates at once.
fn check_size(info: &crate::DeviceInfo, name: &str, bytes: u64, kind: BufferKind) -> Result<()> {
    if kind == BufferKind::Device && bytes > info.max_buffer_bytes() {
        return Err(Error::Unsupported(format!(
            "buffer `{name}` needs {bytes} bytes but {} binds at most {} bytes per storage \
                 buffer and allocates at most {} at once",
            info.name, info.max_storage_buffer_range, info.max_memory_allocation_size
        )));
    }
    let alloc_limit = match info.max_memory_allocation_size {
        0 => u64::MAX,
        n => n,
    };
    if kind != BufferKind::Device && bytes > alloc_limit {
        return Err(Error::Unsupported(format!(
            "staging buffer `{name}` needs {bytes} bytes but {} allocates at most {} at once",
            info.name, info.max_memory_allocation_size
        )));
    }
    Ok(())
}

/// The buffer's memory, from the device's allocator (or a simulated
/// failure under `LATENTAM_FAULTS=alloc_fail_after=N`).
fn allocate(
    dev: &crate::context::Device,
    name: &str,
    requirements: vk::MemoryRequirements,
    location: MemoryLocation,
) -> std::result::Result<gpu_allocator::vulkan::Allocation, gpu_allocator::AllocationError> {
    if latentam_base::faults::allocation_fails() {
        return Err(gpu_allocator::AllocationError::OutOfMemory);
    }
    let mut guard = dev.allocator.lock().unwrap_or_else(|p| p.into_inner());
    let alloc = guard
        .as_mut()
        .expect("allocator lives as long as the device");
    alloc.allocate(&AllocationCreateDesc {
        name,
        requirements,
        location,
        linear: true,
        allocation_scheme: AllocationScheme::GpuAllocatorManaged,
    })
}

impl Buffer {
    pub(crate) fn new(ctx: &Context, name: &str, bytes: u64, kind: BufferKind) -> Result<Self> {
        let dev = &ctx.dev;
        check_size(&dev.info, name, bytes, kind)?;
        // Vulkan forbids empty buffers; keep the logical size separately.
        let alloc_bytes = bytes.max(4).next_multiple_of(4);
        let usage = match kind {
            BufferKind::Device => {
                // Any device buffer may hold a kernel's workgroup counts
                // (`Recorder::dispatch_indirect`).
                vk::BufferUsageFlags::STORAGE_BUFFER
                    | vk::BufferUsageFlags::TRANSFER_SRC
                    | vk::BufferUsageFlags::TRANSFER_DST
                    | vk::BufferUsageFlags::INDIRECT_BUFFER
            }
            BufferKind::Upload => vk::BufferUsageFlags::TRANSFER_SRC,
            BufferKind::Readback => vk::BufferUsageFlags::TRANSFER_DST,
        };
        let families = dev.queue_families();
        let mut ci = vk::BufferCreateInfo::default()
            .size(alloc_bytes)
            .usage(usage);
        ci = if families.len() > 1 {
            // Shared with the transfer queue without ownership transfers.
            ci.sharing_mode(vk::SharingMode::CONCURRENT)
                .queue_family_indices(&families)
        } else {
            ci.sharing_mode(vk::SharingMode::EXCLUSIVE)
        };
        // SAFETY: valid create info.
        let raw = unsafe { dev.raw.create_buffer(&ci, None) }.vk("vkCreateBuffer")?;
        // SAFETY: `raw` was just created on this device.
        let req = unsafe { dev.raw.get_buffer_memory_requirements(raw) };
        let cat = category(name);
        if let Err(e) = dev.memory.reserve(cat, name, req.size) {
            // SAFETY: unused buffer.
            unsafe { dev.raw.destroy_buffer(raw, None) };
            return Err(e);
        }
        let location = match kind {
            BufferKind::Device => MemoryLocation::GpuOnly,
            BufferKind::Upload => MemoryLocation::CpuToGpu,
            BufferKind::Readback => MemoryLocation::GpuToCpu,
        };
        let allocation = allocate(dev, name, req, location);
        let allocation = match allocation {
            Ok(a) => a,
            Err(e) => {
                dev.memory.release(cat, req.size);
                // SAFETY: unused buffer.
                unsafe { dev.raw.destroy_buffer(raw, None) };
                return Err(Error::OutOfMemory(format!(
                    "allocating {} bytes for `{name}`: {e}",
                    req.size
                )));
            }
        };
        dev.objects.created(ObjectKind::Buffer);
        // SAFETY: memory and offset come from an allocation for this buffer.
        if let Err(e) = unsafe {
            dev.raw
                .bind_buffer_memory(raw, allocation.memory(), allocation.offset())
        } {
            dev.retire(Retired::Buffer {
                buffer: raw,
                allocation,
                category: cat.to_string(),
                bytes: req.size,
            });
            return Err(e).vk("vkBindBufferMemory");
        }
        Ok(Self {
            dev: dev.clone(),
            raw,
            allocation: Some(allocation),
            bytes,
            allocated: req.size,
            name: name.to_string(),
            kind,
        })
    }

    /// Creates a device-local storage buffer of `bytes` bytes (contents
    /// undefined). `name` is used in errors and memory reports; its part
    /// before the first `/` is the accounting category.
    pub fn device(ctx: &Context, name: &str, bytes: u64) -> Result<Self> {
        Self::new(ctx, name, bytes, BufferKind::Device)
    }

    /// Logical size in bytes.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// An error naming `context`, this buffer and both sizes when it holds
    /// fewer than `need` bytes (every kernel wrapper checks its operands so
    /// a short buffer is an error rather than an out-of-bounds GPU access).
    pub fn ensure_bytes(&self, need: u64, context: &str) -> Result<()> {
        if self.bytes < need {
            return Err(Error::bad_input(
                context,
                format!("`{}` has {} bytes, needs {need}", self.name, self.bytes),
            ));
        }
        Ok(())
    }

    /// Number of `T` elements that fit.
    pub fn len_of<T>(&self) -> u64 {
        self.bytes / std::mem::size_of::<T>() as u64
    }

    /// The name given at creation.
    pub fn name(&self) -> &str {
        &self.name
    }

    pub(crate) fn kind(&self) -> BufferKind {
        self.kind
    }

    /// Host view of a staging buffer.
    pub(crate) fn mapped(&self) -> &[u8] {
        let s = self
            .allocation
            .as_ref()
            .and_then(|a| a.mapped_slice())
            .expect("staging buffers are host-visible");
        &s[..self.bytes as usize]
    }

    pub(crate) fn mapped_mut(&mut self) -> &mut [u8] {
        let n = self.bytes as usize;
        let s = self
            .allocation
            .as_mut()
            .and_then(|a| a.mapped_slice_mut())
            .expect("staging buffers are host-visible");
        &mut s[..n]
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        if let Some(allocation) = self.allocation.take() {
            self.dev.retire(Retired::Buffer {
                buffer: self.raw,
                allocation,
                category: category(&self.name).to_string(),
                bytes: self.allocated,
            });
        }
    }
}

/// Data read back from the GPU, available after the submission that recorded
/// it has completed (see [`super::Recorder::download`]).
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context, buf: &latentam_gpu::Buffer) -> latentam_gpu::Result<()> {
/// let mut rec = ctx.recorder()?;
/// let readback = rec.download(buf, 0, buf.bytes())?;
/// rec.submit()?.wait()?;
/// let values: Vec<f32> = readback.read()?;
/// assert_eq!(values.len() as u64, buf.len_of::<f32>());
/// # Ok(())
/// # }
/// ```
pub struct Readback {
    /// Shared with the recorder, so dropping the readback before the
    /// submission cannot free the buffer the copy writes into.
    pub(crate) staging: std::sync::Arc<Buffer>,
    pub(crate) transfer: bool,
    pub(crate) after: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl Readback {
    /// Copies the data out as `T`s. Fails if the GPU has not finished the
    /// submission yet.
    pub fn read<T: bytemuck::Pod>(&self) -> Result<Vec<T>> {
        let bytes = self.bytes()?;
        let n = bytes.len() / std::mem::size_of::<T>();
        Ok(bytemuck::pod_collect_to_vec(
            &bytes[..n * std::mem::size_of::<T>()],
        ))
    }

    /// The downloaded bytes in place, in the mapped staging memory (no
    /// copy: for large readbacks consumed once). Errors like
    /// [`Readback::read`] before the submission completed.
    pub fn bytes(&self) -> Result<&[u8]> {
        let done = self.staging.dev.completed();
        let done = if self.transfer { done.1 } else { done.0 };
        if done < self.after.load(std::sync::atomic::Ordering::SeqCst) {
            return Err(Error::bad_input(
                "readback",
                "used before its submission completed; wait on it first",
            ));
        }
        Ok(self.staging.mapped())
    }
}
