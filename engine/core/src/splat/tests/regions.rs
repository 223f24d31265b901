//! Region pooling inside the rasterizer and the backward pass from pooled
//! region rows, against the f64 reference.

use super::*;

/// Region pooling inside the rasterizer against the f64 reference render
/// pooled by the reference pooling.
fn check_pool_vs_reference(ctx: &Context, seed_name: &str) {
    let mut r = rng(seed_name);
    let cams: Vec<Camera> = [(37, 29), (48, 32)]
        .iter()
        .map(|&(w, h)| random_camera(&mut r, w, h, 3.0))
        .collect();
    let n = 200;
    let host = awkward_scene(&mut r, n, &cams);
    let buf = upload(ctx, &host);
    let batch = BatchLayout::for_cameras(&cams).unwrap();
    let regions = random_regions(&mut r, &batch);
    let rows = regions.len() as usize;
    assert!(rows >= 4, "{rows} regions");
    let gs = Gaussian::all(&host);
    let mut image = Vec::new();
    for cam in &cams {
        for c in reference::render(&gs, cam, [0.0; 3]).channels {
            image.extend(c[4..].iter().map(|&v| v as f32));
        }
    }
    let want =
        latentam_reference::pooling::pool(&image, QUERY_DIM, regions.offsets(), regions.pixels());
    let labels = region_labels(ctx, &regions);
    // Rows before `first_row` belong to other chunks: never written.
    let first_row = 3usize;
    let pooled = latentam_gpu::Buffer::device(
        ctx,
        "test/pooled",
        ((first_row + rows) * QUERY_DIM * 4) as u64,
    )
    .unwrap();
    for layout in LAYOUTS {
        for channels in [Channels::Colour, Channels::All] {
            let mut raster = Rasterizer::new(ctx);
            raster.settings.layout = layout;
            raster.settings.query_gradient_image = false;
            raster
                .forward_channels(&buf, n as u64, &cams, channels)
                .unwrap();
            let mut rec = ctx.recorder().unwrap();
            rec.fill_u32(&pooled, 0x7fc0_0000);
            rec.fill_range_u32(
                &pooled,
                (first_row * QUERY_DIM * 4) as u64,
                (rows * QUERY_DIM * 4) as u64,
                0,
            )
            .unwrap();
            raster
                .record_pool(
                    &mut rec,
                    raster.last_batch(),
                    &buf,
                    &pooled,
                    first_row as u32,
                    &labels,
                    batch.pixels as u32,
                )
                .unwrap();
            rec.submit().unwrap().wait().unwrap();
            let got = ctx.download::<f32>(&pooled).unwrap();
            assert!(got[..first_row * QUERY_DIM].iter().all(|v| v.is_nan()));
            let got = &got[first_row * QUERY_DIM..];
            let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(scale > 0.1, "queries were rendered: {scale}");
            for (i, (&g, &w)) in got.iter().zip(&want).enumerate() {
                assert!(
                    (g as f64 - w).abs() <= 1e-4 * scale.max(1.0),
                    "{layout:?} {channels:?}: row {} channel {}: {g} vs {w}",
                    i / QUERY_DIM,
                    i % QUERY_DIM
                );
            }
        }
    }
}

#[test]
fn pooling_inside_the_rasterizer_matches_reference() {
    with_context(|ctx| check_pool_vs_reference(ctx, "pooling_inside_the_rasterizer"));
    with_cas_atomics(|ctx| check_pool_vs_reference(ctx, "pooling_inside_the_rasterizer_cas"));
    let o = ContextOptions {
        subgroup_arithmetic: false,
        ..ContextOptions::default()
    };
    with_options(o, |ctx| {
        assert!(!ctx.info().subgroup_arithmetic);
        check_pool_vs_reference(ctx, "pooling_inside_the_rasterizer_plain")
    });
}

/// The backward pass with query gradients taken from pooled region rows
/// through each pixel's region (no per-pixel query gradient image) against
/// the f64 reference given the image region pooling's adjoint would write.
/// Detached, the forward renders no query channels at all.
fn check_region_gradients_vs_reference(ctx: &Context, seed_name: &str, detach: bool) {
    use latentam_reference::pooling::pool_backward;
    let mut r = rng(seed_name);
    let cams: Vec<Camera> = [(37, 29), (48, 32)]
        .iter()
        .map(|&(w, h)| random_camera(&mut r, w, h, 3.0))
        .collect();
    let n = 200;
    let host = awkward_scene(&mut r, n, &cams);
    let buf = upload(ctx, &host);
    let grads = GaussianBuffers::new(ctx, "test_grads", n as u64).unwrap();
    let batch = BatchLayout::for_cameras(&cams).unwrap();
    let regions = random_regions(&mut r, &batch);
    let rows = regions.len() as usize;
    assert!(rows >= 4, "{rows} regions");
    // Rows before `first_row` belong to other chunks: never read.
    let first_row = 3usize;
    let grad_rows: Vec<f32> = (0..(first_row + rows) * QUERY_DIM)
        .map(|i| {
            if i < first_row * QUERY_DIM {
                f32::NAN
            } else {
                r.random_range(-1.0..1.0)
            }
        })
        .collect();
    let per_pixel = pool_backward(
        &grad_rows[first_row * QUERY_DIM..],
        QUERY_DIM,
        regions.offsets(),
        regions.pixels(),
        batch.pixels as usize,
    );
    let mut up = random_upstream(&mut r, &cams);
    let mut p = 0;
    for g in &mut up {
        for c in &mut g.channels {
            for k in 0..QUERY_DIM {
                c[4 + k] = per_pixel[p * QUERY_DIM + k];
            }
            p += 1;
        }
    }
    let gs = Gaussian::all(&host);
    let want = reference::backward(&gs, &cams, [0.3, 0.1, 0.7], &up, detach).grads;
    let at_cutoff = gaussians_at_cutoffs(&gs, &cams);
    let rows_buf = ctx.upload_new("test/grad_rows", &grad_rows).unwrap();
    let labels = region_labels(ctx, &regions);
    for layout in LAYOUTS {
        let mut raster = Rasterizer::new(ctx);
        raster.settings.background = [0.3, 0.1, 0.7];
        raster.settings.detach_query_gradients = detach;
        raster.settings.layout = layout;
        raster.settings.query_gradient_image = false;
        let channels = if detach {
            Channels::Colour
        } else {
            Channels::All
        };
        raster
            .forward_channels(&buf, n as u64, &cams, channels)
            .unwrap();
        // No per-pixel query gradient image, and detached no query image.
        assert!(raster.image_grads().unwrap().query().is_err());
        assert_eq!(raster.images().unwrap().query().is_ok(), !detach);
        let mut rgbd = Vec::new();
        let mut alpha = Vec::new();
        for g in &up {
            for (c, a) in g.channels.iter().zip(&g.alpha) {
                rgbd.extend(c[..4].iter().map(|&v| v as f32));
                alpha.push(*a as f32);
            }
        }
        let b = raster.image_grads().unwrap();
        ctx.upload(&b.rgbd, 0, &rgbd).unwrap();
        ctx.upload(&b.alpha, 0, &alpha).unwrap();
        let mut rec = ctx.recorder().unwrap();
        grads.record_fill(&mut rec, 0x7fc0_0000);
        raster
            .record_backward_into(
                &mut rec,
                raster.last_batch(),
                &buf,
                &grads,
                false,
                QueryGradients::Regions {
                    rows: &rows_buf,
                    first_row: first_row as u32,
                    labels: &labels,
                    offsets_at: batch.pixels as u32,
                },
            )
            .unwrap();
        rec.submit().unwrap().wait().unwrap();
        let got = Gaussian::all(&grads.download(ctx, n as u64).unwrap());
        assert_grads_match(&got, &want, &at_cutoff, &format!("{layout:?}"));
    }
}

#[test]
fn backward_from_region_rows_matches_reference() {
    with_context(|ctx| {
        check_region_gradients_vs_reference(ctx, "backward_from_region_rows_detached", true);
        check_region_gradients_vs_reference(ctx, "backward_from_region_rows_attached", false);
    });
}
