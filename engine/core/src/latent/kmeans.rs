//! Streaming k-means with a fixed dictionary size (paper Sec. III-C, Eq. 10) on the GPU:
//! the online initialisation of the decoder's dictionary. Kernels
//! `glsl/kmeans_seed.comp`, `argmax_rows.comp`, `kmeans_update.comp`,
//! `kmeans_novelty.comp`, `kmeans_patch_sims.comp`, `kmeans_stale.comp`,
//! `kmeans_resim.comp`, `kmeans_moved.comp`, plus row normalisation and GEMM
//! for the cosine similarities. CPU reference (and the statement of the
//! algorithm): `latentam_reference::kmeans`.
//!
//! Once the dictionary is full, each keyframe re-clusters K + m points into
//! K centres warm-started from the atoms. The K × K cosines of the atoms
//! are computed only when a micro-centre is a new concept, since only then
//! does the novelty step need each atom's most similar other atom (the GPU
//! decides, with an indirect dispatch, so the host does not wait for it).
//! The first Lloyd iteration needs only the micro-centres' rows: an atom
//! whose centre was not replaced starts in its own cluster. After it, only
//! the centres whose members changed move, so the later iterations
//! recompute just their columns (and a point's whole row once its own
//! centre moved) and reassign against them: (K + m) × (a few) × d_f work
//! instead of (K + m) × K × d_f.

use std::cell::Cell;

use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Recorder};

mod steps;
#[cfg(test)]
mod tests;
mod update;

/// Largest dictionary the novelty kernel can track (its shared bit set).
pub const MAX_KMEANS_ATOMS: u32 = 65536;

/// Norms are divided by (norm + this) when comparing directions.
const UNIT_EPS: f32 = 1e-12;

/// A centre's column of the cosine matrix is recomputed once its unit
/// vector is this far (L2) from the one the column was computed with: the
/// cosines are then off by at most this, below the rounding of a 768-long
/// f32 dot product, while re-normalising an unchanged centre (~1e-7) does
/// not count as a change.
const STALE_TOLERANCE: f32 = 1e-6;

/// Settings of [`StreamingKMeans`]; defaults: the paper's K and m, the rest chosen here.
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions};
/// use latentam_core::latent::{KMeansConfig, StreamingKMeans};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// // 512-d CLIP embeddings into 1000 atoms, slowly forgetting old keyframes.
/// let cfg = KMeansConfig { atoms: 1000, dim: 512, decay: 0.99, ..Default::default() };
/// let kmeans = StreamingKMeans::new(&ctx, cfg)?;
/// assert_eq!(kmeans.config().micro_clusters, 5);
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KMeansConfig {
    /// Dictionary capacity K (the paper's 2000).
    pub atoms: u32,
    /// Embedding dimension d_f.
    pub dim: u32,
    /// Most region embeddings per keyframe.
    pub max_points: u32,
    /// Micro-clusters per keyframe, m (the paper's 5).
    pub micro_clusters: u32,
    /// Lloyd iterations of the micro-clustering (≥ 1).
    pub local_iterations: u32,
    /// Lloyd iterations of the re-clustering into K (≥ 1).
    pub global_iterations: u32,
    /// Factor on the old atoms' weights per keyframe (1 = no forgetting).
    pub decay: f32,
    /// Cosine below which a micro-centre is a new concept that gets its own
    /// atom once the dictionary is full (the closest pair of atoms is merged
    /// to make room).
    pub novelty_threshold: f32,
    /// Re-normalise atoms to unit length after each update (targets are
    /// unit-norm).
    pub normalize: bool,
    /// An atom that moved more than this (L2) is reported as moved.
    pub moved_tolerance: f32,
}

impl Default for KMeansConfig {
    fn default() -> Self {
        Self {
            atoms: 2000,
            dim: 768,
            max_points: 4096,
            micro_clusters: 5,
            local_iterations: 10,
            global_iterations: 3,
            decay: 1.0,
            novelty_threshold: 0.5,
            normalize: true,
            moved_tolerance: 1e-4,
        }
    }
}

/// What one keyframe's update did.
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context};
/// # use latentam_core::latent::StreamingKMeans;
/// # fn f(ctx: &Context, kmeans: &StreamingKMeans, features: &Buffer, n: u32, atoms: &Buffer, anchor: &Buffer, moved: &Buffer) -> latentam_core::Result<()> {
/// let mut rec = ctx.recorder()?;
/// let step = kmeans.record_update(&mut rec, features, None, n, atoms, anchor, moved)?;
/// rec.submit()?.wait()?;
/// if step.reclustered {
///     println!("{} micro-centres merged into {} atoms", step.micro_clusters, step.atoms_after);
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KMeansStep {
    /// Atoms in use before.
    pub atoms_before: u32,
    /// Atoms in use after.
    pub atoms_after: u32,
    /// Micro-centres formed from the keyframe.
    pub micro_clusters: u32,
    /// Whether the dictionary was full and re-clustered (rather than
    /// appended to).
    pub reclustered: bool,
}

/// Maintains a dictionary of at most K atoms from a stream of keyframes'
/// region embeddings. The dictionary rows (`atoms`), its trust-region anchor
/// D⁰ and the per-atom "moved" flags are the caller's buffers (the decoder
/// and the optimiser share them); the atom weights live here.
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context, ContextOptions};
/// use latentam_core::latent::{KMeansConfig, StreamingKMeans};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let cfg = KMeansConfig { atoms: 64, dim: 32, max_points: 100, ..Default::default() };
/// let kmeans = StreamingKMeans::new(&ctx, cfg)?;
/// let atoms = Buffer::device(&ctx, "D", 64 * 32 * 4)?;
/// let anchor = Buffer::device(&ctx, "D0", 64 * 32 * 4)?;
/// let moved = Buffer::device(&ctx, "moved", 64 * 4)?;
/// let features = ctx.upload_new("F", &vec![0.1f32; 10 * 32])?; // 10 regions
/// let mut rec = ctx.recorder()?;
/// let step = kmeans.record_update(&mut rec, &features, None, 10, &atoms, &anchor, &moved)?;
/// rec.submit()?.wait()?;
/// assert_eq!(step.atoms_after, 5);
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct StreamingKMeans {
    cfg: KMeansConfig,
    /// Advances when an update is recorded (the recording must be submitted).
    atom_count: Cell<u32>,
    weights: Buffer,
    ones: Buffer,
    unit: Buffer,
    closest: Buffer,
    micro: Buffer,
    micro_unit: Buffer,
    micro_weights: Buffer,
    points: Buffer,
    point_mass: Buffer,
    centre_unit: Buffer,
    norms: Buffer,
    sims: Buffer,
    best_value: Buffer,
    best_index: Buffer,
    replaced: Buffer,
    /// Per centre: its members changed since it was last computed.
    dirty: Buffer,
    /// Per centre: its column of the cosine matrix is stale.
    stale: Buffer,
    /// The stale centres: [count, indices...].
    stale_list: Buffer,
    /// Per point: its row of `sims` holds every column.
    row_complete: Buffer,
    /// Written by `kmeans_gate`: the workgroup counts of the atoms' cosine
    /// product (bytes 0..12) and its argmax (16..28), then whether a
    /// micro-centre was new (word 8).
    gate: Buffer,
}

/// Byte offsets of the indirect dispatch counts in `StreamingKMeans::gate`.
const GATE_PRODUCT: u64 = 0;
const GATE_ARGMAX: u64 = 16;

impl StreamingKMeans {
    /// An empty dictionary state for `cfg`.
    pub fn new(ctx: &Context, cfg: KMeansConfig) -> Result<Self> {
        let ok = cfg.atoms > 0
            && cfg.atoms <= MAX_KMEANS_ATOMS
            && cfg.dim > 0
            && cfg.max_points > 0
            && cfg.micro_clusters > 0
            && cfg.micro_clusters <= cfg.atoms
            && cfg.local_iterations > 0
            && cfg.global_iterations > 0
            && (0.0..=1.0).contains(&cfg.decay)
            && cfg.novelty_threshold.is_finite()
            && cfg.moved_tolerance >= 0.0;
        if !ok {
            return Err(Error::bad_input(
                "k-means settings",
                format!(
                    "out of range (need 1 ≤ K ≤ {MAX_KMEANS_ATOMS}, 1 ≤ m ≤ K, iterations ≥ 1, \
                     decay in [0, 1]): {cfg:?}"
                ),
            ));
        }
        let (k, m, n, d) = (
            cfg.atoms as u64,
            cfg.micro_clusters as u64,
            cfg.max_points as u64,
            cfg.dim as u64,
        );
        let rows = (k + m).max(n);
        let buf =
            |name: &str, elems: u64| Buffer::device(ctx, &format!("kmeans/{name}"), elems * 4);
        let s = Self {
            cfg,
            atom_count: Cell::new(0),
            weights: buf("weights", k)?,
            ones: ctx.upload_new("kmeans/ones", &vec![1.0f32; n as usize])?,
            unit: buf("unit", rows * d)?,
            closest: buf("closest", n)?,
            micro: buf("micro", m * d)?,
            micro_unit: buf("micro_unit", m * d)?,
            micro_weights: buf("micro_weights", m)?,
            points: buf("points", (k + m) * d)?,
            point_mass: buf("point_mass", k + m)?,
            centre_unit: buf("centre_unit", k * d)?,
            norms: buf("norms", rows)?,
            sims: buf("sims", (n * m).max((k + m) * k))?,
            best_value: buf("best_value", rows)?,
            best_index: buf("best_index", rows)?,
            replaced: buf("replaced", m)?,
            dirty: buf("dirty", k)?,
            stale: buf("stale", k)?,
            stale_list: buf("stale_list", k + 1)?,
            row_complete: buf("row_complete", k + m)?,
            gate: buf("gate", 9)?,
        };
        Ok(s)
    }

    /// Atoms in use.
    pub fn atom_count(&self) -> u32 {
        self.atom_count.get()
    }

    /// Accumulated mass per atom (K floats; the first
    /// [`Self::atom_count`] are in use).
    pub fn weights(&self) -> &Buffer {
        &self.weights
    }

    /// The settings.
    pub fn config(&self) -> &KMeansConfig {
        &self.cfg
    }

    /// Restores the state of a saved dictionary of `atom_count` atoms whose
    /// weights are in `weights` (e.g. when a map is loaded).
    pub fn restore(&self, ctx: &Context, atom_count: u32, weights: &[f32]) -> Result<()> {
        if atom_count > self.cfg.atoms || weights.len() != atom_count as usize {
            return Err(Error::bad_input(
                "atoms to restore",
                format!(
                    "restoring {atom_count} atoms with {} weights into a dictionary of {}",
                    weights.len(),
                    self.cfg.atoms
                ),
            ));
        }
        ctx.upload(&self.weights, 0, weights)?;
        self.atom_count.set(atom_count);
        Ok(())
    }

    /// Records one keyframe's update from its `n` region embeddings
    /// (`features`, n × d_f, ideally unit-norm) with optional per-region
    /// masses (e.g. pixel areas; 1 each when `None`). Rewrites the rows of
    /// `atoms` it changes, copies the result to `anchor` (D⁰ of the trust
    /// region) and sets `moved[k]` to 1 for every atom that is new or moved.
    /// With n = 0 nothing is recorded. The atom count advances when the
    /// update is recorded, so the recording must be submitted.
    #[allow(clippy::too_many_arguments)]
    pub fn record_update<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        features: &'a Buffer,
        mass: Option<&'a Buffer>,
        n: u32,
        atoms: &'a Buffer,
        anchor: &'a Buffer,
        moved: &'a Buffer,
    ) -> Result<KMeansStep> {
        self.check_update(features, mass, n, atoms, anchor, moved)?;
        let before = self.atom_count.get();
        let mut step = KMeansStep {
            atoms_before: before,
            atoms_after: before,
            ..Default::default()
        };
        if n == 0 {
            return Ok(step);
        }
        let mass = mass.unwrap_or(&self.ones);
        let m = self.cfg.micro_clusters.min(n);

        // 1. Micro-clusters of the keyframe.
        self.record_micro_clusters(rec, features, mass, n, m)?;
        // 2. The points of the re-clustering: [old atoms; micro-centres].
        self.record_reclustering_points(rec, atoms, before, m)?;

        let after = if before + m <= self.cfg.atoms {
            // 3a. Room left: append.
            self.record_append(rec, atoms, before, m)?
        } else {
            // 3b. Full: novelty, then weighted Lloyd warm-started from the atoms.
            step.reclustered = true;
            self.record_recluster(rec, atoms, before, m)?
        };

        // 4. Moved flags and the trust-region anchor.
        self.record_moved_and_anchor(rec, atoms, anchor, moved, before, after)?;
        self.atom_count.set(after);
        step.atoms_after = after;
        step.micro_clusters = m;
        Ok(step)
    }
}
