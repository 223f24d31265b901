//! The local window: the Gaussians near the camera, on the GPU.
//!
//! Rows `0..len` of the window's buffers hold the resident Gaussians; the
//! CPU keeps each row's voxel key. Re-synchronising with the global map
//! ([`LocalWindow::plan`], [`LocalWindow::record_sync`]) is all transfer
//! commands, so it can run on the dedicated transfer queue while Stage II
//! (which reads no Gaussian) runs on the compute queue:
//! 1. every resident row is downloaded (write-back of what Stage I changed);
//! 2. rows from the tail are copied into the rows of evicted Gaussians,
//!    keeping residents contiguous (sources and destinations are disjoint,
//!    so the copies are order-free);
//! 3. fetched Gaussians are uploaded after the last resident row.
//!
//! Per-Gaussian state kept beside the parameters (Adam moments, step
//! counts) is moved the same way through [`Companion`] buffers, and zeroed
//! for fetched rows.

use glam::DVec3;

use super::global::{Gaussian, GlobalMap};
use super::voxel::{KeySet, VoxelKey};
use crate::splat::{GaussianBuffers, GaussianReadback, HostGaussians, FIELD_WIDTHS};
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Recorder};

/// A buffer with one fixed-size row per window row, moved along with the
/// Gaussians (e.g. an Adam moment buffer: `row_bytes` = 4 × width).
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context};
/// use latentam_core::map::{Companion, GlobalMap, LocalWindow, SyncPlan};
/// # fn f(ctx: &Context, window: &mut LocalWindow, global: &mut GlobalMap, plan: &SyncPlan) -> latentam_core::Result<()> {
/// // A per-Gaussian step count (one u32 a row) that moves with its Gaussian.
/// let steps = Buffer::device(ctx, "steps", window.capacity() * 4)?;
/// let mut rec = ctx.transfer_recorder()?;
/// let pending = window.record_sync(&mut rec, plan, global, &[Companion { buffer: &steps, row_bytes: 4 }])?;
/// rec.submit()?.wait()?;
/// pending.apply(global)?;
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy)]
pub struct Companion<'a> {
    /// The buffer (at least capacity × `row_bytes`).
    pub buffer: &'a Buffer,
    /// Bytes per row.
    pub row_bytes: u64,
}

/// What a re-synchronisation changes.
///
/// ```
/// # fn f(window: &latentam_core::map::LocalWindow, global: &latentam_core::map::GlobalMap, camera: glam::DVec3) {
/// let plan = window.plan(global, camera, 4.0); // keep everything within 4 m
/// println!("{} stay, {} leave, {} come in", plan.keep, plan.evict.len(), plan.fetch.len());
/// if plan.over_capacity > 0 {
///     println!("{} Gaussians within 4 m do not fit the window", plan.over_capacity);
/// }
/// # }
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SyncPlan {
    /// Rows whose Gaussians leave the window (outside the radius, or the
    /// farthest when the capacity is exceeded), ascending.
    pub evict: Vec<u32>,
    /// Gaussians that come in, nearest first.
    pub fetch: Vec<VoxelKey>,
    /// Residents within the radius that stay.
    pub keep: usize,
    /// Gaussians within the radius left out for lack of capacity.
    pub over_capacity: usize,
}

/// A recorded synchronisation: apply it once its submission completed.
///
/// ```no_run
/// use latentam_core::map::{GlobalMap, LocalWindow};
/// # fn f(ctx: &latentam_gpu::Context, window: &mut LocalWindow, global: &mut GlobalMap, camera: glam::DVec3) -> latentam_core::Result<()> {
/// let plan = window.plan(global, camera, 4.0);
/// let mut rec = ctx.transfer_recorder()?;
/// let pending = window.record_sync(&mut rec, &plan, global, &[])?;
/// rec.submit()?.wait()?; // the download is complete only now
/// let written_back = pending.apply(global)?;
/// # Ok(())
/// # }
/// ```
#[must_use = "the write-back must be applied to the global map"]
pub struct PendingSync {
    readback: GaussianReadback,
    keys: Vec<VoxelKey>,
}

impl PendingSync {
    /// Writes the downloaded Gaussians back to the global map by key.
    /// Errors if the submission has not completed.
    pub fn apply(self, global: &mut GlobalMap) -> Result<usize> {
        let host = self.readback.read()?;
        for (i, key) in self.keys.iter().enumerate() {
            if !global.write_back(*key, gaussian_at(&host, i)) {
                return Err(Error::bad_input(
                    "global map",
                    format!(
                        "window row {i} holds voxel {key:?}, which the global map does not have"
                    ),
                ));
            }
        }
        Ok(self.keys.len())
    }
}

/// One Gaussian out of a host SoA.
pub fn gaussian_at(h: &HostGaussians, i: usize) -> Gaussian {
    Gaussian {
        mean: h.means[i],
        log_scale: h.log_scales[i],
        quat: h.quats[i],
        color: h.colors[i],
        opacity_logit: h.opacity_logits[i],
        query: h.queries[i],
    }
}

/// Appends one Gaussian to a host SoA.
pub fn push_gaussian(h: &mut HostGaussians, g: &Gaussian) {
    h.means.push(g.mean);
    h.log_scales.push(g.log_scale);
    h.quats.push(g.quat);
    h.colors.push(g.color);
    h.opacity_logits.push(g.opacity_logit);
    h.queries.push(g.query);
}

/// The resident Gaussians and their GPU buffers.
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions};
/// use latentam_core::map::{GlobalMap, LocalWindow};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let mut global = GlobalMap::new(0.02);
/// let mut window = LocalWindow::new(&ctx, 100_000)?; // room for 100k Gaussians on the GPU
/// let plan = window.plan(&global, glam::DVec3::ZERO, 5.0);
/// let mut rec = ctx.transfer_recorder()?;
/// let pending = window.record_sync(&mut rec, &plan, &global, &[])?;
/// rec.submit()?.wait()?;
/// pending.apply(&mut global)?;
/// println!("{} resident, {} rows free", window.len(), window.free());
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct LocalWindow {
    ctx: Context,
    params: GaussianBuffers,
    keys: Vec<VoxelKey>,
    /// Rows in transit during compaction (grown as needed).
    scratch: Option<Buffer>,
}

impl LocalWindow {
    /// A window for at most `capacity` Gaussians (buffers named
    /// `window/...` in the memory report).
    pub fn new(ctx: &Context, capacity: u64) -> Result<Self> {
        if capacity == 0 {
            return Err(Error::bad_input(
                "window capacity",
                "a window needs room for at least one Gaussian",
            ));
        }
        Ok(LocalWindow {
            ctx: ctx.clone(),
            params: GaussianBuffers::new(ctx, "window", capacity)?,
            keys: Vec::new(),
            scratch: None,
        })
    }

    /// Rows available.
    pub fn capacity(&self) -> u64 {
        self.params.capacity()
    }

    /// Resident Gaussians (rows `0..len`).
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    /// Whether nothing is resident.
    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// The voxel key of every resident row.
    pub fn keys(&self) -> &[VoxelKey] {
        &self.keys
    }

    /// The parameter buffers (rows `0..len` are valid).
    pub fn params(&self) -> &GaussianBuffers {
        &self.params
    }

    /// Which residents leave and which Gaussians come in for a camera at
    /// `centre` keeping everything within `radius`: residents outside the
    /// radius leave; when the Gaussians within it exceed the capacity, the
    /// farthest are left out (residents among them evicted).
    pub fn plan(&self, global: &GlobalMap, centre: DVec3, radius: f64) -> SyncPlan {
        let mut wanted = global.within_by_distance(centre, radius);
        let cap = self.capacity() as usize;
        let over_capacity = wanted.len().saturating_sub(cap);
        wanted.truncate(cap);
        let wanted_set: KeySet = wanted.iter().map(|w| w.1).collect();
        let resident: KeySet = self.keys.iter().copied().collect();
        let evict: Vec<u32> = (0..self.keys.len() as u32)
            .filter(|&r| !wanted_set.contains(&self.keys[r as usize]))
            .collect();
        let fetch: Vec<VoxelKey> = wanted
            .iter()
            .map(|w| w.1)
            .filter(|k| !resident.contains(k))
            .collect();
        SyncPlan {
            keep: self.keys.len() - evict.len(),
            evict,
            fetch,
            over_capacity,
        }
    }

    /// Records a synchronisation on `rec` (a transfer recorder, normally):
    /// write-back download of every resident row, compaction over the
    /// evicted rows, upload of the fetched Gaussians from `global`, and the
    /// same moves for `companions` (fetched rows zeroed). The row → key
    /// table is updated now; apply the returned [`PendingSync`] to the
    /// global map once the submission has completed.
    pub fn record_sync<'a>(
        &'a mut self,
        rec: &mut Recorder<'a>,
        plan: &SyncPlan,
        global: &GlobalMap,
        companions: &[Companion<'a>],
    ) -> Result<PendingSync> {
        let n = self.keys.len();
        let keep = n - plan.evict.len();
        self.check_room(keep, plan.fetch.len(), companions)?;
        let fetched = gather(global, &plan.fetch)?;
        let largest_row = FIELD_WIDTHS
            .iter()
            .map(|w| w * 4)
            .chain(companions.iter().map(|c| c.row_bytes))
            .max()
            .unwrap_or(4);
        let scratch_bytes = plan.evict.len().min(keep.max(1)) as u64 * largest_row;
        if self
            .scratch
            .as_ref()
            .is_none_or(|b| b.bytes() < scratch_bytes)
        {
            self.scratch = None;
            self.scratch = Some(Buffer::device(
                &self.ctx,
                "window/compaction",
                scratch_bytes.max(largest_row),
            )?);
        }
        let (params, keys, scratch) = (&self.params, &mut self.keys, &self.scratch);

        // 1. Write-back of every resident row, before anything moves.
        let readback = params.record_download(rec, n as u64)?;
        let pending = PendingSync {
            readback,
            keys: keys.clone(),
        };

        // 2. Compaction: live rows from the tail fill the holes below `keep`,
        // through the scratch buffer (a copy within one buffer makes
        // validation layers compare every pair of regions for overlap).
        let mut evicted = vec![false; n];
        for &r in &plan.evict {
            if let Some(e) = evicted.get_mut(r as usize) {
                *e = true;
            }
        }
        let holes = plan.evict.iter().copied().filter(|&r| (r as usize) < keep);
        let movers = (keep as u32..n as u32).filter(|&r| !evicted[r as usize]);
        let moves: Vec<(u32, u32)> = holes.zip(movers).collect();
        let gather: Vec<(u64, u64, u64)> = runs(
            moves
                .iter()
                .enumerate()
                .map(|(i, &(_, s))| (s as u64, i as u64)),
        );
        let scatter: Vec<(u64, u64, u64)> = runs(
            moves
                .iter()
                .enumerate()
                .map(|(i, &(d, _))| (i as u64, d as u64)),
        );
        let rows: Vec<(&Buffer, u64)> = params
            .fields()
            .into_iter()
            .zip(FIELD_WIDTHS)
            .map(|(b, w)| (b, w * 4))
            .chain(companions.iter().map(|c| (c.buffer, c.row_bytes)))
            .collect();
        if !moves.is_empty() {
            let scratch = scratch.as_ref().expect("sized above");
            for (buf, row) in rows {
                let scale = |r: &[(u64, u64, u64)]| -> Vec<(u64, u64, u64)> {
                    r.iter()
                        .map(|&(s, d, len)| (s * row, d * row, len * row))
                        .collect()
                };
                rec.copy_regions(buf, scratch, &scale(&gather))?;
                rec.copy_regions(scratch, buf, &scale(&scatter))?;
            }
        }
        for &(dst, src) in &moves {
            keys[dst as usize] = keys[src as usize];
        }
        keys.truncate(keep);

        // 3. Fetched Gaussians after the residents.
        record_fetch(rec, params, keep as u64, &fetched, companions)?;
        keys.extend_from_slice(&plan.fetch);
        Ok(pending)
    }

    /// Records the upload of `keys` (present in `global`, not resident)
    /// after the resident rows, without write-back or eviction: the cheap
    /// way to bring a keyframe's new Gaussians in before Stage I. Errors
    /// when they do not fit.
    pub fn record_append<'a>(
        &'a mut self,
        rec: &mut Recorder<'a>,
        keys: &[VoxelKey],
        global: &GlobalMap,
        companions: &[Companion<'a>],
    ) -> Result<()> {
        let n = self.keys.len();
        self.check_room(n, keys.len(), companions)?;
        let fetched = gather(global, keys)?;
        record_fetch(rec, &self.params, n as u64, &fetched, companions)?;
        self.keys.extend_from_slice(keys);
        Ok(())
    }

    /// Errors unless `keep` residents and `incoming` Gaussians fit and every
    /// companion buffer covers the capacity.
    fn check_room(&self, keep: usize, incoming: usize, companions: &[Companion<'_>]) -> Result<()> {
        if keep + incoming > self.capacity() as usize {
            return Err(Error::budget(
                "the window capacity",
                format!(
                    "keeping {keep} and bringing in {incoming} Gaussians overflows a window of {}",
                    self.capacity()
                ),
            ));
        }
        for c in companions {
            c.buffer
                .ensure_bytes(self.capacity() * c.row_bytes, "window companion buffer")?;
        }
        Ok(())
    }

    /// Rows still free.
    pub fn free(&self) -> usize {
        self.capacity() as usize - self.keys.len()
    }
}

/// Copy regions (source row, destination row, rows) covering the
/// (source, destination) row pairs, merging runs where both advance by one.
fn runs(pairs: impl Iterator<Item = (u64, u64)>) -> Vec<(u64, u64, u64)> {
    let mut out: Vec<(u64, u64, u64)> = Vec::new();
    for (s, d) in pairs {
        match out.last_mut() {
            Some((ls, ld, len)) if *ls + *len == s && *ld + *len == d => *len += 1,
            _ => out.push((s, d, 1)),
        }
    }
    out
}

/// The Gaussians of `keys`, as host SoA.
fn gather(global: &GlobalMap, keys: &[VoxelKey]) -> Result<HostGaussians> {
    let mut fetched = HostGaussians::default();
    for k in keys {
        let g = global.get(*k).ok_or_else(|| {
            Error::bad_input(
                "global map",
                format!("sync fetches voxel {k:?}, which the global map does not have"),
            )
        })?;
        push_gaussian(&mut fetched, g);
    }
    Ok(fetched)
}

/// Uploads `fetched` at row `first`; their companion rows start from zero.
fn record_fetch<'a>(
    rec: &mut Recorder<'a>,
    params: &'a GaussianBuffers,
    first: u64,
    fetched: &HostGaussians,
    companions: &[Companion<'a>],
) -> Result<()> {
    if fetched.means.is_empty() {
        return Ok(());
    }
    params.record_upload(rec, first, fetched)?;
    for c in companions {
        let bytes = fetched.means.len() as u64 * c.row_bytes;
        rec.fill_range_u32(c.buffer, first * c.row_bytes, bytes, 0)?;
    }
    Ok(())
}
