//! Which variant of each blending kernel a device runs: one table for the
//! dispatches and for `Rasterizer::blend_kernel_names`. The kernels'
//! `@select` lines generate the selectors, so every combination of flags
//! names a kernel that exists.

use latentam_base::Result;
use latentam_gpu::{DeviceInfo, Recorder};
use latentam_shaders::{
    bind, push, KernelDef, RasterBackwardVariant, RasterForwardVariant, RasterPoolVariant,
};

use super::{BlendLayout, Channels, RenderSettings};

/// Whether the blending kernels map a tile's pixels to columns on this
/// device (see [`BlendLayout`]).
fn columns(info: &DeviceInfo, settings: &RenderSettings) -> bool {
    settings.layout.resolve(info.device_type) == BlendLayout::Columns
}

pub(super) fn forward_kernel(
    info: &DeviceInfo,
    settings: &RenderSettings,
    channels: Channels,
) -> &'static KernelDef<push::RasterForward, bind::RasterForward> {
    RasterForwardVariant {
        columns: columns(info, settings),
        query: channels == Channels::All,
    }
    .kernel()
}

pub(super) fn backward_kernel(
    info: &DeviceInfo,
    settings: &RenderSettings,
) -> &'static KernelDef<push::RasterBackward, bind::RasterBackward> {
    let columns = columns(info, settings);
    // The column kernels sum each 8 of a tile's 16 invocations with a
    // shuffle butterfly, which needs those 8 to be exactly one subgroup.
    let subgroup = if columns {
        info.subgroup_shuffle && info.subgroup_size == 8
    } else {
        info.subgroup_arithmetic
    };
    RasterBackwardVariant {
        columns,
        // Only the column kernels have a variant that also takes the query
        // gradients (the pixel ones always do).
        attached: !settings.detach_query_gradients,
        subgroup,
        cas: !info.native_float_atomics,
    }
    .kernel()
}

pub(super) fn pool_kernel(
    info: &DeviceInfo,
    settings: &RenderSettings,
) -> &'static KernelDef<push::RasterPool, bind::RasterPool> {
    RasterPoolVariant {
        columns: columns(info, settings),
        // The column kernel sums without subgroup operations.
        subgroup: info.subgroup_arithmetic,
        cas: !info.native_float_atomics,
    }
    .kernel()
}

/// The variant `pick` chooses for `settings`, unless it is a column
/// variant the driver cannot build: then the pixel one (the pipeline cache
/// warns once, when the build fails). Column variants keep a tile column's pixels in
/// registers, and the largest of them can exceed what a GPU's compiler
/// accepts (NVIDIA's 580 driver rejects the attached ones without
/// subgroups); every device builds the pixel variants, and the two
/// layouts read and write the same per-pixel buffers, so they mix.
pub(super) fn buildable<P, B>(
    rec: &Recorder<'_>,
    settings: &RenderSettings,
    pick: impl Fn(&RenderSettings) -> &'static KernelDef<P, B>,
) -> Result<&'static KernelDef<P, B>> {
    let chosen = pick(settings);
    if !columns(rec.info(), settings) || rec.kernel_builds(&chosen.kernel)? {
        return Ok(chosen);
    }
    Ok(pick(&RenderSettings {
        layout: BlendLayout::Pixels,
        ..*settings
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam_gpu::testing::devices::recorded_devices;

    /// On the GPUs robots carry, every blending kernel the rasterizer picks
    /// is one the device runs: pixels by default, subgroups where the
    /// device offers them in compute, compare-and-swap where it has no
    /// float atomic add (the RX 6600), in either layout and with query
    /// gradients attached or not.
    #[test]
    fn every_recorded_device_runs_the_blending_kernels_chosen_for_it() {
        for d in recorded_devices() {
            let info = &d.info;
            assert_eq!(
                BlendLayout::Auto.resolve(info.device_type),
                BlendLayout::Pixels,
                "{}",
                d.label
            );
            for layout in [BlendLayout::Auto, BlendLayout::Pixels, BlendLayout::Columns] {
                for detach_query_gradients in [true, false] {
                    let s = RenderSettings {
                        layout,
                        detach_query_gradients,
                        ..RenderSettings::default()
                    };
                    let kernels = [
                        &forward_kernel(info, &s, Channels::All).kernel,
                        &forward_kernel(info, &s, Channels::Colour).kernel,
                        &backward_kernel(info, &s).kernel,
                        &pool_kernel(info, &s).kernel,
                    ];
                    for k in kernels {
                        assert!(
                            info.can_run(k),
                            "{}: {layout:?} picks `{}`",
                            d.label,
                            k.name
                        );
                    }
                }
            }
            let pixel = backward_kernel(info, &RenderSettings::default())
                .kernel
                .name;
            assert_eq!(
                pixel.contains("cas"),
                !info.native_float_atomics,
                "{}: `{pixel}`",
                d.label
            );
            assert_eq!(
                !pixel.contains("plain"),
                info.subgroup_arithmetic,
                "{}: `{pixel}`",
                d.label
            );
        }
    }
}
