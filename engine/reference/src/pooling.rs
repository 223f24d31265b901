//! Region pooling of rendered queries (kernels
//! `glsl/region_pool.comp`, `glsl/region_pool_backward.comp`).
//! Per region r: `Q_r = (1/|r|) Σ_{p∈r} Q(p)`; backward, each pixel of r gets
//! `∂L/∂Q_r / |r|`. The paper mask-pools the target embeddings over these
//! regions (paper Sec. III-B, after Eq. 4); the queries are pooled likewise.

/// Mean of `channels`-wide pixel vectors over each region:
/// `pooled[r] = (1/|r|) Σ_{p∈r} image[p]`, with regions as CSR
/// (`offsets[r]..offsets[r+1]` index `pixels`).
pub fn pool(image: &[f32], channels: usize, offsets: &[u32], pixels: &[u32]) -> Vec<f64> {
    let regions = offsets.len().saturating_sub(1);
    let mut pooled = vec![0.0; regions * channels];
    for r in 0..regions {
        let members = &pixels[offsets[r] as usize..offsets[r + 1] as usize];
        for &p in members {
            for c in 0..channels {
                pooled[r * channels + c] += image[p as usize * channels + c] as f64;
            }
        }
        for c in 0..channels {
            pooled[r * channels + c] /= members.len() as f64;
        }
    }
    pooled
}

/// The adjoint of [`pool`]: each pixel of region r receives
/// `grad_pooled[r] / |r|`; pixels in no region receive 0. `image_pixels` is
/// the length of the image in pixels.
pub fn pool_backward(
    grad_pooled: &[f32],
    channels: usize,
    offsets: &[u32],
    pixels: &[u32],
    image_pixels: usize,
) -> Vec<f64> {
    let mut grad = vec![0.0; image_pixels * channels];
    for r in 0..offsets.len().saturating_sub(1) {
        let members = &pixels[offsets[r] as usize..offsets[r + 1] as usize];
        for &p in members {
            for c in 0..channels {
                grad[p as usize * channels + c] +=
                    grad_pooled[r * channels + c] as f64 / members.len() as f64;
            }
        }
    }
    grad
}
