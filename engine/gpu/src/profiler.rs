//! GPU timestamp profiler: per-kernel statistics and a Chrome/Perfetto trace.
//!
//! Enable it with [`super::ContextOptions::profiling`]; every dispatch and
//! copy is then bracketed by timestamp queries, read back when its submission
//! is waited on.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use std::time::Instant;

use crate::host_time::{host_ns, thread_name, ClockSync, HostSample};
use latentam_base::Result;

/// One timed GPU command.
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context) {
/// let profiler = ctx.profiler_snapshot();
/// let copy_ns: f64 = profiler.samples().iter().filter(|s| s.name == "copy").map(|s| s.duration_ns).sum();
/// println!("copies took {:.3} ms", copy_ns * 1e-6);
/// # }
/// ```
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
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context) {
/// for (kernel, stats) in ctx.profiler_snapshot().stats() {
///     println!("{kernel}: {} dispatches, {:.3} ± {:.3} ms", stats.count, stats.mean_ms, stats.std_ms);
/// }
/// # }
/// ```
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

/// Samples kept for the trace by default: a long run times millions of
/// dispatches, and a trace of the first hundred thousand (about 10 MB)
/// shows every kernel many times over. Statistics cover every sample.
pub const DEFAULT_TRACE_SAMPLES: usize = 100_000;

/// Running statistics of one kernel (Welford's mean and variance, so they
/// stay exact over any number of samples without keeping them).
#[derive(Clone, Copy, Debug, Default)]
struct Running {
    count: u64,
    mean: f64,
    m2: f64,
    min: f64,
    max: f64,
}

impl Running {
    fn add(&mut self, x: f64) {
        if self.count == 0 {
            self.min = x;
            self.max = x;
        }
        self.count += 1;
        let delta = x - self.mean;
        self.mean += delta / self.count as f64;
        self.m2 += delta * (x - self.mean);
        self.min = self.min.min(x);
        self.max = self.max.max(x);
    }
}

/// Collected timings. Obtain it with [`super::Context::profiler_snapshot`].
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions};
///
/// let ctx = Context::new(ContextOptions { profiling: true, ..Default::default() })?;
/// // ... record, submit and wait on work ...
/// let profiler = ctx.profiler_snapshot();
/// println!("{}", profiler.table());
/// profiler.write_chrome_trace(std::path::Path::new("trace.json"))?;
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct Profiler {
    samples: Vec<Sample>,
    running: BTreeMap<&'static str, Running>,
    trace_limit: usize,
    dropped: u64,
    host: Vec<HostSample>,
    host_dropped: u64,
    /// Every calibration, oldest first.
    clocks: Vec<ClockSync>,
}

impl Default for Profiler {
    fn default() -> Self {
        Profiler {
            samples: Vec::new(),
            running: BTreeMap::new(),
            trace_limit: DEFAULT_TRACE_SAMPLES,
            dropped: 0,
            host: Vec::new(),
            host_dropped: 0,
            clocks: Vec::new(),
        }
    }
}

impl Profiler {
    pub(crate) fn record(&mut self, name: &'static str, queue: &'static str, start: f64, dur: f64) {
        self.running.entry(name).or_default().add(dur * 1e-6);
        if self.samples.len() < self.trace_limit {
            self.samples.push(Sample {
                name,
                queue,
                start_ns: start,
                duration_ns: dur,
            });
        } else {
            self.dropped += 1;
        }
    }

    /// Keeps the host span `name` from `start` to `end`, on the current
    /// thread's track; returns its end on the host clock.
    pub(crate) fn record_host(&mut self, name: &'static str, start: Instant, end: Instant) -> f64 {
        let (start_ns, end_ns) = (host_ns(start), host_ns(end));
        if self.host.len() < self.trace_limit {
            self.host.push(HostSample {
                name,
                thread: thread_name(),
                start_ns,
                duration_ns: (end_ns - start_ns).max(0.0),
            });
        } else {
            self.host_dropped += 1;
        }
        end_ns
    }

    pub(crate) fn set_clock(&mut self, clock: ClockSync) {
        // Bounded like the samples: past the limit the latest replaces the
        // last kept (the trace keeps only the first samples anyway).
        if self.clocks.len() < self.trace_limit.max(2) {
            self.clocks.push(clock);
        } else if let Some(last) = self.clocks.last_mut() {
            *last = clock;
        }
    }

    /// Nanoseconds from the last calibration to host time `now_ns`
    /// (infinite before the first).
    pub(crate) fn clock_age_ns(&self, now_ns: f64) -> f64 {
        self.clocks
            .last()
            .map_or(f64::INFINITY, |c| now_ns - c.host_ns)
    }

    /// The device time of host time `host_ns`: the offsets of the
    /// calibrations on either side interpolated, the nearest one beyond
    /// them.
    fn device_ns(&self, host_ns: f64) -> Option<f64> {
        let i = self.clocks.partition_point(|c| c.host_ns <= host_ns);
        let offset = match (
            i.checked_sub(1).map(|j| &self.clocks[j]),
            self.clocks.get(i),
        ) {
            (Some(a), Some(b)) if b.host_ns > a.host_ns => {
                let f = (host_ns - a.host_ns) / (b.host_ns - a.host_ns);
                a.host_to_device_ns + f * (b.host_to_device_ns - a.host_to_device_ns)
            }
            (Some(a), _) => a.host_to_device_ns,
            (None, Some(b)) => b.host_to_device_ns,
            (None, None) => return None,
        };
        Some(host_ns + offset)
    }

    /// The host spans kept for the trace (CPU stages, waits for the GPU),
    /// on the host clock.
    pub fn host_samples(&self) -> &[HostSample] {
        &self.host
    }

    /// The latest measurement of how host times map onto the device
    /// clock (profiling on a queue with timestamps).
    pub fn clock(&self) -> Option<ClockSync> {
        self.clocks.last().copied()
    }

    /// Keeps at most `limit` samples for [`Profiler::samples`] and the
    /// trace (the first ones); statistics still cover every sample.
    pub fn set_trace_limit(&mut self, limit: usize) {
        self.trace_limit = limit;
        self.samples.truncate(limit);
        self.host.truncate(limit);
    }

    /// The samples kept for the trace, in the order the batches were
    /// waited on.
    pub fn samples(&self) -> &[Sample] {
        &self.samples
    }

    /// Samples timed but not kept for the trace.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Per-kernel statistics over every timed sample, keyed by kernel name.
    pub fn stats(&self) -> BTreeMap<&'static str, KernelStats> {
        self.running
            .iter()
            .map(|(&k, r)| {
                (
                    k,
                    KernelStats {
                        count: r.count,
                        total_ms: r.mean * r.count as f64,
                        mean_ms: r.mean,
                        std_ms: (r.m2 / r.count.max(1) as f64).max(0.0).sqrt(),
                        min_ms: r.min,
                        max_ms: r.max,
                    },
                )
            })
            .collect()
    }

    /// GPU time of every timed command, milliseconds.
    pub fn total_ms(&self) -> f64 {
        self.running.values().map(|r| r.mean * r.count as f64).sum()
    }

    /// A plain-text table sorted by total time; the share column is of
    /// the total GPU time.
    pub fn table(&self) -> String {
        self.table_with_share_of(self.total_ms())
    }

    /// The table with the share column taken of `frame_ms` (e.g. the wall
    /// time of the frames profiled).
    pub fn table_with_share_of(&self, frame_ms: f64) -> String {
        let stats = self.stats();
        let all = frame_ms;
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

    /// Writes the kept samples as a Chrome trace (`chrome://tracing`,
    /// Perfetto): one complete event per command, one track per queue,
    /// and the host spans as a second process with one track per thread,
    /// placed on the device clock by the calibration ([`Profiler::clock`];
    /// its error bound is in `otherData`); times relative to the first
    /// sample.
    pub fn write_chrome_trace(&self, path: &Path) -> Result<()> {
        // Queues become numbered threads of one process, named by metadata
        // events, which is what trace viewers key their tracks on.
        let mut queues: Vec<&'static str> = self.samples.iter().map(|s| s.queue).collect();
        queues.sort_unstable();
        queues.dedup();
        let tid = |q: &str| queues.iter().position(|&n| n == q).map_or(0, |i| i + 1);
        // Host times on the device clock; without a calibration the host
        // track starts with the GPU's.
        let fallback = {
            let gpu0 = self
                .samples
                .iter()
                .map(|s| s.start_ns)
                .fold(f64::INFINITY, f64::min);
            let host0 = self
                .host
                .iter()
                .map(|s| s.start_ns)
                .fold(f64::INFINITY, f64::min);
            if gpu0.is_finite() && host0.is_finite() {
                gpu0 - host0
            } else {
                0.0
            }
        };
        let on_device = |h: f64| self.device_ns(h).unwrap_or(h + fallback);
        let t0 = self
            .samples
            .iter()
            .map(|s| s.start_ns)
            .chain(self.host.iter().map(|s| on_device(s.start_ns)))
            .fold(f64::INFINITY, f64::min);
        let mut events = vec![serde_json::json!({
            "name": "process_name", "ph": "M", "pid": 1, "tid": 0,
            "args": { "name": "latentam GPU" },
        })];
        for q in &queues {
            events.push(serde_json::json!({
                "name": "thread_name", "ph": "M", "pid": 1, "tid": tid(q),
                "args": { "name": format!("{q} queue") },
            }));
        }
        events.extend(self.samples.iter().map(|s| {
            serde_json::json!({
                "name": s.name,
                "cat": "gpu",
                "ph": "X",
                "ts": (s.start_ns - t0) * 1e-3,
                "dur": s.duration_ns * 1e-3,
                "pid": 1,
                "tid": tid(s.queue),
            })
        }));
        let mut threads: Vec<&str> = self.host.iter().map(|s| s.thread.as_str()).collect();
        threads.sort_unstable();
        threads.dedup();
        if !threads.is_empty() {
            events.push(serde_json::json!({
                "name": "process_name", "ph": "M", "pid": 2, "tid": 0,
                "args": { "name": "latentam host" },
            }));
        }
        let host_tid = |t: &str| threads.iter().position(|&n| n == t).map_or(0, |i| i + 1);
        for t in &threads {
            events.push(serde_json::json!({
                "name": "thread_name", "ph": "M", "pid": 2, "tid": host_tid(t),
                "args": { "name": t },
            }));
        }
        events.extend(self.host.iter().map(|s| {
            serde_json::json!({
                "name": s.name,
                "cat": "host",
                "ph": "X",
                "ts": (on_device(s.start_ns) - t0) * 1e-3,
                "dur": s.duration_ns * 1e-3,
                "pid": 2,
                "tid": host_tid(&s.thread),
            })
        }));
        let doc = serde_json::json!({
            "traceEvents": events,
            "displayTimeUnit": "ms",
            "otherData": {
                "samples_not_traced": self.dropped,
                "host_samples_not_traced": self.host_dropped,
                "host_clock_error_us": self
                    .clocks
                    .iter()
                    .map(|c| c.error_ns * 1e-3)
                    .reduce(f64::max),
                "host_clock_calibrations": self.clocks.len(),
            },
        });
        latentam_base::files::write_atomically(path, |f| {
            serde_json::to_writer(&mut *f, &doc)?;
            f.flush()
        })
    }

    /// Forgets every sample (the clock calibration stays).
    pub fn clear(&mut self) {
        self.samples.clear();
        self.running.clear();
        self.dropped = 0;
        self.host.clear();
        self.host_dropped = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn host(name: &'static str, start_ns: f64, duration_ns: f64) -> HostSample {
        HostSample {
            name,
            thread: "main".into(),
            start_ns,
            duration_ns,
        }
    }

    /// Host times map onto the device clock through the calibrations on
    /// either side, interpolated; before the first and after the last,
    /// the nearest one holds; the trace places the host spans there.
    #[test]
    fn host_spans_are_placed_by_the_calibrations_around_them() {
        let mut p = Profiler::default();
        assert_eq!(p.device_ns(5.0), None);
        // The device clock runs 1000 ns ahead at host 1000, 1100 ahead at
        // host 2000 (a drift of 10 %, to make it visible).
        for (h, off) in [(1000.0, 1000.0), (2000.0, 1100.0)] {
            p.set_clock(ClockSync {
                host_ns: h,
                host_to_device_ns: off,
                error_ns: 5.0,
            });
        }
        assert_eq!(p.device_ns(500.0), Some(1500.0));
        assert_eq!(p.device_ns(1500.0), Some(1500.0 + 1050.0));
        assert_eq!(p.device_ns(3000.0), Some(4100.0));
        assert_eq!(p.clock_age_ns(2500.0), 500.0);

        p.record("k", "compute", 2000.0, 100.0);
        p.host.push(host("stage", 1500.0, 200.0));
        let path =
            std::env::temp_dir().join(format!("latentam-synthetic-{}.json", std::process::id()));
        p.write_chrome_trace(&path).unwrap();
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        std::fs::remove_file(&path).ok();
        let ev = v["traceEvents"].as_array().unwrap();
        let ts = |name: &str| {
            ev.iter()
                .find(|e| e["name"] == name && e["ph"] == "X")
                .map(|e| e["ts"].as_f64().unwrap())
                .unwrap()
        };
        // The kernel at device 2000 ns, the stage at device 2550 ns; times
        // in µs from the first.
        assert!((ts("k") - 0.0).abs() < 1e-9);
        assert!((ts("stage") - 0.55).abs() < 1e-9, "{}", ts("stage"));
        assert_eq!(v["otherData"]["host_clock_calibrations"], 2);
        assert_eq!(v["otherData"]["host_clock_error_us"], 0.005);
    }
}
