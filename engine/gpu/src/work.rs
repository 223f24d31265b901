//! What the recorded work asks of a GPU, counted from launch sizes: per
//! kernel the arithmetic and the bytes of global memory its dispatches need
//! (each kernel's `// @cost` line, or what the dispatching code stated),
//! plus the bytes copied between host and device. With a GPU's peak rate
//! and bandwidth ([`GpuModel`]) this gives a floor on the GPU time: the
//! time no implementation of the same algorithm could beat on that GPU,
//! so a real-time claim can rest on arithmetic before a GPU measures it.

use std::collections::BTreeMap;
use std::ops::Sub;
use std::sync::Mutex;

use latentam_shaders::Work;
use serde::Serialize;

use crate::GpuCalls;

/// The work of one kernel's dispatches (or one kind of copy).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct KernelWork {
    /// Dispatches (or copy commands) recorded.
    pub dispatches: u64,
    /// Of those, dispatches whose work nothing counted (an indirect
    /// dispatch whose `@cost` needs the workgroup counts, or a `caller`
    /// kernel whose dispatching code stated nothing): their work is
    /// missing from `flops` and `bytes`.
    pub uncounted: u64,
    /// Arithmetic operations.
    pub flops: f64,
    /// Bytes of global memory read plus written.
    pub bytes: f64,
}

impl KernelWork {
    fn sub(self, e: KernelWork) -> KernelWork {
        KernelWork {
            dispatches: self.dispatches.saturating_sub(e.dispatches),
            uncounted: self.uncounted.saturating_sub(e.uncounted),
            flops: (self.flops - e.flops).max(0.0),
            bytes: (self.bytes - e.bytes).max(0.0),
        }
    }
}

/// A snapshot of [`crate::Context::gpu_work`]; subtract two to get what
/// was recorded between them.
///
/// ```
/// # use latentam_gpu::*;
/// let ctx = Context::new(ContextOptions::default())?;
/// let buf = Buffer::device(&ctx, "example/buf", 256)?;
/// let before = ctx.gpu_work();
/// ctx.upload(&buf, 0, &[1u32; 64])?;
/// let done = ctx.gpu_work() - before;
/// assert_eq!(done.uploaded_bytes, 256);
/// assert_eq!(done.flops(), 0.0);
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct GpuWork {
    /// By kernel name; copies between device buffers as `copy`, fills as
    /// `fill`.
    pub kernels: BTreeMap<&'static str, KernelWork>,
    /// Bytes copied from host-visible staging into device buffers.
    pub uploaded_bytes: u64,
    /// Bytes copied from device buffers into host-visible staging.
    pub downloaded_bytes: u64,
}

impl GpuWork {
    /// Arithmetic operations of every kernel.
    pub fn flops(&self) -> f64 {
        self.kernels.values().map(|k| k.flops).sum()
    }

    /// Bytes of global memory every kernel and copy moved.
    pub fn bytes(&self) -> f64 {
        self.kernels.values().map(|k| k.bytes).sum()
    }

    /// Dispatches whose work nothing counted.
    pub fn uncounted(&self) -> u64 {
        self.kernels.values().map(|k| k.uncounted).sum()
    }
}

impl std::ops::AddAssign<&GpuWork> for GpuWork {
    fn add_assign(&mut self, other: &GpuWork) {
        for (name, w) in &other.kernels {
            let k = self.kernels.entry(name).or_default();
            k.dispatches += w.dispatches;
            k.uncounted += w.uncounted;
            k.flops += w.flops;
            k.bytes += w.bytes;
        }
        self.uploaded_bytes += other.uploaded_bytes;
        self.downloaded_bytes += other.downloaded_bytes;
    }
}

impl Sub for GpuWork {
    type Output = GpuWork;

    fn sub(self, earlier: GpuWork) -> GpuWork {
        let kernels = self
            .kernels
            .iter()
            .map(|(name, w)| {
                let before = earlier.kernels.get(name).copied().unwrap_or_default();
                (*name, w.sub(before))
            })
            .filter(|(_, w)| w.dispatches > 0)
            .collect();
        GpuWork {
            kernels,
            uploaded_bytes: self.uploaded_bytes.saturating_sub(earlier.uploaded_bytes),
            downloaded_bytes: self
                .downloaded_bytes
                .saturating_sub(earlier.downloaded_bytes),
        }
    }
}

/// The device's running work counts.
#[derive(Default)]
pub(crate) struct WorkCounters {
    inner: Mutex<GpuWork>,
}

impl WorkCounters {
    /// One dispatch (or copy command) of `name`; `work` None when nothing
    /// counted it.
    pub fn recorded(&self, name: &'static str, work: Option<Work>) {
        let mut all = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let k = all.kernels.entry(name).or_default();
        k.dispatches += 1;
        match work {
            Some(w) => {
                k.flops += w.flops;
                k.bytes += w.bytes;
            }
            None => k.uncounted += 1,
        }
    }

    pub fn uploaded(&self, bytes: u64) {
        self.inner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .uploaded_bytes += bytes;
    }

    pub fn downloaded(&self, bytes: u64) {
        self.inner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .downloaded_bytes += bytes;
    }

    pub fn snapshot(&self) -> GpuWork {
        self.inner.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

/// A GPU as the floor needs it: peak rates from its data sheet, and the
/// fixed costs of launching work and waiting for it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GpuModel {
    /// Its name, for reports.
    pub name: String,
    /// Peak FP32 arithmetic, operations per second ÷ 10¹² (a fused
    /// multiply-add counts two, as data sheets count it).
    pub fp32_tflops: f64,
    /// Memory bandwidth, GB/s.
    pub memory_gbs: f64,
    /// Host–device bandwidth for uploads and downloads, GB/s (the PCIe
    /// link of a discrete GPU; the memory bandwidth where host and GPU
    /// share memory).
    pub link_gbs: f64,
    /// Fixed cost of one dispatch in a command buffer (launch, and the
    /// barrier that orders it after the one before), µs.
    pub dispatch_us: f64,
    /// Fixed cost of one host wait: the round trip from submission to
    /// the host seeing the result, with the GPU idle meanwhile, µs.
    pub host_wait_us: f64,
}

impl GpuModel {
    /// NVIDIA GeForce RTX 4090 (Ada, desktop): 82.6 TFLOPS FP32 and
    /// 1008 GB/s (NVIDIA's data sheet), PCIe 4.0 ×16 at about 25 GB/s
    /// achieved; 2 µs a dispatch and 30 µs a host wait, typical of
    /// Vulkan compute on a desktop driver.
    pub fn rtx_4090() -> GpuModel {
        GpuModel {
            name: "NVIDIA GeForce RTX 4090".into(),
            fp32_tflops: 82.6,
            memory_gbs: 1008.0,
            link_gbs: 25.0,
            dispatch_us: 2.0,
            host_wait_us: 30.0,
        }
    }

    /// NVIDIA Jetson AGX Orin 64 GB (Ampere, 2048 CUDA cores at 1.3 GHz):
    /// 5.3 TFLOPS FP32 and 204.8 GB/s of LPDDR5 shared with the CPU (NVIDIA's
    /// data sheet), so uploads move at memory speed; 4 µs a dispatch and
    /// 50 µs a host wait, an embedded driver being slower to launch.
    pub fn jetson_agx_orin() -> GpuModel {
        GpuModel {
            name: "NVIDIA Jetson AGX Orin 64GB".into(),
            fp32_tflops: 5.3,
            memory_gbs: 204.8,
            link_gbs: 204.8,
            dispatch_us: 4.0,
            host_wait_us: 50.0,
        }
    }

    /// The least time, ms, of `flops` operations over `bytes` of memory
    /// traffic on this GPU: the longer of the two at its peak rates (a
    /// kernel can overlap them, not beat either).
    pub fn kernel_ms(&self, flops: f64, bytes: f64) -> f64 {
        (flops / (self.fp32_tflops * 1e9)).max(bytes / (self.memory_gbs * 1e6))
    }

    /// The models reports state their floor on.
    pub fn presets() -> Vec<GpuModel> {
        vec![GpuModel::rtx_4090(), GpuModel::jetson_agx_orin()]
    }

    /// The floor of `work` with `calls`' dispatches and host waits on this
    /// GPU, divided by `per` (the keyframes it took, say): each kernel
    /// takes at least the longer of its arithmetic at the peak rate and
    /// its bytes at the memory bandwidth (it can overlap the two, not beat
    /// either); then every dispatch and host wait its fixed cost, and the
    /// host–device copies at the link's bandwidth. Work that nothing
    /// counted (`GpuWork::uncounted`) adds only its dispatch cost.
    ///
    /// ```
    /// use latentam_gpu::{GpuCalls, GpuModel, GpuWork, KernelWork};
    /// let mut work = GpuWork::default();
    /// // 1 TFLOP over 1 GB: compute-bound on an RTX 4090 (12.1 ms against 1 ms).
    /// work.kernels.insert("gemm_nn", KernelWork { dispatches: 1, uncounted: 0, flops: 1e12, bytes: 1e9 });
    /// let calls = GpuCalls { submissions: 1, host_waits: 1, dispatches: 1, ..GpuCalls::default() };
    /// let floor = GpuModel::rtx_4090().floor(&work, calls, 1.0);
    /// assert!((floor.kernels_ms - 1e12 / 82.6e9).abs() < 1e-9);
    /// assert!((floor.total_ms - floor.kernels_ms - 0.002 - 0.030).abs() < 1e-9);
    /// ```
    pub fn floor(&self, work: &GpuWork, calls: GpuCalls, per: f64) -> Floor {
        let per = per.max(1e-9);
        let mut kernels_ms = 0.0;
        let mut compute_bound_ms = 0.0;
        for k in work.kernels.values() {
            let ms = self.kernel_ms(k.flops, k.bytes) / per;
            kernels_ms += ms;
            if self.kernel_ms(k.flops, 0.0) / per >= ms {
                compute_bound_ms += ms;
            }
        }
        let dispatch_ms = calls.dispatches as f64 * self.dispatch_us / 1e3 / per;
        let host_wait_ms = calls.host_waits as f64 * self.host_wait_us / 1e3 / per;
        let link_ms =
            (work.uploaded_bytes + work.downloaded_bytes) as f64 / (self.link_gbs * 1e6 * per);
        Floor {
            gpu: self.name.clone(),
            kernels_ms,
            compute_bound_ms,
            dispatch_ms,
            host_wait_ms,
            link_ms,
            total_ms: kernels_ms + dispatch_ms + host_wait_ms + link_ms,
        }
    }
}

/// The least time some work can take on a [`GpuModel`], by term.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Floor {
    /// The GPU's name.
    pub gpu: String,
    /// Σ over kernels of max(arithmetic ÷ peak rate, bytes ÷ bandwidth).
    pub kernels_ms: f64,
    /// Of that, the kernels whose arithmetic is the longer term.
    pub compute_bound_ms: f64,
    /// Dispatches × their fixed cost.
    pub dispatch_ms: f64,
    /// Host waits × their round trip.
    pub host_wait_ms: f64,
    /// Uploads and downloads at the link's bandwidth.
    pub link_ms: f64,
    /// The sum: the floor.
    pub total_ms: f64,
}
