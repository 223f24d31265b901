//! Which blending kernels run, and the work they state.

use super::*;

/// The blending kernels a device runs are the ones `blend_kernel_names`
/// names (what mapping compiles ahead of time), for every device kind
/// lavapipe can play and both layouts.
#[test]
fn dispatched_blend_kernels_are_the_ones_named_for_the_device() {
    let modes = [
        (latentam_gpu::FloatAtomics::Auto, true),
        (latentam_gpu::FloatAtomics::CompareAndSwap, true),
        (latentam_gpu::FloatAtomics::Auto, false),
    ];
    for (float_atomics, subgroups) in modes {
        let o = ContextOptions {
            profiling: true,
            float_atomics,
            subgroup_arithmetic: subgroups,
            ..ContextOptions::default()
        };
        with_options(o, |ctx| {
            let mut r = rng("dispatched_blend_kernels");
            let cams = [random_camera(&mut r, 40, 30, 3.0)];
            let host = awkward_scene(&mut r, 100, &cams);
            let buf = upload(ctx, &host);
            let grads = GaussianBuffers::new(ctx, "test_grads", 100).unwrap();
            let batch = BatchLayout::for_cameras(&cams).unwrap();
            let regions = random_regions(&mut r, &batch);
            let labels = region_labels(ctx, &regions);
            let rows = latentam_gpu::Buffer::device(
                ctx,
                "test/rows",
                (regions.len() as u64).max(1) * QUERY_DIM as u64 * 4,
            )
            .unwrap();
            for layout in LAYOUTS {
                let mut raster = Rasterizer::new(ctx);
                raster.settings.layout = layout;
                ctx.profiler_reset();
                raster.forward(&buf, 100, &cams).unwrap();
                raster
                    .forward_channels(&buf, 100, &cams, Channels::Colour)
                    .unwrap();
                let mut rec = ctx.recorder().unwrap();
                rec.fill_u32(&rows, 0);
                raster
                    .record_pool(
                        &mut rec,
                        raster.last_batch(),
                        &buf,
                        &rows,
                        0,
                        &labels,
                        batch.pixels as u32,
                    )
                    .unwrap();
                raster
                    .record_backward_into(
                        &mut rec,
                        raster.last_batch(),
                        &buf,
                        &grads,
                        false,
                        QueryGradients::Zero,
                    )
                    .unwrap();
                rec.submit().unwrap().wait().unwrap();
                let named = Rasterizer::blend_kernel_names(ctx.info(), &raster.settings);
                let ran: Vec<&str> = ctx
                    .profiler_snapshot()
                    .stats()
                    .keys()
                    .copied()
                    .filter(|k| k.starts_with("raster_"))
                    .collect();
                assert_eq!(ran.len(), 4, "{ran:?}");
                for k in &ran {
                    assert!(named.contains(k), "{layout:?}: {k} ran, named {named:?}");
                }
            }
        });
    }
}

/// The work the blending kernels state (`splat/rasterizer/work.rs`) bounds
/// what the f64 reference's walk of every pixel tests: 25 operations per
/// tested pair at least, and every tile-list entry tested by every pixel
/// of its tile at most.
#[test]
fn stated_blend_work_bounds_the_reference_walk() {
    with_context(|ctx| {
        let mut r = rng("stated_blend_work");
        let cams: Vec<Camera> = (0..2)
            .map(|_| {
                let d = r.random_range(2.2..3.5);
                random_camera(&mut r, 80, 56, d)
            })
            .collect();
        let n = 400;
        let host = awkward_scene(&mut r, n, &cams);
        let buf = upload(ctx, &host);
        let gs = Gaussian::all(&host);
        let tested: u64 = cams
            .iter()
            .map(|c| reference::blend_work(&gs, c).tested)
            .sum();
        let pixels: u64 = cams.iter().map(|c| c.pixels()).sum();
        assert!(tested > 0);
        for layout in LAYOUTS {
            let mut raster = Rasterizer::new(ctx);
            raster.settings.layout = layout;
            raster.forward(&buf, n as u64, &cams).unwrap();
            let before = ctx.gpu_work();
            let stats = raster.forward(&buf, n as u64, &cams).unwrap();
            let work = ctx.gpu_work() - before;
            assert_eq!(work.uncounted(), 0, "{work:?}");
            let blend = work
                .kernels
                .iter()
                .find(|(k, _)| k.starts_with("raster_forward"))
                .map(|(_, w)| *w)
                .unwrap();
            let most = 140.0 * 256.0 * stats.intersections as f64 + 7.0 * pixels as f64;
            assert!(
                blend.flops >= 25.0 * tested as f64 && blend.flops <= most,
                "{layout:?}: {} flops stated, {tested} pairs tested by the reference, {} entries",
                blend.flops,
                stats.intersections
            );
        }
    });
}
