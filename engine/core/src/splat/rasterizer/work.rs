//! The work of the rasterizer's data-dependent kernels (`// @cost caller`
//! in their sources), from the counts the host has when it records them:
//! the batch's (view, Gaussian) pairs, the visible ones and the tile-list
//! entries read back by `measure`, its pixels and tiles. Each kernel's
//! source comment derives its constants (operations per tested pair, per
//! visible pair, per pixel). The blending passes count every tile-list
//! entry as tested by every pixel of its tile: an upper bound, since a
//! pixel stops at its last contributor and a tile once all its pixels
//! are opaque, so their share of a floor leans high.

use latentam_shaders::{Kernel, Work};

use super::RenderBatch;

/// Pixels of a tile.
const TILE_PIXELS: f64 = 256.0;

/// The host's counts of one batch, as floats.
pub(super) struct BatchCounts {
    gaussians: f64,
    views: f64,
    pairs: f64,
    visible: f64,
    entries: f64,
    pixels: f64,
    tiles: f64,
}

impl BatchCounts {
    /// Before `measure` has read a batch's counts back they are 0: every
    /// pair then counts as visible (an upper bound for the projection that
    /// measures them).
    pub fn of(batch: &RenderBatch) -> Self {
        let pairs = batch.pairs() as f64;
        let measured = batch.stats.visible > 0 || batch.stats.intersections > 0;
        BatchCounts {
            gaussians: batch.count as f64,
            views: batch.layout.views.len() as f64,
            pairs,
            visible: if measured {
                batch.stats.visible as f64
            } else {
                pairs
            },
            entries: batch.stats.intersections as f64,
            pixels: batch.layout.pixels as f64,
            tiles: batch.layout.tiles as f64,
        }
    }

    /// Gaussians in some tile list, at most.
    fn listed(&self) -> f64 {
        self.gaussians.min(self.visible)
    }

    /// `project_forward.comp`: every pair transformed and depth-tested,
    /// every visible one projected in full.
    pub fn project_forward(&self) -> Work {
        Work {
            flops: 20.0 * self.pairs + 335.0 * self.visible,
            bytes: 44.0 * self.gaussians
                + 128.0 * self.views
                + 8.0 * self.pairs
                + 40.0 * self.visible,
        }
    }

    /// `project_backward.comp`: the chain rule of every visible pair.
    pub fn project_backward(&self, accumulate: bool) -> Work {
        let acc = accumulate as u8 as f64;
        Work {
            flops: self.pairs + 785.0 * self.visible + 11.0 * self.gaussians * acc,
            bytes: 88.0 * self.gaussians
                + 44.0 * self.gaussians * acc
                + 128.0 * self.views
                + 4.0 * self.pairs
                + 28.0 * self.visible,
        }
    }

    /// `compact_visible` (tile_bins.comp).
    pub fn compact_visible(&self) -> Work {
        Work {
            flops: self.pairs,
            bytes: 4.0 * self.pairs + 16.0 * self.visible,
        }
    }

    /// `emit_tiles` (tile_bins.comp): a key and value per entry.
    pub fn emit_tiles(&self) -> Work {
        Work {
            flops: 0.0,
            bytes: 16.0 * self.visible + 8.0 * self.entries + 8.0 * self.views,
        }
    }

    /// `raster_forward.comp`, the variant `kernel`, writing the query
    /// channels of `query_pixels` pixels.
    pub fn blend_forward(&self, kernel: &Kernel, query_pixels: f64) -> Work {
        let colour_only = kernel.name.contains("_colour");
        let per_test = match (kernel.is_column_layout(), colour_only) {
            (true, true) => 44.0,
            (true, false) => 140.0,
            (false, _) => 25.0,
        };
        let per_gaussian = if colour_only { 12.0 } else { 140.0 };
        let query_pixels = if colour_only { 0.0 } else { query_pixels };
        Work {
            flops: per_test * TILE_PIXELS * self.entries + 7.0 * self.pixels,
            bytes: 4.0 * self.entries
                + 28.0 * self.visible
                + per_gaussian * self.listed()
                + 8.0 * self.tiles
                + 28.0 * self.pixels
                + 128.0 * query_pixels,
        }
    }

    /// `raster_backward.wgsl`, the variant `kernel`; `query_gradients`
    /// whether an upstream query gradient image is read.
    pub fn blend_backward(
        &self,
        kernel: &Kernel,
        detach_query: bool,
        query_gradients: bool,
    ) -> Work {
        let columns = kernel.is_column_layout();
        let attached = kernel.name.contains("_attached");
        let flops = match (columns, attached) {
            (false, _) => 25.0 * TILE_PIXELS * self.entries + 80.0 * self.pixels,
            (true, false) => (210.0 * TILE_PIXELS + 680.0) * self.entries + 80.0 * self.pixels,
            (true, true) => (280.0 * TILE_PIXELS + 680.0) * self.entries + 80.0 * self.pixels,
        };
        let per_gaussian = if columns && !attached { 12.0 } else { 140.0 };
        let query_image = if attached || (!columns && !detach_query) {
            128.0 * self.pixels
        } else {
            0.0
        };
        let upstream = if query_gradients {
            128.0 * self.pixels
        } else {
            0.0
        };
        // 42 words of 8 bytes per flush: per entry, every invocation of a
        // _plain column tile (16), each subgroup of the others (2), or
        // once (pixel layouts, a floor).
        let atomics = match (columns, kernel.name.contains("_plain")) {
            (true, true) => 5376.0,
            (true, false) => 672.0,
            (false, _) => 336.0,
        };
        Work {
            flops,
            bytes: 4.0 * self.entries
                + 32.0 * self.visible
                + 4.0 * self.tiles
                + 44.0 * self.pixels
                + query_image
                + upstream
                + per_gaussian * self.listed()
                + atomics * self.entries,
        }
    }

    /// `raster_pool.wgsl`, the variant `kernel`, into `regions` rows.
    pub fn pool(&self, kernel: &Kernel, regions: f64) -> Work {
        let per_test = if kernel.is_column_layout() {
            125.0
        } else {
            25.0
        };
        let row_adds = if kernel.name.contains("_plain") {
            256.0
        } else {
            // Subgroup or column sums: one row add per 16 pixels or so.
            16.0
        };
        Work {
            flops: per_test * TILE_PIXELS * self.entries + 70.0 * self.pixels,
            bytes: 4.0 * self.entries
                + 32.0 * self.visible
                + 128.0 * self.listed()
                + 4.0 * self.tiles
                + 8.0 * self.pixels
                + 4.0 * regions
                + row_adds * self.pixels,
        }
    }
}
