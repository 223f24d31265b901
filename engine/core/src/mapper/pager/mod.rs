//! The paging part of the mapper: the CPU global map keyed by voxel and the
//! GPU window of it around the camera (paper §III-D), kept in step. New
//! Gaussians come into the window before Stage I; the window follows the
//! camera beside Stage II on the transfer queue; it is written back when a
//! reader needs the whole map; pruning removes Gaussians from both.

use std::time::Instant;

use glam::DVec3;

use crate::map::{
    push_gaussian, Companion, GlobalMap, KeySet, LocalWindow, PendingSync, SyncPlan, VoxelKey,
};
use crate::mapper::budget::WindowBudget;
use crate::mapper::keyframe_report::PagingReport;
use crate::mapper::seeder::Extent;
use latentam_base::{HostGaussians, Result};
use latentam_gpu::{Context, GpuSpan, Submission};

#[cfg(test)]
mod tests;

/// A paging batch in flight on the transfer queue.
pub(crate) struct PagingRun {
    submission: Submission,
    pending: PendingSync,
    report: PagingReport,
}

/// What a finished paging batch took on the GPU: its milliseconds, and
/// those it overlapped with the span it ran beside.
pub(crate) type PagingSpan = Option<(f64, Option<f64>)>;

/// Where the window stands against the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PagerSettings {
    /// Gaussians within this distance of the camera are kept resident.
    pub radius: f64,
    /// The window follows the camera once it moved this far.
    pub sync_distance: f64,
}

/// The global map and its GPU window.
pub(crate) struct Pager {
    settings: PagerSettings,
    global: GlobalMap,
    /// Created at the first keyframe, when the image size is known.
    window: Option<LocalWindow>,
    budget: Option<WindowBudget>,
    /// Where the window was last centred.
    last_sync: Option<DVec3>,
    /// The last sync left Gaussians within the radius out of the window.
    partial: bool,
    /// Training changed resident Gaussians since the last write-back.
    dirty: bool,
}

impl Pager {
    /// An empty map of voxels of `voxel_size` metres, with no window yet.
    pub(crate) fn new(voxel_size: f64, settings: PagerSettings) -> Self {
        Pager {
            settings,
            global: GlobalMap::new(voxel_size),
            window: None,
            budget: None,
            last_sync: None,
            partial: false,
            dirty: false,
        }
    }

    /// The global map, current up to the last write-back.
    pub(crate) fn global(&self) -> &GlobalMap {
        &self.global
    }

    /// The global map, for inserting new Gaussians (they reach the window
    /// through [`Pager::make_resident`]).
    pub(crate) fn global_mut(&mut self) -> &mut GlobalMap {
        &mut self.global
    }

    /// The window, once the first keyframe sized it.
    pub(crate) fn window(&self) -> Option<&LocalWindow> {
        self.window.as_ref()
    }

    /// How the window was sized.
    pub(crate) fn budget(&self) -> Option<WindowBudget> {
        self.budget
    }

    /// Gaussians resident on the GPU.
    pub(crate) fn resident(&self) -> usize {
        self.window.as_ref().map_or(0, |w| w.len())
    }

    /// Where the window was last centred.
    pub(crate) fn last_sync(&self) -> Option<DVec3> {
        self.last_sync
    }

    /// Host bytes of the map and the window's key table.
    pub(crate) fn cpu_bytes(&self) -> u64 {
        self.global.bytes()
            + self.window.as_ref().map_or(0, |w| {
                w.len() as u64 * std::mem::size_of::<VoxelKey>() as u64
            })
    }

    /// Creates the window, sized as `budget` says (first keyframe only).
    pub(crate) fn open_window(&mut self, ctx: &Context, budget: WindowBudget) -> Result<()> {
        self.window = Some(LocalWindow::new(ctx, budget.capacity)?);
        self.budget = Some(budget);
        Ok(())
    }

    /// Puts a loaded state's Gaussian at `key`; false when it is taken.
    pub(crate) fn restore_gaussian(&mut self, key: VoxelKey, g: crate::map::Gaussian) -> bool {
        self.global.insert_at(key, g)
    }

    /// Sets where a loaded state's window was last centred.
    pub(crate) fn restore_last_sync(&mut self, at: Option<DVec3>) {
        self.last_sync = at;
    }

    /// How much of the map a render of the window shows.
    pub(crate) fn extent(&self) -> Extent {
        let resident = self.resident();
        // Paged-out Gaussians beyond the window's radius do not render:
        // their surface must not be seeded again.
        let complete = self.global.len() == resident;
        Extent {
            partial: self.partial || (!complete && self.last_sync.is_none()),
            complete_within: match (complete, self.last_sync) {
                (false, Some(c)) => Some((c, self.settings.radius)),
                _ => None,
            },
        }
    }

    /// Makes the global map's Gaussians `keys` resident for Stage I: into
    /// free rows when they fit, else by re-centring the window on
    /// `centre` at once. Returns the paging report and its host
    /// milliseconds when it had to page.
    pub(crate) fn make_resident(
        &mut self,
        ctx: &Context,
        keys: &[VoxelKey],
        rows: &[Companion<'_>],
        centre: DVec3,
    ) -> Result<Option<(PagingReport, f64)>> {
        let window = self.window.as_ref().expect("opened at the first keyframe");
        if keys.len() <= window.free() {
            self.append(ctx, keys, rows)?;
            return Ok(None);
        }
        let t_page = Instant::now();
        let plan = window.plan(&self.global, centre, self.settings.radius);
        self.partial = plan.over_capacity > 0;
        let run = self.submit(ctx, &plan, rows, true)?;
        let (report, _) = self.finish(run, None)?;
        self.last_sync = Some(centre);
        Ok(Some((report, ms_since(t_page))))
    }

    /// Uploads Gaussians of the global map into free window rows.
    pub(crate) fn append(
        &mut self,
        ctx: &Context,
        keys: &[VoxelKey],
        rows: &[Companion<'_>],
    ) -> Result<()> {
        if keys.is_empty() {
            return Ok(());
        }
        let window = self.window.as_mut().expect("opened at the first keyframe");
        let mut rec = ctx.recorder()?;
        window.record_append(&mut rec, keys, &self.global, rows)?;
        rec.submit()?.wait()
    }

    /// Training changed the resident Gaussians: a reader of the global map
    /// needs a write-back first.
    pub(crate) fn mark_trained(&mut self) {
        self.dirty = true;
    }

    /// When the camera moved more than the sync distance from where the
    /// window was centred, re-centres it on `centre`: recorded and
    /// submitted on the transfer queue, to finish with [`Pager::finish`].
    pub(crate) fn follow(
        &mut self,
        ctx: &Context,
        centre: DVec3,
        rows: &[Companion<'_>],
    ) -> Result<Option<PagingRun>> {
        let moved = self
            .last_sync
            .is_none_or(|p| p.distance(centre) > self.settings.sync_distance);
        if !moved {
            return Ok(None);
        }
        let window = self.window.as_ref().expect("opened at the first keyframe");
        let plan = window.plan(&self.global, centre, self.settings.radius);
        let run = self.submit(ctx, &plan, rows, false)?;
        self.last_sync = Some(centre);
        Ok(Some(run))
    }

    /// Records and submits a window sync on the transfer queue (timed).
    fn submit(
        &mut self,
        ctx: &Context,
        plan: &SyncPlan,
        rows: &[Companion<'_>],
        blocking: bool,
    ) -> Result<PagingRun> {
        let window = self.window.as_mut().expect("opened at the first keyframe");
        let report = PagingReport {
            written_back: window.len(),
            evicted: plan.evict.len(),
            fetched: plan.fetch.len(),
            over_capacity: plan.over_capacity,
            blocking,
        };
        let mut rec = ctx.transfer_recorder()?;
        rec.start_span();
        let pending = window.record_sync(&mut rec, plan, &self.global, rows)?;
        let submission = rec.submit()?;
        Ok(PagingRun {
            submission,
            pending,
            report,
        })
    }

    /// Waits for a sync and writes the window back to the global map.
    /// Returns the report and, when timed, the GPU milliseconds and those
    /// overlapping `beside`.
    pub(crate) fn finish(
        &mut self,
        run: PagingRun,
        beside: Option<&GpuSpan>,
    ) -> Result<(PagingReport, PagingSpan)> {
        let span = run.submission.wait_span()?;
        run.pending.apply(&mut self.global)?;
        self.dirty = false;
        let timing = span.map(|s| (s.ms(), beside.map(|b| s.overlap_ms(b))));
        Ok((run.report, timing))
    }

    /// Writes the window back to the global map (nothing moves), so that
    /// [`Pager::global`] is current; nothing to do when no training step
    /// ran since the last write-back.
    pub(crate) fn flush(&mut self, ctx: &Context, rows: &[Companion<'_>]) -> Result<()> {
        let Some(window) = &self.window else {
            return Ok(());
        };
        if window.is_empty() || !self.dirty {
            return Ok(());
        }
        let plan = SyncPlan {
            keep: window.len(),
            ..SyncPlan::default()
        };
        let run = self.submit(ctx, &plan, rows, true)?;
        self.finish(run, None)?;
        Ok(())
    }

    /// Every Gaussian of the map as it stands, changing nothing: the
    /// window's rows as the GPU holds them (when training changed them
    /// since the last write-back), then the global map's others. Unlike
    /// [`Pager::flush`] it writes nothing back, so taking it between
    /// keyframes leaves mapping exactly as without it.
    pub(crate) fn gaussians_now(&self, ctx: &Context) -> Result<HostGaussians> {
        let mut resident = KeySet::default();
        let mut out = HostGaussians::default();
        if let Some(window) = self.window.as_ref().filter(|w| self.dirty && !w.is_empty()) {
            out = window.params().download(ctx, window.len() as u64)?;
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
                push_gaussian(&mut out, g);
            }
        }
        Ok(out)
    }

    /// Removes `superseded` Gaussians, and the resident ones that are
    /// nearly transparent (opacity below `min_opacity`) or too large (a
    /// scale above `max_scale` metres), from the window and the global
    /// map, after writing the window back. Returns how many were removed.
    pub(crate) fn prune(
        &mut self,
        ctx: &Context,
        rows: &[Companion<'_>],
        mut superseded: KeySet,
        min_opacity: f32,
        max_scale: f32,
    ) -> Result<usize> {
        let Some(window) = &self.window else {
            return Ok(0);
        };
        // Superseded guesses outside the window go at once.
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
        let host = window.params().download(ctx, n as u64)?;
        let min_logit = {
            let o = min_opacity.clamp(1e-7, 1.0 - 1e-7);
            (o / (1.0 - o)).ln()
        };
        let max_log_scale = max_scale.max(1e-9).ln();
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
        let run = self.submit(ctx, &plan, rows, true)?;
        self.finish(run, None)?;
        for key in &doomed {
            self.global.remove(*key);
        }
        Ok(removed + doomed.len())
    }
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
