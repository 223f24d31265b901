//! The stages of one `StreamingKMeans::record_update`, in its order: the
//! checks, the keyframe's micro-clusters, the points of the re-clustering,
//! then appending to a dictionary with room or re-clustering a full one
//! (the novelty step and the first Lloyd iteration; the later ones are in
//! `steps.rs`), and the moved flags and anchor.

use latentam_shaders::{
    bind, push, KMEANS_FIRST_ASSIGN, KMEANS_MOVED, KMEANS_NOVELTY, KMEANS_PATCH_SIMS, KMEANS_SEED,
};

use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Recorder};

use super::*;

impl StreamingKMeans {
    /// Before an update: refuses more regions than the buffers were sized
    /// for, and buffers too small for `n` regions or for the dictionary.
    pub(super) fn check_update(
        &self,
        features: &Buffer,
        mass: Option<&Buffer>,
        n: u32,
        atoms: &Buffer,
        anchor: &Buffer,
        moved: &Buffer,
    ) -> Result<()> {
        let (k_max, d) = (self.cfg.atoms as u64, self.cfg.dim as u64);
        if n > self.cfg.max_points {
            return Err(Error::bad_input(
                "regions to cluster",
                format!(
                    "k-means update with {n} regions; sized for {}",
                    self.cfg.max_points
                ),
            ));
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
        Ok(())
    }

    /// Step 1: the keyframe's `n` region embeddings clustered into `m`
    /// micro-clusters (seeded, then `local_iterations` weighted Lloyd
    /// iterations): their centres in `micro`, their masses in
    /// `micro_weights`.
    pub(super) fn record_micro_clusters<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        features: &'a Buffer,
        mass: &'a Buffer,
        n: u32,
        m: u32,
    ) -> Result<()> {
        let dim = self.cfg.dim;
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
        Ok(())
    }

    /// Step 2: the points of the re-clustering, the `before` atoms then the
    /// `m` micro-centres (`points`), with their masses (`point_mass`).
    pub(super) fn record_reclustering_points<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        atoms: &'a Buffer,
        before: u32,
        m: u32,
    ) -> Result<()> {
        let d = self.cfg.dim as u64;
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
        Ok(())
    }

    /// Step 3a, while the dictionary has room: the `m` micro-centres
    /// appended as new atoms, their masses as the new atoms' weights.
    /// Returns the atom count after.
    pub(super) fn record_append<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        atoms: &'a Buffer,
        before: u32,
        m: u32,
    ) -> Result<u32> {
        let d = self.cfg.dim as u64;
        let (row, bytes) = (d * 4, before as u64 * d * 4);
        rec.copy(&self.micro, 0, atoms, bytes, m as u64 * row)?;
        rec.copy(
            &self.micro_weights,
            0,
            &self.weights,
            before as u64 * 4,
            m as u64 * 4,
        )?;
        Ok(before + m)
    }

    /// Step 3b, once the dictionary is full: the novelty step, then
    /// `global_iterations` weighted Lloyd iterations over the atoms and the
    /// micro-centres warm-started from the atoms (the first from the
    /// novelty step's similarities, the later ones sparse). The atom count
    /// stays.
    pub(super) fn record_recluster<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        atoms: &'a Buffer,
        before: u32,
        m: u32,
    ) -> Result<u32> {
        let total = before + m;
        self.record_novelty(rec, atoms, before, m)?;
        for iteration in 0..self.cfg.global_iterations {
            if iteration == 0 {
                self.record_first_global_iteration(rec, atoms, before, m)?;
            } else {
                // The first iteration computed every centre.
                self.record_sparse_iteration(rec, atoms, total, before, iteration == 1)?;
            }
        }
        Ok(before)
    }

    /// The novelty step of a full dictionary: each micro-centre whose best
    /// cosine to the atoms is below `novelty_threshold` (a new concept)
    /// replaces, as a warm-start centre, the lighter atom of the most
    /// similar pair, whose points the Lloyd iterations then merge into the
    /// other; `replaced` records the slot each micro-centre took.
    fn record_novelty<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        atoms: &'a Buffer,
        before: u32,
        m: u32,
    ) -> Result<()> {
        let dim = self.cfg.dim;
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
        Ok(())
    }

    /// The first Lloyd iteration of the re-clustering: the cosines to the
    /// atoms are known from the novelty step but for the replaced columns,
    /// which are patched; then every point is assigned and every centre
    /// updated.
    fn record_first_global_iteration<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        atoms: &'a Buffer,
        before: u32,
        m: u32,
    ) -> Result<()> {
        let dim = self.cfg.dim;
        let total = before + m;
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
        Ok(())
    }

    /// Step 4: flags the atoms that are new or moved by more than
    /// `moved_tolerance` in `moved`, and copies the `after` atoms to
    /// `anchor`, the trust region's D⁰.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn record_moved_and_anchor<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        atoms: &'a Buffer,
        anchor: &'a Buffer,
        moved: &'a Buffer,
        before: u32,
        after: u32,
    ) -> Result<()> {
        let dim = self.cfg.dim;
        let row = dim as u64 * 4;
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
        Ok(())
    }
}
