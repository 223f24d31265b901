//! The paging part of the mapper: the CPU global map keyed by voxel and the
//! GPU window of it around the camera (paper §III-D), kept in step block by
//! block. New Gaussians come into the window with their blocks before
//! Stage I; the window follows the camera after Stage I, its moves on the
//! compute queue and the download of the leaving rows on the transfer queue
//! beside Stage II; the rows training changed are written back when a
//! reader needs the whole map; pruning removes Gaussians from both.

use std::time::Instant;

use glam::DVec3;

use crate::map::{
    push_gaussian, Companion, GlobalMap, KeySet, LocalWindow, PendingSync, StagedArrivals,
    SyncPlan, VoxelKey,
};
use crate::mapper::budget::WindowBudget;
use crate::mapper::keyframe_report::PagingReport;
use crate::mapper::seeder::Extent;
use latentam_base::{HostGaussians, Result};
use latentam_gpu::{Buffer, Context, GpuSpan, Submission, SyncPoint};

mod prune_scan;
#[cfg(test)]
mod tests;

use prune_scan::prune_bounds;
pub(crate) use prune_scan::PruneScan;

/// A window sync planned before Stage I, its arrivals uploading beside it
/// (a detached batch on the transfer queue), to be carried out after it
/// with [`Pager::follow`].
pub(crate) struct PreparedSync {
    plan: SyncPlan,
    staged: Option<StagedArrivals>,
    upload: Option<Submission>,
    /// Bytes its upload sent.
    bytes_up: u64,
}

/// A paging batch in flight: the arrivals' upload (ahead, beside Stage I),
/// the moves on the compute queue, and the download of the leaving rows
/// after them (on the transfer queue when the device has one).
pub(crate) struct PagingRun {
    upload: Option<Submission>,
    moves: Submission,
    download: Option<Submission>,
    pending: PendingSync,
    report: PagingReport,
}

/// What a finished paging batch took on the GPU: its milliseconds, and
/// those it overlapped with the span it ran beside.
pub(crate) type PagingSpan = Option<(f64, Option<f64>)>;

/// Where the window stands against the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PagerSettings {
    /// Blocks within this distance of the camera are kept resident.
    pub radius: f64,
    /// The window follows the camera once it moved this far; resident
    /// blocks stay until they are this far beyond the radius.
    pub sync_distance: f64,
    /// Host bytes the global map may hold before blocks spill to disk
    /// (0: no limit).
    pub host_budget: u64,
}

/// What the disk tier did during one keyframe.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct DiskMoves {
    /// Host milliseconds it took.
    pub ms: f64,
    /// Blocks written.
    pub written: u64,
    /// Blocks read back.
    pub read: u64,
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
    /// Batches submitted without a wait (appends, pruning's moves): the
    /// queue orders later work after them; their timestamps are collected
    /// once a later wait shows them finished.
    unwaited: Vec<Submission>,
    /// Syncs submitted and not yet finished.
    in_flight: Vec<PagingRun>,
    /// The last batch that read the window's inbox.
    inbox_read_by: Option<SyncPoint>,
    /// The last download of the window's outbox.
    outbox_read_by: Option<SyncPoint>,
    /// Whether the transfer queue is a queue of its own (else what runs
    /// "beside" compute runs after it).
    dedicated_transfer: bool,
    /// The pruning scan's mask (one bit a row), once pruning ran.
    prune_mask: Option<Buffer>,
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
            unwaited: Vec::new(),
            in_flight: Vec::new(),
            inbox_read_by: None,
            outbox_read_by: None,
            dedicated_transfer: false,
            prune_mask: None,
        }
    }

    /// The global map, current up to the last write-back.
    pub(crate) fn global(&self) -> &GlobalMap {
        &self.global
    }

    /// Spills go to a scratch file in `dir` (see
    /// [`GlobalMap::set_spill_dir`]).
    pub(crate) fn set_spill_dir(&mut self, dir: &str) {
        self.global.set_spill_dir(dir);
    }

    /// Reads back the spilled blocks near `centre` (before a keyframe
    /// seeds or plans there): every block within the window's reach or
    /// `sight` (the farthest point the keyframe sees), and a margin of two
    /// blocks, so that seeding, its checks and the plan see the map whole
    /// where they look. Returns what it moved.
    pub(crate) fn load_around(&mut self, centre: DVec3, sight: f64) -> Result<DiskMoves> {
        if self.global.spilled_blocks() == 0 {
            return Ok(DiskMoves::default());
        }
        let t = Instant::now();
        let edge = self.global.voxel_size() * crate::map::BLOCK_VOXELS as f64;
        let reach = (self.settings.radius + self.settings.sync_distance).max(sight) + 2.0 * edge;
        let read = self.global.load_near(centre, reach)? as u64;
        Ok(DiskMoves {
            ms: ms_since(t),
            written: 0,
            read,
        })
    }

    /// After a keyframe: marks the window's blocks used, and spills the
    /// blocks used longest ago, never a resident one, until the global
    /// map is within the host budget. Syncs must be settled (what left
    /// the window is written back). Returns what it moved.
    pub(crate) fn spill_to_budget(&mut self) -> Result<DiskMoves> {
        debug_assert!(!self.in_flight(), "spilling while syncs are in flight");
        self.global.tick();
        let Pager { global, window, .. } = self;
        if let Some(w) = window {
            for block in w.block_keys() {
                global.touch(block);
            }
        }
        if self.settings.host_budget == 0 {
            return Ok(DiskMoves::default());
        }
        let t = Instant::now();
        let window = self.window.as_ref();
        let written = self
            .global
            .spill_to_budget(self.settings.host_budget, |b| {
                window.is_some_and(|w| w.holds_block(b))
            })? as u64;
        Ok(DiskMoves {
            ms: ms_since(t),
            written,
            read: 0,
        })
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
        self.global.bytes() + self.window.as_ref().map_or(0, LocalWindow::table_bytes)
    }

    /// Creates the window, sized as `budget` says (first keyframe only).
    pub(crate) fn open_window(&mut self, ctx: &Context, budget: WindowBudget) -> Result<()> {
        self.window = Some(LocalWindow::new(ctx, budget.capacity)?);
        self.dedicated_transfer = ctx.info().dedicated_transfer_queue;
        self.budget = Some(budget);
        Ok(())
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

    /// Makes the global map's new Gaussians `keys` resident for Stage I:
    /// into free rows when they fit, else by re-centring the window on
    /// `centre` first. They come alone, not with the rest of their blocks:
    /// a block beyond the radius would otherwise come in for one new
    /// Gaussian, train from a fresh optimiser state and leave again at
    /// every keyframe; the next sync completes the blocks within the
    /// radius. Neither way waits: Stage I runs after the moves on the same
    /// queue, and a re-centring's download is finished by
    /// [`Pager::settle`] after Stage II. Returns the host milliseconds of
    /// paging when it re-centred.
    pub(crate) fn make_resident(
        &mut self,
        ctx: &Context,
        keys: &[VoxelKey],
        rows: &[Companion<'_>],
        centre: DVec3,
    ) -> Result<Option<f64>> {
        let window = self.window.as_ref().expect("opened at the first keyframe");
        if keys.len() <= window.free() {
            self.append(ctx, keys, rows)?;
            return Ok(None);
        }
        let t_page = Instant::now();
        let run = self.page_around(ctx, centre, rows, true)?;
        self.in_flight.push(run);
        Ok(Some(ms_since(t_page)))
    }

    /// Uploads Gaussians of the global map into free window rows, in this
    /// order (a saved window is restored row for row), without waiting.
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
        self.unwaited.push(rec.submit()?);
        Ok(())
    }

    /// Training changed the resident Gaussians: their blocks are dirty
    /// until written back.
    pub(crate) fn mark_trained(&mut self) {
        if let Some(w) = &mut self.window {
            w.mark_trained();
        }
    }

    /// When the camera moved more than the sync distance from where the
    /// window was centred, plans the window around `centre` and uploads
    /// the arriving blocks into the window's inbox on a detached transfer
    /// batch, which runs beside Stage I (Stage I neither reads nor waits
    /// for it). `None` when the camera did not move far enough, or no
    /// block comes or goes.
    pub(crate) fn prepare(&mut self, ctx: &Context, centre: DVec3) -> Result<Option<PreparedSync>> {
        let moved = self
            .last_sync
            .is_none_or(|p| p.distance(centre) > self.settings.sync_distance);
        if !moved {
            return Ok(None);
        }
        let plan = self.plan_around(centre);
        if plan.evict.is_empty() && plan.fetch.is_empty() {
            return Ok(None);
        }
        let window = self.window.as_mut().expect("opened at the first keyframe");
        if plan.fetch.is_empty() {
            return Ok(Some(PreparedSync {
                plan,
                staged: None,
                upload: None,
                bytes_up: 0,
            }));
        }
        let before = ctx.gpu_work();
        let mut rec = ctx.transfer_recorder()?;
        rec.detach();
        rec.start_span();
        // The inbox's last reader (the previous sync's moves) was waited
        // for; name it anyway, since this batch waits for nothing else.
        if let Some(point) = self.inbox_read_by {
            rec.wait_for(point);
        }
        let staged = window.record_arrivals(&mut rec, &plan, &self.global)?;
        let upload = rec.submit()?;
        Ok(Some(PreparedSync {
            plan,
            staged: Some(staged),
            upload: Some(upload),
            bytes_up: (ctx.gpu_work() - before).uploaded_bytes,
        }))
    }

    /// Carries out a prepared sync after Stage I: the moves (gathering
    /// the leaving rows, compaction, the arrivals copied in from the inbox)
    /// on the compute queue, the download of what leaves on the transfer
    /// queue; [`Pager::settle`] finishes it after Stage II.
    pub(crate) fn follow(
        &mut self,
        ctx: &Context,
        prepared: PreparedSync,
        rows: &[Companion<'_>],
    ) -> Result<()> {
        let PreparedSync {
            plan,
            staged,
            upload,
            bytes_up,
        } = prepared;
        let mut run = self.submit(ctx, &plan, rows, false, staged, upload.as_ref())?;
        run.upload = upload;
        run.report.bytes_up += bytes_up;
        self.in_flight.push(run);
        Ok(())
    }

    /// Finishes every sync in flight, in order (one host wait for the
    /// last; the GPU finished the others before it), writing what left
    /// the window back to the global map. Returns each sync's report and,
    /// when timed, its GPU milliseconds and those hidden beside `beside`
    /// (Stage II's span).
    pub(crate) fn settle(
        &mut self,
        beside: Option<&GpuSpan>,
    ) -> Result<Vec<(PagingReport, PagingSpan)>> {
        let mut runs = std::mem::take(&mut self.in_flight);
        // Wait for the last: once it is done, so are those before it (each
        // sync's moves wait for the previous download).
        let Some(last) = runs.pop() else {
            return Ok(Vec::new());
        };
        let last = self.finish(last, beside, false)?;
        let mut finished = Vec::with_capacity(runs.len() + 1);
        for run in runs {
            finished.push(self.finish(run, beside, true)?);
        }
        finished.push(last);
        // Written back in submission order.
        let mut out = Vec::with_capacity(finished.len());
        for (report, span, pending) in finished {
            pending.apply(&mut self.global)?;
            out.push((report, span));
        }
        self.collect_unwaited()?;
        Ok(out)
    }

    /// Whether syncs are in flight (between seeding and the end of Stage
    /// II), so that the global map lacks what left the window.
    pub(crate) fn in_flight(&self) -> bool {
        !self.in_flight.is_empty()
    }

    /// The plan around `centre`, which becomes the window's centre.
    fn plan_around(&mut self, centre: DVec3) -> SyncPlan {
        let window = self.window.as_ref().expect("opened at the first keyframe");
        let plan = window.plan(
            &self.global,
            centre,
            self.settings.radius,
            self.settings.sync_distance,
        );
        self.partial = plan.over_capacity > 0;
        self.last_sync = Some(centre);
        plan
    }

    /// Plans the window around `centre` and submits the sync at once
    /// (arrivals uploaded in the same batch as the moves).
    fn page_around(
        &mut self,
        ctx: &Context,
        centre: DVec3,
        rows: &[Companion<'_>],
        before_stage_one: bool,
    ) -> Result<PagingRun> {
        let plan = self.plan_around(centre);
        self.submit(ctx, &plan, rows, before_stage_one, None, None)
    }

    /// Records and submits a window sync (timed): the moves on the compute
    /// queue, the download of what leaves on the transfer queue.
    fn submit(
        &mut self,
        ctx: &Context,
        plan: &SyncPlan,
        rows: &[Companion<'_>],
        before_stage_one: bool,
        staged: Option<StagedArrivals>,
        upload: Option<&Submission>,
    ) -> Result<PagingRun> {
        let window = self.window.as_mut().expect("opened at the first keyframe");
        let before = ctx.gpu_work();
        let mut rec = ctx.recorder()?;
        rec.start_span();
        if let Some(u) = upload {
            rec.wait_for(u.sync_point());
        }
        // The gather overwrites the outbox: after its last download.
        if let Some(point) = self.outbox_read_by {
            rec.wait_for(point);
        }
        let outbox = window.record_sync(&mut rec, plan, &self.global, rows, staged)?;
        let moves = rec.submit()?;
        self.inbox_read_by = Some(moves.sync_point());
        let (download, pending) = if outbox.is_empty() {
            (None, PendingSync::default())
        } else {
            // Detached: the compute queue's later work (Stage I after a
            // re-centring, Stage II) does not wait for it; it waits for the
            // moves by name, and the next gather for it.
            let mut rec = ctx.transfer_recorder()?;
            rec.detach();
            rec.wait_for(moves.sync_point());
            rec.start_span();
            let pending = window.record_outbox(&mut rec, outbox)?;
            let download = rec.submit()?;
            self.outbox_read_by = Some(download.sync_point());
            (Some(download), pending)
        };
        let moved = ctx.gpu_work() - before;
        let report = PagingReport {
            written_back: pending.len(),
            evicted: plan.evict.len(),
            fetched: plan.fetch.len(),
            over_capacity: plan.over_capacity,
            blocks_in: plan.blocks_in,
            blocks_out: plan.blocks_out,
            bytes_up: moved.uploaded_bytes,
            bytes_down: moved.downloaded_bytes,
            before_stage_one,
        };
        Ok(PagingRun {
            upload: None,
            moves,
            download,
            pending,
            report,
        })
    }

    /// Finishes a sync: a host wait only when it is still running (`done`:
    /// a later sync that waited for it on the GPU was waited for; on a
    /// single queue, Stage II's wait covered it). Returns the report, when
    /// timed the GPU milliseconds and those overlapping `beside`, and the
    /// write-back to apply.
    fn finish(
        &mut self,
        run: PagingRun,
        beside: Option<&GpuSpan>,
        done: bool,
    ) -> Result<(PagingReport, PagingSpan, PendingSync)> {
        let PagingRun {
            upload,
            moves,
            download,
            pending,
            report,
        } = run;
        // The download waited for the moves on the GPU, and the moves for
        // the upload: once the last is done, so are the others.
        // Not done yet only where it runs on a transfer queue of its
        // own and outlasted Stage II: then it is waited for.
        let last = |s: Submission| match done {
            true => s.finished_span(),
            false if s.is_done() => s.finished_span(),
            false => s.wait_span(),
        };
        let (moves, download) = match download {
            Some(d) => {
                let d = last(d)?;
                (moves.finished_span()?, d)
            }
            None => (last(moves)?, None),
        };
        let upload = match upload {
            Some(u) => u.finished_span()?,
            None => None,
        };
        let spans = [&upload, &moves, &download];
        if spans.iter().all(|s| s.is_none()) {
            return Ok((report, None, pending));
        }
        let gpu: f64 = spans
            .iter()
            .filter_map(|s| s.as_ref())
            .map(GpuSpan::ms)
            .sum();
        // Hidden: the download's time beside Stage II, and, on a transfer
        // queue of its own, the upload's time before the moves began (it
        // ran beside Stage I: the moves were the first to wait for it).
        let beside_two = match (&download, beside) {
            (Some(d), Some(b)) => Some(d.overlap_ms(b)),
            _ => None,
        };
        let beside_one = match (&upload, &moves) {
            (Some(u), Some(m)) if self.dedicated_transfer => Some(u.ms_before(m)),
            (Some(_), Some(_)) => Some(0.0),
            _ => None,
        };
        let hidden = match (beside_one, beside_two) {
            (None, None) => None,
            (a, b) => Some(a.unwrap_or(0.0) + b.unwrap_or(0.0)),
        };
        Ok((report, Some((gpu, hidden)), pending))
    }

    /// Hands the timestamps of batches submitted without a wait to the
    /// profiler, once finished.
    fn collect_unwaited(&mut self) -> Result<()> {
        for s in self.unwaited.drain(..) {
            if s.is_done() {
                s.finished_span()?;
            }
        }
        Ok(())
    }

    /// Writes the rows training changed back to the global map (one
    /// gather, one copy, one wait), so that [`Pager::global`] is current;
    /// nothing to do when no block is dirty.
    pub(crate) fn flush(&mut self, ctx: &Context) -> Result<()> {
        self.settle(None)?;
        let Pager { window, global, .. } = self;
        let Some(window) = window else {
            return Ok(());
        };
        let mut rec = ctx.recorder()?;
        let pending = window.record_write_back(&mut rec)?;
        if pending.is_empty() {
            return Ok(());
        }
        rec.submit()?.wait()?;
        pending.apply(global)?;
        self.collect_unwaited()
    }

    /// Every Gaussian of the map as it stands, changing nothing: the rows
    /// training changed as the GPU holds them, then the global map's
    /// others (current for every clean block). Unlike [`Pager::flush`] it
    /// writes nothing back, so taking it between keyframes leaves mapping
    /// exactly as without it.
    pub(crate) fn gaussians_now(&self, ctx: &Context) -> Result<HostGaussians> {
        // Syncs are settled before a keyframe ends: readers come between.
        debug_assert!(!self.in_flight(), "a reading while syncs are in flight");
        let (keys, mut out) = match &self.window {
            Some(w) => w.read_dirty(ctx)?,
            None => Default::default(),
        };
        let changed: KeySet = keys.into_iter().collect();
        out.reserve(self.global.len().saturating_sub(changed.len()));
        self.global.for_each_block(|_, keys, gaussians| {
            for (key, g) in keys.iter().zip(gaussians) {
                if !changed.contains(key) {
                    push_gaussian(&mut out, g);
                }
            }
            Ok(())
        })?;
        Ok(out)
    }

    /// Submits the scan [`Pager::prune`] reads (see [`PruneScan`]), on
    /// the compute queue after everything submitted so far; `None` before
    /// the window holds anything.
    pub(crate) fn submit_prune_scan(
        &mut self,
        ctx: &Context,
        min_opacity: f32,
        max_scale: f32,
    ) -> Result<Option<PruneScan>> {
        match &self.window {
            Some(w) => PruneScan::submit(ctx, w, &mut self.prune_mask, min_opacity, max_scale),
            None => Ok(None),
        }
    }

    /// Removes `superseded` Gaussians, and the resident ones that are
    /// nearly transparent (opacity below `min_opacity`) or too large (a
    /// scale above `max_scale` metres), from the window and the global
    /// map. The residents are scanned on the GPU (`scan`, when submitted
    /// earlier for this window: [`Pager::submit_prune_scan`]), and only
    /// one bit a row is read back; the doomed rows are compacted away on
    /// the GPU without being written back. Returns how many were removed.
    pub(crate) fn prune(
        &mut self,
        ctx: &Context,
        rows: &[Companion<'_>],
        mut superseded: KeySet,
        min_opacity: f32,
        max_scale: f32,
        scan: Option<PruneScan>,
    ) -> Result<usize> {
        let Some(window) = &self.window else {
            return Ok(0);
        };
        // Superseded guesses outside the window go at once (read back
        // first if their block was spilled).
        for key in superseded.iter() {
            if !window.holds(*key) {
                self.global.load(GlobalMap::block_of(*key))?;
            }
        }
        let mut removed = 0;
        superseded.retain(|key| {
            if window.holds(*key) {
                return true;
            }
            removed += self.global.remove(*key).is_some() as usize;
            false
        });
        let n = window.len();
        if n == 0 {
            return Ok(removed);
        }
        let bounds = prune_bounds(min_opacity, max_scale);
        let early = match scan {
            Some(scan) => scan.rows(n, bounds)?,
            None => None,
        };
        // Not scanned for this window: scanned now, with a wait.
        let mut evict = match early {
            Some(marked) => marked,
            None => PruneScan::submit(ctx, window, &mut self.prune_mask, min_opacity, max_scale)?
                .map(|scan| scan.rows(n, bounds))
                .transpose()?
                .flatten()
                .unwrap_or_default(),
        };
        // Resident superseded guesses: found through their blocks, not by
        // asking every row.
        evict.extend(superseded.iter().filter_map(|&key| window.row_of(key)));
        evict.sort_unstable();
        evict.dedup();
        if evict.is_empty() {
            return Ok(removed);
        }
        let doomed: Vec<_> = evict.iter().map(|&r| window.keys()[r as usize]).collect();
        let plan = window.plan_removal(evict);
        let run = self.submit(ctx, &plan, rows, true, None, None)?;
        // Nothing to download: the moves need no wait, later work on the
        // compute queue runs after them.
        self.unwaited.push(run.moves);
        for key in &doomed {
            self.global.remove(*key);
        }
        Ok(removed + doomed.len())
    }
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
