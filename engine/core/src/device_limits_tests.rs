//! The mapper's sizes on the GPUs robots carry, from their drivers'
//! reports (`latentam_gpu::testing::devices`): the window a default
//! budget gives at 640×480 and 1280×720, the per-pixel decoder's batches
//! and their GEMMs, and the rasterizer's query image. The kernel variants
//! are checked in `splat/rasterizer/variants.rs`, the device-level limits
//! in `latentam-gpu`.

use latentam_gpu::ops::{Gemm, Transpose};
use latentam_gpu::testing::devices::recorded_devices;

use crate::latent::DevicePixelDecoder;
use crate::mapper::budget::{head_bytes, pixel_bytes, window_budget, MIN_WINDOW};
use crate::mapper::MapperConfig;
use crate::mapper::{views_per_chunk, DEFAULT_CHUNK_PIXELS};
use crate::splat::QUERY_DIM;

const CAMERAS: [(u64, u64); 2] = [(640, 480), (1280, 720)];

#[test]
fn the_default_budget_gives_every_device_a_window_of_a_million_within_one_buffer() {
    let cfg = MapperConfig::default();
    for d in recorded_devices() {
        let info = &d.info;
        // The default budget: half the largest device-local heap.
        let budget = info.device_local_bytes / 2;
        for (w, h) in CAMERAS {
            let pixels = w * h;
            let views = views_per_chunk(pixels, cfg.replay + 1, DEFAULT_CHUNK_PIXELS) as u64;
            let head = head_bytes(cfg.atoms as u64, 768, cfg.max_regions as u64);
            let later = pixel_bytes(pixels, views, cfg.attach_feature_gradients);
            let sized = window_budget(budget, head, later, views, info.max_buffer_bytes())
                .unwrap_or_else(|e| panic!("{} at {w}x{h}: {e}", d.label));
            assert!(sized.capacity >= MIN_WINDOW);
            assert!(sized.capacity <= sized.buffer_limit_rows, "{}", d.label);
            assert!(
                sized.reserved + sized.capacity * sized.bytes_per_row <= budget,
                "{} at {w}x{h}: the window overruns the budget",
                d.label
            );
            // An 8 GB board still holds a million Gaussians in view (a
            // 7-Scenes kitchen keeps under 200 000 there).
            assert!(
                sized.capacity >= 1_000_000,
                "{} at {w}x{h}: {} Gaussians",
                d.label,
                sized.capacity
            );
        }
    }
}

#[test]
fn decoding_batches_and_their_products_fit_every_device() {
    for d in recorded_devices() {
        let info = &d.info;
        for (atoms, dim, texts) in [
            (5u32, 24u32, 10u64),
            (405, 384, 100),
            (2000, 768, 1000),
            (8000, 1280, 1000),
        ] {
            let stride = atoms.next_multiple_of(4);
            let rows = DevicePixelDecoder::batch_rows_within(info.max_buffer_bytes(), stride, dim)
                .unwrap_or_else(|e| panic!("{}: {e}", d.label));
            assert!(rows >= 1024, "{}: {rows} pixels a batch", d.label);
            for buffer in [
                rows as u64 * stride as u64,
                rows as u64 * dim as u64,
                rows as u64 * texts,
            ] {
                assert!(buffer * 4 <= info.max_buffer_bytes(), "{}", d.label);
            }
            let products = [
                (rows, stride, QUERY_DIM as u32, Transpose::None),
                (rows, dim, stride, Transpose::None),
                (rows, texts as u32, dim, Transpose::B),
            ];
            for (m, n, k, transpose) in products {
                let gemm = Gemm {
                    transpose,
                    m,
                    n,
                    k,
                    alpha: 1.0,
                    beta: 0.0,
                };
                let groups = gemm.groups();
                for axis in 0..3 {
                    assert!(
                        groups[axis] <= info.max_workgroup_count[axis],
                        "{}: GEMM {m}x{n}x{k} needs {groups:?} workgroups",
                        d.label
                    );
                }
            }
        }
    }
}

#[test]
fn one_query_image_band_holds_a_whole_batch_of_views() {
    let cfg = MapperConfig::default();
    // A pixel's 32 query channels (the rasterizer splits the query image
    // into bands of what one buffer holds; on these devices one band holds
    // the whole batch).
    let query_bytes = QUERY_DIM as u64 * 4;
    for d in recorded_devices() {
        for (w, h) in CAMERAS {
            let views = views_per_chunk(w * h, cfg.replay + 1, DEFAULT_CHUNK_PIXELS) as u64;
            let band = d.info.max_buffer_bytes() / query_bytes;
            assert!(
                band >= w * h * views,
                "{} at {w}x{h}: bands of {band} pixels",
                d.label
            );
        }
    }
}
