//! `report.json`: what a run of a log did, written into its run folder
//! (see [`LogRun`](crate::live::LogRun)).

use std::collections::BTreeMap;

use serde::Serialize;

use super::budget::MemorySplit;
use super::keyframe_report::{KeyframeGpuCalls, KeyframeReport, KeyframeTimings};
use latentam_gpu::KernelStats;
use latentam_io::IngestReport;

/// How a run of a log ended.
///
/// ```
/// use latentam_core::mapper::Ending;
/// # fn f(run: &latentam_core::live::LogRun) {
/// match &run.ending {
///     Ending::Complete | Ending::FrameLimit => println!("mapped {} frames", run.frames),
///     Ending::Interrupted => println!("stopped on request after {} frames", run.frames),
///     Ending::Running => {}
///     Ending::Failed(why) => eprintln!("mapping failed ({why}); the map so far is kept"),
/// }
/// # }
/// ```
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Ending {
    /// The log ended.
    Complete,
    /// [`LogRunOptions::max_frames`](crate::live::LogRunOptions::max_frames) was
    /// reached.
    FrameLimit,
    /// The caller asked it to stop
    /// ([`RunObserver::stop_requested`](crate::live::RunObserver::stop_requested)).
    Interrupted,
    /// The run was still going when this folder was written (an
    /// autosave); a later write replaces it.
    Running,
    /// An error stopped it; what was mapped before is kept.
    Failed(String),
}

/// `report.json` of a run folder.
///
/// ```no_run
/// # fn f(run: &latentam_core::live::LogRun) -> Result<(), Box<dyn std::error::Error>> {
/// let report = run.report(&latentam_core::mapper::new_run_id());
/// println!("{} keyframes at {:.1} fps, peak GPU {} MiB", report.keyframes, report.fps, report.peak_gpu_bytes >> 20);
/// std::fs::write("report.json", serde_json::to_string_pretty(&report)?)?;
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    /// Shared by every file of this version of the run folder.
    pub run_id: String,
    /// The input log, as an absolute path (a run from live topics names
    /// them instead, e.g. `ros2:/latentam`).
    pub log: String,
    /// The Vulkan device it ran on.
    pub device: String,
    /// Time from opening the device to every kernel compiled (the mapper
    /// was ready for its first frame), ms: kept out of every per-keyframe
    /// figure and the kernel table.
    pub time_to_ready_ms: Option<f64>,
    /// Bytes of compiled pipelines the persistent pipeline cache gave at
    /// start (0: a cold start, or a driver that keeps its own cache, as
    /// Mesa's drivers do: see `kernel_builds` for what building cost).
    pub pipeline_cache_loaded_bytes: usize,
    /// What building the kernels cost before the mapper was ready: seconds
    /// on a machine whose driver has never compiled them, milliseconds
    /// once its caches are warm.
    pub kernel_builds: KernelBuilds,
    /// The first keyframe's time over the median of the next five (of
    /// those there are; `None` below two keyframes): above 1, the first
    /// keyframe paid for something the others did not.
    pub first_keyframe_over_median: Option<f64>,
    /// How the run ended.
    pub ending: Ending,
    /// Frames offered to the mapper in this run.
    pub frames: u64,
    /// Frames skipped because a resumed state had mapped them.
    pub frames_skipped_as_already_mapped: u64,
    /// Keyframes of the map (resumed runs included).
    pub keyframes: u64,
    /// Wall time of this run, seconds.
    pub wall_s: f64,
    /// Frames per second of wall time, end to end (reading, decoding,
    /// mapping; embeddings come precomputed in the log).
    pub fps: f64,
    /// Keyframes mapped in this run per second of wall time.
    pub keyframes_per_s: f64,
    /// Gaussians in the map.
    pub gaussians: usize,
    /// Of those, on the GPU.
    pub resident: usize,
    /// The GPU memory budget, bytes.
    pub gpu_budget: u64,
    /// Gaussians the GPU window can hold.
    pub window_capacity: u64,
    /// Peak GPU bytes.
    pub peak_gpu_bytes: u64,
    /// Peak GPU bytes by part (images, latent head, window, staging).
    pub peak_gpu_split: MemorySplit,
    /// Peak bytes of the CPU map and its buffers (counted by the mapper).
    pub peak_cpu_bytes: u64,
    /// Peak resident memory of the whole process as the operating system
    /// measured it (`getrusage`), bytes, when the report was made; `None`
    /// where the platform does not say. It includes the driver's memory
    /// (a CPU driver's GPU memory is host memory) and the caller's.
    pub peak_rss_bytes: Option<u64>,
    /// The global map's disk tier at the end, and the blocks it wrote and
    /// read back over the map's life (see `host_budget`).
    pub disk: super::DiskReport,
    /// Gaussians paged out to the CPU map.
    pub evicted: u64,
    /// Gaussians paged back in.
    pub fetched: u64,
    /// Mean timings per keyframe.
    pub ms_per_keyframe: KeyframeTimings,
    /// What each keyframe asked of the GPU: host waits (each a CPU–GPU
    /// round trip; in all and in Stage I + II), submissions, dispatches.
    pub host_waits_per_keyframe: HostWaits,
    /// The work per keyframe counted from the kernels' launch sizes, and
    /// the floor it puts on the time per keyframe on named GPUs.
    pub gpu_work: super::GpuWorkReport,
    /// Share of paging's GPU time hidden behind training: the arrivals'
    /// upload beside Stage I (on a transfer queue of its own) and the
    /// download of what left beside Stage II.
    pub paging_hidden_share: Option<f64>,
    /// What paging moved per keyframe, on average.
    pub paging_per_keyframe: PagingPerKeyframe,
    /// Whether paging ran on a transfer queue of its own.
    pub dedicated_transfer_queue: bool,
    /// The embedding model named by the log, if any.
    pub embedding_model: Option<String>,
    /// Keyframe count of the last autosave.
    pub autosaved_at: Option<u64>,
    /// Autosaves that failed (mapping went on).
    pub autosave_failures: Vec<String>,
    /// What the log held and what of it was skipped.
    pub ingest: IngestReport,
    /// Per kernel, when profiled.
    pub kernels: BTreeMap<&'static str, KernelStats>,
    /// Every keyframe mapped in this run.
    pub keyframe_reports: Vec<KeyframeReport>,
}

/// What building the kernels cost in the run's process, from the device's
/// build log (`Context::kernel_build_times`).
///
/// ```
/// # fn f(report: &latentam_core::mapper::RunReport) {
/// let b = &report.kernel_builds;
/// println!("{} kernels built, {:.1} s of work", b.kernels, b.work_ms / 1e3);
/// # }
/// ```
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct KernelBuilds {
    /// Kernels built before the mapper was ready.
    pub kernels: usize,
    /// The sum of their build times (pipeline creation and first
    /// dispatch), ms. Pipelines are created on all cores at once, so the
    /// wall time (within `time_to_ready_ms`) can be less.
    pub work_ms: f64,
    /// The five slowest, slowest first: kernel and ms.
    pub slowest: Vec<(String, f64)>,
}

impl KernelBuilds {
    /// From a build log.
    ///
    /// ```
    /// let none = latentam_core::mapper::KernelBuilds::of(&[]);
    /// assert_eq!((none.kernels, none.work_ms), (0, 0.0));
    /// ```
    pub fn of(times: &[latentam_gpu::KernelBuildTime]) -> Self {
        let mut sorted: Vec<_> = times.iter().collect();
        sorted.sort_by(|a, b| b.total_ms().total_cmp(&a.total_ms()));
        KernelBuilds {
            kernels: times.len(),
            work_ms: times.iter().map(|t| t.total_ms()).sum(),
            slowest: sorted
                .iter()
                .take(5)
                .map(|t| (t.kernel.to_string(), t.total_ms()))
                .collect(),
        }
    }
}

/// The first keyframe's total time over the median of the next five;
/// `None` below two keyframes.
///
/// ```
/// use latentam_core::mapper::first_keyframe_over_median;
/// assert_eq!(first_keyframe_over_median(&[30.0, 10.0, 20.0, 10.0]), Some(3.0));
/// assert_eq!(first_keyframe_over_median(&[30.0]), None);
/// ```
pub fn first_keyframe_over_median(total_ms: &[f64]) -> Option<f64> {
    let (first, next) = total_ms.split_first()?;
    let mut next: Vec<f64> = next.iter().take(5).copied().collect();
    if next.is_empty() {
        return None;
    }
    next.sort_by(f64::total_cmp);
    let n = next.len();
    let median = if n % 2 == 1 {
        next[n / 2]
    } else {
        0.5 * (next[n / 2 - 1] + next[n / 2])
    };
    Some(first / median.max(1e-9))
}

/// What paging moved per keyframe, averaged over a run's keyframes (those
/// that did not page count as nothing moved).
///
/// ```
/// # fn f(report: &latentam_core::mapper::RunReport) {
/// let p = &report.paging_per_keyframe;
/// println!("{:.2} MB up, {:.2} MB down, {:.1} blocks in, {:.1} out per keyframe",
///     p.bytes_up / 1e6, p.bytes_down / 1e6, p.blocks_in, p.blocks_out);
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PagingPerKeyframe {
    /// Bytes uploaded: arriving Gaussians and row lists.
    pub bytes_up: f64,
    /// Bytes downloaded: Gaussians written back as their blocks left.
    pub bytes_down: f64,
    /// Blocks that came into the window.
    pub blocks_in: f64,
    /// Blocks that left it.
    pub blocks_out: f64,
}

impl PagingPerKeyframe {
    /// Over the keyframes' [`KeyframeReport::paging`](super::KeyframeReport::paging).
    ///
    /// ```
    /// let none = latentam_core::mapper::PagingPerKeyframe::of(&[]);
    /// assert_eq!(none.bytes_up, 0.0);
    /// ```
    pub fn of(keyframes: &[super::KeyframeReport]) -> Self {
        let n = keyframes.len().max(1) as f64;
        let mean = |f: &dyn Fn(&super::PagingReport) -> f64| {
            keyframes
                .iter()
                .flat_map(|k| k.paging.iter())
                .map(f)
                .sum::<f64>()
                / n
        };
        PagingPerKeyframe {
            bytes_up: mean(&|p| p.bytes_up as f64),
            bytes_down: mean(&|p| p.bytes_down as f64),
            blocks_in: mean(&|p| p.blocks_in as f64),
            blocks_out: mean(&|p| p.blocks_out as f64),
        }
    }
}

/// Host waits per keyframe (mean and most), in all and in Stage I and
/// Stage II together, with the mean submissions and dispatches.
///
/// ```
/// # fn f(report: &latentam_core::mapper::RunReport) {
/// let w = &report.host_waits_per_keyframe;
/// println!("{:.1} host waits per keyframe (at most {}), {:.1} in Stage I + II", w.mean, w.max, w.stage_one_and_two_mean);
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct HostWaits {
    /// Mean host waits per keyframe.
    pub mean: f64,
    /// Most host waits of one keyframe.
    pub max: u64,
    /// Mean host waits of Stage I and II together.
    pub stage_one_and_two_mean: f64,
    /// Most host waits of Stage I and II together.
    pub stage_one_and_two_max: u64,
    /// Mean submissions per keyframe.
    pub submissions_mean: f64,
    /// Mean dispatches per keyframe.
    pub dispatches_mean: f64,
}

impl HostWaits {
    /// Over the keyframes' [`KeyframeReport::gpu_calls`].
    ///
    /// ```
    /// let none = latentam_core::mapper::HostWaits::of(&[]);
    /// assert_eq!((none.mean, none.max), (0.0, 0));
    /// ```
    pub fn of(keyframes: &[KeyframeGpuCalls]) -> Self {
        let n = keyframes.len().max(1) as f64;
        let mean = |f: &dyn Fn(&KeyframeGpuCalls) -> u64| {
            keyframes.iter().map(|k| f(k) as f64).sum::<f64>() / n
        };
        let max = |f: &dyn Fn(&KeyframeGpuCalls) -> u64| keyframes.iter().map(f).max().unwrap_or(0);
        let all = |k: &KeyframeGpuCalls| k.total().host_waits;
        let training = |k: &KeyframeGpuCalls| k.training().host_waits;
        HostWaits {
            mean: mean(&all),
            max: max(&all),
            stage_one_and_two_mean: mean(&training),
            stage_one_and_two_max: max(&training),
            submissions_mean: mean(&|k| k.total().submissions),
            dispatches_mean: mean(&|k| k.total().dispatches),
        }
    }

    /// One line for a summary.
    pub fn summary(&self) -> String {
        format!(
            "host waits on the GPU per keyframe: {:.1} on average, {} at most ({:.1} and {} in \
             Stage I + II); {:.1} submissions and {:.0} dispatches on average",
            self.mean,
            self.max,
            self.stage_one_and_two_mean,
            self.stage_one_and_two_max,
            self.submissions_mean,
            self.dispatches_mean
        )
    }
}

impl KeyframeTimings {
    /// Per-keyframe means of timings summed over `keyframes` keyframes.
    ///
    /// ```
    /// let sum = latentam_core::mapper::KeyframeTimings { total_ms: 30.0, ..Default::default() };
    /// assert_eq!(sum.per_keyframe(3).total_ms, 10.0);
    /// ```
    pub fn per_keyframe(&self, keyframes: u64) -> KeyframeTimings {
        let n = keyframes.max(1) as f64;
        let s = |x: f64| x / n;
        KeyframeTimings {
            kmeans_ms: s(self.kmeans_ms),
            insertion_ms: s(self.insertion_ms),
            stage_one_ms: s(self.stage_one_ms),
            stage_two_ms: s(self.stage_two_ms),
            stage_two_gpu_ms: self.stage_two_gpu_ms.map(s),
            paging_cpu_ms: s(self.paging_cpu_ms),
            paging_gpu_ms: self.paging_gpu_ms.map(s),
            paging_hidden_ms: self.paging_hidden_ms.map(s),
            disk_ms: s(self.disk_ms),
            prune_ms: s(self.prune_ms),
            total_ms: s(self.total_ms),
        }
    }
}
