//! The backward pass against the f64 reference, on every device kind
//! lavapipe can play.

use super::*;

#[test]
fn backward_matches_reference() {
    with_context(|ctx| check_backward_vs_reference(ctx, "backward_matches_reference", true));
}

#[test]
fn backward_matches_reference_with_query_gradients_reaching_geometry() {
    with_context(|ctx| {
        check_backward_vs_reference(ctx, "backward_matches_reference_attached", false)
    });
}

#[test]
fn backward_matches_reference_with_cas_atomics() {
    with_cas_atomics(|ctx| {
        assert!(!ctx.info().native_float_atomics);
        check_backward_vs_reference(ctx, "backward_matches_reference_with_cas_atomics", true)
    });
}

/// A driver that cannot build the column-layout blending kernels (NVIDIA's
/// 580 driver cannot build the largest) gets the pixel ones: the `Columns`
/// layout still renders and differentiates as the reference does, and the
/// context lists what it could not build.
#[test]
fn column_kernels_a_driver_rejects_fall_back_to_the_pixel_layout() {
    let rejected: Vec<String> = latentam_shaders::ALL
        .iter()
        .filter(|k| k.is_column_layout())
        .map(|k| k.name.to_string())
        .collect();
    let o = ContextOptions {
        rejected_kernels: rejected,
        ..ContextOptions::default()
    };
    with_options(o, |ctx| {
        check_backward_vs_reference(ctx, "column_kernels_rejected", false);
        let failed = ctx.kernel_build_failures();
        assert!(
            failed.len() >= 2
                && failed
                    .iter()
                    .all(|(k, _)| latentam_shaders::is_column_layout(k)),
            "{failed:?}"
        );
    });
}

#[test]
fn backward_matches_reference_without_subgroups() {
    for cas in [false, true] {
        let o = ContextOptions {
            subgroup_arithmetic: false,
            float_atomics: if cas {
                latentam_gpu::FloatAtomics::CompareAndSwap
            } else {
                latentam_gpu::FloatAtomics::Auto
            },
            ..ContextOptions::default()
        };
        with_options(o, |ctx| {
            assert!(!ctx.info().subgroup_arithmetic && !ctx.info().subgroup_shuffle);
            check_backward_vs_reference(ctx, "backward_matches_reference_without_subgroups", false)
        });
    }
}
