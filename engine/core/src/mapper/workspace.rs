//! Sizing the GPU workspace at the first keyframe, when the image size is
//! known: how many Gaussians the window holds within the GPU budget once
//! the trainer's per-pixel buffers and the latent head have their room.

use super::budget::{
    bytes_per_window_row, head_bytes, largest_row_bytes, pixel_bytes, window_budget, WindowBudget,
};
use super::config::MapperConfig;
use super::trainer::{kept_target_bytes, views_per_chunk, TrainerConfig, DEFAULT_CHUNK_PIXELS};
use latentam_base::{Error, Result};
use latentam_gpu::Context;

/// The GPU bytes a map on `ctx` may use: `gpu_budget`, or half the
/// device's local memory.
pub(crate) fn gpu_budget(ctx: &Context, cfg: &MapperConfig) -> u64 {
    cfg.gpu_budget
        .unwrap_or(ctx.info().device_local_bytes / 2)
        .max(1)
}

/// The window's size and the trainer's for views of `pixels` pixels.
/// `dim` is the embedding dimension the head has or will have, `None`
/// when no embeddings were seen yet; `has_head` says whether the head's
/// memory is allocated already.
pub(crate) fn size_workspace(
    ctx: &Context,
    cfg: &MapperConfig,
    pixels: u64,
    dim: Option<u32>,
    has_head: bool,
) -> Result<(WindowBudget, TrainerConfig)> {
    // Stage I renders its batch a chunk of views at a time: the pixel
    // buffers and the rasterizer's per-view buffers are sized for one
    // chunk, whatever the number of replayed keyframes.
    let views = views_per_chunk(pixels, cfg.replay + 1, DEFAULT_CHUNK_PIXELS) as u64;
    let budget = gpu_budget(ctx, cfg);
    // The head is created after the workspace, from this keyframe's
    // embeddings; one created later (embeddings arriving after the first
    // keyframes) must still fit: room for a 1024-d one is kept.
    let later_head = match has_head {
        true => 0,
        false => head_bytes(
            cfg.atoms as u64,
            dim.unwrap_or(1024) as u64,
            cfg.max_regions as u64,
        ),
    };
    // Replayed keyframes' targets kept on the GPU: as many as asked, within
    // a thirty-second of the budget and one buffer (one slot always exists:
    // every target is expanded from one).
    let slot = kept_target_bytes(pixels);
    let max_buffer = ctx.info().max_buffer_bytes();
    let room = (budget / 32).min(max_buffer) / slot;
    let kept_views = cfg.replay_on_gpu.min(room.min(u32::MAX as u64) as u32);
    let in_use = ctx.memory_report().total.current;
    let later = pixel_bytes(pixels, views, cfg.attach_feature_gradients)
        + later_head
        + kept_views.max(1) as u64 * slot;
    let sized = match cfg.window_capacity {
        Some(capacity) => {
            let buffer_limit_rows = max_buffer / largest_row_bytes(views);
            if capacity > buffer_limit_rows {
                return Err(Error::config(
                    "window_capacity",
                    format!(
                        "{capacity}, but {} can hold at most {buffer_limit_rows} Gaussians in \
                         one buffer ({max_buffer} bytes); lower window_capacity",
                        ctx.info().name
                    ),
                ));
            }
            WindowBudget {
                budget,
                reserved: in_use + later,
                bytes_per_row: bytes_per_window_row(views),
                capacity,
                buffer_limit_rows,
            }
        }
        None => window_budget(budget, in_use, later, views, max_buffer)?,
    };
    log::info!(
        "window: {} Gaussians ({} bytes each) in a GPU budget of {} bytes",
        sized.capacity,
        sized.bytes_per_row,
        budget
    );
    let trainer = TrainerConfig {
        capacity: sized.capacity,
        max_view_pixels: pixels,
        max_views: cfg.replay + 1,
        chunk_pixels: DEFAULT_CHUNK_PIXELS,
        max_regions: cfg.max_regions,
        min_region_pixels: cfg.min_region_pixels,
        weights: cfg.weights,
        learning_rates: cfg.learning_rates,
        attach_feature_gradients: cfg.attach_feature_gradients,
        blend_layout: cfg.blend_layout,
        kept_views,
    };
    Ok((sized, trainer))
}
