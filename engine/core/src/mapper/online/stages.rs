//! The stages of one keyframe that `OnlineMapper::integrate_keyframe`
//! chains (the paper's Algorithm 1): new Gaussians into the window,
//! Stage I, and Stage II with the window's paging beside it.

use std::sync::atomic::Ordering;
use std::time::Instant;

use glam::DVec3;

use super::{ms_since, OnlineMapper};
use crate::mapper::history::KeyframeRecord;
use crate::mapper::keyframe_report::{KeyframeGpuCalls, KeyframeTimings, PagingReport};
use crate::mapper::StageOneReport;
use latentam_base::Result;
use latentam_gpu::GpuCalls;
use latentam_io::Frame;

impl OnlineMapper {
    /// Seeds the keyframe's new Gaussians (what the map already explains
    /// at its pose is left alone) and makes them resident for Stage I,
    /// paging the window around the camera when they do not fit. Returns
    /// their voxels.
    pub(super) fn insert_new_gaussians(
        &mut self,
        frame: &Frame,
        record: &mut KeyframeRecord,
        seed: u64,
        timings: &mut KeyframeTimings,
        paging: &mut Vec<PagingReport>,
    ) -> Result<Vec<crate::map::VoxelKey>> {
        let new_keys = self.seed(frame, record, seed)?;
        let centre = frame.pose.translation;
        let window = self.window.as_ref().expect("ensured");
        if new_keys.len() <= window.free() {
            self.append(&new_keys)?;
        } else {
            let t_page = Instant::now();
            let plan = window.plan(&self.global, centre, self.cfg.window_radius);
            self.window_partial = plan.over_capacity > 0;
            let run = self.submit_sync(&plan, true)?;
            let (report, _) = self.finish_sync(run, None)?;
            timings.paging_cpu_ms += ms_since(t_page);
            paging.push(report);
            self.last_sync = Some(centre);
        }
        Ok(new_keys)
    }

    /// Stage I: R1 steps on the keyframe and B past ones drawn among those
    /// the window can render; the report is the first step's (the losses
    /// before this keyframe trained anything).
    pub(super) fn train_stage_one(
        &mut self,
        record: &KeyframeRecord,
        seed: u64,
        centre: DVec3,
    ) -> Result<StageOneReport> {
        let picks = self.history.sample_near(
            self.cfg.replay as usize,
            seed,
            centre,
            self.cfg.window_radius,
        );
        let mut batch: Vec<&KeyframeRecord> = vec![record];
        batch.extend(picks.iter().filter_map(|&i| self.history.get(i)));
        let hurried = || {
            self.hurry.is_some_and(|f| f.load(Ordering::SeqCst)) || self.stop.load(Ordering::SeqCst)
        };
        let trainer = self.trainer.as_mut().expect("ensured");
        let window = self.window.as_ref().expect("ensured");
        let stage_one = trainer.stage_one(&self.ctx, window, self.head.as_ref(), &batch)?;
        for _ in 1..self.cfg.stage_one_iterations {
            if hurried() {
                break;
            }
            trainer.stage_one(&self.ctx, window, self.head.as_ref(), &batch)?;
        }
        self.window_dirty = true;
        Ok(stage_one)
    }

    /// Stage II, with the window paged around the camera beside it when the
    /// camera moved far enough (Stage II reads no Gaussian). The paging
    /// batch is submitted first so that it waits for Stage I only (see
    /// `Recorder::submit`). Returns Stage II's loss.
    pub(super) fn stage_two_and_paging(
        &mut self,
        centre: DVec3,
        timings: &mut KeyframeTimings,
        paging: &mut Vec<PagingReport>,
        lap: &mut dyn FnMut(&mut GpuCalls),
        calls: &mut KeyframeGpuCalls,
    ) -> Result<f64> {
        let moved = self
            .last_sync
            .is_none_or(|p| p.distance(centre) > self.cfg.sync_distance);
        let run = if moved {
            let t_page = Instant::now();
            let plan = self.window.as_ref().expect("ensured").plan(
                &self.global,
                centre,
                self.cfg.window_radius,
            );
            let run = self.submit_sync(&plan, false)?;
            timings.paging_cpu_ms += ms_since(t_page);
            self.last_sync = Some(centre);
            lap(&mut calls.paging);
            Some(run)
        } else {
            None
        };
        let stage_two_iterations = if self.hurried() {
            0
        } else {
            self.cfg.stage_two_iterations
        };
        let stage_two_run = self.trainer.as_ref().expect("ensured").submit_stage_two(
            &self.ctx,
            self.head.as_ref(),
            stage_two_iterations,
        )?;
        let (stage_two, stage_two_span) = stage_two_run.finish()?;
        timings.stage_two_gpu_ms = stage_two_span.map(|s| s.ms());
        lap(&mut calls.stage_two);
        if let Some(run) = run {
            let t_page = Instant::now();
            let (report, span) = self.finish_sync(run, stage_two_span.as_ref())?;
            timings.paging_cpu_ms += ms_since(t_page);
            timings.paging_gpu_ms = span.map(|s| s.0);
            timings.paging_hidden_ms = span.and_then(|s| s.1);
            paging.push(report);
            lap(&mut calls.paging);
        }
        Ok(stage_two)
    }
}
