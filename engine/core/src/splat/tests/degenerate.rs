//! Degenerate Gaussians and bad batches.

use super::*;

#[test]
fn degenerate_gaussians_do_not_poison_others() {
    with_context(|ctx| {
        let mut r = rng("degenerate_gaussians_do_not_poison_others");
        let cams = vec![
            random_camera(&mut r, 40, 30, 3.0),
            // Looks away from everything: an empty view.
            Camera::looking_at(
                DVec3::new(0.0, 0.0, 5.0),
                DVec3::new(0.0, 0.0, 10.0),
                DVec3::Y,
                24,
                18,
                20.0,
            ),
        ];
        let n = 60;
        let mut host = random_gaussians(&mut r, n, (-3.0, -1.5), (-1.0, 3.0));
        host.means[3] = [f32::NAN, 0.0, 0.0];
        host.log_scales[7] = [f32::NEG_INFINITY; 3]; // zero scale
        host.quats[11] = [0.0; 4]; // no rotation defined
        host.opacity_logits[13] = f32::NAN;
        host.queries[17][5] = f32::INFINITY; // only its own query gradient may suffer
        host.log_scales[19] = [f32::NAN, 0.0, 0.0];
        let buf = upload(ctx, &host);
        let grads = GaussianBuffers::new(ctx, "test_grads", n as u64).unwrap();
        let up = random_upstream(&mut r, &cams);
        for layout in LAYOUTS {
            let mut raster = Rasterizer::new(ctx);
            raster.settings.layout = layout;
            raster.forward(&buf, n as u64, &cams).unwrap();
            let empty = raster.download_view(1).unwrap();
            assert!(empty.alpha.iter().all(|&a| a == 0.0));
            assert!(empty.rgbd.iter().all(|c| c == &[0.0; 4]));
            upload_upstream(ctx, &raster, &up);
            raster.backward(&buf, &grads).unwrap();
            let got = grads.download(ctx, n as u64).unwrap();

            // The reference without the broken Gaussians (NaN ones are culled,
            // so they must not matter); the zero-scale one stays in.
            let broken = [3usize, 11, 13, 17, 19];
            let mut gs = Gaussian::all(&host);
            for b in [3usize, 11, 13, 19] {
                gs[b].mean = [0.0, 0.0, 1e9]; // far away: never visible
            }
            // Gaussian 17 stays visible with an infinite query channel; with the
            // query gradients detached that reaches nobody else's gradients.
            gs[17].query = [0.0; QUERY_DIM];
            let want = reference::backward(&gs, &cams, [0.0; 3], &up, true).grads;
            let got64 = Gaussian::all(&got);
            // A Gaussian's gradient is compared on its own, but against
            // float rounding at the scale of its field over all Gaussians:
            // a tiny sum of large terms differs by a few per cent with the
            // order the atomics happen to add in.
            let field_scale: Vec<f64> = kinds(&want)
                .iter()
                .map(|(_, v)| v.iter().fold(0.0f64, |m, x| m.max(x.abs())))
                .collect();
            for i in 0..n {
                if broken.contains(&i) && i != 17 {
                    continue;
                }
                for (k, ((name, a), (_, b))) in kinds(&got64[i..=i])
                    .into_iter()
                    .zip(kinds(&want[i..=i]))
                    .enumerate()
                {
                    if i == 17 && name == "query" {
                        continue;
                    }
                    assert!(
                        a.iter().all(|v| v.is_finite()),
                        "{layout:?}: Gaussian {i} {name}: {a:?}"
                    );
                    let e = rel_err(&a, &b);
                    let close = a
                        .iter()
                        .zip(&b)
                        .all(|(x, y)| (x - y).abs() < 1e-4 * field_scale[k]);
                    assert!(
                        e < 5e-3 || close || b.iter().all(|v| v.abs() < 1e-6),
                        "{layout:?}: Gaussian {i} {name}: {a:?} vs {b:?}"
                    );
                }
            }
        }
    });
}

#[test]
fn bad_batches_are_rejected() {
    with_context(|ctx| {
        let host = HostGaussians::zeros(4);
        let buf = upload(ctx, &host);
        let mut raster = Rasterizer::new(ctx);
        assert!(raster.forward(&buf, 4, &[]).is_err());
        let mut cam = Camera::looking_at(DVec3::Z, DVec3::ZERO, DVec3::Y, 8, 8, 8.0);
        assert!(raster.forward(&buf, 5, &[cam]).is_err());
        cam.fx = f64::NAN;
        assert!(raster.forward(&buf, 4, &[cam]).is_err());
        cam.fx = 8.0;
        cam.near = -1.0;
        assert!(raster.forward(&buf, 4, &[cam]).is_err());
        assert!(raster.download_view(0).is_err());
        let grads = GaussianBuffers::new(ctx, "test_grads", 4).unwrap();
        assert!(raster.backward(&buf, &grads).is_err());
        // Zero Gaussians render the background.
        cam.near = 0.01;
        raster.settings.background = [0.25, 0.5, 1.0];
        raster.forward(&buf, 0, &[cam]).unwrap();
        let v = raster.download_view(0).unwrap();
        assert!(v.rgbd.iter().all(|c| c == &[0.25, 0.5, 1.0, 0.0]));
    });
}
