//! Mapping a whole log into a run folder, with autosave and resume: the
//! loop a recording or a robot's log goes through, shared by every client
//! (the `latentam map` command is one).
//!
//! The run folder is replaced whole (see [`RunFolder`](crate::mapper::RunFolder)): every autosave and
//! the final write put a complete, consistent version in place, or leave
//! the previous one. A run that stops early (a stop request, a frame
//! limit, an unreadable frame, a frame refused for its content) still
//! writes what was mapped, with the failure in `report.json`; a failure in
//! the middle of a keyframe, or a run that mapped nothing, leaves the
//! folder as it was.
//!
//! A resumed run skips the frames its saved state mapped already, by
//! timestamp (the resumed map's `last_frame_stamp_ns`), so a log with a frame more or
//! less than the first time resumes where the map ends.

use std::path::Path;
use std::time::Instant;

use super::handle::LiveMapper;
use super::log_run_types::{Kept, LogRun, LogRunOptions, RunObserver, Written};
use super::options::LiveOptions;
use super::tally::Tally;
use crate::mapper::{
    Ending, GpuWorkReport, HostWaits, Mapper, PagingPerKeyframe, RunFolder, RunReport,
};
use latentam_base::files::write_bytes_atomically;
use latentam_base::{Error, Result};
use latentam_gpu::GpuModel;
use latentam_io::{write_tum, AssemblyConfig, CameraPose, McapFrames, McapLog};

impl LogRun {
    /// Maps the log at `log` with `mapper` (new, or loaded to be
    /// continued), writing the run folder `folder` at every autosave when
    /// given. Errors only when the log cannot be opened; failures
    /// part-way end the run with [`Ending::Failed`]. The final write is
    /// the caller's ([`LogRun::write_folder`]), so it can decide what an
    /// unfinished run is worth.
    ///
    /// ```no_run
    /// # fn f(mapper: latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// use latentam_io::AssemblyConfig;
    /// use latentam_core::live::{LogRun, LogRunOptions};
    /// // No run folder: map only, in memory.
    /// let run = LogRun::map(mapper, "log.mcap".as_ref(), AssemblyConfig::default(),
    ///                       &LogRunOptions::default(), None, &mut ())?;
    /// println!("{} keyframes in {:.1} s", run.keyframes.len(), run.wall_s);
    /// # Ok(())
    /// # }
    /// ```
    pub fn map(
        mapper: Mapper,
        log: &Path,
        assembly: AssemblyConfig,
        options: &LogRunOptions,
        folder: Option<&RunFolder>,
        observer: &mut dyn RunObserver,
    ) -> Result<LogRun> {
        let mut mapper = mapper;
        if let Some(flag) = options.hurry {
            mapper.set_hurry_flag(flag);
        }
        let opened = McapLog::open(log)?;
        let mut frames = McapFrames::from_log(opened.clone(), assembly)?;
        // Colour images bound the frames; the summary says how many there are.
        let in_log = opened
            .message_count(&frames.topics().color)
            .map(|n| n as usize);
        let total = match (in_log, options.max_frames) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        observer.started(&frames, total);
        // A state from before stamps were saved resumes by count.
        let stats = mapper.stats();
        let skip_by_count = match stats.last_frame_stamp_ns {
            Some(_) => 0,
            None => stats.frames,
        };
        let mut mapped_up_to = stats.last_frame_stamp_ns;
        let limit = options.max_frames.unwrap_or(usize::MAX);
        let mut run = Tally::new(log);
        let start = Instant::now();
        // The log goes through the live handle, as a robot's frames would,
        // but nothing is dropped: the reader waits for room, and reads the
        // next frames while the worker maps.
        let live = LiveMapper::start(
            mapper,
            LiveOptions {
                queue_frames: 3,
                stop_on_rejected: true,
                ..LiveOptions::default()
            },
        )?;
        live.record_outcomes();
        observer.live_started(&live.reader());
        let mut warned = 0;
        let mut ending = loop {
            for w in &frames.report().warnings[warned..] {
                observer.input_warning(w);
            }
            warned = frames.report().warnings.len();
            if let Some(failed) = run.take_outcomes(&live, options, folder, observer, &mut frames) {
                break failed;
            }
            if observer.stop_requested() {
                break Ending::Interrupted;
            }
            if (run.skipped + run.submitted) as usize >= limit {
                break Ending::FrameLimit;
            }
            let Some(frame) = frames.next() else {
                break Ending::Complete;
            };
            let frame = match frame {
                Ok(f) => f,
                Err(e) => break Ending::Failed(format!("reading {}: {e}", log.display())),
            };
            let mapped = mapped_up_to.is_some_and(|last| frame.stamp_ns <= last);
            if mapped || run.skipped < skip_by_count {
                run.skipped += 1;
                frames.recycle(frame);
                observer.frame_done(run.skipped + run.frames, &run.stats, None);
                continue;
            }
            mapped_up_to = Some(frame.stamp_ns);
            run.submitted += 1;
            if let Some(ended) = run.submit(&live, frame, options, folder, observer, &mut frames) {
                break ended;
            }
        };
        // A run that read its last frame maps what is queued, counting (and
        // autosaving) as it goes.
        if matches!(ending, Ending::Complete | Ending::FrameLimit) {
            if let Some(ended) = run.drain(&live, options, folder, observer, &mut frames) {
                ending = ended;
            }
        }
        let mut run = run.close(live, ending, &mut frames, observer)?;
        run.wall_s = start.elapsed().as_secs_f64();
        run.ingest = frames.report().clone();
        Ok(run)
    }

    /// The mapper and the counts apart (for an autosave while mapping).
    pub(super) fn into_parts(self) -> (Mapper, Tally) {
        let stats = self.mapper.stats();
        let tally = Tally {
            log: self.log,
            submitted: self.frames,
            frames: self.frames,
            skipped: self.skipped,
            keyframes: self.keyframes,
            autosaved_at: self.autosaved_at,
            autosave_failures: self.autosave_failures,
            not_keyframes: self.not_keyframes,
            stats,
            pending: Vec::new(),
        };
        (self.mapper, tally)
    }

    /// The report of this run, with the profiler's per-kernel statistics,
    /// for the run folder version `run_id`.
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// let report = run.report("example-run");
    /// println!("{}", serde_json::to_string_pretty(&report).unwrap());
    /// # Ok(())
    /// # }
    /// ```
    pub fn report(&self, run_id: &str) -> RunReport {
        let kernels = self.mapper.context().profiler_snapshot().stats();
        self.report_with(run_id, kernels)
    }

    fn report_with(
        &self,
        run_id: &str,
        kernels: std::collections::BTreeMap<&'static str, latentam_gpu::KernelStats>,
    ) -> RunReport {
        let stats = self.mapper.stats();
        let t = &stats.timings;
        let ctx = self.mapper.context();
        let calls: Vec<_> = self.keyframes.iter().map(|k| k.gpu_calls).collect();
        RunReport {
            run_id: run_id.to_string(),
            // Absolute, so that a tool run from another directory finds
            // the same log; an input that is no file (a ROS 2 graph's
            // topics) is named as given.
            log: if self.log.exists() {
                std::path::absolute(&self.log).unwrap_or_else(|_| self.log.clone())
            } else {
                self.log.clone()
            }
            .display()
            .to_string(),
            device: ctx.info().name.clone(),
            time_to_ready_ms: ctx.time_to_ready_ms(),
            pipeline_cache_loaded_bytes: ctx.info().pipeline_cache_loaded_bytes,
            kernel_builds: crate::mapper::KernelBuilds::of(&ctx.kernel_build_times()),
            first_keyframe_over_median: crate::mapper::first_keyframe_over_median(
                &self
                    .keyframes
                    .iter()
                    .map(|k| k.timings.total_ms)
                    .collect::<Vec<_>>(),
            ),
            ending: self.ending.clone(),
            frames: self.frames,
            frames_skipped_as_already_mapped: self.skipped,
            keyframes: stats.keyframes,
            wall_s: self.wall_s,
            fps: self.frames as f64 / self.wall_s.max(1e-9),
            keyframes_per_s: self.keyframes.len() as f64 / self.wall_s.max(1e-9),
            gaussians: stats.gaussians,
            resident: stats.resident,
            gpu_budget: stats.window.map_or(0, |w| w.budget),
            window_capacity: stats.window.map_or(0, |w| w.capacity),
            peak_gpu_bytes: stats.gpu_peak_bytes,
            peak_gpu_split: stats.gpu_peak_split,
            peak_cpu_bytes: stats.cpu_peak_bytes,
            peak_rss_bytes: latentam_base::process::peak_rss_bytes(),
            disk: stats.disk,
            evicted: stats.evicted,
            fetched: stats.fetched,
            ms_per_keyframe: t.per_keyframe(stats.keyframes),
            host_waits_per_keyframe: HostWaits::of(&calls),
            gpu_work: GpuWorkReport::of(&stats.gpu_work, &calls, &GpuModel::presets()),
            paging_hidden_share: match (t.paging_gpu_ms, t.paging_hidden_ms) {
                (Some(g), Some(h)) if g > 0.0 => Some(h / g),
                _ => None,
            },
            paging_per_keyframe: PagingPerKeyframe::of(&self.keyframes),
            dedicated_transfer_queue: ctx.info().dedicated_transfer_queue,
            embedding_model: self.mapper.embedding_model().map(str::to_string),
            ingest: self.ingest.clone(),
            autosaved_at: self.autosaved_at,
            autosave_failures: self.autosave_failures.clone(),
            kernels,
            keyframe_reports: self.keyframes.clone(),
        }
    }

    /// The keyframe trajectory, every keyframe of the map (resumed runs
    /// included), camera-to-world.
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// for (stamp_ns, pose) in run.trajectory() {
    ///     println!("{stamp_ns} {:?}", pose.translation);
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn trajectory(&self) -> Vec<(i64, CameraPose)> {
        self.mapper.trajectory().to_vec()
    }

    /// The GPU context the run mapped on: the device's name, and the
    /// profiler's kernel timings when profiling was on.
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) {
    /// let ctx = run.context();
    /// println!("{} kernels timed on {}", ctx.profiler_snapshot().stats().len(), ctx.info().name);
    /// # }
    /// ```
    pub fn context(&self) -> &latentam_gpu::Context {
        self.mapper.context()
    }

    /// Why the run folder must not be replaced by this run, if so.
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// match run.not_to_save() {
    ///     Some(why) => eprintln!("not saving: {why}"),
    ///     None => println!("ready to save"),
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn not_to_save(&self) -> Option<Kept> {
        let stats = self.mapper.stats();
        if self.mapper.is_broken() {
            Some(Kept::Broken)
        } else if self.frames == 0 && self.skipped > 0 && stats.gaussians > 0 {
            Some(Kept::NothingNew)
        } else if stats.keyframes == 0 || stats.gaussians == 0 {
            Some(Kept::NothingMapped(self.why_nothing()))
        } else {
            None
        }
    }

    /// What the folder holds when this run did not replace it.
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// if run.not_to_save().is_some() {
    ///     eprintln!("{}", run.kept_description());
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn kept_description(&self) -> String {
        match self.autosaved_at {
            Some(k) => format!("its autosave at keyframe {k}"),
            None => "the run it held before, if any".into(),
        }
    }

    /// Why no keyframe (or no Gaussian) came of the log, with counts.
    ///
    /// ```no_run
    /// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
    /// if run.keyframes.is_empty() {
    ///     eprintln!("no keyframe: {}", run.why_nothing());
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn why_nothing(&self) -> String {
        let mut parts = Vec::new();
        let stats = self.mapper.stats();
        if stats.keyframes > 0 {
            parts.push(format!(
                "{} keyframes seeded no Gaussian: their depth gave no point within range",
                stats.keyframes
            ));
        }
        parts.push(format!(
            "{} frames assembled from {} messages",
            self.ingest.frames, self.ingest.messages
        ));
        if self.not_keyframes > 0 {
            parts.push(format!("{} frames were not keyframes", self.not_keyframes));
        }
        for (reason, c) in &self.ingest.skipped {
            parts.push(format!("{} × {reason} (first: {})", c.count, c.first));
        }
        if let Ending::Failed(e) = &self.ending {
            parts.push(format!("stopped by: {e}"));
        }
        parts.join("; ")
    }

    /// Replaces the run folder with this run: the resumable state,
    /// `decoder.safetensors` (when the map has embeddings), `map.ply`,
    /// `config.toml`, `trajectory.txt`, `trace.json` (when profiled),
    /// `report.json` and the observer's own files, all with one run id.
    /// Either every file is written and the folder swapped in whole, or it
    /// is left as it was: kept for [`LogRun::not_to_save`]'s reasons, an
    /// error for a file that could not be written.
    ///
    /// ```no_run
    /// # fn f(run: &mut latentam_core::live::LogRun, folder: &latentam_core::mapper::RunFolder) -> latentam_core::Result<()> {
    /// let written = run.write_folder(folder, &mut ())?;
    /// # Ok(())
    /// # }
    /// ```
    pub fn write_folder(
        &mut self,
        folder: &RunFolder,
        observer: &mut dyn RunObserver,
    ) -> Result<Written> {
        if let Some(why) = self.not_to_save() {
            return Ok(Written::Kept(why));
        }
        let staging = folder.stage()?;
        let dir = staging.path().to_path_buf();
        self.mapper.save_into(&staging)?;
        let config = format!(
            "# The effective configuration of this run (`latentam map --config` and\n\
             # `MapperConfig::from_toml` read it back; `latentam config --print-defaults`\n\
             # documents every key).\n{}",
            self.mapper.config().to_toml()
        );
        write_bytes_atomically(&dir.join("config.toml"), config.as_bytes())?;
        self.mapper.export_ply(&dir.join("map.ply"))?;
        write_tum(&dir.join("trajectory.txt"), &self.trajectory())?;
        let profile = self.mapper.context().profiler_snapshot();
        if !profile.samples().is_empty() {
            profile.write_chrome_trace(&dir.join("trace.json"))?;
        }
        let report = self.report_with(staging.run_id(), profile.stats());
        let path = dir.join("report.json");
        let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::Io {
            path: path.clone(),
            source: e.into(),
        })?;
        write_bytes_atomically(&path, &json)?;
        observer.write_extra_files(&dir, &report)?;
        staging.commit()?;
        Ok(Written::Saved(Box::new(report)))
    }
}
