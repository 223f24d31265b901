//! Region pooling (regions as in paper Sec. III-B): rendered per-pixel queries averaged over each
//! region of a view (a SAM-style mask or a coarse feature-grid cell), and the
//! gradient sent back to the pixels. A view's regions are counted on the
//! CPU once ([`RegionCounts`]: which are kept, their sizes), the rows of a
//! batch laid out from the counts ([`RegionRows`]), and the pixel lists
//! built where a caller needs them ([`Regions`]); the GPU side is
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

/// Where one view's regions come from, laid over the view: a label image
/// with `count` regions, or a feature grid of `rows × cols` cells (one
/// region per cell). View pixels take the cell under their centre.
#[derive(Clone, Copy, Debug)]
pub enum RegionSource<'a> {
    /// A label image with labels `0..count` ([`NO_REGION_LABEL`] for none).
    Labels {
        /// The labels.
        image: LabelImage<'a>,
        /// Regions in the image's message.
        count: u32,
    },
    /// A feature grid: cell (row, column) is region `row * cols + column`.
    Grid {
        /// Cell rows.
        rows: u32,
        /// Cell columns.
        cols: u32,
    },
}

impl RegionSource<'_> {
    /// Regions the source numbers (kept or not).
    pub fn count(&self) -> u32 {
        match self {
            RegionSource::Labels { count, .. } => *count,
            RegionSource::Grid { rows, cols } => rows * cols,
        }
    }

    /// Cells across and down.
    fn cells(&self) -> (u32, u32) {
        match self {
            RegionSource::Labels { image, .. } => (image.width, image.height),
            RegionSource::Grid { rows, cols } => (*cols, *rows),
        }
    }

    /// Region of cell (`row`, `col`), [`NO_REGION`] for none.
    fn region(&self, row: u32, col: u32) -> u32 {
        match self {
            RegionSource::Labels { image, .. } => {
                match image.labels[(row * image.width + col) as usize] {
                    NO_REGION_LABEL => NO_REGION,
                    l => l as u32,
                }
            }
            RegionSource::Grid { cols, .. } => row * cols + col,
        }
    }

    /// An error naming `view` when the source is malformed: an empty grid,
    /// a label image of the wrong length, or a label ≥ the count.
    fn check(&self, view: usize) -> Result<()> {
        match self {
            RegionSource::Grid { rows, cols } => {
                if *rows == 0 || *cols == 0 {
                    return Err(Error::bad_input(
                        format!("view {view}"),
                        format!("feature grid of {rows}x{cols} cells"),
                    ));
                }
            }
            RegionSource::Labels { image, count } => {
                if image.width == 0
                    || image.height == 0
                    || image.labels.len() as u64 != image.width as u64 * image.height as u64
                {
                    return Err(Error::bad_input(
                        "label image",
                        format!(
                            "{}x{} with {} labels",
                            image.width,
                            image.height,
                            image.labels.len()
                        ),
                    ));
                }
                if let Some(&bad) = image
                    .labels
                    .iter()
                    .find(|&&l| l != NO_REGION_LABEL && l as u32 >= *count)
                {
                    return Err(Error::bad_input(
                        format!("view {view}"),
                        format!("region label {bad} but the message has {count} regions"),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// One view's regions, counted: which regions of its source are kept
/// (they cover at least the minimum of pixels) and how many pixels each
/// covers. It depends on the source, the view's size and the minimum only,
/// not on the batch the view trains in, so Stage I counts a keyframe's
/// regions once and keeps the counts for its replays.
///
/// Counting costs one step per source cell, not per pixel: the cell under
/// a pixel is separable (its column from the pixel's column, its row from
/// the pixel's row), so a cell covers (pixel rows onto its row) × (pixel
/// columns onto its column) pixels.
///
/// ```
/// use latentam_core::latent::{RegionCounts, RegionSource};
///
/// // A 2×2 grid over an 8×6 view: four regions of 4×3 pixels.
/// let counts = RegionCounts::of(RegionSource::Grid { rows: 2, cols: 2 }, 8, 6, 10)?;
/// assert_eq!(counts.sources, [0, 1, 2, 3]);
/// assert_eq!(counts.sizes, [12, 12, 12, 12]);
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RegionCounts {
    /// The view's columns.
    pub width: u32,
    /// The view's rows.
    pub height: u32,
    /// The kept regions' indices in the source, in increasing order: the
    /// view's pooled rows, in this order.
    pub sources: Vec<u32>,
    /// Pixels of each kept region.
    pub sizes: Vec<u32>,
    /// Regions with fewer pixels than the minimum (ignored).
    pub too_small: u32,
    /// Regions that cover no pixel of the view.
    pub empty: u32,
}

impl RegionCounts {
    /// The regions of `source` laid over a `width × height` view, kept when
    /// they cover at least `min_pixels` pixels (at least 1). A malformed
    /// source is an error.
    pub fn of(source: RegionSource, width: u32, height: u32, min_pixels: u32) -> Result<Self> {
        source.check(0)?;
        Ok(Self::counted(source, width, height, min_pixels))
    }

    /// [`Self::of`] for a source already checked.
    fn counted(source: RegionSource, width: u32, height: u32, min_pixels: u32) -> Self {
        let count = source.count();
        let (cells_x, cells_y) = source.cells();
        let spans = |n: u32, m: u32| {
            let mut per_cell = vec![0u32; m as usize];
            for i in 0..n {
                per_cell[nearest(i, n, m) as usize] += 1;
            }
            per_cell
        };
        let (per_col, per_row) = (spans(width, cells_x), spans(height, cells_y));
        let mut sizes = vec![0u64; count as usize];
        for (row, &rows) in per_row.iter().enumerate().filter(|(_, &n)| n > 0) {
            for (col, &cols) in per_col.iter().enumerate().filter(|(_, &n)| n > 0) {
                let r = source.region(row as u32, col as u32);
                if r != NO_REGION {
                    sizes[r as usize] += rows as u64 * cols as u64;
                }
            }
        }
        let mut out = RegionCounts {
            width,
            height,
            ..Default::default()
        };
        for (region, &size) in sizes.iter().enumerate() {
            if size == 0 {
                out.empty += 1;
            } else if size < min_pixels.max(1) as u64 {
                out.too_small += 1;
            } else {
                out.sources.push(region as u32);
                // At most the view's pixels, which a camera keeps below 2^32.
                out.sizes.push(size as u32);
            }
        }
        out
    }

    /// Calls `f(pixel, row)` for every pixel of the view in row-major order
    /// (`pixel` its index in the view), with `row` its kept region's row
    /// among [`Self::sources`] (from 0), [`NO_REGION`] for none. `source`
    /// must be the one counted (an error when its count differs or a label
    /// is out of range).
    pub fn for_each_pixel(&self, source: RegionSource, f: impl FnMut(usize, u32)) -> Result<()> {
        for_each_pixel_row(&self.sources, self.width, self.height, source, f)
    }
}

impl ViewRegions {
    /// [`RegionCounts::for_each_pixel`] for this view, of `width × height`
    /// pixels, with `source` the regions it was counted from; `row` is
    /// local to the view (its [`Self::first_row`] is 0).
    pub fn for_each_pixel(
        &self,
        width: u32,
        height: u32,
        source: RegionSource,
        f: impl FnMut(usize, u32),
    ) -> Result<()> {
        for_each_pixel_row(&self.sources, width, height, source, f)
    }
}

/// Calls `f(pixel, row)` for the pixels of a `width × height` view in
/// row-major order, `row` the index among `sources` (kept regions, in
/// increasing order) of the region of `source` under the pixel's centre,
/// [`NO_REGION`] for none.
fn for_each_pixel_row(
    sources: &[u32],
    width: u32,
    height: u32,
    source: RegionSource,
    f: impl FnMut(usize, u32),
) -> Result<()> {
    source.check(0)?;
    let count = source.count();
    if let Some(&last) = sources.last().filter(|&&s| s >= count) {
        return Err(Error::bad_input(
            "region source",
            format!("{count} regions, but region {last} was counted"),
        ));
    }
    each_pixel_row(sources, width, height, source, f);
    Ok(())
}

/// [`for_each_pixel_row`] for a source already checked against `sources`.
fn each_pixel_row(
    sources: &[u32],
    width: u32,
    height: u32,
    source: RegionSource,
    mut f: impl FnMut(usize, u32),
) {
    let mut row_of = vec![NO_REGION; source.count() as usize];
    for (row, &s) in sources.iter().enumerate() {
        row_of[s as usize] = row as u32;
    }
    let (cells_x, cells_y) = source.cells();
    let columns: Vec<u32> = (0..width).map(|u| nearest(u, width, cells_x)).collect();
    let mut pixel = 0;
    for v in 0..height {
        let cell_row = nearest(v, height, cells_y);
        for &cell_col in &columns {
            let r = source.region(cell_row, cell_col);
            f(
                pixel,
                if r == NO_REGION {
                    NO_REGION
                } else {
                    row_of[r as usize]
                },
            );
            pixel += 1;
        }
    }
}

/// The pooled rows of a batch of views, without their pixels: each row's
/// pixel count (as CSR offsets) and each view's rows. What Stage I keeps
/// on the host for a chunk, where the pixels' rows are expanded on the GPU
/// (see [`RegionPooling::record_offsets_at`]); [`Regions`] adds the pixel
/// lists.
///
/// ```
/// use latentam_core::latent::{RegionCounts, RegionRows, RegionSource};
/// use latentam_core::splat::{BatchLayout, Camera};
///
/// let layout = BatchLayout::for_cameras(&[Camera::at_origin(8, 6); 2])?;
/// let grid = RegionCounts::of(RegionSource::Grid { rows: 2, cols: 2 }, 8, 6, 1)?;
/// let mut rows = RegionRows::new(&layout);
/// rows.add(1, &grid)?; // the second view only
/// assert_eq!(rows.offsets(), &[0, 12, 24, 36, 48]);
/// assert_eq!(rows.rows_per_view(), [0, 4]);
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct RegionRows {
    layout: BatchLayout,
    offsets: Vec<u32>,
    views: Vec<ViewRegions>,
}

impl RegionRows {
    /// No rows yet for the views of `layout`.
    pub fn new(layout: &BatchLayout) -> Self {
        RegionRows {
            layout: layout.clone(),
            offsets: vec![0],
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

    /// CSR offsets: row r covers `offsets[r]..offsets[r + 1]` of the
    /// member pixels, grouped by row.
    pub fn offsets(&self) -> &[u32] {
        &self.offsets
    }

    /// Pixels in kept regions over all views.
    pub fn members(&self) -> u64 {
        *self.offsets.last().unwrap_or(&0) as u64
    }

    /// The batch's layout.
    pub fn layout(&self) -> &BatchLayout {
        &self.layout
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

    /// Where view `view` lies in the batch; an error for a view the batch
    /// does not have.
    fn slot(&self, view: usize) -> Result<crate::splat::ViewSlot> {
        self.layout.views.get(view).copied().ok_or_else(|| {
            Error::bad_input(
                format!("regions for view {view}"),
                format!("the batch has {} views", self.layout.views.len()),
            )
        })
    }

    /// Adds view `view`'s counted regions as the next rows. Views must be
    /// added in increasing order, and the counts must be of the view's
    /// size; otherwise an error, and nothing changes.
    pub fn add(&mut self, view: usize, counts: &RegionCounts) -> Result<&ViewRegions> {
        let slot = self.slot(view)?;
        if self.views.last().is_some_and(|v| v.view >= view) {
            return Err(Error::bad_input(
                format!("regions for view {view}"),
                format!(
                    "added after view {}; add views in order, once each",
                    self.views.last().map_or(0, |v| v.view)
                ),
            ));
        }
        if (counts.width, counts.height) != (slot.width, slot.height)
            || counts.sizes.len() != counts.sources.len()
        {
            return Err(Error::bad_input(
                format!("regions for view {view}"),
                format!(
                    "counted over {}x{} pixels with {} sizes for {} regions; the view is {}x{}",
                    counts.width,
                    counts.height,
                    counts.sizes.len(),
                    counts.sources.len(),
                    slot.width,
                    slot.height
                ),
            ));
        }
        let first_row = self.len();
        let mut end = self.members();
        for &size in &counts.sizes {
            end += size as u64;
            self.offsets.push(end as u32);
        }
        self.views.push(ViewRegions {
            view,
            first_row,
            sources: counts.sources.clone(),
            too_small: counts.too_small,
            empty: counts.empty,
        });
        Ok(self.views.last().expect("just pushed"))
    }
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
    rows: RegionRows,
    min_pixels: u32,
    pixels: Vec<u32>,
    pixel_region: Vec<u32>,
}

impl Regions {
    /// No regions yet for the views of `layout`; regions with fewer than
    /// `min_pixels` pixels (at least 1) will be ignored and counted.
    pub fn new(layout: &BatchLayout, min_pixels: u32) -> Self {
        Self {
            rows: RegionRows::new(layout),
            min_pixels: min_pixels.max(1),
            pixels: Vec::new(),
            pixel_region: vec![NO_REGION; layout.pixels as usize],
        }
    }

    /// The rows without their pixels.
    pub fn rows(&self) -> &RegionRows {
        &self.rows
    }

    /// Pooled rows (kept regions) over all views.
    pub fn len(&self) -> u32 {
        self.rows.len()
    }

    /// Whether no region was kept.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// CSR offsets: region r owns `pixels()[offsets[r]..offsets[r + 1]]`.
    pub fn offsets(&self) -> &[u32] {
        self.rows.offsets()
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
        self.rows.views()
    }

    /// Pooled rows per view of the layout (0 for views without regions), as
    /// [`crate::loss::mean_per_view_weights`] takes them.
    pub fn rows_per_view(&self) -> Vec<u32> {
        self.rows.rows_per_view()
    }

    /// Adds the regions of view `view` from a label image with `count`
    /// regions (labels 0..count). Views must be added in increasing order.
    /// A label ≥ `count` or a label image of the wrong length is an error,
    /// and leaves the regions unchanged.
    pub fn add_labels(&mut self, view: usize, img: LabelImage, count: u32) -> Result<&ViewRegions> {
        self.add(view, RegionSource::Labels { image: img, count })
    }

    /// Adds view `view`'s regions from a feature grid of `rows × cols`
    /// cells laid over it (cell index = row * cols + col).
    pub fn add_grid(&mut self, view: usize, rows: u32, cols: u32) -> Result<&ViewRegions> {
        self.add(view, RegionSource::Grid { rows, cols })
    }

    /// Adds view `view`'s regions from `source`; on an error nothing
    /// changes.
    pub fn add(&mut self, view: usize, source: RegionSource) -> Result<&ViewRegions> {
        source.check(view)?;
        let slot = self.rows.slot(view)?;
        let counts = RegionCounts::counted(source, slot.width, slot.height, self.min_pixels);
        let first_row = self.rows.add(view, &counts)?.first_row;
        // Counting sort of the view's pixels by row: each row's pixels
        // follow the offsets, in the view's row-major order.
        let mut next: Vec<u32> =
            self.rows.offsets[first_row as usize..self.rows.offsets.len() - 1].to_vec();
        self.pixels.resize(self.rows.members() as usize, 0);
        let (pixels, pixel_region) = (&mut self.pixels, &mut self.pixel_region);
        each_pixel_row(
            &counts.sources,
            slot.width,
            slot.height,
            source,
            |i, row| {
                if row != NO_REGION {
                    let p = slot.first_pixel as u32 + i as u32;
                    let at = &mut next[row as usize];
                    pixels[*at as usize] = p;
                    *at += 1;
                    pixel_region[p as usize] = first_row + row;
                }
            },
        );
        Ok(self.rows.views.last().expect("just added"))
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
        self.record_offsets_at(rec, regions.rows(), first_row)?;
        rec.upload(&self.offsets, 0, regions.offsets())?;
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
        regions: &RegionRows,
        first_row: u32,
    ) -> Result<()> {
        let pixels = regions.layout().pixels;
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
        rec.upload(&self.pixel_region, self.max_pixels * 4, regions.offsets())?;
        self.regions.set(regions.len());
        self.first_row.set(first_row);
        self.pixels.set(pixels);
        self.member_pixels.set(regions.members());
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
