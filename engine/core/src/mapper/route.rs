//! A frame's route through the mapper's parts (the paper's Algorithm 1):
//! decide whether it is a keyframe; for a keyframe update the dictionary,
//! seed new Gaussians, run Stage I, page the window beside Stage II, and
//! report.

use std::borrow::Borrow;
use std::time::Instant;

use glam::DVec3;

use super::facade::Mapper;
use super::history::{KeyframeRecord, ReplayKey};
use super::keyframe_report::{
    DiskReport, Integrated, KeyframeGpuCalls, KeyframeGpuWork, KeyframeReport, KeyframeTimings,
    PagingReport,
};
use super::pager::{PreparedSync, PruneScan};
use super::seeder::Coverage;
use super::trainer::{StageOneReport, SubmittedStageOne, Trainer};
use super::workspace::size_workspace;
use crate::map::{QueryInit, RegionQueries, VoxelKey};
use latentam_base::Result;
use latentam_gpu::{Context, GpuCalls, GpuWork};
use latentam_io::Frame;

impl Mapper {
    /// Offers one frame: keyframe selection, then for a keyframe the
    /// dictionary update, Gaussian seeding, Stage I over the keyframe and
    /// past ones, Stage II with the window's paging beside it, and at its
    /// interval pruning (the paper's Algorithm 1). A frame refused for its
    /// content leaves the map as it was; a failure part-way through a
    /// keyframe leaves it unusable: it refuses further frames and saves
    /// (reload the last save to go on).
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper, frame: latentam_io::Frame) -> latentam_core::Result<()> {
    /// use latentam_core::mapper::Integrated;
    /// if let Integrated::Keyframe(report) = mapper.integrate(frame)? {
    ///     println!("keyframe {}: {} Gaussians", report.index, report.gaussians);
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn integrate(&mut self, frame: impl Borrow<Frame>) -> Result<Integrated> {
        let frame = frame.borrow();
        frame.check()?;
        self.integrate_checked(frame)
    }

    /// [`Mapper::integrate`] for a frame that passed `Frame::check`
    /// already (the live handle checks at `submit`, on the caller's
    /// thread).
    pub(crate) fn integrate_checked(&mut self, frame: &Frame) -> Result<Integrated> {
        self.progress.check_consistent()?;
        self.dictionary.check_frame(frame)?;
        let selector = self.selector.state();
        if !self.selector.decide(frame, self.pager.global()).keyframe {
            self.progress.count_frame(frame.stamp_ns);
            return Ok(Integrated::Skipped);
        }
        // A keyframe changes the map and the decoder, even one that fails
        // part-way.
        self.relevance_index = None;
        // The first keyframe sizes the window against the budget before any
        // GPU work, so a configuration that cannot map fails here, with the
        // setting to change, and with the map as it was.
        let pixels = frame.color.width as u64 * frame.color.height as u64;
        if let Err(e) = self.ensure_workspace(pixels, self.dictionary.dim_for(frame)) {
            self.selector.restore(selector.0, selector.1);
            return Err(e);
        }
        self.progress.keyframe_started(frame.stamp_ns);
        let report = self.integrate_keyframe(frame)?;
        self.progress.keyframe_done(frame.stamp_ns);
        Ok(Integrated::Keyframe(report))
    }

    /// Creates the window and the trainer, sized from the budget (first
    /// keyframe only). `dim` is the embedding dimension the head has or
    /// will have, `None` when no embeddings were seen yet.
    pub(super) fn ensure_workspace(&mut self, pixels: u64, dim: Option<u32>) -> Result<()> {
        if self.trainer.is_some() {
            return Ok(());
        }
        let has_head = self.dictionary.head().is_some();
        let (window, trainer) = size_workspace(&self.ctx, &self.cfg, pixels, dim, has_head)?;
        self.pager.open_window(&self.ctx, window)?;
        self.trainer = Some(Trainer::new(&self.ctx, trainer, dim.unwrap_or(1))?);
        Ok(())
    }

    /// One keyframe, a line per step of the algorithm.
    fn integrate_keyframe(&mut self, frame: &Frame) -> Result<Box<KeyframeReport>> {
        let mut clock = KeyframeClock::start(&self.ctx);
        let mut record = KeyframeRecord::from_frame(frame);
        let seed = self.cfg.seed ^ self.progress.keyframes().wrapping_mul(0x9e37_79b9);
        let ctx = self.ctx.clone();
        let centre = frame.pose.translation;
        let keyframe_span = ctx.host_span("keyframe");

        // Spilled blocks near the camera come back before anything reads
        // the map there.
        let loaded = self
            .pager
            .load_around(centre, sight(frame, self.cfg.seeding.max_depth))?;
        let dictionary_update = clock.step(Step::Dictionary, |_| {
            self.dictionary.update(&ctx, frame, &record)
        })?;
        let new_keys = clock.step(Step::Seeding, |clock| {
            self.seed(frame, &mut record, seed, clock)
        })?;
        // Seeding waited for its render, which the queue ran after the
        // dictionary's update: that one is done, and no wait of its own
        // is needed (it waits, counted, only when seeding rendered
        // nothing).
        if let Some(update) = dictionary_update {
            update.finished_span()?;
        }
        // The window's next sync is planned now, its arrivals uploading
        // beside Stage I.
        let t_page = Instant::now();
        let prepared = self.pager.prepare(&ctx, centre)?;
        clock.timings.paging_cpu_ms += ms_since(t_page);
        clock.lap(|c| &mut c.paging);
        // The keyframe's targets are kept on the GPU under the key it will
        // be replayed by.
        let key = ReplayKey::fresh();
        let stage_one = clock.step(Step::StageOne, |_| {
            self.stage_one(&record, key, seed, centre)
        })?;
        let prunes = self.prunes_after_this_keyframe();
        let (stage_two, prune_scan) = clock.step(Step::StageTwo, |clock| {
            self.stage_two_and_paging(prepared, prunes, clock)
        })?;
        let stage_one = stage_one.finish()?;
        let exposure = self.remember(frame, record, key);
        let pruned = clock.step(Step::Pruning, |_| match prunes {
            true => self.prune(prune_scan),
            false => Ok(0),
        })?;
        let spilled = self.pager.spill_to_budget()?;
        clock.timings.disk_ms = loaded.ms + spilled.ms;
        clock.disk_moves = (loaded.read, spilled.written);

        drop(keyframe_span);
        let trained = Trained {
            added: new_keys.len(),
            stage_one,
            stage_two,
            pruned,
            exposure,
        };
        Ok(self.report(frame, clock, trained))
    }

    /// Seeds the keyframe's new Gaussians where the map rendered at its
    /// pose does not explain it, inserts them into the global map and makes
    /// them resident for Stage I (paging the window around the camera when
    /// they do not fit). Returns their voxels.
    fn seed(
        &mut self,
        frame: &Frame,
        record: &mut KeyframeRecord,
        seed: u64,
        clock: &mut KeyframeClock,
    ) -> Result<Vec<VoxelKey>> {
        let trainer = self.trainer.as_mut().expect("ensured");
        let window = self.pager.window().expect("ensured");
        // New Gaussians in a region start from its embedding projected
        // through the decoder's W, read back with the render.
        let project =
            record.regions.is_some() && self.cfg.seeding.query_init == QueryInit::Embedding;
        let w = project.then(|| self.dictionary.w_buffer()).flatten();
        let grid = self.seeder.candidate_grid(frame);
        let coverage = Coverage::render(trainer.rasterizer(), window, record, grid, w)?;
        if self.cfg.exposure_compensation {
            // The last keyframe's where too little of the map is in view.
            let last_gain = self.exposure.iter().last().map_or(1.0, |(_, g)| g);
            record.exposure = coverage
                .as_ref()
                .and_then(|c| c.exposure(frame, record, self.cfg.seeding.depth_error))
                .unwrap_or(last_gain);
        }
        let projected = match &record.regions {
            Some(r) if project => {
                let read = coverage.as_ref().and_then(|c| c.w.as_deref());
                self.dictionary
                    .projected_queries(&self.ctx, r, read)?
                    .map(|q| (r, q))
            }
            _ => None,
        };
        let queries = projected.as_ref().map(|(r, queries)| RegionQueries {
            width: r.width,
            height: r.height,
            labels: &r.labels,
            queries,
        });
        let global = self.pager.global();
        let seeds = self.seeder.seeds(
            frame,
            coverage.as_ref(),
            self.pager.extent(),
            record.exposure,
            global,
            seed,
            queries.as_ref(),
        );
        self.seeder.check_guesses(frame, global);
        let keys = self.seeder.insert(frame, seeds, self.pager.global_mut());

        let rows = self.trainer.as_ref().expect("ensured").window_rows();
        let centre = frame.pose.translation;
        if let Some(ms) = self.pager.make_resident(&self.ctx, &keys, &rows, centre)? {
            clock.timings.paging_cpu_ms += ms;
        }
        Ok(keys)
    }

    /// Stage I: R1 steps on the keyframe and B past ones drawn among those
    /// the window can render; the report is the first step's (the losses
    /// before this keyframe trained anything). The first step is not
    /// waited for: nothing before Stage II's wait reads what it wrote on
    /// the host, and Stage II, after it on the same queue, covers it.
    fn stage_one(
        &mut self,
        record: &KeyframeRecord,
        key: ReplayKey,
        seed: u64,
        centre: DVec3,
    ) -> Result<SubmittedStageOne> {
        let picks = self.history.sample_near(
            self.cfg.replay as usize,
            seed,
            centre,
            self.cfg.window_radius,
        );
        let mut batch: Vec<&KeyframeRecord> = vec![record];
        let mut keys = vec![key];
        for &i in &picks {
            if let (Some(r), Some(k)) = (self.history.get(i), self.history.key(i)) {
                batch.push(r);
                keys.push(k);
            }
        }
        let trainer = self.trainer.as_mut().expect("ensured");
        let window = self.pager.window().expect("ensured");
        let head = self.dictionary.head();
        let report = trainer.submit_stage_one(&self.ctx, window, head, &batch, &keys)?;
        for _ in 1..self.cfg.stage_one_iterations {
            if self.progress.hurried() {
                break;
            }
            trainer.stage_one(&self.ctx, window, head, &batch, &keys)?;
        }
        self.pager.mark_trained();
        Ok(report)
    }

    /// Stage II, with the window's prepared sync carried out beside it
    /// (Stage II reads no Gaussian): the moves after Stage I on the compute
    /// queue, the download of what leaves beside Stage II on the transfer
    /// queue. The paging batches are submitted first so that they wait for
    /// Stage I only (see `Recorder::submit`). When the keyframe `prunes`,
    /// the scan pruning reads is submitted after Stage II and its wait is
    /// the one that ends Stage II. Returns Stage II's loss and the scan.
    fn stage_two_and_paging(
        &mut self,
        prepared: Option<PreparedSync>,
        prunes: bool,
        clock: &mut KeyframeClock,
    ) -> Result<(f64, Option<PruneScan>)> {
        let trainer = self.trainer.as_ref().expect("ensured");
        let rows = trainer.window_rows();
        let t_page = Instant::now();
        if let Some(p) = prepared {
            self.pager.follow(&self.ctx, p, &rows)?;
            clock.timings.paging_cpu_ms += ms_since(t_page);
            clock.lap(|c| &mut c.paging);
        }
        let iterations = match self.progress.hurried() {
            true => 0,
            false => self.cfg.stage_two_iterations,
        };
        let head = self.dictionary.head();
        let run = trainer.submit_stage_two(&self.ctx, head, iterations)?;
        let (min_opacity, max_scale) = (self.cfg.prune_min_opacity, self.cfg.prune_max_scale);
        let mut scan = match prunes {
            true => self
                .pager
                .submit_prune_scan(&self.ctx, min_opacity, max_scale)?,
            false => None,
        };
        // The scan's wait, counted as pruning's, ends Stage II too.
        let (stage_two, span) = match &mut scan {
            Some(scan) => {
                clock.lap(|c| &mut c.stage_two);
                scan.wait()?;
                clock.lap(|c| &mut c.prune);
                run.finish_after_later_wait()?
            }
            None => run.finish()?,
        };
        clock.timings.stage_two_gpu_ms = span.map(|s| s.ms());
        clock.lap(|c| &mut c.stage_two);
        // Every sync of the keyframe (a re-centring before Stage I, the
        // one beside Stage II) is finished here, with one host wait.
        let t_page = Instant::now();
        let settled = self.pager.settle(span.as_ref())?;
        if !settled.is_empty() {
            clock.timings.paging_cpu_ms += ms_since(t_page);
            for (report, gpu) in settled {
                if let Some((ms, hidden)) = gpu {
                    *clock.timings.paging_gpu_ms.get_or_insert(0.0) += ms;
                    if let Some(h) = hidden {
                        *clock.timings.paging_hidden_ms.get_or_insert(0.0) += h;
                    }
                }
                clock.paging.push(report);
            }
            clock.lap(|c| &mut c.paging);
        }
        Ok((stage_two, scan))
    }

    /// Keeps the keyframe: its pose, its exposure and its record for
    /// replay. Returns its exposure.
    fn remember(&mut self, frame: &Frame, record: KeyframeRecord, key: ReplayKey) -> f32 {
        let (stamp_ns, exposure) = (record.stamp_ns, record.exposure);
        self.trajectory.push((stamp_ns, frame.pose));
        self.exposure.push(stamp_ns, exposure);
        self.history.push_keyed(record, key);
        self.progress.keyframe_trained();
        exposure
    }

    /// Whether the keyframe being mapped prunes once it is trained: every
    /// `prune_interval` keyframes.
    fn prunes_after_this_keyframe(&self) -> bool {
        let interval = self.cfg.prune_interval as u64;
        interval > 0 && (self.progress.keyframes() + 1).is_multiple_of(interval)
    }

    /// Removes the resident Gaussians that are nearly transparent or too
    /// large ([`MapperConfig::prune_min_opacity`](super::MapperConfig::prune_min_opacity),
    /// `prune_max_scale`), and the guesses a keyframe saw float in front of
    /// its surface. Returns how many were removed.
    /// Reads `scan` when the window was scanned for it already (after
    /// Stage II); scans it now otherwise.
    fn prune(&mut self, scan: Option<PruneScan>) -> Result<usize> {
        let rows = self
            .trainer
            .as_ref()
            .map(Trainer::window_rows)
            .unwrap_or_default();
        let superseded = self.seeder.take_superseded();
        let (min_opacity, max_scale) = (self.cfg.prune_min_opacity, self.cfg.prune_max_scale);
        self.pager
            .prune(&self.ctx, &rows, superseded, min_opacity, max_scale, scan)
    }

    /// The keyframe's report, its figures added to the run's.
    fn report(
        &mut self,
        frame: &Frame,
        clock: KeyframeClock,
        trained: Trained,
    ) -> Box<KeyframeReport> {
        let KeyframeClock {
            mut timings,
            calls,
            paging,
            start,
            work_before,
            disk_moves: clock_disk,
            ..
        } = clock;
        timings.total_ms = ms_since(start);
        self.progress.count_paging(&paging);
        let work = self.ctx.gpu_work() - work_before;
        let cpu_bytes = self.cpu_bytes();
        let stats = self.progress.stats_mut();
        stats.timings.add(&timings);
        stats.gpu_work += &work;
        stats.cpu_peak_bytes = stats.cpu_peak_bytes.max(cpu_bytes);
        Box::new(KeyframeReport {
            index: self.progress.keyframes() - 1,
            frame: self.progress.counters().frames,
            stamp_ns: frame.stamp_ns,
            added: trained.added,
            stage_one: trained.stage_one,
            stage_two: trained.stage_two,
            pruned: trained.pruned,
            paging,
            timings,
            gaussians: self.pager.global().len(),
            resident: self.pager.resident(),
            gpu_bytes: self.ctx.memory_report().total.current,
            cpu_bytes,
            disk: DiskReport {
                spilled_gaussians: self.pager.global().spilled_len(),
                spilled_blocks: self.pager.global().spilled_blocks(),
                bytes: self.pager.global().disk_bytes(),
                blocks_read: clock_disk.0,
                blocks_written: clock_disk.1,
            },
            atoms: self.dictionary.head().map_or(0, |h| h.atom_count()),
            exposure: trained.exposure,
            gpu_calls: calls,
            gpu_work: KeyframeGpuWork::of(&work),
        })
    }
}

/// The distance from the camera to the farthest point `frame`'s depth
/// measured, up to `max_depth` (seeding's; 0 without depth): seeding and
/// its checks look no farther. (A camera looking down a corridor sees tens
/// of metres: reading all of that back at every keyframe would turn the
/// disk tier over far faster than the camera moves.)
fn sight(frame: &Frame, max_depth: f32) -> f64 {
    let depth = &frame.depth;
    let far = (0..depth.len())
        .filter_map(|i| depth.metres(i))
        .filter(|z| z.is_finite())
        .fold(0.0f32, f32::max)
        .min(max_depth) as f64;
    // A ray through the image's farthest corner is this much longer than
    // its depth.
    let k = frame.intrinsics;
    let (w, h) = (depth.width as f64, depth.height as f64);
    let dx = k.cx.abs().max((w - k.cx).abs()) / k.fx.abs().max(1e-9);
    let dy = k.cy.abs().max((h - k.cy).abs()) / k.fy.abs().max(1e-9);
    far * (1.0 + dx * dx + dy * dy).sqrt()
}

/// What a keyframe's steps did to the map.
struct Trained {
    /// Gaussians seeded.
    added: usize,
    stage_one: StageOneReport,
    /// Stage II's loss.
    stage_two: f64,
    pruned: usize,
    /// The keyframe's exposure over the map's brightness.
    exposure: f32,
}

/// The steps of a keyframe timed on their own: each is a host span of the
/// profile (`trace.json`), with its wall time and GPU calls in the report.
#[derive(Clone, Copy)]
enum Step {
    Dictionary,
    Seeding,
    StageOne,
    StageTwo,
    Pruning,
}

impl Step {
    fn name(self) -> &'static str {
        match self {
            Step::Dictionary => "dictionary",
            Step::Seeding => "seeding",
            Step::StageOne => "stage I",
            Step::StageTwo => "stage II and paging",
            Step::Pruning => "pruning",
        }
    }

    fn ms(self, t: &mut KeyframeTimings) -> &mut f64 {
        match self {
            Step::Dictionary => &mut t.kmeans_ms,
            Step::Seeding => &mut t.insertion_ms,
            Step::StageOne => &mut t.stage_one_ms,
            Step::StageTwo => &mut t.stage_two_ms,
            Step::Pruning => &mut t.prune_ms,
        }
    }

    fn calls(self, c: &mut KeyframeGpuCalls) -> &mut GpuCalls {
        match self {
            Step::Dictionary => &mut c.dictionary,
            Step::Seeding => &mut c.insertion,
            Step::StageOne => &mut c.stage_one,
            // Stage II laps its paging and its own calls as they end.
            Step::StageTwo => &mut c.stage_two,
            Step::Pruning => &mut c.prune,
        }
    }
}

/// What a keyframe's steps took: wall time, GPU calls by step, paging.
struct KeyframeClock {
    ctx: Context,
    start: Instant,
    work_before: GpuWork,
    /// GPU calls when the last step ended.
    since: GpuCalls,
    calls: KeyframeGpuCalls,
    timings: KeyframeTimings,
    paging: Vec<PagingReport>,
    /// Blocks the disk tier read back and wrote.
    disk_moves: (u64, u64),
}

impl KeyframeClock {
    fn start(ctx: &Context) -> Self {
        KeyframeClock {
            ctx: ctx.clone(),
            start: Instant::now(),
            work_before: ctx.gpu_work(),
            since: ctx.gpu_calls(),
            calls: KeyframeGpuCalls::default(),
            timings: KeyframeTimings::default(),
            paging: Vec::new(),
            disk_moves: (0, 0),
        }
    }

    /// Runs `step` as a host span, records its wall time and adds the GPU
    /// calls since the last lap to its count.
    fn step<T>(&mut self, step: Step, run: impl FnOnce(&mut Self) -> Result<T>) -> Result<T> {
        let t = Instant::now();
        let span = self.ctx.host_span(step.name());
        let out = run(self)?;
        *step.ms(&mut self.timings) = ms_since(t);
        drop(span);
        self.lap(|c| step.calls(c));
        Ok(out)
    }

    /// Adds the GPU calls since the last lap to the count `stage` picks.
    fn lap(&mut self, stage: impl FnOnce(&mut KeyframeGpuCalls) -> &mut GpuCalls) {
        let now = self.ctx.gpu_calls();
        let slot = stage(&mut self.calls);
        *slot = *slot + (now - self.since);
        self.since = now;
    }
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
