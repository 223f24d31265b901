//! The GPU work model of a run: per keyframe, what each kernel's
//! dispatches need in arithmetic and bytes (counted from their launch
//! sizes), the dispatches and host waits, and the floor this puts on the
//! time per keyframe on named GPUs. Until a GPU measures the engine, this
//! is what its real-time claim rests on.

use std::collections::BTreeMap;

use latentam_gpu::{Floor, GpuCalls, GpuModel, GpuWork};
use serde::Serialize;

use super::keyframe_report::KeyframeGpuCalls;

/// One kernel's work per keyframe (means over the run's keyframes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct KernelWorkPerKeyframe {
    /// Dispatches.
    pub dispatches: f64,
    /// Of those, dispatches whose work nothing counted.
    pub uncounted: f64,
    /// Arithmetic, 10⁹ operations.
    pub gflop: f64,
    /// GPU memory read plus written, 10⁶ bytes.
    pub mb: f64,
}

/// What the run's keyframes asked of the GPU and the least time that
/// takes on the GPUs of [`GpuModel::presets`] (and any given).
///
/// ```no_run
/// # fn f(report: &latentam_core::mapper::RunReport) {
/// let w = &report.gpu_work;
/// println!("{:.1} GFLOP and {:.0} MB per keyframe", w.gflop_per_keyframe, w.mb_per_keyframe);
/// for floor in &w.floors {
///     println!("at least {:.1} ms per keyframe on {}", floor.total_ms, floor.gpu);
/// }
/// # }
/// ```
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct GpuWorkReport {
    /// Keyframes the means are over.
    pub keyframes: u64,
    /// Arithmetic per keyframe, 10⁹ operations.
    pub gflop_per_keyframe: f64,
    /// GPU memory traffic per keyframe, 10⁶ bytes.
    pub mb_per_keyframe: f64,
    /// Host to device, 10⁶ bytes per keyframe.
    pub uploaded_mb_per_keyframe: f64,
    /// Device to host, 10⁶ bytes per keyframe.
    pub downloaded_mb_per_keyframe: f64,
    /// Dispatches per keyframe.
    pub dispatches_per_keyframe: f64,
    /// Host waits per keyframe.
    pub host_waits_per_keyframe: f64,
    /// Dispatches per keyframe whose work nothing counted (their work is
    /// missing from the figures above, their launch cost is not).
    pub uncounted_dispatches_per_keyframe: f64,
    /// Per kernel (copies between device buffers as `copy`, fills as
    /// `fill`).
    pub kernels: BTreeMap<&'static str, KernelWorkPerKeyframe>,
    /// The floor per keyframe on each GPU model.
    pub floors: Vec<Floor>,
}

impl GpuWorkReport {
    /// From the work the keyframes recorded (`MapperStats::gpu_work`) and
    /// their calls, with floors on `models`.
    ///
    /// ```
    /// use latentam_core::mapper::GpuWorkReport;
    /// let none = GpuWorkReport::of(&Default::default(), &[], &latentam_gpu::GpuModel::presets());
    /// assert_eq!((none.keyframes, none.gflop_per_keyframe), (0, 0.0));
    /// ```
    pub fn of(work: &GpuWork, keyframes: &[KeyframeGpuCalls], models: &[GpuModel]) -> Self {
        let n = keyframes.len() as f64;
        let per = n.max(1.0);
        let calls = keyframes
            .iter()
            .fold(GpuCalls::default(), |sum, k| sum + k.total());
        let kernels = work
            .kernels
            .iter()
            .map(|(name, k)| {
                let mean = KernelWorkPerKeyframe {
                    dispatches: k.dispatches as f64 / per,
                    uncounted: k.uncounted as f64 / per,
                    gflop: k.flops / 1e9 / per,
                    mb: k.bytes / 1e6 / per,
                };
                (*name, mean)
            })
            .collect();
        GpuWorkReport {
            keyframes: keyframes.len() as u64,
            gflop_per_keyframe: work.flops() / 1e9 / per,
            mb_per_keyframe: work.bytes() / 1e6 / per,
            uploaded_mb_per_keyframe: work.uploaded_bytes as f64 / 1e6 / per,
            downloaded_mb_per_keyframe: work.downloaded_bytes as f64 / 1e6 / per,
            dispatches_per_keyframe: calls.dispatches as f64 / per,
            host_waits_per_keyframe: calls.host_waits as f64 / per,
            uncounted_dispatches_per_keyframe: work.uncounted() as f64 / per,
            kernels,
            floors: models.iter().map(|m| m.floor(work, calls, per)).collect(),
        }
    }

    /// One line for a summary.
    pub fn summary(&self) -> String {
        let floors: Vec<String> = self
            .floors
            .iter()
            .map(|f| format!("{:.1} ms on {}", f.total_ms, f.gpu))
            .collect();
        format!(
            "GPU work per keyframe: {:.1} GFLOP, {:.0} MB of GPU memory traffic, {:.0} \
             dispatches, {:.1} host waits; floor {}",
            self.gflop_per_keyframe,
            self.mb_per_keyframe,
            self.dispatches_per_keyframe,
            self.host_waits_per_keyframe,
            floors.join(", ")
        )
    }
}
