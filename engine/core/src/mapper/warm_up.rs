//! Kernel builds kept out of the first keyframe: every kernel a mapper can
//! dispatch, for its configuration and device, is built (and run once, for
//! drivers that compile at first dispatch) before the mapper is ready.

use latentam_gpu::ops::GemmKernel;
use latentam_gpu::{Context, DeviceInfo};
use latentam_shaders::Kernel;

use super::{Mapper, MapperConfig};
use crate::splat::{BlendLayout, Rasterizer, RenderSettings};

/// Builds ahead of time every kernel a mapper with the default
/// configuration dispatches on `ctx`'s device (see [`Mapper::warm_up`]
/// for a mapper of another configuration). Returns the number of kernels
/// ready.
///
/// ```
/// let ctx = latentam_gpu::Context::new(Default::default())?;
/// assert!(latentam_core::mapper::warm_up(&ctx)? < latentam_shaders::ALL.len());
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub fn warm_up(ctx: &Context) -> crate::Result<usize> {
    build(ctx, &MapperConfig::default(), &mut |_, _| {})
}

impl Mapper {
    /// Builds every kernel this mapper can dispatch with its configuration
    /// on its device, so that no keyframe waits for one: pipelines are
    /// created on all cores, and each is run once empty, since some drivers
    /// (lavapipe) compile at first dispatch. Kernels already built cost
    /// nothing, so calling it again is cheap. [`Mapper::new`] calls it;
    /// call it after [`Mapper::with_context`] or [`Mapper::load`] before
    /// the first frame. Returns the number of kernels ready; the cost of
    /// each is in `Context::kernel_build_times`.
    ///
    /// ```no_run
    /// let ctx = latentam_gpu::Context::new(Default::default())?;
    /// let mapper = latentam_core::mapper::Mapper::load(&ctx, "runs/kitchen")?;
    /// mapper.warm_up()?;
    /// # Ok::<(), latentam_core::Error>(())
    /// ```
    pub fn warm_up(&self) -> crate::Result<usize> {
        // Callers without a progress line of their own (the live handle,
        // the ROS node, the Python and C bindings) see one in the log when
        // building takes long.
        let start = std::time::Instant::now();
        let mut said = start;
        self.warm_up_reporting(|built, of| {
            if said.elapsed().as_secs_f64() >= 5.0 {
                said = std::time::Instant::now();
                log::info!(
                    "building kernels ({built} of {of}), {:.0} s so far",
                    start.elapsed().as_secs_f64()
                );
            }
        })
    }

    /// [`Mapper::warm_up`], calling `progress(built, of)` after each kernel
    /// (on this thread): on a machine whose driver has never compiled the
    /// kernels this takes tens of seconds, worth a progress line.
    pub fn warm_up_reporting(
        &self,
        mut progress: impl FnMut(usize, usize),
    ) -> crate::Result<usize> {
        build(&self.ctx, &self.cfg, &mut progress)
    }
}

fn build(
    ctx: &Context,
    config: &MapperConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> crate::Result<usize> {
    let chosen = dispatched(ctx.info(), config, config.blend_layout);
    let mut ready = ctx.warm_up_reporting(|k| chosen.contains(&k.name), &mut *progress)?;
    // A GPU's compiler may reject a column-layout blending kernel (see
    // `Context::kernel_builds`); the rasterizer then takes the pixel
    // layout's, which must be ready too.
    let failed = ctx.kernel_build_failures();
    if failed.iter().any(|(name, _)| chosen.contains(name)) {
        let pixels = dispatched(ctx.info(), config, BlendLayout::Pixels);
        ready += ctx.warm_up_reporting(
            |k| pixels.contains(&k.name) && !chosen.contains(&k.name),
            progress,
        )?;
    }
    Ok(ready)
}

/// The names of the kernels a mapper with `config` can dispatch on `info`'s
/// device, its blending kernels taken in `layout`: every kernel of the
/// catalogue but the blending variants and matrix-product family meant for
/// other settings or devices, and the benchmarks' own probe.
fn dispatched(info: &DeviceInfo, config: &MapperConfig, layout: BlendLayout) -> Vec<&'static str> {
    // The trainer's settings (crate::mapper::trainer), whose forward
    // variants the evaluator's renders share.
    let settings = RenderSettings {
        layout,
        detach_query_gradients: !config.attach_feature_gradients,
        ..RenderSettings::default()
    };
    let blending = Rasterizer::blend_kernel_names(info, &settings);
    let gemm = GemmKernel::for_device(info.device_type);
    let wanted = |k: &Kernel| {
        if is_blending(k) {
            blending.contains(&k.name)
        } else if GemmKernel::Tiled.includes(k) || GemmKernel::Blocked.includes(k) {
            gemm.includes(k)
        } else {
            k.name != "fma_peak"
        }
    };
    latentam_shaders::ALL
        .iter()
        .filter(|k| wanted(k))
        .map(|k| k.name)
        .collect()
}

fn is_blending(k: &Kernel) -> bool {
    ["raster_forward", "raster_backward", "raster_pool"]
        .iter()
        .any(|family| k.name.starts_with(family))
}
