//! The steps `StreamingKMeans::record_update` chains: normalising rows,
//! cosine products and their row maxima, the weighted Lloyd update, the
//! novelty step's similarities and the sparse Lloyd iterations of a full
//! dictionary.

use latentam_shaders::{
    push, ARGMAX_ROWS, KMEANS_GATE, KMEANS_MICRO_ROWS, KMEANS_REASSIGN, KMEANS_RESIM, KMEANS_STALE,
    KMEANS_STALE_LIST, KMEANS_UPDATE, KMEANS_UPDATE_DIRTY,
};

use latentam_base::Result;
use latentam_gpu::ops::{normalize_rows, Gemm, Transpose};
use latentam_gpu::{Buffer, Recorder};
use latentam_shaders::bind;

use super::*;

impl StreamingKMeans {
    pub(super) fn normalize<'a>(
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
    pub(super) fn similarities<'a>(
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
    pub(super) fn best_centres<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        rows: u32,
        cols: u32,
    ) -> Result<()> {
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
    pub(super) fn lloyd_update<'a>(
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
    pub(super) fn record_novelty_similarities<'a>(
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
    pub(super) fn record_sparse_iteration<'a>(
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
}
