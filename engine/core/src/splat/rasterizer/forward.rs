//! The forward pass in two steps, so that a caller can render several
//! batches of views with one host wait: [`Rasterizer::measure`] sizes the
//! batches (the pass's only read-back: how many pairs are visible and how
//! many tile intersections follow), and [`Rasterizer::record_forward`]
//! records one of them into any recorder, with no wait.

use latentam_shaders::{
    push, COMPACT_VISIBLE, COVERAGE_GRID, EMIT_TILES, GATHER_COUNTS, PROJECT_FORWARD, TILE_RANGES,
};

use super::work::BatchCounts;
use super::{Channels, ColourRender, ForwardStats, Rasterizer, RenderBatch, QUERY_BYTES};
use crate::splat::views::BatchLayout;
use crate::splat::{Camera, GaussianBuffers, PixelGrid};

/// Invocations per workgroup of `glsl/coverage_grid.comp`.
const GRID_THREADS: u64 = 256;
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Recorder};
use latentam_shaders::bind;
use latentam_shaders::shared::{PixelState, Splat, TileRange, TileRect, View};

impl Rasterizer {
    /// Renders `cameras` from Gaussians `0..count` of `gaussians` and waits
    /// for the result (read it with [`Rasterizer::images`] or
    /// [`Rasterizer::download_view`]).
    pub fn forward(
        &mut self,
        gaussians: &GaussianBuffers,
        count: u64,
        cameras: &[Camera],
    ) -> Result<ForwardStats> {
        self.forward_channels(gaussians, count, cameras, Channels::All)
    }

    /// [`Rasterizer::forward`] writing only the images `channels` names.
    /// Two host waits: [`Rasterizer::measure`], then the rendering.
    pub fn forward_channels(
        &mut self,
        gaussians: &GaussianBuffers,
        count: u64,
        cameras: &[Camera],
        channels: Channels,
    ) -> Result<ForwardStats> {
        let batch = self
            .measure(gaussians, count, &[cameras], channels)?
            .pop()
            .expect("one batch measured");
        // A query image too large for one buffer is rendered in bands: the
        // blend runs once per band, and the bands are kept on the host for
        // `download_view`.
        let pixels = batch.layout.pixels;
        let band = self.query_band_pixels();
        let banded = channels == Channels::All && pixels > band;
        let ctx = self.ctx.clone();
        let first_band = {
            let mut rec = ctx.recorder()?;
            self.record_binning(&mut rec, gaussians, &batch)?;
            self.record_blend(&mut rec, gaussians, &batch, 0, band)?;
            let images = self.images()?;
            let first_band = if banded {
                Some(rec.download(images.query()?, 0, band * QUERY_BYTES)?)
            } else {
                None
            };
            rec.submit()?.wait()?;
            first_band
        };
        self.banded_query = None;
        if let Some(first_band) = first_band {
            let mut host = Vec::with_capacity((pixels * QUERY_BYTES / 4) as usize);
            host.extend(first_band.read::<f32>()?);
            let mut start = band;
            while start < pixels {
                let len = band.min(pixels - start);
                let mut rec = ctx.recorder()?;
                self.record_blend(&mut rec, gaussians, &batch, start, len)?;
                let rb = rec.download(self.images()?.query()?, 0, len * QUERY_BYTES)?;
                rec.submit()?.wait()?;
                host.extend(rb.read::<f32>()?);
                start += len;
            }
            self.banded_query = Some(host);
        }
        let stats = batch.stats;
        self.last = batch;
        Ok(stats)
    }

    /// One camera's colour, depth and alpha at the pixels of `grid` (no
    /// query channels), rendered and read back in the same submission:
    /// two host waits (the measure, then the render with its read-back),
    /// where [`Rasterizer::forward_channels`] then
    /// [`Rasterizer::download_alpha_rgbd`] take three. With
    /// [`PixelGrid::ALL`] the alpha and the colour-and-depth image are as
    /// `download_alpha_rgbd` gives them; with a coarser grid, their values
    /// at its cells, row by row (gathered on the GPU by
    /// `glsl/coverage_grid.comp`, so that only the cells cross the host
    /// link). `also` is a buffer read back in the same submission, after
    /// everything queued before it (its `f32` words), so that a caller
    /// needing another read-back at that point waits no extra time.
    pub fn render_alpha_rgbd(
        &mut self,
        gaussians: &GaussianBuffers,
        count: u64,
        camera: &Camera,
        grid: PixelGrid,
        also: Option<&Buffer>,
    ) -> Result<ColourRender> {
        let (width, height) = (camera.width, camera.height);
        let cells = grid.cells(width, height);
        if grid.stride == 0 || cells == 0 {
            return Err(Error::bad_input(
                "pixel grid",
                format!("{grid:?} has no cell in a {width}x{height} view"),
            ));
        }
        // The kernel's word indices are 32-bit: five words a cell, four a
        // pixel of the image it reads.
        if 5 * cells > u32::MAX as u64 || 4 * width as u64 * height as u64 > u32::MAX as u64 {
            return Err(Error::bad_input(
                "pixel grid",
                format!("a {width}x{height} view is past 2^32 words"),
            ));
        }
        let batch = self
            .measure(
                gaussians,
                count,
                &[std::slice::from_ref(camera)],
                Channels::Colour,
            )?
            .pop()
            .expect("one batch measured");
        let slot = batch.layout.views[0];
        if grid != PixelGrid::ALL {
            self.grid_cells.ensure(&self.ctx, cells * 20)?;
        }
        let ctx = self.ctx.clone();
        let (alpha, rgbd, also) = {
            let mut rec = ctx.recorder()?;
            self.record_binning(&mut rec, gaussians, &batch)?;
            // As `forward_channels` records it (colour: no query image).
            self.record_blend(&mut rec, gaussians, &batch, 0, self.query_band_pixels())?;
            let images = self.images()?;
            let (rgbd, alpha) = if grid == PixelGrid::ALL {
                let n = slot.width as u64 * slot.height as u64;
                (
                    rec.download(&images.rgbd, slot.first_pixel * 16, n * 16)?,
                    rec.download(&images.alpha, slot.first_pixel * 4, n * 4)?,
                )
            } else {
                let out = self.grid_cells.get();
                let words = |w: u64| {
                    u32::try_from(w).map_err(|_| Error::bad_input("pixel grid", "past 2^32 pixels"))
                };
                rec.dispatch_linear(
                    &COVERAGE_GRID,
                    cells.div_ceil(GRID_THREADS) as u32,
                    bind::CoverageGridBuffers {
                        rgbd: &images.rgbd,
                        alpha: &images.alpha,
                        cells: out,
                    },
                    &push::CoverageGrid {
                        count: words(cells)?,
                        cols: grid.cols(width),
                        stride: grid.stride,
                        start_u: grid.start[0],
                        start_v: grid.start[1],
                        width,
                        first_pixel: words(slot.first_pixel)?,
                    },
                )?;
                (
                    rec.download(out, 0, cells * 16)?,
                    rec.download(out, cells * 16, cells * 4)?,
                )
            };
            let also = also.map(|b| rec.download(b, 0, b.bytes())).transpose()?;
            rec.submit()?.wait()?;
            (alpha, rgbd, also)
        };
        self.banded_query = None;
        self.last = batch;
        Ok(ColourRender {
            alpha: alpha.read::<f32>()?,
            rgbd: bytemuck::cast_slice(&rgbd.read::<f32>()?).to_vec(),
            grid,
            also: also.map(|b| b.read::<f32>()).transpose()?,
        })
    }

    /// Measures batches of views of Gaussians `0..count`, all in one
    /// submission and one host wait, and grows the rasterizer's buffers
    /// for the largest, so that any of them can then be recorded with
    /// [`Rasterizer::record_forward`] without waiting.
    pub fn measure(
        &mut self,
        gaussians: &GaussianBuffers,
        count: u64,
        batches: &[&[Camera]],
        channels: Channels,
    ) -> Result<Vec<RenderBatch>> {
        if count > gaussians.capacity() {
            return Err(Error::bad_input(
                "Gaussians to render",
                format!(
                    "rendering {count} Gaussians from buffers of capacity {}",
                    gaussians.capacity()
                ),
            ));
        }
        let mut measured = Vec::with_capacity(batches.len());
        for cameras in batches {
            if cameras.is_empty() {
                return Err(Error::bad_input("batch", "no views to render"));
            }
            let (layout, views) = BatchLayout::new(cameras)?;
            let pairs = count * cameras.len() as u64;
            let max_view_tiles = layout
                .views
                .iter()
                .map(|v| (v.tiles_x * v.tiles_y) as u64)
                .max()
                .unwrap_or(0);
            // Every count below is a u32 on the GPU, intersections included.
            if pairs.saturating_mul(max_view_tiles) >= u32::MAX as u64 {
                return Err(Error::bad_input(
                    "batch",
                    format!(
                        "{} views x {count} Gaussians could exceed 2^32 tile intersections; \
                         render fewer views per batch",
                        cameras.len()
                    ),
                ));
            }
            measured.push(RenderBatch {
                layout,
                views,
                count,
                channels,
                stats: ForwardStats::default(),
            });
        }
        self.reserve_projection(&measured)?;

        // Each batch is projected, and its visible pairs and intersections
        // are counted by scanning the counts in pair order (an extra scan
        // for the total) so that one read-back sizes everything after.
        let ctx = self.ctx.clone();
        let mut rec = ctx.recorder()?;
        let mut readbacks = Vec::with_capacity(measured.len());
        for batch in &measured {
            let pairs = batch.pairs();
            self.record_projection(&mut rec, gaussians, batch)?;
            let pair_offsets = self.pair_offsets.get();
            rec.fill_u32(pair_offsets, 0);
            rec.copy(self.tile_counts.get(), 0, pair_offsets, 0, pairs * 4)?;
            let scan = self.scan.as_ref().expect("scan sized above");
            scan.record(&mut rec, pair_offsets, pairs + 1)?;
            let visible = rec.download(self.positions.get(), pairs * 4, 4)?;
            let intersections = rec.download(pair_offsets, pairs * 4, 4)?;
            readbacks.push((visible, intersections));
        }
        rec.submit()?.wait()?;
        for (batch, (visible, intersections)) in measured.iter_mut().zip(readbacks) {
            batch.stats = ForwardStats {
                visible: visible.read::<u32>()?[0] as u64,
                intersections: intersections.read::<u32>()?[0] as u64,
            };
        }
        self.reserve_rendering(&measured)?;
        Ok(measured)
    }

    /// Records the forward pass of `batch` (measured on these Gaussians,
    /// unchanged since) into `rec`: the images then hold its views, and
    /// `record_pool` and `record_backward_into` may follow for it. The
    /// query image must fit one buffer of the device (no banding; see
    /// [`PixelBuffers::query`](super::PixelBuffers::query)).
    pub fn record_forward<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        gaussians: &'a GaussianBuffers,
        batch: &RenderBatch,
    ) -> Result<()> {
        let pixels = batch.layout.pixels;
        if batch.channels == Channels::All && pixels > self.query_band_pixels() {
            return Err(Error::Unsupported(format!(
                "a query image of {pixels} pixels needs more than one buffer of this device; \
                 render it with Rasterizer::forward_channels"
            )));
        }
        self.record_binning(rec, gaussians, batch)?;
        self.record_blend(rec, gaussians, batch, 0, pixels)
    }

    /// Grows what projecting `batches` needs.
    fn reserve_projection(&mut self, batches: &[RenderBatch]) -> Result<()> {
        let ctx = self.ctx.clone();
        let pairs = batches.iter().map(RenderBatch::pairs).max().unwrap_or(0);
        let views = batches.iter().map(|b| b.views.len()).max().unwrap_or(0);
        self.views.ensure(&ctx, bytes::<View>(views as u64))?;
        self.splats.ensure(&ctx, bytes::<Splat>(pairs))?;
        self.rects.ensure(&ctx, bytes::<TileRect>(pairs))?;
        self.tile_counts.ensure(&ctx, pairs * 4)?;
        self.positions.ensure(&ctx, (pairs + 1) * 4)?;
        self.pair_offsets.ensure(&ctx, (pairs + 1) * 4)?;
        self.ensure_scan(pairs + 1)
    }

    /// Grows the rest of what rendering and differentiating measured
    /// `batches` needs (their projection's buffers are grown already).
    fn reserve_rendering(&mut self, batches: &[RenderBatch]) -> Result<()> {
        let ctx = self.ctx.clone();
        let max = |f: &dyn Fn(&RenderBatch) -> u64| batches.iter().map(f).max().unwrap_or(0);
        let pairs = max(&|b| b.pairs());
        let intersections = max(&|b| b.stats.intersections);
        let sorted = max(&|b| b.stats.visible.max(b.stats.intersections));
        let tiles = max(&|b| b.layout.tiles as u64);
        let pixels = max(&|b| b.layout.pixels);
        let all_channels = batches.iter().any(|b| b.channels == Channels::All);
        self.depth_keys.ensure(&ctx, pairs * 4)?;
        self.depth_order.ensure(&ctx, pairs * 4)?;
        self.sorted_offsets.ensure(&ctx, (pairs + 1) * 4)?;
        self.grad_splats.ensure(&ctx, bytes::<Splat>(pairs))?;
        self.isect_keys.ensure(&ctx, intersections * 4)?;
        self.isect_pairs.ensure(&ctx, intersections * 4)?;
        self.ranges.ensure(&ctx, bytes::<TileRange>(tiles))?;
        self.state.ensure(&ctx, bytes::<PixelState>(pixels))?;
        let channels = if all_channels {
            Channels::All
        } else {
            Channels::Colour
        };
        self.ensure_pixels(pixels, channels)?;
        self.ensure_sorter(sorted)
    }

    /// Projection: every (view, Gaussian) pair's splat, tile rectangle and
    /// tile count, and in `positions` the visible pairs' exclusive scan.
    fn record_projection<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        gaussians: &'a GaussianBuffers,
        batch: &RenderBatch,
    ) -> Result<()> {
        let pairs = batch.pairs();
        let positions = self.positions.get();
        rec.upload(self.views.get(), 0, &batch.views)?;
        rec.fill_u32(positions, 0);
        rec.work_of_next(BatchCounts::of(batch).project_forward());
        rec.dispatch_linear(
            &PROJECT_FORWARD,
            pairs.div_ceil(256) as u32,
            bind::ProjectForwardBuffers {
                views: self.views.get(),
                means: &gaussians.means,
                log_scales: &gaussians.log_scales,
                quats: &gaussians.quats,
                logits: &gaussians.opacity_logits,
                splats: self.splats.get(),
                rects: self.rects.get(),
                tile_counts: self.tile_counts.get(),
                flags: positions,
            },
            &push::ProjectForward {
                n_gaussians: batch.count as u32,
                n_views: batch.views.len() as u32,
            },
        )?;
        let scan = self.scan.as_ref().expect("scan sized by reserve");
        scan.record(rec, positions, pairs + 1)
    }

    /// Projection, depth sort and tile binning of `batch`: everything
    /// before blending.
    fn record_binning<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        gaussians: &'a GaussianBuffers,
        batch: &RenderBatch,
    ) -> Result<()> {
        let (scan, sorter) = match (&self.scan, &self.sorter) {
            (Some(scan), Some(sorter)) => (scan, sorter),
            _ => return Err(not_measured()),
        };
        let pairs = batch.pairs();
        let ForwardStats {
            visible,
            intersections,
        } = batch.stats;
        let grown =
            |buf: &super::Grow, bytes: u64| buf.buf.as_ref().is_some_and(|b| b.bytes() >= bytes);
        let images_fit = self
            .images
            .as_ref()
            .is_some_and(|i| i.pixels >= batch.layout.pixels);
        if !(grown(&self.splats, bytes::<Splat>(pairs))
            && grown(&self.isect_keys, intersections * 4)
            && grown(&self.ranges, bytes::<TileRange>(batch.layout.tiles as u64))
            && grown(&self.views, bytes::<View>(batch.views.len() as u64))
            && images_fit
            && sorter.max_len() >= visible.max(intersections))
        {
            return Err(not_measured());
        }
        self.record_projection(rec, gaussians, batch)?;
        let bins = |n: u64| push::TileBins {
            n: n as u32,
            n_gaussians: batch.count as u32,
            n_views: batch.views.len() as u32,
        };
        let counts = BatchCounts::of(batch);
        rec.work_of_next(counts.compact_visible());
        rec.dispatch_linear(
            &COMPACT_VISIBLE,
            pairs.div_ceil(256) as u32,
            bind::CompactVisibleBuffers {
                splats: self.splats.get(),
                counts: self.tile_counts.get(),
                positions: self.positions.get(),
                keys: self.depth_keys.get(),
                vals: self.depth_order.get(),
            },
            &bins(pairs),
        )?;
        sorter.record(
            rec,
            self.depth_keys.get(),
            self.depth_order.get(),
            visible,
            32,
        )?;
        rec.dispatch_linear(
            &GATHER_COUNTS,
            visible.div_ceil(256) as u32,
            bind::GatherCountsBuffers {
                counts: self.tile_counts.get(),
                order: self.depth_order.get(),
                sorted: self.sorted_offsets.get(),
            },
            &bins(visible),
        )?;
        scan.record(rec, self.sorted_offsets.get(), visible)?;
        rec.work_of_next(counts.emit_tiles());
        rec.dispatch_linear(
            &EMIT_TILES,
            visible.div_ceil(256) as u32,
            bind::EmitTilesBuffers {
                views: self.views.get(),
                rects: self.rects.get(),
                order: self.depth_order.get(),
                offsets: self.sorted_offsets.get(),
                keys: self.isect_keys.get(),
                vals: self.isect_pairs.get(),
            },
            &bins(visible),
        )?;
        let tiles = batch.layout.tiles;
        let tile_bits = (32 - tiles.saturating_sub(1).leading_zeros()).max(1);
        sorter.record(
            rec,
            self.isect_keys.get(),
            self.isect_pairs.get(),
            intersections,
            tile_bits,
        )?;
        rec.fill_u32(self.ranges.get(), 0);
        rec.dispatch_linear(
            &TILE_RANGES,
            intersections.div_ceil(256) as u32,
            bind::TileRangesBuffers {
                keys: self.isect_keys.get(),
                ranges: self.ranges.get(),
            },
            &bins(intersections),
        )
    }
}

fn not_measured() -> Error {
    Error::bad_input(
        "batch",
        "record_forward of a batch this rasterizer has not measured: call Rasterizer::measure \
         for it first",
    )
}

/// Bytes of `n` elements of a layout shared with the kernels.
fn bytes<T>(n: u64) -> u64 {
    n * std::mem::size_of::<T>() as u64
}
