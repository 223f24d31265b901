//! What `bench live` reports: the JSON it writes, section by section.

use latentam_core::live::DropCounts;
use serde::Serialize;

/// A latency sample, summarised.
#[derive(Serialize, Clone, Copy)]
pub(super) struct Latencies {
    pub(super) count: usize,
    pub(super) p50_ms: f64,
    pub(super) p99_ms: f64,
    pub(super) max_ms: f64,
}

impl Latencies {
    pub(super) fn of(ms: &[f64]) -> Option<Self> {
        if ms.is_empty() {
            return None;
        }
        let mut s = ms.to_vec();
        s.sort_by(f64::total_cmp);
        let at = |q: f64| s[((s.len() as f64 * q).ceil() as usize).clamp(1, s.len()) - 1];
        Some(Latencies {
            count: s.len(),
            p50_ms: at(0.5),
            p99_ms: at(0.99),
            max_ms: s[s.len() - 1],
        })
    }
}

/// Time from opening the device to every kernel compiled.
#[derive(Serialize)]
pub(super) struct Ready {
    /// With empty driver and engine caches (a new machine), ms.
    pub(super) cold_ms: f64,
    /// Again with the caches the cold start filled, ms.
    pub(super) warm_ms: f64,
    /// Bytes of the pipeline cache file the warm start loaded.
    pub(super) warm_cache_bytes: usize,
    /// What building the kernels cost in each start.
    pub(super) cold_builds: latentam_core::mapper::KernelBuilds,
    pub(super) warm_builds: latentam_core::mapper::KernelBuilds,
}

/// The first keyframe's times against the next five's.
#[derive(Serialize)]
pub(super) struct FirstKeyframe {
    pub(super) stage_one_ms: Vec<f64>,
    pub(super) total_ms: Vec<f64>,
    /// Stage I of the first keyframe over the median of the next five.
    pub(super) first_over_median_of_later: f64,
    /// The whole first keyframe over the median of the next five.
    pub(super) total_first_over_median_of_later: f64,
}

/// One pass of the scene through the live handle.
#[derive(Serialize)]
pub(super) struct Pass {
    /// How the frames were submitted.
    pub(super) fed: &'static str,
    /// What a second thread asked while the scene was submitted.
    pub(super) probing: &'static str,
    pub(super) submitted: u64,
    pub(super) keyframes: u64,
    pub(super) dropped: DropCounts,
    pub(super) wall_s: f64,
    /// Mean mapping time per keyframe (the worker's), ms.
    pub(super) mapping_ms_per_keyframe: f64,
    /// Keyframes per second of mapping time.
    pub(super) keyframes_per_mapping_s: f64,
    pub(super) submit: Option<Latencies>,
    /// Relevance of one vocabulary word on the live map's snapshots.
    pub(super) live_map_queries: Option<Latencies>,
    /// Relevance of one embedding on the large snapshot.
    pub(super) large_snapshot_queries: Option<Latencies>,
    pub(super) renders: Option<Latencies>,
    pub(super) last_keyframe_latency_ms: Option<f64>,
    pub(super) gaussians: usize,
}

#[derive(Serialize)]
pub(super) struct LargeSnapshot {
    pub(super) gaussians: u64,
    pub(super) atoms: u64,
    pub(super) dim: u64,
    /// Building its relevance index (what the indexer thread spends on
    /// each new snapshot of this size).
    pub(super) index_build_ms: f64,
    pub(super) index_bytes: u64,
    pub(super) mean_atoms_per_gaussian: f64,
}

#[derive(Serialize)]
pub(super) struct Report {
    pub(super) device: String,
    pub(super) cores: usize,
    pub(super) frames: u64,
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) dim: u64,
    pub(super) rate_hz: f64,
    pub(super) query_hz: f64,
    pub(super) queue_frames: u64,
    pub(super) ready: Ready,
    pub(super) first_keyframe_cold: FirstKeyframe,
    pub(super) first_keyframe_warm: FirstKeyframe,
    pub(super) large_snapshot: LargeSnapshot,
    pub(super) passes: Vec<Pass>,
    /// Mapping throughput with queries over without.
    pub(super) throughput_with_queries: f64,
    pub(super) abort_ms: f64,
}
