//! Paging between the GPU window and the global map: bringing new
//! Gaussians in, re-synchronising the window with the camera (on the
//! transfer queue, beside Stage II), writing it back, and pruning.

use super::*;

/// A paging batch in flight on the transfer queue.
pub(super) struct PagingRun {
    submission: Submission,
    pending: PendingSync,
    report: PagingReport,
}

impl OnlineMapper {
    /// Uploads Gaussians of the global map into free window rows.
    pub(in crate::mapper) fn append(&mut self, keys: &[VoxelKey]) -> Result<()> {
        if keys.is_empty() {
            return Ok(());
        }
        let trainer = self.trainer.as_ref().expect("ensured");
        let window = self.window.as_mut().expect("ensured");
        let companions = optimizer_rows(trainer);
        let mut rec = self.ctx.recorder()?;
        window.record_append(&mut rec, keys, &self.global, &companions)?;
        rec.submit()?.wait()
    }

    /// Records and submits a window sync on the transfer queue (timed).
    pub(super) fn submit_sync(&mut self, plan: &SyncPlan, blocking: bool) -> Result<PagingRun> {
        let trainer = self
            .trainer
            .as_ref()
            .expect("the trainer exists before the first sync");
        let window = self.window.as_mut().expect("ensured");
        let companions = optimizer_rows(trainer);
        let report = PagingReport {
            written_back: window.len(),
            evicted: plan.evict.len(),
            fetched: plan.fetch.len(),
            over_capacity: plan.over_capacity,
            blocking,
        };
        let mut rec = self.ctx.transfer_recorder()?;
        rec.start_span();
        let pending = window.record_sync(&mut rec, plan, &self.global, &companions)?;
        let submission = rec.submit()?;
        Ok(PagingRun {
            submission,
            pending,
            report,
        })
    }

    /// Waits for a sync and writes the window back to the global map.
    /// Returns the report and, when timed, (GPU ms, ms overlapping
    /// `beside`).
    #[allow(clippy::type_complexity)]
    pub(super) fn finish_sync(
        &mut self,
        run: PagingRun,
        beside: Option<&GpuSpan>,
    ) -> Result<(PagingReport, Option<(f64, Option<f64>)>)> {
        let span = run.submission.wait_span()?;
        run.pending.apply(&mut self.global)?;
        self.window_dirty = false;
        let timing = span.map(|s| (s.ms(), beside.map(|b| s.overlap_ms(b))));
        Ok((run.report, timing))
    }

    /// Writes the window back to the global map (nothing moves), so that
    /// [`OnlineMapper::global`] is current; nothing to do when no training
    /// step ran since the last write-back.
    pub fn flush(&mut self) -> Result<()> {
        let Some(window) = &self.window else {
            return Ok(());
        };
        if window.is_empty() || !self.window_dirty {
            return Ok(());
        }
        let plan = SyncPlan {
            keep: window.len(),
            ..SyncPlan::default()
        };
        let run = self.submit_sync(&plan, true)?;
        self.finish_sync(run, None)?;
        Ok(())
    }

    /// Every Gaussian of the map as it stands, changing nothing: the
    /// window's rows as the GPU holds them (when training changed them
    /// since the last write-back), then the global map's others. Unlike
    /// [`OnlineMapper::flush`] it writes nothing back, so taking it
    /// between keyframes leaves mapping exactly as without it.
    pub fn gaussians_now(&self) -> Result<latentam_base::HostGaussians> {
        let mut resident = KeySet::default();
        let mut out = latentam_base::HostGaussians::default();
        if let Some(window) = self
            .window
            .as_ref()
            .filter(|w| self.window_dirty && !w.is_empty())
        {
            out = window.params().download(&self.ctx, window.len() as u64)?;
            resident.extend(window.keys().iter().copied());
        }
        let more = self.global.len().saturating_sub(resident.len());
        out.means.reserve(more);
        out.log_scales.reserve(more);
        out.quats.reserve(more);
        out.colors.reserve(more);
        out.opacity_logits.reserve(more);
        out.queries.reserve(more);
        for (key, g) in self.global.iter() {
            if !resident.contains(&key) {
                crate::map::push_gaussian(&mut out, g);
            }
        }
        Ok(out)
    }

    /// Removes the resident Gaussians that are nearly transparent or too
    /// large ([`MapperConfig::prune_min_opacity`], `prune_max_scale`) from
    /// the window and the global map, after writing the window back.
    /// Returns how many were removed.
    pub fn prune(&mut self) -> Result<usize> {
        let Some(window) = &self.window else {
            return Ok(0);
        };
        // Superseded guesses outside the window go at once.
        let mut superseded = std::mem::take(&mut self.superseded);
        let mut removed = 0;
        let resident: KeySet = window.keys().iter().copied().collect();
        superseded.retain(|key| {
            if resident.contains(key) {
                return true;
            }
            removed += self.global.remove(*key).is_some() as usize;
            false
        });
        let n = window.len();
        if n == 0 {
            return Ok(removed);
        }
        let host = window.params().download(&self.ctx, n as u64)?;
        let min_logit = {
            let o = self.cfg.prune_min_opacity.clamp(1e-7, 1.0 - 1e-7);
            (o / (1.0 - o)).ln()
        };
        let max_log_scale = self.cfg.prune_max_scale.max(1e-9).ln();
        let evict: Vec<u32> = (0..n)
            .filter(|&i| {
                let o = host.opacity_logits[i];
                let s = host.log_scales[i].iter().copied().fold(f32::MIN, f32::max);
                // NaN parameters are pruned too.
                let keep =
                    o >= min_logit && s <= max_log_scale && !superseded.contains(&window.keys()[i]);
                !keep
            })
            .map(|i| i as u32)
            .collect();
        if evict.is_empty() {
            return Ok(removed);
        }
        let doomed: Vec<_> = evict.iter().map(|&r| window.keys()[r as usize]).collect();
        let plan = SyncPlan {
            keep: n - evict.len(),
            evict,
            fetch: Vec::new(),
            over_capacity: 0,
        };
        let run = self.submit_sync(&plan, true)?;
        self.finish_sync(run, None)?;
        for key in &doomed {
            self.global.remove(*key);
        }
        Ok(removed + doomed.len())
    }
}

/// The Gaussian optimiser's per-row state, moved with the window's rows.
pub(super) fn optimizer_rows(trainer: &Trainer) -> Vec<Companion<'_>> {
    trainer
        .optimizer()
        .state()
        .into_iter()
        .map(|(buffer, row_bytes)| Companion { buffer, row_bytes })
        .collect()
}
