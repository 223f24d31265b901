//! GPU timestamp profiler: per-kernel statistics and a Chrome/Perfetto trace.
//!
//! Enable it with [`super::ContextOptions::profiling`]; every dispatch and
//! copy is then bracketed by timestamp queries, read back when its submission
//! is waited on.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use crate::error::{Error, Result};

/// One timed GPU command.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Sample {
    /// Kernel name (or `copy`).
    pub name: &'static str,
    /// Queue it ran on (`compute` or `transfer`).
    pub queue: &'static str,
    /// Start on the device clock, in nanoseconds.
    pub start_ns: f64,
    /// Duration in nanoseconds.
    pub duration_ns: f64,
}

/// Aggregate timings of one kernel.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct KernelStats {
    /// Number of timed dispatches.
    pub count: u64,
    /// Total time, milliseconds.
    pub total_ms: f64,
    /// Mean time, milliseconds.
    pub mean_ms: f64,
    /// Standard deviation, milliseconds.
    pub std_ms: f64,
    /// Fastest dispatch, milliseconds.
    pub min_ms: f64,
    /// Slowest dispatch, milliseconds.
    pub max_ms: f64,
}

/// Collected samples. Obtain it with [`super::Context::profiler_snapshot`].
#[derive(Clone, Debug, Default)]
pub struct Profiler {
    samples: Vec<Sample>,
}

impl Profiler {
    pub(crate) fn record(&mut self, name: &'static str, queue: &'static str, start: f64, dur: f64) {
        self.samples.push(Sample {
            name,
            queue,
            start_ns: start,
            duration_ns: dur,
        });
    }

    /// Every sample, in the order the batches were waited on.
    pub fn samples(&self) -> &[Sample] {
        &self.samples
    }

    /// Per-kernel statistics, keyed by kernel name.
    pub fn stats(&self) -> BTreeMap<&'static str, KernelStats> {
        let mut by: BTreeMap<&'static str, Vec<f64>> = BTreeMap::new();
        for s in &self.samples {
            by.entry(s.name).or_default().push(s.duration_ns * 1e-6);
        }
        by.into_iter()
            .map(|(k, v)| {
                let n = v.len() as f64;
                let total: f64 = v.iter().sum();
                let mean = total / n;
                let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
                (
                    k,
                    KernelStats {
                        count: v.len() as u64,
                        total_ms: total,
                        mean_ms: mean,
                        std_ms: var.sqrt(),
                        min_ms: v.iter().cloned().fold(f64::INFINITY, f64::min),
                        max_ms: v.iter().cloned().fold(0.0, f64::max),
                    },
                )
            })
            .collect()
    }

    /// A plain-text table sorted by total time.
    pub fn table(&self) -> String {
        let stats = self.stats();
        let all: f64 = stats.values().map(|s| s.total_ms).sum();
        let mut rows: Vec<_> = stats.into_iter().collect();
        rows.sort_by(|a, b| b.1.total_ms.total_cmp(&a.1.total_ms));
        let mut out = format!(
            "{:<28} {:>7} {:>11} {:>19} {:>10} {:>10} {:>6}\n",
            "kernel", "count", "total ms", "mean ± std ms", "min ms", "max ms", "share"
        );
        for (k, s) in rows {
            out.push_str(&format!(
                "{:<28} {:>7} {:>11.3} {:>10.4} ± {:<7.4} {:>10.4} {:>10.4} {:>5.1}%\n",
                k,
                s.count,
                s.total_ms,
                s.mean_ms,
                s.std_ms,
                s.min_ms,
                s.max_ms,
                if all > 0.0 {
                    100.0 * s.total_ms / all
                } else {
                    0.0
                }
            ));
        }
        out
    }

    /// Writes the samples as a Chrome trace (`chrome://tracing`, Perfetto):
    /// one complete event per command, one track per queue, times relative
    /// to the first sample.
    pub fn write_chrome_trace(&self, path: &Path) -> Result<()> {
        let t0 = self
            .samples
            .iter()
            .map(|s| s.start_ns)
            .fold(f64::INFINITY, f64::min);
        let events: Vec<serde_json::Value> = self
            .samples
            .iter()
            .map(|s| {
                serde_json::json!({
                    "name": s.name,
                    "cat": "gpu",
                    "ph": "X",
                    "ts": (s.start_ns - t0) * 1e-3,
                    "dur": s.duration_ns * 1e-3,
                    "pid": 1,
                    "tid": s.queue,
                })
            })
            .collect();
        let doc = serde_json::json!({ "traceEvents": events, "displayTimeUnit": "ms" });
        let io = |source| Error::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut f = std::fs::File::create(path).map_err(io)?;
        f.write_all(doc.to_string().as_bytes()).map_err(io)?;
        Ok(())
    }

    /// Forgets every sample.
    pub fn clear(&mut self) {
        self.samples.clear();
    }
}
