//! Region pooling (regions as in paper Sec. III-B): rendered per-pixel queries averaged over each
//! region of a view (a SAM-style mask or a coarse feature-grid cell), and the
//! gradient sent back to the pixels. The region lists are built on the CPU
//! ([`Regions`]) when a frame is ingested; the GPU side is
//! [`RegionPooling`] (kernels `glsl/region_pool.comp`,
//! `glsl/region_pool_backward.comp`; CPU reference
//! `latentam_reference::pooling`).

use latentam_shaders::{push, Work, REGION_POOL, REGION_POOL_BACKWARD};

use std::cell::Cell;

use crate::splat::{BatchLayout, QUERY_DIM};
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Recorder};
use latentam_shaders::bind;

/// Label value meaning "this pixel belongs to no region" in a label image
/// (as in `latentam_msgs/msg/MaskFeatures`).
pub const NO_REGION_LABEL: u16 = u16::MAX;

/// Region index of a batch pixel that belongs to no kept region.
pub use latentam_shaders::shared::NO_REGION;

/// A row-major image of region labels (one u16 per pixel,
/// [`NO_REGION_LABEL`] for none). It may be smaller or larger than the view
/// it labels: view pixels take the label under their centre (nearest
/// neighbour).
///
/// ```
/// use latentam_core::latent::{LabelImage, Regions, NO_REGION_LABEL};
/// use latentam_core::splat::{BatchLayout, Camera};
///
/// let layout = BatchLayout::for_cameras(&[Camera::at_origin(8, 8)])?;
/// // A 2×2 mask at a quarter of the view's resolution: two regions on top,
/// // nothing below.
/// let labels = [0u16, 1, NO_REGION_LABEL, NO_REGION_LABEL];
/// let mut regions = Regions::new(&layout, 1);
/// regions.add_labels(0, LabelImage { width: 2, height: 2, labels: &labels }, 2)?;
/// assert_eq!(regions.offsets(), &[0, 16, 32]); // two 4×4-pixel regions
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct LabelImage<'a> {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// width × height labels.
    pub labels: &'a [u16],
}

/// What became of one view's regions.
///
/// ```
/// use latentam_core::latent::Regions;
/// use latentam_core::splat::{BatchLayout, Camera};
///
/// let layout = BatchLayout::for_cameras(&[Camera::at_origin(8, 8); 2])?;
/// let mut regions = Regions::new(&layout, 10); // regions need 10 pixels
/// regions.add_grid(0, 2, 2)?; // four cells of 16 pixels
/// let second = regions.add_grid(1, 4, 4)?; // sixteen cells of 4 pixels
/// assert_eq!(second.first_row, 4);
/// assert_eq!(second.too_small, 16);
/// assert!(second.sources.is_empty());
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ViewRegions {
    /// Index of the view in the batch.
    pub view: usize,
    /// First pooled row of this view.
    pub first_row: u32,
    /// For each pooled row of this view, the region's index in the input
    /// (label value or grid cell), to gather its target embedding.
    pub sources: Vec<u32>,
    /// Regions with fewer pixels than the minimum (ignored).
    pub too_small: u32,
    /// Regions that cover no pixel of the view.
    pub empty: u32,
}

/// The regions of a batch of views as pixel lists (CSR: region → batch pixel
/// indices) plus the region of every pixel, ready for [`RegionPooling`].
/// Regions are disjoint: each pixel has one label.
///
/// ```
/// use latentam_core::latent::{LabelImage, Regions};
/// use latentam_core::splat::{BatchLayout, Camera};
///
/// let layout = BatchLayout::for_cameras(&[Camera::at_origin(4, 2)])?;
/// let mut regions = Regions::new(&layout, 2);
/// // A 2x1 label image: left half region 0, right half region 1.
/// let labels = [0u16, 1];
/// regions.add_labels(0, LabelImage { width: 2, height: 1, labels: &labels }, 2)?;
/// assert_eq!(regions.len(), 2);
/// assert_eq!(regions.offsets(), &[0, 4, 8]);
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct Regions {
    layout: BatchLayout,
    min_pixels: u32,
    offsets: Vec<u32>,
    pixels: Vec<u32>,
    pixel_region: Vec<u32>,
    views: Vec<ViewRegions>,
}

impl Regions {
    /// No regions yet for the views of `layout`; regions with fewer than
    /// `min_pixels` pixels (at least 1) will be ignored and counted.
    pub fn new(layout: &BatchLayout, min_pixels: u32) -> Self {
        Self {
            layout: layout.clone(),
            min_pixels: min_pixels.max(1),
            offsets: vec![0],
            pixels: Vec::new(),
            pixel_region: vec![NO_REGION; layout.pixels as usize],
            views: Vec::new(),
        }
    }

    /// Pooled rows (kept regions) over all views.
    pub fn len(&self) -> u32 {
        (self.offsets.len() - 1) as u32
    }

    /// Whether no region was kept.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// CSR offsets: region r owns `pixels()[offsets[r]..offsets[r + 1]]`.
    pub fn offsets(&self) -> &[u32] {
        &self.offsets
    }

    /// Batch pixel indices, grouped by region.
    pub fn pixels(&self) -> &[u32] {
        &self.pixels
    }

    /// Region of every batch pixel ([`NO_REGION`] for none).
    pub fn pixel_region(&self) -> &[u32] {
        &self.pixel_region
    }

    /// Per view that has regions, in the order they were added.
    pub fn views(&self) -> &[ViewRegions] {
        &self.views
    }

    /// Pooled rows per view of the layout (0 for views without regions), as
    /// [`crate::loss::mean_per_view_weights`] takes them.
    pub fn rows_per_view(&self) -> Vec<u32> {
        let mut counts = vec![0; self.layout.views.len()];
        for v in &self.views {
            counts[v.view] = v.sources.len() as u32;
        }
        counts
    }

    /// Adds the regions of view `view` from a label image with `count`
    /// regions (labels 0..count). Views must be added in increasing order.
    /// A label ≥ `count` or a label image of the wrong length is an error,
    /// and leaves the regions unchanged.
    pub fn add_labels(&mut self, view: usize, img: LabelImage, count: u32) -> Result<&ViewRegions> {
        if img.width == 0
            || img.height == 0
            || img.labels.len() != (img.width * img.height) as usize
        {
            return Err(Error::bad_input(
                "label image",
                format!(
                    "{}x{} with {} labels",
                    img.width,
                    img.height,
                    img.labels.len()
                ),
            ));
        }
        if let Some(&bad) = img
            .labels
            .iter()
            .find(|&&l| l != NO_REGION_LABEL && l as u32 >= count)
        {
            return Err(Error::bad_input(
                format!("view {view}"),
                format!("region label {bad} but the message has {count} regions"),
            ));
        }
        self.add(view, count, (img.width, img.height), |lv, lu| {
            let l = img.labels[(lv * img.width + lu) as usize];
            (l != NO_REGION_LABEL).then_some(l as u32)
        })
    }

    /// Adds the regions of view `view` as the cells of a `rows` × `cols`
    /// feature grid laid over the image (cell index = row · cols + col).
    pub fn add_grid(&mut self, view: usize, rows: u32, cols: u32) -> Result<&ViewRegions> {
        if rows == 0 || cols == 0 {
            return Err(Error::bad_input(
                format!("view {view}"),
                format!("feature grid of {rows}x{cols} cells"),
            ));
        }
        self.add(view, rows * cols, (cols, rows), |lv, lu| {
            Some(lv * cols + lu)
        })
    }

    /// Adds view `view`'s regions from a source of `source` (width,
    /// height) cells laid over it: each pixel takes the region of the cell
    /// under its centre, `label_of(row, column)` of that cell.
    fn add(
        &mut self,
        view: usize,
        count: u32,
        source: (u32, u32),
        label_of: impl Fn(u32, u32) -> Option<u32>,
    ) -> Result<&ViewRegions> {
        let Some(slot) = self.layout.views.get(view).copied() else {
            return Err(Error::bad_input(
                format!("regions for view {view}"),
                format!("the batch has {} views", self.layout.views.len()),
            ));
        };
        if self.views.last().is_some_and(|v| v.view >= view) {
            return Err(Error::bad_input(
                format!("regions for view {view}"),
                format!(
                    "added after view {}; add views in order, once each",
                    self.views.last().map_or(0, |v| v.view)
                ),
            ));
        }
        // The cell under each pixel is separable: its column from the
        // pixel's column, its row from the pixel's row (computed once
        // each, not per pixel: this runs over every pixel of every view
        // Stage I trains on).
        let columns: Vec<u32> = (0..slot.width)
            .map(|u| nearest(u, slot.width, source.0))
            .collect();
        let mut labels = Vec::with_capacity((slot.width * slot.height) as usize);
        let mut sizes = vec![0u32; count as usize];
        for v in 0..slot.height {
            let lv = nearest(v, slot.height, source.1);
            for &lu in &columns {
                let l = label_of(lv, lu).unwrap_or(NO_REGION);
                if l != NO_REGION {
                    sizes[l as usize] += 1;
                }
                labels.push(l);
            }
        }
        let mut out = ViewRegions {
            view,
            first_row: self.len(),
            ..Default::default()
        };
        // Row of each input region, or NO_REGION when it is not kept.
        let mut row_of = vec![NO_REGION; count as usize];
        for (region, &size) in sizes.iter().enumerate() {
            if size == 0 {
                out.empty += 1;
            } else if size < self.min_pixels {
                out.too_small += 1;
            } else {
                row_of[region] = out.first_row + out.sources.len() as u32;
                out.sources.push(region as u32);
            }
        }
        // Counting sort of the view's pixels by row.
        let base = self.pixels.len() as u32;
        let mut next: Vec<u32> = Vec::with_capacity(out.sources.len());
        let mut start = base;
        for &src in &out.sources {
            next.push(start);
            start += sizes[src as usize];
            self.offsets.push(start);
        }
        self.pixels.resize(start as usize, 0);
        for (i, &l) in labels.iter().enumerate() {
            if l == NO_REGION {
                continue;
            }
            let row = row_of[l as usize];
            if row == NO_REGION {
                continue;
            }
            let p = slot.first_pixel as u32 + i as u32;
            let slot_in_view = &mut next[(row - out.first_row) as usize];
            self.pixels[*slot_in_view as usize] = p;
            *slot_in_view += 1;
            self.pixel_region[p as usize] = row;
        }
        self.views.push(out);
        Ok(self.views.last().expect("just pushed"))
    }
}

/// Index of the source cell under the centre of pixel `i` of `n` when the
/// source has `m` cells along the same axis.
fn nearest(i: u32, n: u32, m: u32) -> u32 {
    let x = ((i as f64 + 0.5) * m as f64 / n as f64).floor() as u32;
    x.min(m - 1)
}

/// GPU side of region pooling for batches of up to `max_regions` regions and
/// `max_pixels` pixels: the region lists, and the pooled queries
/// (regions × 32) that the decoder reads.
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context};
/// # use latentam_core::latent::Regions;
/// # fn f(ctx: &Context, regions: &Regions, query_image: &Buffer, max_pixels: u64) -> latentam_core::Result<()> {
/// use latentam_core::latent::RegionPooling;
///
/// let pooling = RegionPooling::new(ctx, 2048, max_pixels)?;
/// let mut rec = ctx.recorder()?;
/// pooling.record_upload(&mut rec, regions)?;
/// pooling.record_forward(&mut rec, query_image)?; // the rasterizer's query image
/// let rows = rec.download(pooling.pooled(), 0, regions.len() as u64 * 32 * 4)?;
/// rec.submit()?.wait()?;
/// let pooled: Vec<f32> = rows.read()?; // one mean 32-d query per region
/// # Ok(())
/// # }
/// ```
pub struct RegionPooling {
    max_regions: u32,
    max_pixels: u64,
    /// Regions, their first pooled row and pixels of the last recorded
    /// upload.
    regions: Cell<u32>,
    first_row: Cell<u32>,
    pixels: Cell<u64>,
    /// Pixels that belong to a region in that upload: the pooling's work
    /// (`@cost caller` in region_pool.comp).
    member_pixels: Cell<u64>,
    offsets: Buffer,
    members: Buffer,
    pixel_region: Buffer,
    pooled: Buffer,
}

impl RegionPooling {
    /// Allocates the buffers.
    pub fn new(ctx: &Context, max_regions: u32, max_pixels: u64) -> Result<Self> {
        let p = max_pixels.max(1);
        Ok(Self {
            max_regions,
            max_pixels,
            regions: Cell::new(0),
            first_row: Cell::new(0),
            pixels: Cell::new(0),
            member_pixels: Cell::new(0),
            offsets: Buffer::device(ctx, "pooling/offsets", (max_regions as u64 + 1) * 4)?,
            members: Buffer::device(ctx, "pixels/pooling_members", p * 4)?,
            pixel_region: Buffer::device(
                ctx,
                "pixels/pooling_pixel_region",
                (p + max_regions as u64 + 1) * 4,
            )?,
            pooled: Buffer::device(
                ctx,
                "pooling/pooled",
                max_regions.max(1) as u64 * QUERY_DIM as u64 * 4,
            )?,
        })
    }

    /// Pooled queries of the last forward pass (regions × 32).
    pub fn pooled(&self) -> &Buffer {
        &self.pooled
    }

    /// Regions of the last recorded upload.
    pub fn regions(&self) -> u32 {
        self.regions.get()
    }

    /// u32s: the region of every pixel of the last upload ([`NO_REGION`]
    /// for none; numbered from 0, row [`Self::first_row`] of the pooled
    /// rows), then from [`Self::labels_offsets_at`] the regions' CSR
    /// offsets: what the rasterizer's backward reads for
    /// `QueryGradients::Regions`.
    pub fn labels(&self) -> &Buffer {
        &self.pixel_region
    }

    /// Index of the first CSR offset in [`Self::labels`].
    pub fn labels_offsets_at(&self) -> u32 {
        self.max_pixels as u32
    }

    /// Pooled row of the last upload's region 0.
    pub fn first_row(&self) -> u32 {
        self.first_row.get()
    }

    /// Records the upload of a batch's region lists, to run before the
    /// pooling passes recorded after it (in the same or a later submission).
    pub fn record_upload<'a>(&'a self, rec: &mut Recorder<'a>, regions: &Regions) -> Result<()> {
        self.record_upload_at(rec, regions, 0)
    }

    /// [`Self::record_upload`] for one chunk of a batch's views: its regions
    /// are pooled into (and their gradients read from) rows `first_row..` of
    /// the batch's pooled rows, so a batch can be rendered a chunk at a
    /// time into one set of rows.
    pub fn record_upload_at<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        regions: &Regions,
        first_row: u32,
    ) -> Result<()> {
        // Checks the sizes before anything is recorded.
        self.record_offsets_at(rec, regions, first_row)?;
        rec.upload(&self.offsets, 0, &regions.offsets)?;
        rec.upload(&self.members, 0, &regions.pixels)?;
        rec.upload(&self.pixel_region, 0, &regions.pixel_region)
    }

    /// What the rasterizer's pooling and its backward pass read of
    /// `regions` beside the per-pixel rows: the regions' offsets (after
    /// the pixels in [`Self::labels`]) and the counts, for regions pooled
    /// into rows `first_row..`. The per-pixel rows themselves are the
    /// caller's to write into [`Self::labels`] (Stage I expands them from
    /// keyframes kept on the GPU), and the member lists, which only
    /// [`Self::record_forward`] reads, are left as they are.
    pub fn record_offsets_at<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        regions: &Regions,
        first_row: u32,
    ) -> Result<()> {
        let pixels = regions.pixel_region.len() as u64;
        let rows = first_row as u64 + regions.len() as u64;
        if rows > self.max_regions as u64 || pixels > self.max_pixels {
            return Err(Error::bad_input(
                "regions to pool",
                format!(
                    "{} regions from row {first_row} over {pixels} pixels; region pooling was \
                     sized for {} over {}",
                    regions.len(),
                    self.max_regions,
                    self.max_pixels
                ),
            ));
        }
        rec.upload(&self.pixel_region, self.max_pixels * 4, &regions.offsets)?;
        self.regions.set(regions.len());
        self.first_row.set(first_row);
        self.pixels.set(pixels);
        self.member_pixels.set(regions.pixels.len() as u64);
        Ok(())
    }

    /// Records the mean query of every region of `query_image` (the
    /// rasterizer's 32-channel output for the batch) into [`Self::pooled`].
    pub fn record_forward<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        query_image: &'a Buffer,
    ) -> Result<()> {
        self.check_image(query_image)?;
        let (members, regions) = (self.member_pixels.get() as f64, self.regions() as f64);
        // A sum per member pixel and channel, a division per pooled value;
        // the members' indices and query rows read, the pooled rows written.
        rec.work_of_next(Work {
            flops: 32.0 * members + 128.0 * regions,
            bytes: 132.0 * members + 132.0 * regions + 4.0,
        });
        rec.dispatch_linear(
            &REGION_POOL,
            self.regions(),
            bind::RegionPoolBuffers {
                query: query_image,
                offsets: &self.offsets,
                pixels: &self.members,
                pooled: &self.pooled,
            },
            &push::RegionPool {
                regions: self.regions(),
                first_row: self.first_row.get(),
            },
        )
    }

    /// Records ∂L/∂query_image from ∂L/∂pooled (regions × 32); every pixel
    /// of the batch is written (0 outside the regions).
    pub fn record_backward<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        grad_pooled: &'a Buffer,
        grad_query_image: &'a Buffer,
    ) -> Result<()> {
        self.check_image(grad_query_image)?;
        grad_pooled.ensure_bytes(
            (self.first_row.get() + self.regions()) as u64 * QUERY_DIM as u64 * 4,
            "region pooling backward: pooled gradient",
        )?;
        let elems = self.pixels.get() * QUERY_DIM as u64;
        // A division per member pixel and channel; every pixel's region
        // read and its 32 gradients written, the pooled gradients read.
        rec.work_of_next(Work {
            flops: 128.0 * self.member_pixels.get() as f64,
            bytes: 132.0 * self.pixels.get() as f64 + 132.0 * self.regions() as f64 + 4.0,
        });
        rec.dispatch_linear(
            &REGION_POOL_BACKWARD,
            elems.div_ceil(256) as u32,
            bind::RegionPoolBackwardBuffers {
                grad_pooled,
                offsets: &self.offsets,
                pixel_region: &self.pixel_region,
                grad_query: grad_query_image,
            },
            &push::RegionPoolBackward {
                pixels: self.pixels.get() as u32,
                first_row: self.first_row.get(),
            },
        )
    }

    fn check_image(&self, image: &Buffer) -> Result<()> {
        image.ensure_bytes(
            self.pixels.get() * QUERY_DIM as u64 * 4,
            "region pooling: query image of the uploaded batch",
        )
    }
}

#[cfg(test)]
#[path = "pooling_tests.rs"]
mod tests;
