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

use latentam_shaders::{
    push, ARGMAX_ROWS, KMEANS_FIRST_ASSIGN, KMEANS_GATE, KMEANS_MICRO_ROWS, KMEANS_MOVED,
    KMEANS_NOVELTY, KMEANS_PATCH_SIMS, KMEANS_REASSIGN, KMEANS_RESIM, KMEANS_SEED, KMEANS_STALE,
    KMEANS_STALE_LIST, KMEANS_UPDATE, KMEANS_UPDATE_DIRTY,
};

use std::cell::Cell;

use latentam_base::{Error, Result};
use latentam_gpu::ops::{normalize_rows, Gemm, Transpose};
use latentam_gpu::{Buffer, Context, Recorder};
use latentam_shaders::bind;

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
            return Err(Error::InvalidArgument(format!(
                "k-means settings out of range (need 1 ≤ K ≤ {MAX_KMEANS_ATOMS}, 1 ≤ m ≤ K, \
                 iterations ≥ 1, decay in [0, 1]): {cfg:?}"
            )));
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
            return Err(Error::InvalidArgument(format!(
                "restoring {atom_count} atoms with {} weights into a dictionary of {}",
                weights.len(),
                self.cfg.atoms
            )));
        }
        ctx.upload(&self.weights, 0, weights)?;
        self.atom_count.set(atom_count);
        Ok(())
    }

    fn normalize<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        x: &'a Buffer,
        y: &'a Buffer,
        rows: u32,
    ) -> Result<()> {
        normalize_rows(rec, x, y, &self.norms, rows, self.cfg.dim, UNIT_EPS)
    }

    /// Cosine similarities of `rows` unit points to `cols` unit centres into
    /// `sims`.
    fn similarities<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        unit_points: &'a Buffer,
        unit_centres: &'a Buffer,
        rows: u32,
        cols: u32,
    ) -> Result<()> {
        Gemm {
            transpose: Transpose::B,
            m: rows,
            n: cols,
            k: self.cfg.dim,
            alpha: 1.0,
            beta: 0.0,
        }
        .record(rec, unit_points, unit_centres, &self.sims)
    }

    /// Each row's best column of `sims`.
    fn best_centres<'a>(&'a self, rec: &mut Recorder<'a>, rows: u32, cols: u32) -> Result<()> {
        rec.dispatch_linear(
            &ARGMAX_ROWS,
            rows,
            bind::ArgmaxRowsBuffers {
                m: &self.sims,
                best_value: &self.best_value,
                best_index: &self.best_index,
            },
            &push::ArgmaxRows {
                rows,
                cols,
                exclude_diagonal: 0,
            },
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn lloyd_update<'a>(
        &self,
        rec: &mut Recorder<'a>,
        points: &'a Buffer,
        mass: &'a Buffer,
        assignment: &'a Buffer,
        centres: &'a Buffer,
        weights: &'a Buffer,
        points_count: u32,
        centres_count: u32,
        decayed: u32,
        only_dirty: Option<&'a Buffer>,
    ) -> Result<()> {
        let p = push::KmeansUpdate {
            points_count,
            centres_count,
            dim: self.cfg.dim,
            decayed,
            decay: self.cfg.decay,
            normalize: self.cfg.normalize as u32,
        };
        match only_dirty {
            None => rec.dispatch_linear(
                &KMEANS_UPDATE,
                centres_count,
                bind::KmeansUpdateBuffers {
                    points,
                    mass,
                    assign: assignment,
                    centres,
                    weights,
                },
                &p,
            ),
            Some(dirty) => rec.dispatch_linear(
                &KMEANS_UPDATE_DIRTY,
                centres_count,
                bind::KmeansUpdateDirtyBuffers {
                    points,
                    mass,
                    assign: assignment,
                    centres,
                    weights,
                    dirty,
                },
                &p,
            ),
        }
    }

    /// Records what the novelty step reads: the micro-centres' rows of the
    /// cosine matrix (points `atoms..atoms + m` against the atoms) with
    /// their best atom, and, only when one of them is new, the atoms' own
    /// rows with each atom's most similar other atom.
    fn record_novelty_similarities<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        atoms: u32,
        m: u32,
    ) -> Result<()> {
        rec.dispatch_linear(
            &KMEANS_MICRO_ROWS,
            m,
            bind::KmeansMicroRowsBuffers {
                unit: &self.unit,
                centre_unit: &self.centre_unit,
                sims: &self.sims,
                best_value: &self.best_value,
                best_index: &self.best_index,
            },
            &push::KmeansMicroRows {
                first: atoms,
                count: m,
                centres_count: atoms,
                dim: self.cfg.dim,
            },
        )?;
        let product = Gemm {
            transpose: Transpose::B,
            m: atoms,
            n: atoms,
            k: self.cfg.dim,
            alpha: 1.0,
            beta: 0.0,
        };
        let [product_x, product_y, _] = product.groups();
        // One workgroup per row, at most MAX_KMEANS_ATOMS: within every
        // device's limits once split.
        let [argmax_x, argmax_y, _] = rec.linear_groups(atoms);
        rec.dispatch(
            &KMEANS_GATE,
            [1, 1, 1],
            bind::KmeansGateBuffers {
                best_value: &self.best_value,
                gate: &self.gate,
            },
            &push::KmeansGate {
                atoms,
                micro_count: m,
                threshold: self.cfg.novelty_threshold,
                product_x,
                product_y,
                argmax_x,
                argmax_y,
            },
        )?;
        product.record_indirect(
            rec,
            &self.unit,
            &self.centre_unit,
            &self.sims,
            &self.gate,
            GATE_PRODUCT,
        )?;
        rec.dispatch_indirect(
            &ARGMAX_ROWS,
            &self.gate,
            GATE_ARGMAX,
            bind::ArgmaxRowsBuffers {
                m: &self.sims,
                best_value: &self.best_value,
                best_index: &self.best_index,
            },
            &push::ArgmaxRows {
                rows: atoms,
                cols: atoms,
                exclude_diagonal: 1,
            },
        )
    }

    /// Records a Lloyd iteration after the first of the re-clustering of
    /// `points` (K + m rows, their unit vectors in `unit`) into `atoms`
    /// (`centres` rows): recomputes the cosine columns of the centres that
    /// moved, reassigns the points against those, and updates the centres
    /// whose members changed. The same assignments as a dense iteration, up
    /// to [`STALE_TOLERANCE`] in the cosines.
    fn record_sparse_iteration<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        atoms: &'a Buffer,
        points: u32,
        centres: u32,
        all_dirty: bool,
    ) -> Result<()> {
        let dim = self.cfg.dim;
        rec.dispatch_linear(
            &KMEANS_STALE,
            centres,
            bind::KmeansStaleBuffers {
                centres: atoms,
                centre_unit: &self.centre_unit,
                dirty: &self.dirty,
                stale: &self.stale,
            },
            &push::KmeansStale {
                centres_count: centres,
                dim,
                all_dirty: all_dirty as u32,
                eps: UNIT_EPS,
                tolerance: STALE_TOLERANCE,
            },
        )?;
        rec.dispatch(
            &KMEANS_STALE_LIST,
            [1, 1, 1],
            bind::KmeansStaleListBuffers {
                stale: &self.stale,
                dirty: &self.dirty,
                stale_list: &self.stale_list,
            },
            &push::KmeansStaleList {
                centres_count: centres,
            },
        )?;
        rec.dispatch_linear(
            &KMEANS_RESIM,
            points,
            bind::KmeansResimBuffers {
                unit: &self.unit,
                centre_unit: &self.centre_unit,
                stale_list: &self.stale_list,
                stale: &self.stale,
                best_index: &self.best_index,
                row_complete: &self.row_complete,
                sims: &self.sims,
            },
            &push::KmeansResim {
                rows: points,
                centres_count: centres,
                dim,
            },
        )?;
        rec.dispatch_linear(
            &KMEANS_REASSIGN,
            points,
            bind::KmeansReassignBuffers {
                sims: &self.sims,
                stale: &self.stale,
                stale_list: &self.stale_list,
                best_value: &self.best_value,
                best_index: &self.best_index,
                dirty: &self.dirty,
            },
            &push::KmeansReassign {
                rows: points,
                centres_count: centres,
            },
        )?;
        self.lloyd_update(
            rec,
            &self.points,
            &self.point_mass,
            &self.best_index,
            atoms,
            &self.weights,
            points,
            centres,
            centres,
            Some(&self.dirty),
        )
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
        let (k_max, d) = (self.cfg.atoms as u64, self.cfg.dim as u64);
        if n > self.cfg.max_points {
            return Err(Error::InvalidArgument(format!(
                "k-means update with {n} regions; sized for {}",
                self.cfg.max_points
            )));
        }
        let sizes = [
            (features, n as u64 * d * 4),
            (atoms, k_max * d * 4),
            (anchor, k_max * d * 4),
            (moved, k_max * 4),
        ];
        for (b, need) in sizes {
            b.ensure_bytes(need, "k-means")?;
        }
        if let Some(m) = mass {
            m.ensure_bytes(n as u64 * 4, "k-means region masses")?;
        }
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
        let dim = self.cfg.dim;

        // 1. Micro-clusters of the keyframe.
        self.normalize(rec, features, &self.unit, n)?;
        rec.dispatch(
            &KMEANS_SEED,
            [1, 1, 1],
            bind::KmeansSeedBuffers {
                points: features,
                unit: &self.unit,
                mass,
                closest: &self.closest,
                centres: &self.micro,
            },
            &push::KmeansSeed { n, dim, seeds: m },
        )?;
        for _ in 0..self.cfg.local_iterations {
            self.normalize(rec, &self.micro, &self.micro_unit, m)?;
            self.similarities(rec, &self.unit, &self.micro_unit, n, m)?;
            self.best_centres(rec, n, m)?;
            self.lloyd_update(
                rec,
                features,
                mass,
                &self.best_index,
                &self.micro,
                &self.micro_weights,
                n,
                m,
                0,
                None,
            )?;
        }

        // 2. The points of the re-clustering: [old atoms; micro-centres].
        let (row, bytes) = (d * 4, before as u64 * d * 4);
        rec.copy(atoms, 0, &self.points, 0, bytes)?;
        rec.copy(&self.micro, 0, &self.points, bytes, m as u64 * row)?;
        rec.copy(&self.weights, 0, &self.point_mass, 0, before as u64 * 4)?;
        rec.copy(
            &self.micro_weights,
            0,
            &self.point_mass,
            before as u64 * 4,
            m as u64 * 4,
        )?;

        let after = if before + m <= self.cfg.atoms {
            // 3a. Room left: append.
            rec.copy(&self.micro, 0, atoms, bytes, m as u64 * row)?;
            rec.copy(
                &self.micro_weights,
                0,
                &self.weights,
                before as u64 * 4,
                m as u64 * 4,
            )?;
            before + m
        } else {
            // 3b. Full: novelty, then weighted Lloyd warm-started from the atoms.
            step.reclustered = true;
            let total = before + m;
            self.normalize(rec, &self.points, &self.unit, total)?;
            self.normalize(rec, atoms, &self.centre_unit, before)?;
            self.record_novelty_similarities(rec, before, m)?;
            rec.dispatch(
                &KMEANS_NOVELTY,
                [1, 1, 1],
                bind::KmeansNoveltyBuffers {
                    best_value: &self.best_value,
                    best_index: &self.best_index,
                    weights: &self.weights,
                    micro: &self.micro,
                    centres: atoms,
                    replaced: &self.replaced,
                },
                &push::KmeansNovelty {
                    atoms: before,
                    micro_count: m,
                    dim,
                    threshold: self.cfg.novelty_threshold,
                },
            )?;
            for iteration in 0..self.cfg.global_iterations {
                if iteration == 0 {
                    // The similarities to the atoms are known but for the
                    // columns the novelty step replaced.
                    rec.dispatch_linear(
                        &KMEANS_PATCH_SIMS,
                        (total * m).div_ceil(256),
                        bind::KmeansPatchSimsBuffers {
                            unit: &self.unit,
                            replaced: &self.replaced,
                            sims: &self.sims,
                        },
                        &push::KmeansPatchSims {
                            rows: total,
                            atoms: before,
                            micro_count: m,
                            dim,
                        },
                    )?;
                    rec.dispatch_linear(
                        &KMEANS_FIRST_ASSIGN,
                        total,
                        bind::KmeansFirstAssignBuffers {
                            unit: &self.unit,
                            centre_unit: &self.centre_unit,
                            sims: &self.sims,
                            replaced: &self.replaced,
                            gate: &self.gate,
                            best_value: &self.best_value,
                            best_index: &self.best_index,
                            row_complete: &self.row_complete,
                        },
                        &push::KmeansFirstAssign {
                            rows: total,
                            atoms: before,
                            micro_count: m,
                            dim,
                        },
                    )?;
                    self.lloyd_update(
                        rec,
                        &self.points,
                        &self.point_mass,
                        &self.best_index,
                        atoms,
                        &self.weights,
                        total,
                        before,
                        before,
                        None,
                    )?;
                } else {
                    // The first iteration computed every centre.
                    self.record_sparse_iteration(rec, atoms, total, before, iteration == 1)?;
                }
            }
            before
        };

        // 4. Moved flags and the trust-region anchor.
        rec.dispatch_linear(
            &KMEANS_MOVED,
            after,
            bind::KmeansMovedBuffers {
                atoms,
                old: &self.points,
                moved,
            },
            &push::KmeansMoved {
                atoms_count: after,
                old_count: before,
                dim,
                tolerance: self.cfg.moved_tolerance,
            },
        )?;
        rec.copy(atoms, 0, anchor, 0, after as u64 * row)?;
        self.atom_count.set(after);
        step.atoms_after = after;
        step.micro_clusters = m;
        Ok(step)
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use latentam_gpu::testing::{rng, with_context};
    use latentam_reference::kmeans::{self as reference, Dictionary, KMeansSettings};

    /// The GPU's atoms, weights and moved flags against the reference
    /// dictionary's, atom by atom.
    fn assert_matches_reference(
        got: &[f32],
        got_w: &[f32],
        got_moved: &[u32],
        dict: &Dictionary,
        want_moved: &[bool],
        dim: usize,
        what: &str,
    ) {
        for a in 0..dict.atoms.len() {
            for j in 0..dim {
                let (g, w) = (got[a * dim + j] as f64, dict.atoms[a][j]);
                assert!((g - w).abs() < 1e-4, "{what}: atom {a}[{j}]: {g} vs {w}");
            }
            let (g, w) = (got_w[a] as f64, dict.weights[a]);
            assert!(
                (g - w).abs() <= 1e-4 * w.max(1.0),
                "{what}: weight {a}: {g} vs {w}"
            );
            assert_eq!(got_moved[a] != 0, want_moved[a], "{what}: moved {a}");
        }
    }

    fn unit(v: Vec<f64>) -> Vec<f64> {
        let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        v.into_iter().map(|x| x / n).collect()
    }

    /// One keyframe's regions, rounded to f32 as the GPU sees them.
    struct Frame {
        points: Vec<f32>,
        mass: Vec<f32>,
    }

    impl Frame {
        /// `per` noisy unit points around each of the given cluster
        /// directions, with distinct masses.
        fn new(r: &mut impl Rng, dirs: &[Vec<f64>], clusters: &[usize], per: usize) -> Self {
            let mut points = Vec::new();
            let mut mass = Vec::new();
            for &c in clusters {
                for _ in 0..per {
                    let noise = 0.3 / (dirs[c].len() as f64).sqrt();
                    let p = unit(
                        dirs[c]
                            .iter()
                            .map(|x| x + noise * r.random_range(-1.0..1.0))
                            .collect(),
                    );
                    points.extend(p.iter().map(|&v| v as f32));
                    mass.push(r.random_range(0.5f32..2.0));
                }
            }
            Self { points, mass }
        }

        fn rows(&self, dim: usize) -> Vec<Vec<f64>> {
            self.points
                .chunks(dim)
                .map(|c| c.iter().map(|&v| v as f64).collect())
                .collect()
        }

        fn mass(&self) -> Vec<f64> {
            self.mass.iter().map(|&v| v as f64).collect()
        }

        /// Runs one GPU update with this keyframe.
        fn update(
            &self,
            ctx: &Context,
            kmeans: &StreamingKMeans,
            out: &[&Buffer; 3],
        ) -> KMeansStep {
            let fb = ctx.upload_new("test/features", &self.points).unwrap();
            let mb = ctx.upload_new("test/mass", &self.mass).unwrap();
            let mut rec = ctx.recorder().unwrap();
            rec.fill_u32(out[2], 0x7fc0_0000);
            let n = self.mass.len() as u32;
            let step = kmeans
                .record_update(&mut rec, &fb, Some(&mb), n, out[0], out[1], out[2])
                .unwrap();
            rec.submit().unwrap().wait().unwrap();
            step
        }
    }

    /// One keyframe into a full dictionary (`atoms0`, `weights0`) on the
    /// GPU and in the reference; checks that they agree and returns the
    /// reference's result.
    fn recluster_full(
        ctx: &Context,
        cfg: &KMeansConfig,
        atoms0: &[Vec<f64>],
        weights0: &[f64],
        frame: &Frame,
        what: &str,
    ) -> Dictionary {
        let (k, dim) = (atoms0.len(), cfg.dim as usize);
        let kmeans = StreamingKMeans::new(ctx, *cfg).unwrap();
        let flat: Vec<f32> = atoms0.iter().flatten().map(|&v| v as f32).collect();
        let atoms = ctx.upload_new("test/atoms", &flat).unwrap();
        let anchor = Buffer::device(ctx, "test/anchor", (k * dim * 4) as u64).unwrap();
        let moved = Buffer::device(ctx, "test/moved", (k * 4) as u64).unwrap();
        let w32: Vec<f32> = weights0.iter().map(|&w| w as f32).collect();
        kmeans.restore(ctx, k as u32, &w32).unwrap();
        let step = frame.update(ctx, &kmeans, &[&atoms, &anchor, &moved]);
        assert!(step.reclustered, "{what}: the dictionary is full");
        let mut dict = Dictionary {
            atoms: atoms0.to_vec(),
            weights: weights0.to_vec(),
            capacity: k,
        };
        let want_moved = reference::update_dictionary(
            &settings(cfg),
            &mut dict,
            &frame.rows(dim),
            &frame.mass(),
        );
        assert_eq!(dict.atoms.len(), k, "{what}: the dictionary stays full");
        let got = ctx.download::<f32>(&atoms).unwrap();
        let got_w = ctx.download::<f32>(kmeans.weights()).unwrap();
        let got_moved = ctx.download::<u32>(&moved).unwrap();
        assert_matches_reference(&got, &got_w, &got_moved, &dict, &want_moved, dim, what);
        dict
    }

    fn settings(cfg: &KMeansConfig) -> KMeansSettings {
        KMeansSettings {
            micro_clusters: cfg.micro_clusters as usize,
            local_iterations: cfg.local_iterations as usize,
            global_iterations: cfg.global_iterations as usize,
            decay: cfg.decay as f64,
            novelty_threshold: cfg.novelty_threshold as f64,
            normalize: cfg.normalize,
            moved_tolerance: cfg.moved_tolerance as f64,
        }
    }

    /// A stream with known clusters: the dictionary fills up (append), then
    /// runs full (re-clustering), and two clusters first appear after it is
    /// full. GPU and reference are compared after every keyframe; at the
    /// end every cluster, the late ones included, has an atom, and no mass
    /// was lost.
    #[test]
    fn streaming_kmeans_matches_reference_and_finds_late_clusters() {
        let mut r = rng("streaming_kmeans_matches_reference_and_finds_late_clusters");
        with_context(|ctx| {
            // One Lloyd iteration leaves the first (patched) assignment
            // visible in the result; three are the default.
            for global_iterations in [3, 1] {
                check_stream(ctx, &mut r, global_iterations);
            }
        });
    }

    fn check_stream(ctx: &Context, r: &mut impl Rng, global_iterations: u32) {
        let dim = 64usize;
        let dirs: Vec<Vec<f64>> = (0..10)
            .map(|_| unit((0..dim).map(|_| r.random_range(-1.0..1.0)).collect()))
            .collect();
        let cfg = KMeansConfig {
            atoms: 12,
            dim: dim as u32,
            max_points: 64,
            micro_clusters: 3,
            global_iterations,
            ..Default::default()
        };
        let s = settings(&cfg);
        let kmeans = StreamingKMeans::new(ctx, cfg).unwrap();
        let k = cfg.atoms as usize;
        let atoms = Buffer::device(ctx, "test/atoms", (k * dim * 4) as u64).unwrap();
        let anchor = Buffer::device(ctx, "test/anchor", (k * dim * 4) as u64).unwrap();
        let moved = Buffer::device(ctx, "test/moved", (k * 4) as u64).unwrap();
        let mut dict = Dictionary {
            atoms: Vec::new(),
            weights: Vec::new(),
            capacity: k,
        };
        let mut total_mass = 0.0;
        let mut reclustered = 0;
        let mut seen = vec![0u32; dirs.len()];
        for frame in 0..16 {
            let pool: Vec<usize> = if frame < 10 {
                (0..8).collect()
            } else {
                (0..10).collect()
            };
            let mut clusters = Vec::new();
            if frame >= 10 {
                clusters.push(8 + frame % 2); // the late clusters
            }
            while clusters.len() < 3 {
                let c = pool[r.random_range(0..pool.len())];
                if !clusters.contains(&c) {
                    clusters.push(c);
                }
            }
            for &c in &clusters {
                seen[c] += 1;
            }
            let keyframe = Frame::new(r, &dirs, &clusters, 7);
            total_mass += keyframe.mass().iter().sum::<f64>();
            let step = keyframe.update(ctx, &kmeans, &[&atoms, &anchor, &moved]);
            let (points64, mass64) = (keyframe.rows(dim), keyframe.mass());
            let want_moved = reference::update_dictionary(&s, &mut dict, &points64, &mass64);
            reclustered += step.reclustered as u32;
            assert_eq!(step.atoms_after as usize, dict.atoms.len(), "frame {frame}");
            let count = dict.atoms.len();
            let got = ctx.download::<f32>(&atoms).unwrap();
            let got_anchor = ctx.download::<f32>(&anchor).unwrap();
            let got_w = ctx.download::<f32>(kmeans.weights()).unwrap();
            let got_moved = ctx.download::<u32>(&moved).unwrap();
            let what = format!("frame {frame}");
            assert_matches_reference(&got, &got_w, &got_moved, &dict, &want_moved, dim, &what);
            assert_eq!(
                got_anchor[..count * dim],
                got[..count * dim],
                "{what}: anchors"
            );
            // Mass is conserved: it moves between atoms, never vanishes.
            let w_sum: f64 = got_w[..count].iter().map(|&v| v as f64).sum();
            assert!(
                (w_sum - total_mass).abs() < 1e-3 * total_mass,
                "{w_sum} vs {total_mass}"
            );
        }
        assert!(
            reclustered >= 10,
            "the dictionary should have been full for most frames"
        );
        let got = ctx.download::<f32>(&atoms).unwrap();
        // A cluster drawn in only one or two early frames carries little
        // mass and may rightly be merged into another atom once the
        // dictionary is full; every cluster seen three times or more (the
        // late ones are, in frames 10–15) must keep an atom.
        assert!(seen[8] >= 3 && seen[9] >= 3, "{seen:?}");
        for (c, dir) in dirs.iter().enumerate().filter(|&(c, _)| seen[c] >= 3) {
            let best = (0..k)
                .map(|a| {
                    (0..dim)
                        .map(|j| got[a * dim + j] as f64 * dir[j])
                        .sum::<f64>()
                })
                .fold(f64::NEG_INFINITY, f64::max);
            assert!(best > 0.9, "cluster {c} has no atom (best cosine {best})");
        }
    }

    /// Later Lloyd iterations only recompute the columns of the centres
    /// that moved (`kmeans_resim.comp`) and reassign against them
    /// (`kmeans_reassign`). A dictionary on an arc where each iteration
    /// moves a point: a heavy micro-centre pulls atom A away from its own
    /// point, which goes to A's close neighbour C in iteration 2; A, freed
    /// of it, moves on, and a light micro-centre that sat nearer atom B
    /// goes to A in iteration 3. The GPU must match the dense reference
    /// after 1, 2, 3 and 6 iterations, and the reference must change at 2
    /// and at 3 (so the sparse path had work to do).
    #[test]
    fn sparse_lloyd_iterations_match_the_dense_reference() {
        let mut r = rng("sparse_lloyd_iterations_match_the_dense_reference");
        with_context(|ctx| {
            let (dim, k, m) = (32usize, 12usize, 2usize);
            // Two random orthonormal directions span the arc.
            let e0 = unit((0..dim).map(|_| r.random_range(-1.0..1.0)).collect());
            let raw: Vec<f64> = (0..dim).map(|_| r.random_range(-1.0..1.0)).collect();
            let along: f64 = raw.iter().zip(&e0).map(|(a, b)| a * b).sum();
            let e1 = unit(raw.iter().zip(&e0).map(|(a, b)| a - along * b).collect());
            let on_arc = |angle: f64, r: &mut dyn rand::RngCore| -> Vec<f64> {
                unit(
                    (0..dim)
                        .map(|j| {
                            angle.cos() * e0[j]
                                + angle.sin() * e1[j]
                                + 1e-4 * r.random_range(-1.0..1.0)
                        })
                        .collect(),
                )
            };
            let as_f32 = |v: &[f64]| v.iter().map(|&x| x as f32 as f64).collect::<Vec<_>>();
            // C, A, B, then atoms far along the arc.
            let mut angles = vec![-0.01, 0.0, 0.204];
            angles.extend((0..k - 3).map(|i| 0.5 + 0.12 * i as f64));
            let atoms0: Vec<Vec<f64>> =
                angles.iter().map(|&a| as_f32(&on_arc(a, &mut r))).collect();
            let weights0: Vec<f64> = (0..k).map(|_| r.random_range(0.8f32..1.2) as f64).collect();
            // The keyframe: six heavy regions at 0.1, two light ones at 0.15.
            let mut points = Vec::new();
            let mut mass = Vec::new();
            for (angle, count, each) in [(0.1, 6, 3.0f32), (0.15, 2, 0.002)] {
                for _ in 0..count {
                    points.extend(on_arc(angle, &mut r).iter().map(|&v| v as f32));
                    mass.push(each);
                }
            }
            let frame = Frame { points, mass };
            let mut results = Vec::new();
            for iterations in [1u32, 2, 3, 6] {
                let cfg = KMeansConfig {
                    atoms: k as u32,
                    dim: dim as u32,
                    max_points: 64,
                    micro_clusters: m as u32,
                    global_iterations: iterations,
                    ..Default::default()
                };
                let what = format!("{iterations} iterations");
                let dict = recluster_full(ctx, &cfg, &atoms0, &weights0, &frame, &what);
                results.push(dict.weights);
            }
            // Each further iteration moved mass between centres: the
            // sparse iterations had work to do.
            let change =
                |a: &[f64], b: &[f64]| -> f64 { a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum() };
            assert!(change(&results[0], &results[1]) > 0.5, "{results:?}");
            assert!(change(&results[1], &results[2]) > 1e-3, "{results:?}");
        });
    }

    /// Bitwise-identical atoms (a camera that stood still appends the same
    /// micro-centre twice) each keep their own cluster when the keyframe
    /// lands elsewhere: the later one is not merged into the earlier by a
    /// tie. Known concepts and new ones, both checked against the
    /// reference.
    #[test]
    fn duplicate_atoms_keep_their_own_clusters() {
        let mut r = rng("duplicate_atoms_keep_their_own_clusters");
        with_context(|ctx| {
            let (k, dim) = (8usize, 16usize);
            let dirs: Vec<Vec<f64>> = (0..k + 1)
                .map(|_| unit((0..dim).map(|_| r.random_range(-1.0..1.0)).collect()))
                .collect();
            let as_f32 = |v: &[f64]| v.iter().map(|&x| x as f32 as f64).collect::<Vec<_>>();
            let mut atoms0: Vec<Vec<f64>> = dirs[..k].iter().map(|d| as_f32(d)).collect();
            atoms0[5] = atoms0[1].clone();
            let weights0: Vec<f64> = (0..k).map(|i| 1.0 + 0.25 * i as f64).collect();
            // Regions near atoms 3 and 6, then regions of a new concept.
            for (clusters, what) in [(vec![3usize, 6], "known"), (vec![k], "new")] {
                let frame = Frame::new(&mut r, &dirs, &clusters, 4);
                let cfg = KMeansConfig {
                    atoms: k as u32,
                    dim: dim as u32,
                    max_points: 16,
                    micro_clusters: clusters.len() as u32,
                    decay: 0.9,
                    ..Default::default()
                };
                let dict = recluster_full(ctx, &cfg, &atoms0, &weights0, &frame, what);
                if what == "known" {
                    // Each copy kept its own (decayed) mass.
                    for a in [1, 5] {
                        let want = cfg.decay as f64 * weights0[a];
                        assert!((dict.weights[a] - want).abs() < 1e-6, "{what}: weight {a}");
                    }
                }
            }
        });
    }

    /// A centre with more members than the update kernel's shared list
    /// (2048) takes the rescanning path; both paths must agree with the
    /// reference.
    #[test]
    fn large_clusters_match_reference() {
        let mut r = rng("large_clusters_match_reference");
        with_context(|ctx| {
            let dim = 32usize;
            let dirs: Vec<Vec<f64>> = (0..2)
                .map(|_| unit((0..dim).map(|_| r.random_range(-1.0..1.0)).collect()))
                .collect();
            let mut frame = Frame::new(&mut r, &dirs, &[0], 3000);
            let other = Frame::new(&mut r, &dirs, &[1], 500);
            frame.points.extend(other.points);
            frame.mass.extend(other.mass);
            let cfg = KMeansConfig {
                atoms: 4,
                dim: dim as u32,
                max_points: frame.mass.len() as u32,
                micro_clusters: 2,
                ..Default::default()
            };
            let kmeans = StreamingKMeans::new(ctx, cfg).unwrap();
            let atoms = Buffer::device(ctx, "test/atoms", (4 * dim * 4) as u64).unwrap();
            let anchor = Buffer::device(ctx, "test/anchor", (4 * dim * 4) as u64).unwrap();
            let moved = Buffer::device(ctx, "test/moved", 16).unwrap();
            frame.update(ctx, &kmeans, &[&atoms, &anchor, &moved]);
            let (points64, mass64) = (frame.rows(dim), frame.mass());
            let (want, want_w) = reference::micro_clusters(&settings(&cfg), &points64, &mass64);
            let got = ctx.download::<f32>(&atoms).unwrap();
            let got_w = ctx.download::<f32>(kmeans.weights()).unwrap();
            for c in 0..2 {
                for j in 0..dim {
                    assert!(
                        (got[c * dim + j] as f64 - want[c][j]).abs() < 1e-4,
                        "centre {c}[{j}]"
                    );
                }
                assert!(
                    (got_w[c] as f64 - want_w[c]).abs() < 1e-3 * want_w[c],
                    "weight {c}"
                );
            }
        });
    }

    #[test]
    fn small_and_empty_keyframes() {
        with_context(|ctx| {
            let cfg = KMeansConfig {
                atoms: 8,
                dim: 16,
                max_points: 4,
                ..Default::default()
            };
            let kmeans = StreamingKMeans::new(ctx, cfg).unwrap();
            let atoms = Buffer::device(ctx, "test/atoms", 8 * 16 * 4).unwrap();
            let anchor = Buffer::device(ctx, "test/anchor", 8 * 16 * 4).unwrap();
            let moved = Buffer::device(ctx, "test/moved", 8 * 4).unwrap();
            let f: Vec<f32> = (0..5 * 16).map(|i| ((i * 7) % 11) as f32 - 5.0).collect();
            let fb = ctx.upload_new("test/f", &f).unwrap();
            let mut rec = ctx.recorder().unwrap();
            let empty = kmeans
                .record_update(&mut rec, &fb, None, 0, &atoms, &anchor, &moved)
                .unwrap();
            assert_eq!(empty.atoms_after, 0);
            // Fewer regions than micro-clusters: one centre per region.
            let two = kmeans
                .record_update(&mut rec, &fb, None, 2, &atoms, &anchor, &moved)
                .unwrap();
            assert_eq!((two.micro_clusters, two.atoms_after), (2, 2));
            assert!(kmeans
                .record_update(&mut rec, &fb, None, 5, &atoms, &anchor, &moved)
                .is_err());
            rec.submit().unwrap().wait().unwrap();
            assert_eq!(kmeans.atom_count(), 2);
            for bad in [
                KMeansConfig { atoms: 0, ..cfg },
                KMeansConfig {
                    micro_clusters: 9,
                    ..cfg
                },
                KMeansConfig {
                    global_iterations: 0,
                    ..cfg
                },
                KMeansConfig { decay: 1.5, ..cfg },
                KMeansConfig {
                    atoms: MAX_KMEANS_ATOMS + 1,
                    ..cfg
                },
            ] {
                assert!(StreamingKMeans::new(ctx, bad).is_err(), "{bad:?}");
            }
        });
    }
}
