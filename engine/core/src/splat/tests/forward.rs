//! The forward pass against the f64 reference: random scenes, measured
//! batches, query images in bands, many tiles.

use super::*;
use crate::splat::PixelGrid;
use latentam_reference::grid::gather_grid;

#[test]
fn measured_batches_render_in_one_submission() {
    // Two batches of different shapes measured together, then both
    // rendered and read back in one recording: two host waits in all, and
    // every view as the reference renders it.
    with_context(|ctx| {
        let mut r = rng("measured_batches_render_in_one_submission");
        let first = [
            random_camera(&mut r, 48, 40, 2.8),
            random_camera(&mut r, 33, 20, 3.0),
        ];
        let second = [random_camera(&mut r, 64, 50, 2.5)];
        let every: Vec<Camera> = first.iter().chain(&second).copied().collect();
        let n = 300;
        let host = awkward_scene(&mut r, n, &every);
        let buf = upload(ctx, &host);
        let gs = Gaussian::all(&host);
        for layout in LAYOUTS {
            let mut raster = Rasterizer::new(ctx);
            raster.settings.layout = layout;
            let waits = ctx.host_waits();
            let batches = raster
                .measure(&buf, n as u64, &[&first, &second], Channels::All)
                .unwrap();
            let mut rec = ctx.recorder().unwrap();
            let mut readbacks = Vec::new();
            for batch in &batches {
                raster.record_forward(&mut rec, &buf, batch).unwrap();
                let images = raster.images().unwrap();
                for slot in &batch.layout().views {
                    let (first_pixel, pixels) =
                        (slot.first_pixel, slot.width as u64 * slot.height as u64);
                    readbacks.push((
                        *slot,
                        rec.download(&images.rgbd, first_pixel * 16, pixels * 16)
                            .unwrap(),
                        rec.download(&images.alpha, first_pixel * 4, pixels * 4)
                            .unwrap(),
                        rec.download(images.query().unwrap(), first_pixel * 128, pixels * 128)
                            .unwrap(),
                    ));
                }
            }
            rec.submit().unwrap().wait().unwrap();
            assert_eq!(
                ctx.host_waits() - waits,
                2,
                "one wait to measure, one to render"
            );
            for (v, (cam, (slot, rgbd, alpha, query))) in every.iter().zip(readbacks).enumerate() {
                let got = RenderedView {
                    width: slot.width,
                    height: slot.height,
                    rgbd: bytemuck::cast_slice(&rgbd.read::<f32>().unwrap()).to_vec(),
                    alpha: alpha.read::<f32>().unwrap(),
                    query: bytemuck::cast_slice(&query.read::<f32>().unwrap()).to_vec(),
                };
                let what = format!("{layout:?}: view {v}");
                assert_view_matches(&got, &gs, cam, [0.0; 3], &what);
            }
            for (batch, cams) in batches.iter().zip([&first[..], &second[..]]) {
                let visible: usize = cams
                    .iter()
                    .map(|c| {
                        gs.iter()
                            .filter(|g| reference::project(g, c).is_some())
                            .count()
                    })
                    .sum();
                assert_eq!(batch.stats().visible, visible as u64);
                assert!(visible > 0, "the scene must be visible");
            }
            // A batch larger than anything measured is refused, not recorded
            // into buffers too small for it.
            let wide = Rasterizer::new(ctx)
                .measure(&buf, n as u64, &[&every], Channels::All)
                .unwrap()
                .pop()
                .unwrap();
            let mut rec = ctx.recorder().unwrap();
            let err = raster.record_forward(&mut rec, &buf, &wide).unwrap_err();
            assert!(err.to_string().contains("measure"), "{err}");
        }
    });
}

#[test]
fn forward_matches_reference_on_random_scenes() {
    with_context(|ctx| {
        let mut r = rng("forward_matches_reference_on_random_scenes");
        check_forward(ctx, &mut r, &[(37, 29), (64, 48), (16, 16)], 300, [0.0; 3]);
        check_forward(ctx, &mut r, &[(50, 21)], 500, [0.2, 0.5, 0.9]);
    });
}

#[test]
fn query_images_larger_than_a_buffer_are_rendered_in_bands() {
    // A device binding 64 KiB: 512 pixels of query image a buffer, so two
    // views of 2 123 pixels render their queries in 5 bands.
    let o = ContextOptions {
        max_buffer_bytes: Some(64 << 10),
        ..ContextOptions::default()
    };
    with_options(o, |ctx| {
        let mut r = rng("query_images_larger_than_a_buffer_are_rendered_in_bands");
        let cams = [
            random_camera(&mut r, 37, 29, 2.8),
            random_camera(&mut r, 50, 21, 3.1),
        ];
        let host = awkward_scene(&mut r, 300, &cams);
        let buf = upload(ctx, &host);
        let gs = Gaussian::all(&host);
        for layout in LAYOUTS {
            let mut raster = Rasterizer::new(ctx);
            raster.settings.layout = layout;
            raster.settings.query_gradient_image = false;
            let views = gpu_render(ctx, &mut raster, &buf, 300, &cams);
            assert_eq!(
                raster.images().unwrap().query().unwrap().bytes(),
                512 * QUERY_DIM as u64 * 4,
                "one band allocated"
            );
            for (v, cam) in cams.iter().enumerate() {
                let what = format!("{layout:?}: banded view {v}");
                assert_view_matches(&views[v], &gs, cam, [0.0; 3], &what);
            }
        }
    });
}

#[test]
fn forward_handles_many_tiles_and_batches() {
    // Deep tiles: more Gaussians per tile than one shared-memory batch.
    with_context(|ctx| {
        let mut r = rng("forward_handles_many_tiles_and_batches");
        let cams = [random_camera(&mut r, 40, 33, 3.0)];
        let mut host = random_gaussians(&mut r, 1500, (-2.5, -1.5), (-4.0, -2.0));
        for m in &mut host.means {
            m.iter_mut().for_each(|v| *v *= 0.3);
        }
        let buf = upload(ctx, &host);
        let gs = Gaussian::all(&host);
        for layout in LAYOUTS {
            let mut raster = Rasterizer::new(ctx);
            raster.settings.layout = layout;
            let views = gpu_render(ctx, &mut raster, &buf, 1500, &cams);
            let what = format!("{layout:?}: deep tiles");
            assert_view_matches(&views[0], &gs, &cams[0], [0.0; 3], &what);
            assert!(raster.stats().intersections > 1500);
        }
    });
}

/// Seeding's render: one camera's colour, depth and alpha rendered and
/// read back in one submission, two host waits in all, and the very
/// images the forward pass then a read-back give.
#[test]
fn colour_depth_and_alpha_render_and_read_back_in_two_waits() {
    with_context(|ctx| {
        let mut r = rng("colour_depth_and_alpha_render_and_read_back_in_two_waits");
        let cam = random_camera(&mut r, 45, 31, 2.8);
        let n = 400;
        let host = awkward_scene(&mut r, n, &[cam]);
        let buf = upload(ctx, &host);
        // Another buffer, read back beside the render.
        let words: Vec<f32> = (0..37).map(|i| i as f32 * 0.5 - 3.0).collect();
        let other = ctx.upload_new("test/other", &words).unwrap();
        for layout in LAYOUTS {
            let mut raster = Rasterizer::new(ctx);
            raster.settings.layout = layout;
            let waits = ctx.host_waits();
            let render = raster
                .render_alpha_rgbd(&buf, n as u64, &cam, PixelGrid::ALL, Some(&other))
                .unwrap();
            assert_eq!(ctx.host_waits() - waits, 2, "{layout:?}");
            let (alpha, rgbd) = (render.alpha, render.rgbd);
            assert_eq!(
                render.also.as_deref(),
                Some(&words[..]),
                "{layout:?}: the other buffer"
            );
            assert_eq!((alpha.len(), rgbd.len()), (45 * 31, 45 * 31));
            assert!(
                alpha.iter().any(|&a| a > 0.1),
                "{layout:?}: the scene is in view"
            );

            let mut old = Rasterizer::new(ctx);
            old.settings.layout = layout;
            old.forward_channels(&buf, n as u64, &[cam], Channels::Colour)
                .unwrap();
            let (want_alpha, want_rgbd) = old.download_alpha_rgbd(0).unwrap();
            assert_eq!(alpha, want_alpha, "{layout:?}: alpha");
            assert_eq!(rgbd, want_rgbd, "{layout:?}: colour and depth");
            // The render is the rasterizer's last batch, as after a forward.
            assert_eq!(raster.download_alpha_rgbd(0).unwrap().0, alpha);
        }
    });
}

/// The render gathered at a grid of pixels on the GPU
/// (`glsl/coverage_grid.comp`) holds, bit for bit, the whole image's values
/// at those pixels (`latentam_reference::grid::gather_grid`), for grids of
/// several strides and starts, in a view that is not the batch's first
/// pixel row (odd sizes); only the cells are read back.
#[test]
fn a_render_read_back_at_a_grid_of_pixels_is_the_image_at_those_pixels() {
    with_context(|ctx| {
        let mut r = rng("a_render_read_back_at_a_grid_of_pixels_is_the_image_at_those_pixels");
        let cam = random_camera(&mut r, 53, 37, 2.8);
        let n = 500;
        let host = awkward_scene(&mut r, n, &[cam]);
        let buf = upload(ctx, &host);
        let mut raster = Rasterizer::new(ctx);
        let whole = raster
            .render_alpha_rgbd(&buf, n as u64, &cam, PixelGrid::ALL, None)
            .unwrap();
        assert!(whole.alpha.iter().any(|&a| a > 0.1), "the scene is in view");
        for (stride, start) in [
            (2, [1, 1]),
            (3, [1, 2]),
            (5, [4, 0]),
            (1, [2, 3]),
            (60, [0, 0]),
        ] {
            let grid = PixelGrid { stride, start };
            let (cols, cells) = (grid.cols(53), grid.cells(53, 37) as u32);
            let before = ctx.gpu_work();
            let got = raster
                .render_alpha_rgbd(&buf, n as u64, &cam, grid, None)
                .unwrap();
            let down = (ctx.gpu_work() - before).downloaded_bytes;
            let what = format!("stride {stride} from {start:?}");
            assert_eq!(got.grid, grid, "{what}");
            assert_eq!(
                down,
                cells as u64 * 20 + 8,
                "{what}: the cells and the measure"
            );
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let want_alpha = gather_grid(&whole.alpha, 53, stride, start, cols, cells);
            assert_eq!(bits(&got.alpha), bits(&want_alpha), "{what}: alpha");
            let want_rgbd = gather_grid(&whole.rgbd, 53, stride, start, cols, cells);
            let flat = |v: &[[f32; 4]]| bits(bytemuck::cast_slice(v));
            assert_eq!(
                flat(&got.rgbd),
                flat(&want_rgbd),
                "{what}: colour and depth"
            );
        }
        let empty = PixelGrid {
            stride: 2,
            start: [53, 0],
        };
        assert!(raster
            .render_alpha_rgbd(&buf, n as u64, &cam, empty, None)
            .is_err());
    });
}
