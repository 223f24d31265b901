//! The local window: the Gaussians near the camera, on the GPU, by block.
//!
//! The window pages whole blocks (cubes of [`BLOCK_VOXELS`](super::BLOCK_VOXELS) voxels of the
//! global map) in and out; only a keyframe's new Gaussians come in alone
//! ([`LocalWindow::record_append`]), and the next plan completes their
//! blocks if it wants them. Rows `0..len` of its buffers hold the resident
//! Gaussians, densely; the CPU keeps each row's voxel key and, per resident
//! block, its rows. The GPU holds the truth for what is resident: training
//! changes rows there, and the global map's copy of a resident Gaussian is
//! brought up to date only when its block leaves the window or a reader
//! asks for the whole map, and then only for the blocks training changed
//! since their last copy (each block carries a dirty flag).
//!
//! A re-synchronisation ([`LocalWindow::plan`], [`LocalWindow::record_sync`],
//! [`LocalWindow::record_outbox`]) is planned as a difference of block
//! sets and moves rows by kernels (`latentam_gpu::ops`):
//! 1. the rows of the leaving blocks that changed are gathered into one
//!    packed outbox, downloaded with one copy (on the transfer queue, beside
//!    work that reads no Gaussian);
//! 2. rows from the tail move into the rows the leaving Gaussians freed
//!    (compaction: one dispatch per buffer; sources at or above the rows
//!    kept, destinations below, so the moves never race);
//! 3. the arriving blocks' Gaussians are uploaded after the last resident
//!    row from one packed staging buffer (the rows are contiguous there, so
//!    a copy per field is the scatter).
//!
//! Per-Gaussian state kept beside the parameters (Adam moments, step
//! counts) moves the same way through [`Companion`] buffers, and is zeroed
//! for arriving rows.

use glam::DVec3;

use super::global::{Gaussian, GlobalMap};
use super::voxel::{KeyMap, KeySet, VoxelKey};
use crate::splat::{GaussianBuffers, HostGaussians, FIELD_WIDTHS, GAUSSIAN_BYTES};
use latentam_base::{Error, Result};
use latentam_gpu::ops::{gather_rows, move_rows, Packed, RowList};
use latentam_gpu::{Buffer, Context, Readback, Recorder};

/// 32-bit words of one Gaussian's parameters, all fields together.
const GAUSSIAN_WORDS: u64 = GAUSSIAN_BYTES / 4;

/// A buffer with one fixed-size row per window row, moved along with the
/// Gaussians (e.g. an Adam moment buffer: `row_bytes` = 4 × width).
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context};
/// use latentam_core::map::{Companion, GlobalMap, LocalWindow, SyncPlan};
/// # fn f(ctx: &Context, window: &mut LocalWindow, global: &mut GlobalMap, plan: &SyncPlan) -> latentam_core::Result<()> {
/// // A per-Gaussian step count (one u32 a row) that moves with its Gaussian.
/// let steps = Buffer::device(ctx, "steps", window.capacity() * 4)?;
/// let mut rec = ctx.recorder()?;
/// let outbox = window.record_sync(&mut rec, plan, global, &[Companion { buffer: &steps, row_bytes: 4 }], None)?;
/// rec.submit()?; // the moves
/// let mut download = ctx.transfer_recorder()?;
/// let pending = window.record_outbox(&mut download, outbox)?;
/// download.submit()?.wait()?;
/// pending.apply(global)?;
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy)]
pub struct Companion<'a> {
    /// The buffer (at least capacity × `row_bytes`).
    pub buffer: &'a Buffer,
    /// Bytes per row, a multiple of 4.
    pub row_bytes: u64,
}

/// What a re-synchronisation changes.
///
/// ```
/// # fn f(window: &latentam_core::map::LocalWindow, global: &latentam_core::map::GlobalMap, camera: glam::DVec3) {
/// // Keep the blocks within 4 m, and those already resident within 4.5 m.
/// let plan = window.plan(global, camera, 4.0, 0.5);
/// println!("{} stay, {} leave, {} come in", plan.keep, plan.evict.len(), plan.fetch.len());
/// println!("{} blocks in, {} out", plan.blocks_in, plan.blocks_out);
/// if plan.over_capacity > 0 {
///     println!("{} Gaussians within 4 m do not fit the window", plan.over_capacity);
/// }
/// # }
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SyncPlan {
    /// Rows whose Gaussians leave the window, ascending. Those of blocks
    /// training changed since their last copy are copied back to the
    /// global map first, as the blocks stand when the sync is recorded
    /// (a plan made before Stage I is carried out after it).
    pub evict: Vec<u32>,
    /// Drop the evicted rows without copying any back: pruning.
    pub discard: bool,
    /// Gaussians that come in, block by block, nearest block first.
    pub fetch: Vec<VoxelKey>,
    /// Residents that stay.
    pub keep: usize,
    /// Gaussians within the radius left out for lack of capacity.
    pub over_capacity: usize,
    /// Blocks that come in (wholly or, to mend a block only partly
    /// resident, in part).
    pub blocks_in: usize,
    /// Blocks that leave.
    pub blocks_out: usize,
    /// The window's row tables this plan was made against: a plan is
    /// refused once rows came or went since.
    pub generation: u64,
}

/// The rows a recorded synchronisation gathered into the window's outbox,
/// to download with [`LocalWindow::record_outbox`].
#[derive(Debug)]
#[must_use = "the gathered rows must be downloaded and written back"]
pub struct Outbox {
    keys: Vec<VoxelKey>,
}

impl Outbox {
    /// Rows gathered.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    /// Whether nothing was gathered.
    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }
}

/// A plan's arriving Gaussians uploaded ahead into the window's inbox
/// ([`LocalWindow::record_arrivals`]), for the sync of that plan to copy in
/// on the GPU.
#[derive(Debug)]
#[must_use = "staged arrivals are for the sync of their plan"]
pub struct StagedArrivals {
    rows: usize,
    /// Which Gaussians, to refuse another plan's.
    fingerprint: u64,
}

/// A digest of a fetch list: staged arrivals serve only the plan they were
/// staged for.
fn fetch_fingerprint(keys: &[VoxelKey]) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = rustc_hash::FxHasher::default();
    keys.hash(&mut h);
    h.finish()
}

/// A recorded download of window rows: apply it once its submission
/// completed.
///
/// ```no_run
/// use latentam_core::map::{GlobalMap, LocalWindow};
/// # fn f(ctx: &latentam_gpu::Context, window: &mut LocalWindow, global: &mut GlobalMap, camera: glam::DVec3) -> latentam_core::Result<()> {
/// let plan = window.plan(global, camera, 4.0, 0.5);
/// let mut rec = ctx.recorder()?;
/// let outbox = window.record_sync(&mut rec, &plan, global, &[], None)?;
/// rec.submit()?; // the moves
/// let mut download = ctx.transfer_recorder()?; // runs after them
/// let pending = window.record_outbox(&mut download, outbox)?;
/// download.submit()?.wait()?; // the download is complete only now
/// let written_back = pending.apply(global)?;
/// # Ok(())
/// # }
/// ```
#[must_use = "the write-back must be applied to the global map"]
pub struct PendingSync {
    readback: Option<Readback>,
    keys: Vec<VoxelKey>,
}

impl Default for PendingSync {
    /// Nothing to write back.
    fn default() -> Self {
        PendingSync {
            readback: None,
            keys: Vec::new(),
        }
    }
}

impl PendingSync {
    /// Gaussians it writes back.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    /// Whether it writes nothing back.
    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// The downloaded Gaussians with their keys. Errors if the submission
    /// has not completed.
    pub fn read(self) -> Result<(Vec<VoxelKey>, HostGaussians)> {
        let host = match &self.readback {
            Some(r) => unpack(r.bytes()?, self.keys.len()),
            None => HostGaussians::default(),
        };
        Ok((self.keys, host))
    }

    /// Writes the downloaded Gaussians back to the global map by key.
    /// Errors if the submission has not completed.
    pub fn apply(self, global: &mut GlobalMap) -> Result<usize> {
        let Some(readback) = &self.readback else {
            return Ok(0);
        };
        let bytes = readback.bytes()?;
        let n = self.keys.len();
        if bytes.len() < n * GAUSSIAN_BYTES as usize {
            return Err(Error::bad_input(
                "window write-back",
                format!("{} bytes downloaded for {n} Gaussians", bytes.len()),
            ));
        }
        // Mapped memory is aligned far beyond 4 bytes on every driver;
        // copy rather than fail if one is not.
        let copied: Vec<f32>;
        let words: &[f32] = match bytemuck::try_cast_slice(bytes) {
            Ok(words) => words,
            Err(_) => {
                copied = bytemuck::pod_collect_to_vec(bytes);
                &copied
            }
        };
        let fields = packed_fields(words, n);
        for (i, key) in self.keys.iter().enumerate() {
            if !global.write_back(*key, fields.gaussian(i)) {
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

/// `n` Gaussians packed field after field, read in place.
struct PackedFields<'a> {
    means: &'a [[f32; 3]],
    log_scales: &'a [[f32; 3]],
    quats: &'a [[f32; 4]],
    colors: &'a [[f32; 3]],
    opacity_logits: &'a [f32],
    queries: &'a [[f32; crate::splat::QUERY_DIM]],
}

impl PackedFields<'_> {
    fn gaussian(&self, i: usize) -> Gaussian {
        Gaussian {
            mean: self.means[i],
            log_scale: self.log_scales[i],
            quat: self.quats[i],
            color: self.colors[i],
            opacity_logit: self.opacity_logits[i],
            query: self.queries[i],
        }
    }
}

/// The fields of `n` Gaussians packed field after field (the outbox's
/// layout), as slices of `words` (at least `n` Gaussians' worth).
fn packed_fields(words: &[f32], n: usize) -> PackedFields<'_> {
    let mut at = 0;
    let mut field = |width: u64| -> &[f32] {
        let len = n * width as usize;
        let part = &words[at..at + len];
        at += len;
        part
    };
    let [m, s, q, c, o, l] = FIELD_WIDTHS.map(&mut field);
    PackedFields {
        means: bytemuck::cast_slice(m),
        log_scales: bytemuck::cast_slice(s),
        quats: bytemuck::cast_slice(q),
        colors: bytemuck::cast_slice(c),
        opacity_logits: bytemuck::cast_slice(o),
        queries: bytemuck::cast_slice(l),
    }
}

/// `n` Gaussians packed field after field (the outbox's layout: every
/// row's means, then every row's scales, ...), as host SoA.
fn unpack(bytes: &[u8], n: usize) -> HostGaussians {
    let words: Vec<f32> = bytemuck::pod_collect_to_vec(bytes);
    let f = packed_fields(&words, n);
    HostGaussians {
        means: f.means.to_vec(),
        log_scales: f.log_scales.to_vec(),
        quats: f.quats.to_vec(),
        colors: f.colors.to_vec(),
        opacity_logits: f.opacity_logits.to_vec(),
        queries: f.queries.to_vec(),
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

/// A block with rows in the window.
#[derive(Clone, Debug, Default)]
struct ResidentBlock {
    /// Its rows, in no particular order.
    rows: Vec<u32>,
    /// Training may have changed its rows since the global map's copy.
    dirty: bool,
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
/// let plan = window.plan(&global, glam::DVec3::ZERO, 5.0, 0.5);
/// let mut rec = ctx.recorder()?;
/// let outbox = window.record_sync(&mut rec, &plan, &global, &[], None)?;
/// rec.submit()?;
/// let mut download = ctx.transfer_recorder()?;
/// let pending = window.record_outbox(&mut download, outbox)?;
/// download.submit()?.wait()?;
/// pending.apply(&mut global)?;
/// println!("{} resident in {} blocks, {} rows free", window.len(), window.blocks(), window.free());
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct LocalWindow {
    ctx: Context,
    params: GaussianBuffers,
    /// The voxel key of every row.
    keys: Vec<VoxelKey>,
    /// Every row's place in its block's row list.
    place: Vec<u32>,
    blocks: KeyMap<ResidentBlock>,
    /// Row lists for the kernels (grown as needed).
    index: Option<Buffer>,
    /// Rows gathered for download, packed field after field (grown as
    /// needed).
    outbox: Option<Buffer>,
    /// Arriving rows uploaded ahead of their sync, packed field after
    /// field (grown as needed).
    inbox: Option<Buffer>,
    /// Counts changes of the row tables (see [`SyncPlan::generation`]).
    generation: u64,
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
            place: Vec::new(),
            blocks: KeyMap::default(),
            index: None,
            outbox: None,
            inbox: None,
            generation: 0,
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

    /// Blocks with rows in the window.
    pub fn blocks(&self) -> usize {
        self.blocks.len()
    }

    /// The blocks with rows in the window, in no particular order.
    pub fn block_keys(&self) -> impl Iterator<Item = VoxelKey> + '_ {
        self.blocks.keys().copied()
    }

    /// Whether `block` has rows in the window.
    pub fn holds_block(&self, block: VoxelKey) -> bool {
        self.blocks.contains_key(&block)
    }

    /// Whether the Gaussian of voxel `key` is resident (costs its block's
    /// rows).
    pub fn holds(&self, key: VoxelKey) -> bool {
        self.row_of(key).is_some()
    }

    /// The row of voxel `key`'s Gaussian, when it is resident (costs its
    /// block's rows).
    pub fn row_of(&self, key: VoxelKey) -> Option<u32> {
        let block = self.blocks.get(&GlobalMap::block_of(key))?;
        block
            .rows
            .iter()
            .copied()
            .find(|&r| self.keys[r as usize] == key)
    }

    /// The voxel key of every resident row.
    pub fn keys(&self) -> &[VoxelKey] {
        &self.keys
    }

    /// The parameter buffers (rows `0..len` are valid).
    pub fn params(&self) -> &GaussianBuffers {
        &self.params
    }

    /// Rows still free.
    pub fn free(&self) -> usize {
        self.capacity() as usize - self.keys.len()
    }

    /// Host bytes of the row and block tables.
    pub fn table_bytes(&self) -> u64 {
        (self.keys.capacity() * (size_of::<VoxelKey>() + 4 + 4)
            + self.blocks.len() * (size_of::<VoxelKey>() + size_of::<ResidentBlock>() + 16))
            as u64
    }

    /// Training changed the resident rows: every resident block is dirty
    /// (its global map copy is stale) until written back.
    pub fn mark_trained(&mut self) {
        for b in self.blocks.values_mut() {
            b.dirty = true;
        }
    }

    /// Rows whose global map copy may be stale (those of dirty blocks),
    /// ascending.
    pub fn dirty_rows(&self) -> Vec<u32> {
        let mut rows: Vec<u32> = self
            .blocks
            .values()
            .filter(|b| b.dirty)
            .flat_map(|b| b.rows.iter().copied())
            .collect();
        rows.sort_unstable();
        rows
    }

    /// Which blocks leave and which come in for a camera at `centre`:
    /// blocks of the global map that come within `radius` are wanted,
    /// nearest first while they fit the capacity; resident blocks stay
    /// while they are within `radius + margin` and fit (so a camera
    /// moving back and forth across a block's edge does not page it every
    /// time). The plan costs the blocks near the camera and the rows that
    /// move, not the window's or the map's size. A resident block that the
    /// global map holds more of than the window (a restored window, say)
    /// gets its missing Gaussians.
    pub fn plan(&self, global: &GlobalMap, centre: DVec3, radius: f64, margin: f64) -> SyncPlan {
        let radius = radius.max(0.0);
        let reach = radius + margin.max(0.0);
        let cap = self.capacity() as usize;
        let mut used = 0usize;
        let mut over_capacity = 0usize;
        let mut wanted = KeySet::default();
        let mut arriving: Vec<VoxelKey> = Vec::new();
        let r2 = radius * radius;
        for (d2, block, count) in global.blocks_near(centre, reach) {
            let resident = self.blocks.contains_key(&block);
            if !resident && d2 > r2 {
                continue;
            }
            if used + count > cap {
                if d2 <= r2 {
                    over_capacity += count;
                }
                continue;
            }
            used += count;
            wanted.insert(block);
            if !resident {
                arriving.push(block);
            }
        }
        // Leaving: resident blocks not wanted.
        let mut evict = Vec::new();
        let mut blocks_out = 0;
        for (block, b) in &self.blocks {
            if wanted.contains(block) {
                continue;
            }
            blocks_out += 1;
            evict.extend_from_slice(&b.rows);
        }
        evict.sort_unstable();
        // Arriving: whole blocks, and what partly resident blocks lack.
        let mut fetch: Vec<VoxelKey> = Vec::new();
        for &block in &arriving {
            fetch.extend(global.block_keys(block));
        }
        let mut blocks_in = arriving.len();
        // Wanted and already resident: complete any partly resident one.
        for (block, b) in wanted.iter().filter_map(|k| Some((k, self.blocks.get(k)?))) {
            if b.rows.len() < global.block_len(*block) {
                let have: KeySet = b.rows.iter().map(|&r| self.keys[r as usize]).collect();
                fetch.extend(global.block_keys(*block).filter(|k| !have.contains(k)));
                blocks_in += 1;
            }
        }
        // A plan for a window over capacity (restored from a larger one)
        // may not fit: record_sync refuses it.
        SyncPlan {
            keep: self.keys.len() - evict.len(),
            evict,
            discard: false,
            fetch,
            over_capacity,
            blocks_in,
            blocks_out,
            generation: self.generation,
        }
    }

    /// A plan that evicts `rows` (ascending, without duplicates) and
    /// writes none of them back: pruning.
    pub fn plan_removal(&self, rows: Vec<u32>) -> SyncPlan {
        SyncPlan {
            keep: self.keys.len().saturating_sub(rows.len()),
            evict: rows,
            discard: true,
            generation: self.generation,
            ..SyncPlan::default()
        }
    }

    /// Uploads `plan`'s arriving Gaussians from `global` into the window's
    /// inbox, on `rec`: ahead of the sync, on a transfer batch that runs
    /// beside training (it touches nothing but the inbox). Pass the result
    /// to [`LocalWindow::record_sync`] with the same plan, in a batch that
    /// waits for this one; nothing else may be staged in between.
    pub fn record_arrivals<'a>(
        &'a mut self,
        rec: &mut Recorder<'a>,
        plan: &SyncPlan,
        global: &GlobalMap,
    ) -> Result<StagedArrivals> {
        let fetched = gather(global, &plan.fetch)?;
        let n = plan.fetch.len() as u64;
        let bytes = n.max(1) * GAUSSIAN_BYTES;
        let inbox = grow(&mut self.inbox, &self.ctx, "window/inbox", bytes)?;
        let data = fields_of(&fetched);
        let mut parts: Vec<(&'a Buffer, u64, &[u8])> = Vec::with_capacity(6);
        let mut at = 0u64;
        for d in data {
            parts.push((inbox, at, d));
            at += d.len() as u64;
        }
        rec.upload_packed(&parts)?;
        Ok(StagedArrivals {
            rows: plan.fetch.len(),
            fingerprint: fetch_fingerprint(&plan.fetch),
        })
    }

    /// Records a synchronisation on `rec` (a compute recorder: the moves
    /// are kernels): the rows to write back gathered into the outbox, the
    /// compaction over the evicted rows, the fetched Gaussians copied in
    /// after the residents (from `staged`, uploaded ahead, or else uploaded
    /// now from `global`), and the same moves for `companions` (fetched
    /// rows zeroed). The row and block tables are updated now; download the
    /// returned [`Outbox`] with [`LocalWindow::record_outbox`] (on any
    /// queue, after this batch) and apply that to the global map.
    pub fn record_sync<'a>(
        &'a mut self,
        rec: &mut Recorder<'a>,
        plan: &SyncPlan,
        global: &GlobalMap,
        companions: &[Companion<'a>],
        staged: Option<StagedArrivals>,
    ) -> Result<Outbox> {
        let n = self.keys.len();
        self.check_plan(plan)?;
        let keep = n - plan.evict.len();
        self.check_room(keep, plan.fetch.len(), companions)?;
        let fetched = match &staged {
            Some(s) => {
                let fits = self
                    .inbox
                    .as_ref()
                    .is_some_and(|b| b.bytes() >= s.rows as u64 * GAUSSIAN_BYTES);
                if s.rows != plan.fetch.len()
                    || s.fingerprint != fetch_fingerprint(&plan.fetch)
                    || !fits
                {
                    return Err(Error::bad_input(
                        "staged arrivals",
                        "they were staged for another plan",
                    ));
                }
                None
            }
            None => Some(gather(global, &plan.fetch)?),
        };

        // Compaction: live rows from the tail fill the holes below `keep`.
        let mut evicted = vec![false; n];
        for &r in &plan.evict {
            evicted[r as usize] = true;
        }
        let holes = plan.evict.iter().copied().filter(|&r| (r as usize) < keep);
        let movers = (keep as u32..n as u32).filter(|&r| !evicted[r as usize]);
        let (from, to): (Vec<u32>, Vec<u32>) = movers.zip(holes).unzip();
        // The leaving rows training changed, as the blocks stand now.
        let write_back: Vec<u32> = match plan.discard {
            true => Vec::new(),
            false => plan
                .evict
                .iter()
                .copied()
                .filter(|&r| {
                    let block = GlobalMap::block_of(self.keys[r as usize]);
                    self.blocks.get(&block).is_some_and(|b| b.dirty)
                })
                .collect(),
        };
        let wb = write_back.len();
        let list: Vec<u32> = [&write_back[..], &from, &to].concat();
        self.grow_buffers(list.len() as u64, wb as u64)?;

        let outbox_keys: Vec<VoxelKey> =
            write_back.iter().map(|&r| self.keys[r as usize]).collect();
        self.forget_rows(&plan.evict);
        self.move_rows_in_tables(&from, &to);
        self.keys.truncate(keep);
        self.place.truncate(keep);
        self.add_rows(&plan.fetch);

        let (params, index, outbox, inbox) = (&self.params, &self.index, &self.outbox, &self.inbox);
        let index = index.as_ref().expect("grown above");
        let outbox = outbox.as_ref().expect("grown above");
        if !list.is_empty() {
            rec.upload(index, 0, &list)?;
        }
        // 1. The rows to write back, before anything moves.
        record_gather(rec, params, index, 0, wb as u32, outbox)?;
        // 2. Compaction, every buffer whose rows follow the Gaussians.
        let moves = RowList {
            index,
            first: wb as u32,
            count: from.len() as u32,
        };
        for (buf, words) in row_buffers(params, companions) {
            move_rows(rec, buf, words, moves)?;
        }
        // 3. Fetched Gaussians after the residents.
        match (&fetched, inbox) {
            (Some(fetched), _) => record_fetch(rec, params, keep as u64, fetched, companions)?,
            (None, Some(inbox)) => copy_staged(
                rec,
                params,
                keep as u64,
                plan.fetch.len() as u64,
                inbox,
                companions,
            )?,
            (None, None) => unreachable!("checked above"),
        }
        Ok(Outbox { keys: outbox_keys })
    }

    /// Records the download of what `outbox` gathered (one copy), on any
    /// recorder submitted after the one that gathered it: the transfer
    /// queue's, to run beside work that touches no Gaussian.
    pub fn record_outbox<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        outbox: Outbox,
    ) -> Result<PendingSync> {
        if outbox.keys.is_empty() {
            return Ok(PendingSync::default());
        }
        let buf = self.outbox.as_ref().ok_or_else(|| {
            Error::bad_input("outbox", "nothing was gathered into this window's outbox")
        })?;
        let bytes = outbox.keys.len() as u64 * GAUSSIAN_BYTES;
        let readback = rec.download(buf, 0, bytes)?;
        Ok(PendingSync {
            readback: Some(readback),
            keys: outbox.keys,
        })
    }

    /// Records the gathering and download of every dirty row (one
    /// dispatch per field, one copy) and marks every block clean: apply
    /// the result to bring the global map up to date.
    pub fn record_write_back<'a>(&'a mut self, rec: &mut Recorder<'a>) -> Result<PendingSync> {
        let rows = self.dirty_rows();
        if rows.is_empty() {
            return Ok(PendingSync::default());
        }
        self.grow_buffers(rows.len() as u64, rows.len() as u64)?;
        for b in self.blocks.values_mut() {
            b.dirty = false;
        }
        let keys: Vec<VoxelKey> = rows.iter().map(|&r| self.keys[r as usize]).collect();
        let this: &'a LocalWindow = self;
        let (index, outbox) = (
            this.index.as_ref().expect("grown"),
            this.outbox.as_ref().expect("grown"),
        );
        rec.upload(index, 0, &rows)?;
        record_gather(rec, &this.params, index, 0, rows.len() as u32, outbox)?;
        let readback = rec.download(outbox, 0, rows.len() as u64 * GAUSSIAN_BYTES)?;
        Ok(PendingSync {
            readback: Some(readback),
            keys,
        })
    }

    /// The dirty rows as the GPU holds them, with their keys, changing
    /// nothing (through buffers of its own; waits).
    pub fn read_dirty(&self, ctx: &Context) -> Result<(Vec<VoxelKey>, HostGaussians)> {
        let rows = self.dirty_rows();
        if rows.is_empty() {
            return Ok((Vec::new(), HostGaussians::default()));
        }
        let index = ctx.upload_new("window/read index", &rows)?;
        let outbox = Buffer::device(ctx, "window/read", rows.len() as u64 * GAUSSIAN_BYTES)?;
        let mut rec = ctx.recorder()?;
        record_gather(
            &mut rec,
            &self.params,
            &index,
            0,
            rows.len() as u32,
            &outbox,
        )?;
        let readback = rec.download(&outbox, 0, outbox.bytes())?;
        rec.submit()?.wait()?;
        let keys = rows.iter().map(|&r| self.keys[r as usize]).collect();
        Ok((keys, unpack(readback.bytes()?, rows.len())))
    }

    /// Records the upload of `keys` (present in `global`, not resident)
    /// after the resident rows, without write-back or eviction: the cheap
    /// way to bring a keyframe's new Gaussians in before Stage I, and to
    /// restore a saved window row for row. Errors when they do not fit.
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
        self.add_rows(keys);
        record_fetch(rec, &self.params, n as u64, &fetched, companions)?;
        Ok(())
    }

    /// Errors unless the plan was made against the window as it stands
    /// and its rows are resident, ascending and unique.
    fn check_plan(&self, plan: &SyncPlan) -> Result<()> {
        let n = self.keys.len();
        let bad = |why: String| Err(Error::bad_input("window sync plan", why));
        if plan.generation != self.generation {
            return bad("made before the window's rows last changed: plan again".into());
        }
        let ascending = plan.evict.windows(2).all(|w| w[0] < w[1]);
        if !ascending || plan.evict.last().is_some_and(|&r| r as usize >= n) {
            return bad(format!(
                "evicted rows must be ascending, unique and below the {n} resident"
            ));
        }
        Ok(())
    }

    /// Errors unless `keep` residents and `incoming` Gaussians fit and every
    /// companion buffer covers the capacity in whole words.
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
            if c.row_bytes == 0 || !c.row_bytes.is_multiple_of(4) {
                return Err(Error::bad_input(
                    "window companion buffer",
                    format!(
                        "rows of {} bytes: rows move as whole 32-bit words",
                        c.row_bytes
                    ),
                ));
            }
            c.buffer
                .ensure_bytes(self.capacity() * c.row_bytes, "window companion buffer")?;
        }
        Ok(())
    }

    /// Grows the index buffer to `indices` and the outbox to `rows`.
    fn grow_buffers(&mut self, indices: u64, rows: u64) -> Result<()> {
        grow(
            &mut self.index,
            &self.ctx,
            "window/row lists",
            indices.max(1) * 4,
        )?;
        let outbox_bytes = rows.max(1) * GAUSSIAN_BYTES;
        grow(&mut self.outbox, &self.ctx, "window/outbox", outbox_bytes)?;
        Ok(())
    }

    /// Takes `rows` out of their blocks' row lists (their keys stay until
    /// the tables are truncated).
    fn forget_rows(&mut self, rows: &[u32]) {
        self.generation += 1;
        for &r in rows {
            let block = GlobalMap::block_of(self.keys[r as usize]);
            let Some(b) = self.blocks.get_mut(&block) else {
                continue;
            };
            let at = self.place[r as usize] as usize;
            b.rows.swap_remove(at);
            if let Some(&moved) = b.rows.get(at) {
                self.place[moved as usize] = at as u32;
            }
            if b.rows.is_empty() {
                self.blocks.remove(&block);
            }
        }
    }

    /// Row `from[i]` now lives at row `to[i]`.
    fn move_rows_in_tables(&mut self, from: &[u32], to: &[u32]) {
        for (&s, &d) in from.iter().zip(to) {
            let key = self.keys[s as usize];
            let at = self.place[s as usize];
            self.keys[d as usize] = key;
            self.place[d as usize] = at;
            if let Some(b) = self.blocks.get_mut(&GlobalMap::block_of(key)) {
                b.rows[at as usize] = d;
            }
        }
    }

    /// Appends rows for `keys` to the tables (their blocks as they were,
    /// clean when new).
    fn add_rows(&mut self, keys: &[VoxelKey]) {
        self.generation += 1;
        for &key in keys {
            let row = self.keys.len() as u32;
            let b = self.blocks.entry(GlobalMap::block_of(key)).or_default();
            self.place.push(b.rows.len() as u32);
            b.rows.push(row);
            self.keys.push(key);
        }
    }
}

/// The buffer in `slot`, replaced by one of `bytes` and half again when
/// smaller (so that a window paging a little more each time does not
/// reallocate each time; the old one is freed once the GPU is done with it).
fn grow<'s>(
    slot: &'s mut Option<Buffer>,
    ctx: &Context,
    name: &str,
    bytes: u64,
) -> Result<&'s Buffer> {
    if slot.as_ref().is_none_or(|b| b.bytes() < bytes) {
        *slot = None;
        *slot = Some(Buffer::device(ctx, name, bytes + bytes / 2)?);
    }
    Ok(slot.as_ref().expect("set above"))
}

/// Zeroes rows `first..first + n` of every companion (arriving rows start
/// their optimiser state afresh).
fn zero_companions<'a>(
    rec: &mut Recorder<'a>,
    first: u64,
    n: u64,
    companions: &[Companion<'a>],
) -> Result<()> {
    for c in companions {
        rec.fill_range_u32(c.buffer, first * c.row_bytes, n * c.row_bytes, 0)?;
    }
    Ok(())
}

/// Every buffer whose rows follow the Gaussians, with its words per row:
/// the six parameter fields, then the companions.
fn row_buffers<'a>(
    params: &'a GaussianBuffers,
    companions: &[Companion<'a>],
) -> Vec<(&'a Buffer, u32)> {
    params
        .fields()
        .into_iter()
        .zip(FIELD_WIDTHS)
        .map(|(b, w)| (b, w as u32))
        .chain(
            companions
                .iter()
                .map(|c| (c.buffer, (c.row_bytes / 4) as u32)),
        )
        .collect()
}

/// Gathers the `count` rows listed from index `first` of `index` into
/// `outbox`, field after field (`count` means, then `count` scales, ...).
fn record_gather<'a>(
    rec: &mut Recorder<'a>,
    params: &'a GaussianBuffers,
    index: &'a Buffer,
    first: u32,
    count: u32,
    outbox: &'a Buffer,
) -> Result<()> {
    let rows = RowList {
        index,
        first,
        count,
    };
    let mut word = 0u64;
    for (buf, width) in params.fields().into_iter().zip(FIELD_WIDTHS) {
        let to = Packed {
            buffer: outbox,
            word,
        };
        gather_rows(rec, buf, width as u32, rows, to)?;
        word += count as u64 * width;
    }
    debug_assert_eq!(word, count as u64 * GAUSSIAN_WORDS);
    Ok(())
}

/// The Gaussians of `keys`, as host SoA. A plan lists an arriving block's
/// keys in the block's own order, so such a run is copied block by block
/// with one lookup; other keys are looked up one by one.
fn gather(global: &GlobalMap, keys: &[VoxelKey]) -> Result<HostGaussians> {
    let mut fetched = HostGaussians::default();
    let n = keys.len();
    fetched.reserve(n);
    let mut at = 0;
    while at < n {
        let key = keys[at];
        if let Some(block) = global.block(GlobalMap::block_of(key)) {
            if keys[at..].starts_with(block.keys()) {
                for g in block.gaussians() {
                    push_gaussian(&mut fetched, g);
                }
                at += block.len();
                continue;
            }
        }
        let g = global.get(key).ok_or_else(|| {
            Error::bad_input(
                "global map",
                format!("sync fetches voxel {key:?}, which the global map does not have"),
            )
        })?;
        push_gaussian(&mut fetched, g);
        at += 1;
    }
    Ok(fetched)
}

/// Uploads `fetched` at row `first` through one packed staging buffer;
/// their companion rows start from zero.
fn record_fetch<'a>(
    rec: &mut Recorder<'a>,
    params: &'a GaussianBuffers,
    first: u64,
    fetched: &HostGaussians,
    companions: &[Companion<'a>],
) -> Result<()> {
    let n = fetched.means.len() as u64;
    if n == 0 {
        return Ok(());
    }
    if first + n > params.capacity() {
        return Err(Error::budget(
            "the window capacity",
            format!(
                "{n} Gaussians at row {first} overflow a window of {}",
                params.capacity()
            ),
        ));
    }
    let data = fields_of(fetched);
    let parts: Vec<(&'a Buffer, u64, &[u8])> = params
        .fields()
        .into_iter()
        .zip(FIELD_WIDTHS)
        .zip(data)
        .map(|((buf, w), d)| (buf, first * w * 4, d))
        .collect();
    rec.upload_packed(&parts)?;
    zero_companions(rec, first, n, companions)
}

/// The six fields of host Gaussians as bytes, in field order.
fn fields_of(h: &HostGaussians) -> [&[u8]; 6] {
    [
        bytemuck::cast_slice(&h.means),
        bytemuck::cast_slice(&h.log_scales),
        bytemuck::cast_slice(&h.quats),
        bytemuck::cast_slice(&h.colors),
        bytemuck::cast_slice(&h.opacity_logits),
        bytemuck::cast_slice(&h.queries),
    ]
}

/// Copies `n` Gaussians staged in `inbox` (packed field after field) to
/// rows `first..first + n`, on the GPU; their companion rows start from
/// zero.
fn copy_staged<'a>(
    rec: &mut Recorder<'a>,
    params: &'a GaussianBuffers,
    first: u64,
    n: u64,
    inbox: &'a Buffer,
    companions: &[Companion<'a>],
) -> Result<()> {
    if n == 0 {
        return Ok(());
    }
    let mut at = 0u64;
    for (buf, w) in params.fields().into_iter().zip(FIELD_WIDTHS) {
        let bytes = n * w * 4;
        rec.copy(inbox, at, buf, first * w * 4, bytes)?;
        at += bytes;
    }
    zero_companions(rec, first, n, companions)
}
