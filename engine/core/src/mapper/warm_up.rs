//! Kernel compilation kept out of the first keyframe.

/// Creates ahead of time the pipeline of every kernel mapping dispatches on
/// `ctx`'s device, so that no keyframe pays for compiling one: all kernels
/// but the rasterizer's blending variants meant for other devices (see
/// [`crate::splat::Rasterizer::blend_kernel_names`]). Returns the number of
/// pipelines ready.
///
/// ```
/// let ctx = latentam_gpu::Context::new(Default::default())?;
/// assert!(latentam_core::mapper::warm_up(&ctx)? < latentam_shaders::ALL.len());
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub fn warm_up(ctx: &latentam_gpu::Context) -> crate::Result<usize> {
    use crate::splat::{Rasterizer, RenderSettings};
    // The trainer's and the evaluator's settings: the defaults.
    let used = Rasterizer::blend_kernel_names(ctx.info(), &RenderSettings::default());
    ctx.warm_up_only(|k| !k.name.starts_with("raster_") || used.contains(&k.name))
}
