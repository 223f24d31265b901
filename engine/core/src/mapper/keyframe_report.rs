//! What the mapper reports: per frame ([`Integrated`]), per keyframe
//! ([`KeyframeReport`], its timings, GPU calls and GPU work) and over the run
//! ([`MapperStats`]).

use super::budget::{MemorySplit, WindowBudget};
use super::trainer::StageOneReport;
use latentam_base::{Error, Result};
use latentam_gpu::{GpuCalls, GpuWork};
use latentam_io::Vocabulary;

/// What the mapper did with a frame ([`Mapper::integrate`](super::Mapper::integrate)).
///
/// ```no_run
/// use latentam_core::mapper::Integrated;
/// # fn f(mapper: &mut latentam_core::mapper::Mapper, frame: &latentam_io::Frame) -> latentam_core::Result<()> {
/// match mapper.integrate(frame)? {
///     Integrated::Skipped => {} // not a keyframe: nothing was trained
///     Integrated::Keyframe(report) => println!("keyframe {}: +{} Gaussians", report.index, report.added),
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, PartialEq)]
pub enum Integrated {
    /// Not a keyframe.
    Skipped,
    /// A keyframe.
    Keyframe(Box<KeyframeReport>),
}

/// One re-synchronisation of the window with the global map, block by
/// block.
///
/// ```
/// # fn f(report: &latentam_core::mapper::KeyframeReport) {
/// for sync in &report.paging {
///     let how = if sync.before_stage_one { "before Stage I" } else { "beside Stage II" };
///     println!(
///         "paging ({how}): {} blocks out, {} in; {} Gaussians out ({} written back), {} in; {} B up, {} B down",
///         sync.blocks_out, sync.blocks_in, sync.evicted, sync.written_back, sync.fetched, sync.bytes_up, sync.bytes_down
///     );
/// }
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct PagingReport {
    /// Gaussians copied back to the global map: those of the leaving
    /// blocks that training changed since their last copy.
    pub written_back: usize,
    /// Gaussians that left the window (their blocks beyond the radius, or
    /// farthest first when the window was full; pruned ones too).
    pub evicted: usize,
    /// Gaussians brought in from the global map.
    pub fetched: usize,
    /// Gaussians within the radius left out because the window was full.
    pub over_capacity: usize,
    /// Blocks that came in.
    pub blocks_in: usize,
    /// Blocks that left.
    pub blocks_out: usize,
    /// Bytes uploaded: the arriving Gaussians and the row lists.
    pub bytes_up: u64,
    /// Bytes downloaded: the Gaussians written back.
    pub bytes_down: u64,
    /// Whether it re-centred the window before Stage I (new Gaussians did
    /// not fit the free rows) rather than after it, beside Stage II. The
    /// host waits for neither before Stage II ends.
    pub before_stage_one: bool,
}

/// What a keyframe asked of the GPU, by stage: submissions, host waits
/// (each a CPU–GPU round trip) and dispatches.
///
/// ```
/// # fn f(report: &latentam_core::mapper::KeyframeReport) {
/// let calls = report.gpu_calls;
/// let (all, training) = (calls.total(), calls.training());
/// println!("{} host waits ({} in training), {} dispatches", all.host_waits, training.host_waits, all.dispatches);
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct KeyframeGpuCalls {
    /// The dictionary's streaming k-means update.
    pub dictionary: GpuCalls,
    /// Rendering what the map explains, seeding, and paging when new
    /// Gaussians do not fit the window.
    pub insertion: GpuCalls,
    /// Stage I: one measuring wait and one for the step, per iteration.
    pub stage_one: GpuCalls,
    /// Stage II: one wait for all its iterations (none on a keyframe that
    /// prunes: pruning's scan, queued after it, is waited for instead).
    pub stage_two: GpuCalls,
    /// Re-synchronising the window beside Stage II.
    pub paging: GpuCalls,
    /// Pruning, on the keyframes that prune: its scan of the window,
    /// submitted after Stage II, whose one wait ends Stage II too.
    pub prune: GpuCalls,
}

impl KeyframeGpuCalls {
    /// Every stage together.
    pub fn total(&self) -> GpuCalls {
        self.dictionary
            + self.insertion
            + self.stage_one
            + self.stage_two
            + self.paging
            + self.prune
    }

    /// Stage I and Stage II together: the optimisation.
    pub fn training(&self) -> GpuCalls {
        self.stage_one + self.stage_two
    }
}

/// Where a keyframe's time went (milliseconds of wall time unless named
/// GPU).
///
/// ```
/// # fn f(report: &latentam_core::mapper::KeyframeReport) {
/// let t = &report.timings;
/// println!("{:.0} ms, of which Stage I {:.1} and Stage II {:.1}", t.total_ms, t.stage_one_ms, t.stage_two_ms);
/// if let Some(gpu) = t.stage_two_gpu_ms {
///     println!("Stage II on the GPU: {gpu:.1} ms");
/// }
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct KeyframeTimings {
    /// Dictionary (streaming k-means) update.
    pub kmeans_ms: f64,
    /// Coverage render, seeding and bringing new Gaussians into the window.
    pub insertion_ms: f64,
    /// Stage I, until its last step is submitted: the first step is not
    /// waited for, so its GPU time shows in Stage II's wait (on one queue)
    /// or Stage II's own (see `stage_two_gpu_ms` and the per-kernel
    /// timings for the GPU's share).
    pub stage_one_ms: f64,
    /// Stage II and the paging beside it, until both finished (and, with
    /// them, Stage I's first step).
    pub stage_two_ms: f64,
    /// GPU time of Stage II's batch, when timestamps are available.
    pub stage_two_gpu_ms: Option<f64>,
    /// Paging on the host: planning, recording, and writing back to the
    /// global map.
    pub paging_cpu_ms: f64,
    /// GPU time of the paging copies, when the transfer queue has
    /// timestamps.
    pub paging_gpu_ms: Option<f64>,
    /// Of that, the time during which Stage II was running too.
    pub paging_hidden_ms: Option<f64>,
    /// The global map's disk tier: reading spilled blocks back around the
    /// camera before seeding, and spilling blocks past `host_budget`
    /// after Stage II (0 while the map fits).
    pub disk_ms: f64,
    /// Pruning.
    pub prune_ms: f64,
    /// The whole keyframe.
    pub total_ms: f64,
}

/// The global map's disk tier (see `host_budget`): what is spilled, and
/// what was moved (by one keyframe in a [`KeyframeReport`], since the map
/// was made in [`MapperStats`]).
///
/// ```
/// # fn f(report: &latentam_core::mapper::KeyframeReport) {
/// let d = report.disk;
/// println!("{} Gaussians in {} blocks on disk ({} B); {} blocks written, {} read back",
///     d.spilled_gaussians, d.spilled_blocks, d.bytes, d.blocks_written, d.blocks_read);
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct DiskReport {
    /// Gaussians spilled to disk.
    pub spilled_gaussians: usize,
    /// Blocks spilled to disk.
    pub spilled_blocks: usize,
    /// Bytes of the scratch file (records read back count until it is
    /// compacted).
    pub bytes: u64,
    /// Blocks written to disk.
    pub blocks_written: u64,
    /// Blocks read back.
    pub blocks_read: u64,
}

/// What a keyframe did.
///
/// ```no_run
/// use latentam_core::mapper::Integrated;
/// # fn f(mapper: &mut latentam_core::mapper::Mapper, frame: &latentam_io::Frame) -> Result<(), Box<dyn std::error::Error>> {
/// if let Integrated::Keyframe(report) = mapper.integrate(frame)? {
///     println!("keyframe {} (frame {}): {} Gaussians, {} on the GPU", report.index, report.frame, report.gaussians, report.resident);
///     println!("{}", serde_json::to_string(&report)?); // one JSON line per keyframe
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct KeyframeReport {
    /// Keyframe number (0-based).
    pub index: u64,
    /// Frame number within the stream (0-based).
    pub frame: u64,
    /// Frame stamp, ns.
    pub stamp_ns: i64,
    /// New Gaussians in the global map.
    pub added: usize,
    /// Stage I's measurements.
    pub stage_one: StageOneReport,
    /// Feature loss of the last Stage II iteration.
    pub stage_two: f64,
    /// Gaussians pruned after this keyframe.
    pub pruned: usize,
    /// Window re-synchronisations of this keyframe.
    pub paging: Vec<PagingReport>,
    /// Timings.
    pub timings: KeyframeTimings,
    /// Gaussians in the global map afterwards.
    pub gaussians: usize,
    /// Gaussians resident on the GPU afterwards.
    pub resident: usize,
    /// GPU bytes allocated afterwards (allocator accounting).
    pub gpu_bytes: u64,
    /// CPU bytes of the global map (the blocks in memory) and the
    /// keyframe history afterwards.
    pub cpu_bytes: u64,
    /// The global map's disk tier afterwards.
    pub disk: DiskReport,
    /// Dictionary atoms after this keyframe's update.
    pub atoms: u32,
    /// The camera's gain over the map's brightness when it took the
    /// keyframe (1 without `exposure_compensation`).
    pub exposure: f32,
    /// What this keyframe asked of the GPU, by stage.
    pub gpu_calls: KeyframeGpuCalls,
    /// The work it recorded for the GPU, counted from launch sizes.
    pub gpu_work: KeyframeGpuWork,
}

/// The work a keyframe recorded for the GPU, counted from the kernels'
/// launch sizes (their `@cost` lines; per kernel in
/// [`MapperStats::gpu_work`]): what a GPU's peak rate and bandwidth turn
/// into a floor on its time (`latentam_gpu::GpuModel::floor`).
///
/// ```
/// # fn f(report: &latentam_core::mapper::KeyframeReport) {
/// let w = report.gpu_work;
/// println!("{:.1} GFLOP, {:.0} MB of GPU memory traffic", w.flops / 1e9, w.bytes / 1e6);
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct KeyframeGpuWork {
    /// Arithmetic operations of its dispatches.
    pub flops: f64,
    /// Bytes of GPU memory its dispatches and device copies read and wrote.
    pub bytes: f64,
    /// Bytes uploaded from the host.
    pub uploaded_bytes: u64,
    /// Bytes downloaded to the host.
    pub downloaded_bytes: u64,
    /// Dispatches whose work nothing counted (missing from the sums).
    pub uncounted_dispatches: u64,
}

impl KeyframeGpuWork {
    /// The totals of `work`.
    pub fn of(work: &GpuWork) -> Self {
        KeyframeGpuWork {
            flops: work.flops(),
            bytes: work.bytes(),
            uploaded_bytes: work.uploaded_bytes,
            downloaded_bytes: work.downloaded_bytes,
            uncounted_dispatches: work.uncounted(),
        }
    }
}

/// Running totals ([`Mapper::stats`](super::Mapper::stats)).
///
/// ```no_run
/// # fn f(mapper: &latentam_core::mapper::Mapper) {
/// let s = mapper.stats();
/// println!("{} of {} frames were keyframes; {} Gaussians ({} on the GPU)", s.keyframes, s.frames, s.gaussians, s.resident);
/// println!("peak GPU {} MiB, peak CPU {} MiB", s.gpu_peak_bytes >> 20, s.cpu_peak_bytes >> 20);
/// # }
/// ```
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct MapperStats {
    /// Frames offered.
    pub frames: u64,
    /// Stamp of the last frame integrated (ns), kept in saved states: a
    /// resumed run goes on after it.
    pub last_frame_stamp_ns: Option<i64>,
    /// Keyframes mapped.
    pub keyframes: u64,
    /// Gaussians in the global map.
    pub gaussians: usize,
    /// Gaussians resident on the GPU.
    pub resident: usize,
    /// How the window was sized (once mapping started).
    pub window: Option<WindowBudget>,
    /// GPU bytes allocated now and at most (allocator accounting, the
    /// whole context).
    pub gpu_bytes: u64,
    /// Highest GPU bytes.
    pub gpu_peak_bytes: u64,
    /// Peak GPU bytes by part (images, latent head, window, staging).
    pub gpu_peak_split: MemorySplit,
    /// CPU bytes of the global map and keyframe history.
    pub cpu_bytes: u64,
    /// Highest CPU bytes after a keyframe.
    pub cpu_peak_bytes: u64,
    /// Gaussians left out of the window for lack of capacity, summed over
    /// syncs.
    pub over_capacity: u64,
    /// Gaussians evicted, summed over syncs.
    pub evicted: u64,
    /// Gaussians fetched, summed over syncs.
    pub fetched: u64,
    /// The global map's disk tier: what is spilled now, and the blocks
    /// written and read since the map was made.
    pub disk: DiskReport,
    /// Timings summed over keyframes.
    pub timings: KeyframeTimings,
    /// GPU work the keyframes recorded, per kernel, summed over keyframes
    /// (counted from launch sizes; see `latentam_gpu::GpuWork`).
    pub gpu_work: GpuWork,
    /// The dimension d_f of the map's embeddings, once a keyframe with
    /// embeddings was mapped. (Not in `report.json`, which names the
    /// model beside the statistics.)
    #[serde(skip)]
    pub embedding_dim: Option<u32>,
    /// The model of the map's embeddings, once a keyframe with embeddings
    /// was mapped.
    #[serde(skip)]
    pub embedding_model: Option<String>,
    /// Keyframes kept for replay (the history may let some go).
    #[serde(skip)]
    pub kept_keyframes: usize,
    /// The id of the run folder version the map was loaded from or last
    /// saved to. (`report.json` has its own.)
    #[serde(skip)]
    pub run_id: Option<String>,
}

impl MapperStats {
    /// Checks that a vocabulary's embeddings suit the map these
    /// statistics describe (its embedding model and dimension), with an
    /// error that says what differs; [`Error::NoEmbeddings`] before a
    /// keyframe with embeddings.
    ///
    /// ```no_run
    /// # fn f(mapper: &latentam_core::mapper::Mapper) -> Result<(), Box<dyn std::error::Error>> {
    /// let vocabulary = latentam_io::read_vocabulary("words.mcap".as_ref(), "/vocabulary")?;
    /// if let Some(v) = vocabulary {
    ///     mapper.stats().check_vocabulary(&v)?; // names the model or dimension that differs
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn check_vocabulary(&self, vocabulary: &Vocabulary) -> Result<()> {
        let Some(dim) = self.embedding_dim else {
            return Err(Error::NoEmbeddings);
        };
        super::dictionary::check_vocabulary(dim, self.embedding_model.as_deref(), vocabulary)
    }
}

impl KeyframeTimings {
    /// Adds `t` to these sums.
    pub(crate) fn add(&mut self, t: &KeyframeTimings) {
        let sum = self;
        let opt = |a: Option<f64>, b: Option<f64>| match (a, b) {
            (None, None) => None,
            (a, b) => Some(a.unwrap_or(0.0) + b.unwrap_or(0.0)),
        };
        sum.kmeans_ms += t.kmeans_ms;
        sum.insertion_ms += t.insertion_ms;
        sum.stage_one_ms += t.stage_one_ms;
        sum.stage_two_ms += t.stage_two_ms;
        sum.stage_two_gpu_ms = opt(sum.stage_two_gpu_ms, t.stage_two_gpu_ms);
        sum.paging_cpu_ms += t.paging_cpu_ms;
        sum.paging_gpu_ms = opt(sum.paging_gpu_ms, t.paging_gpu_ms);
        sum.paging_hidden_ms = opt(sum.paging_hidden_ms, t.paging_hidden_ms);
        sum.disk_ms += t.disk_ms;
        sum.prune_ms += t.prune_ms;
        sum.total_ms += t.total_ms;
    }
}
