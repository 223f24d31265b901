//! How many Gaussians the GPU window can hold within a memory budget.
//!
//! Everything the mapper allocates on the GPU is either per Gaussian of the
//! window (parameters, gradients, Adam moments, the rasterizer's per-view
//! projection and tile-intersection buffers, staging for paging), per pixel
//! of a batch (images, their gradients, loss and pooling workspaces), or
//! fixed (the latent head). The window gets what the budget leaves after
//! the pixels and the head. The context enforces the budget on every
//! allocation, so an estimate that is too small fails loudly instead of
//! overrunning it.

use crate::splat::FIELD_WIDTHS;
use latentam_base::{Error, Result};

/// Tile intersections budgeted per visible (view, Gaussian) pair; the
/// demo and 7-Scenes runs average 2–3.
pub const INTERSECTIONS_PER_PAIR: u64 = 8;

/// Smallest window worth mapping with.
pub const MIN_WINDOW: u64 = 1024;

/// Bytes of one Gaussian's parameters.
pub fn gaussian_bytes() -> u64 {
    FIELD_WIDTHS.iter().sum::<u64>() * 4
}

/// GPU bytes each window row costs with batches of `views` views.
pub fn bytes_per_window_row(views: u64) -> u64 {
    let p = gaussian_bytes();
    // parameters + gradients + two Adam moments + staging for a full
    // write-back and a full fetch
    let per_gaussian = 4 * p + 2 * p + 8;
    // rasterizer, per (view, Gaussian) pair, with the 25 % growth headroom:
    // projections, rectangles, counts, offsets, keys, order, scan, and the
    // projection gradients (≈ 101 bytes), plus per tile intersection the
    // keys, pairs and the sorter's ping-pong buffers (16 bytes) and scan.
    let per_pair = (101 + INTERSECTIONS_PER_PAIR * 20) * 5 / 4;
    per_gaussian + views * per_pair
}

/// Bytes per window row of the largest single buffer that grows with the
/// window, when `views` views are rendered at once: the query field (and
/// its gradient, moments and paging copies), or the rasterizer's
/// per-(view, Gaussian) splats and tile intersections with their growth
/// headroom. A window larger than the device's largest buffer divided by
/// this could not be bound.
pub fn largest_row_bytes(views: u64) -> u64 {
    let field = FIELD_WIDTHS.iter().max().copied().unwrap_or(1) * 4;
    let per_pair = (32u64).max(INTERSECTIONS_PER_PAIR * 4) * 5 / 4;
    field.max(views * per_pair)
}

/// GPU bytes per pixel of a chunk of views: colour + depth and alpha with
/// their gradients, blending state with growth headroom, target, region
/// lists. The 32 query channels have no per-pixel buffer in mapping: the
/// rasterizer pools them into region rows, and their gradients come back
/// from those rows.
pub const BYTES_PER_CHUNK_PIXEL: u64 = 2 * (16 + 4) + 10 + 16 + 8;

/// A per-pixel query image (32 channels), allocated only by renders that
/// return per-pixel queries (evaluation, relevance images), one view at a
/// time.
pub const QUERY_IMAGE_BYTES_PER_PIXEL: u64 = 128;

/// GPU bytes per pixel of a view for the SSIM workspaces (reused by every
/// view of a chunk).
pub const SSIM_BYTES_PER_PIXEL: u64 = 132;

/// GPU bytes that scale with the pixels of a batch rendered `views` views
/// at a time; `query_images`: Stage I renders each view's query image
/// (feature gradients attached to the geometry).
pub fn pixel_bytes(view_pixels: u64, views: u64, query_images: bool) -> u64 {
    let query = if query_images {
        QUERY_IMAGE_BYTES_PER_PIXEL
    } else {
        0
    };
    view_pixels * (views * (BYTES_PER_CHUNK_PIXEL + query) + SSIM_BYTES_PER_PIXEL)
}

/// GPU bytes of a latent head with `atoms` atoms of `dim` dimensions
/// (D, D⁰, its gradient and Adam moments, k-means workspace, W and its
/// state, region buffers, the regions × atoms attention matrices and the
/// k-means similarity matrix).
pub fn head_bytes(atoms: u64, dim: u64, max_regions: u64) -> u64 {
    atoms * dim * 4 * 8
        + 32 * dim * 4 * 4
        + max_regions * dim * 4 * 6
        + max_regions * atoms * 4 * 4
        + atoms * atoms * 4 * 2
}

/// The window's share of a budget.
///
/// ```
/// use latentam_core::mapper::budget::{head_bytes, pixel_bytes, window_budget, MIN_WINDOW};
///
/// // 4 GiB for 640×480 views rendered 4 at a time and a 2000-atom, 512-d head.
/// let later = pixel_bytes(640 * 480, 4, false) + head_bytes(2000, 512, 2048);
/// let w = window_budget(4 << 30, 0, later, 4, u64::MAX)?;
/// assert!(w.capacity >= MIN_WINDOW && w.capacity <= w.buffer_limit_rows);
/// assert!(w.capacity * w.bytes_per_row <= w.budget - w.reserved);
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct WindowBudget {
    /// The whole GPU budget, bytes.
    pub budget: u64,
    /// Set aside for pixels, the latent head and what was already
    /// allocated.
    pub reserved: u64,
    /// Bytes per window row.
    pub bytes_per_row: u64,
    /// Window rows that fit.
    pub capacity: u64,
    /// Rows the device's largest buffer allows (see [`largest_row_bytes`]);
    /// `capacity` never exceeds it.
    pub buffer_limit_rows: u64,
}

/// Sizes the window: `in_use` bytes are already allocated (e.g. the
/// latent head), `later` bytes will be (pixel buffers, a head not yet
/// created); 10 % of the rest is kept free for allocator granularity. The
/// window also stays within what one buffer of `max_buffer` bytes can hold.
pub fn window_budget(
    budget: u64,
    in_use: u64,
    later: u64,
    views: u64,
    max_buffer: u64,
) -> Result<WindowBudget> {
    let reserved = in_use + later;
    let bytes_per_row = bytes_per_window_row(views);
    let free = budget.saturating_sub(reserved) / 10 * 9;
    let buffer_limit_rows = max_buffer / largest_row_bytes(views);
    let capacity = (free / bytes_per_row).min(buffer_limit_rows);
    if capacity < MIN_WINDOW {
        if buffer_limit_rows < MIN_WINDOW {
            return Err(Error::Unsupported(format!(
                "the device's largest buffer ({max_buffer} bytes) holds {buffer_limit_rows} \
                 Gaussians of the window; at least {MIN_WINDOW} are needed"
            )));
        }
        // The budget that leaves the smallest window, 10 % kept free.
        let needed = reserved + (MIN_WINDOW * bytes_per_row).div_ceil(9) * 10;
        return Err(Error::budget(
            "gpu_budget",
            format!(
                "a GPU budget of {budget} bytes leaves room for {capacity} Gaussians in the \
                 window ({reserved} bytes go to images and the latent head, {bytes_per_row} per \
                 Gaussian); at least {MIN_WINDOW} are needed: set gpu_budget to at least \
                 {needed} (or lower the image size or the dictionary size `atoms`)"
            ),
        ));
    }
    Ok(WindowBudget {
        budget,
        reserved,
        bytes_per_row,
        capacity,
        buffer_limit_rows,
    })
}

/// Peak GPU bytes by part of the mapper, from the per-category peaks of
/// the context's accounting (each part's peak; they may have peaked at
/// different times, so their sum can exceed the overall peak).
///
/// ```
/// use latentam_gpu::{ByteCount, MemoryReport};
/// use latentam_core::mapper::budget::MemorySplit;
///
/// // Normally `ctx.memory_report()` after a run.
/// let mut report = MemoryReport::default();
/// report.by_category.insert("pixels".into(), ByteCount { current: 0, peak: 64 << 20 });
/// report.by_category.insert("decoder".into(), ByteCount { current: 8 << 20, peak: 8 << 20 });
/// let split = MemorySplit::of(&report);
/// assert_eq!((split.images, split.latent_head, split.window), (64 << 20, 8 << 20, 0));
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MemorySplit {
    /// Per-pixel buffers of the chunk of views being rendered: colour,
    /// depth and alpha images, their gradients, blending state, targets,
    /// loss and pooling workspaces (category `pixels`).
    pub images: u64,
    /// Per-pixel feature buffers: rendered query images (category
    /// `features`); none for a map without embeddings.
    pub features: u64,
    /// The latent head: W, the dictionary, its anchor and Adam state,
    /// k-means and decoder workspaces.
    pub latent_head: u64,
    /// Everything sized by the window: its Gaussians, their gradients and
    /// Adam moments, the rasterizer's per-(view, Gaussian) buffers, sort
    /// workspaces and paging scratch.
    pub window: u64,
    /// Host-visible staging for uploads and read-backs.
    pub staging: u64,
}

impl MemorySplit {
    /// The split of `report`.
    pub fn of(report: &latentam_gpu::MemoryReport) -> Self {
        let mut split = Self::default();
        for (category, bytes) in &report.by_category {
            let part = match category.as_str() {
                "pixels" => &mut split.images,
                "features" => &mut split.features,
                "latent" | "decoder" | "kmeans" | "head" | "trust_region" | "feature_loss"
                | "relevance" => &mut split.latent_head,
                "staging" | "warm-up" => &mut split.staging,
                _ => &mut split.window,
            };
            *part += bytes.peak;
        }
        split
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capacity_shrinks_with_views_and_reservations() {
        let big = u64::MAX;
        let a = window_budget(1 << 30, 0, 0, 1, big).unwrap();
        let b = window_budget(1 << 30, 0, 0, 6, big).unwrap();
        let c = window_budget(1 << 30, 1 << 29, 0, 6, big).unwrap();
        assert!(a.capacity > b.capacity && b.capacity > c.capacity);
        assert!(b.capacity * b.bytes_per_row <= (1 << 30));
        let err = window_budget(1 << 20, 0, 0, 6, big).unwrap_err();
        // A budget the caller set, which it can raise.
        assert!(
            matches!(&err, Error::Budget { budget, .. } if budget == "gpu_budget"),
            "{err:?}"
        );
        let err = err.to_string();
        // The budget the error names is enough.
        let needed: u64 = err
            .split("set gpu_budget to at least ")
            .nth(1)
            .and_then(|s| s.split(' ').next())
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("{err}"));
        assert!(window_budget(needed, 0, 0, 6, big).unwrap().capacity >= MIN_WINDOW);
        assert!(window_budget(1 << 20, 1 << 21, 0, 6, big).is_err());
    }

    #[test]
    fn capacity_stays_within_the_largest_buffer() {
        // A large budget on a device binding 128 MiB: the query field
        // (128 bytes a row) bounds the window with one view at a time, the
        // per-view splats and intersections with six.
        let limit = 128 << 20;
        let one = window_budget(64 << 30, 0, 0, 1, limit).unwrap();
        assert_eq!(one.capacity, limit / 128);
        assert_eq!(one.buffer_limit_rows, one.capacity);
        let six = window_budget(64 << 30, 0, 0, 6, limit).unwrap();
        assert_eq!(six.capacity, limit / largest_row_bytes(6));
        assert!(six.capacity * 6 * 40 <= limit);
        // A small budget is still the tighter bound.
        let small = window_budget(1 << 28, 0, 0, 1, limit).unwrap();
        assert!(small.capacity < small.buffer_limit_rows);
    }
}
