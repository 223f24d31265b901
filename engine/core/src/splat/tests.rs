//! Rasterizer tests: GPU forward and backward against the f64 reference, the
//! reference against its own finite differences, GPU gradients against
//! finite differences of the GPU forward, and degenerate inputs.

#![allow(clippy::needless_range_loop)]

use glam::DVec3;
use rand::Rng;

use super::*;
use latentam_gpu::testing::{rng, with_cas_atomics, with_context, with_options};
use latentam_gpu::{Context, ContextOptions};
use latentam_reference::raster::{self as reference, Gaussian, ImageGrads, CHANNELS};

/// A camera on a sphere of radius `dist` around the origin, looking at it.
fn random_camera(r: &mut impl Rng, width: u32, height: u32, dist: f64) -> Camera {
    let dir = DVec3::new(
        r.random_range(-1.0..1.0),
        r.random_range(-0.5..0.5),
        r.random_range(-1.0..1.0),
    )
    .normalize_or(DVec3::Z);
    let target = DVec3::new(
        r.random_range(-0.2..0.2),
        r.random_range(-0.2..0.2),
        r.random_range(-0.2..0.2),
    );
    let mut cam = Camera::looking_at(
        dir * dist,
        target,
        DVec3::Y,
        width,
        height,
        0.9 * width as f64,
    );
    // Off-centre principal point, as real intrinsics have.
    cam.cx += r.random_range(-2.0..2.0);
    cam.cy += r.random_range(-2.0..2.0);
    cam.fy = cam.fx * r.random_range(0.95..1.05);
    cam
}

fn random_quat(r: &mut impl Rng) -> [f32; 4] {
    let q = [0; 4].map(|_| r.random_range(-1.0f32..1.0));
    // Unnormalised on purpose: the kernels normalise.
    let scale = r.random_range(0.5f32..2.0);
    q.map(|v| v * scale + if v == 0.0 { 0.1 } else { 0.0 })
}

/// `n` Gaussians in the unit cube with random shapes, colours and queries.
fn random_gaussians(
    r: &mut impl Rng,
    n: usize,
    log_scale: (f32, f32),
    logit: (f32, f32),
) -> HostGaussians {
    let mut g = HostGaussians::zeros(n);
    for i in 0..n {
        g.means[i] = [0; 3].map(|_| r.random_range(-1.0f32..1.0));
        g.log_scales[i] = [0; 3].map(|_| r.random_range(log_scale.0..log_scale.1));
        g.quats[i] = random_quat(r);
        g.colors[i] = [0; 3].map(|_| r.random_range(0.0f32..1.0));
        g.opacity_logits[i] = r.random_range(logit.0..logit.1);
        g.queries[i] = [0; QUERY_DIM].map(|_| r.random_range(-1.0f32..1.0));
    }
    g
}

/// A random scene with the awkward cases mixed in: Gaussians behind the
/// first camera, tiny ones, huge ones (larger than the image).
fn awkward_scene(r: &mut impl Rng, n: usize, cams: &[Camera]) -> HostGaussians {
    let mut g = random_gaussians(r, n, (-3.5, -1.5), (-2.0, 4.0));
    let eye = cams[0].cam_to_world.translation;
    for i in 0..n {
        match i % 10 {
            0 => {
                // Behind (or at) the first camera.
                let p = eye * r.random_range(1.0..1.5);
                g.means[i] = p.as_vec3().to_array();
            }
            1 => g.log_scales[i] = [-7.0; 3],
            2 if i % 20 == 2 => g.log_scales[i] = [0.3, -1.0, 0.5],
            _ => {}
        }
    }
    g
}

fn upload(ctx: &Context, g: &HostGaussians) -> GaussianBuffers {
    let n = g.len().unwrap() as u64;
    let buf = GaussianBuffers::new(ctx, "test_gaussians", n).unwrap();
    buf.upload(ctx, 0, g).unwrap();
    buf
}

/// Renders on the GPU, with every output poisoned first.
fn gpu_render(
    ctx: &Context,
    raster: &mut Rasterizer,
    buf: &GaussianBuffers,
    n: u64,
    cams: &[Camera],
) -> Vec<RenderedView> {
    // A first forward sizes the buffers; poison them, then render again so
    // every pixel must be written by the pass under test.
    raster.forward(buf, n, cams).unwrap();
    let mut rec = ctx.recorder().unwrap();
    raster.images().unwrap().record_fill(&mut rec, 0x7fc0_0000);
    rec.submit().unwrap().wait().unwrap();
    raster.forward(buf, n, cams).unwrap();
    (0..cams.len())
        .map(|v| raster.download_view(v).unwrap())
        .collect()
}

/// Checks one rendered view against the f64 reference: every channel
/// within 2e-4 of the pixel's scale (its largest |value|, at least 1), plus,
/// where a blending decision sits within f32 rounding of its threshold,
/// the contribution that decision can move (see [`reference::cutoffs::near_cutoffs`]):
/// there f32 and f64 may both be right and still differ.
fn assert_view_matches(
    gpu: &RenderedView,
    gs: &[Gaussian],
    cam: &Camera,
    background: [f64; 3],
    what: &str,
) {
    let want = reference::render(gs, cam, background);
    let near = reference::cutoffs::near_cutoffs(gs, cam);
    // The largest |feature| a pixel blends: colours and queries are in
    // [-1, 1], depth is the camera-frame depth.
    let features = gs
        .iter()
        .filter_map(|g| reference::project(g, cam))
        .fold(1.0f64, |m, p| m.max(p.depth));
    for i in 0..gpu.alpha.len() {
        let mut err = (gpu.alpha[i] as f64 - want.alpha[i]).abs();
        let mut scale = 1.0f64;
        for k in 0..4 {
            err = err.max((gpu.rgbd[i][k] as f64 - want.channels[i][k]).abs());
            scale = scale.max(want.channels[i][k].abs());
        }
        for k in 0..QUERY_DIM {
            err = err.max((gpu.query[i][k] as f64 - want.channels[i][4 + k]).abs());
            scale = scale.max(want.channels[i][4 + k].abs());
        }
        let slack = 2.0 * near.slack[i] * features;
        assert!(
            err <= 2e-4 * scale + slack,
            "{what}: pixel {i} differs by {err:e} (scale {scale}, cut-off slack {slack:e})"
        );
    }
}

fn check_forward(ctx: &Context, r: &mut impl Rng, sizes: &[(u32, u32)], n: usize, bg: [f32; 3]) {
    let cams: Vec<Camera> = sizes
        .iter()
        .map(|&(w, h)| {
            let d = r.random_range(2.2..3.5);
            random_camera(r, w, h, d)
        })
        .collect();
    let host = awkward_scene(r, n, &cams);
    let buf = upload(ctx, &host);
    let gs = Gaussian::all(&host);
    let bg64 = bg.map(|v| v as f64);
    for layout in LAYOUTS {
        let mut raster = Rasterizer::new(ctx);
        raster.settings.background = bg;
        raster.settings.layout = layout;
        let views = gpu_render(ctx, &mut raster, &buf, n as u64, &cams);
        let mut visible = 0;
        for (v, cam) in cams.iter().enumerate() {
            visible += gs
                .iter()
                .filter(|g| reference::project(g, cam).is_some())
                .count();
            let what = format!("{layout:?}: view {v} ({}x{})", cam.width, cam.height);
            assert_view_matches(&views[v], &gs, cam, bg64, &what);
        }
        assert_eq!(raster.stats().visible, visible as u64);
        assert!(visible > 0, "the scene must be visible");
    }
}

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

/// Both pixel-to-invocation mappings of the blending kernels.
const LAYOUTS: [BlendLayout; 2] = [BlendLayout::Pixels, BlendLayout::Columns];

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

fn random_upstream(r: &mut impl Rng, cams: &[Camera]) -> Vec<ImageGrads> {
    cams.iter()
        .map(|c| {
            let n = c.pixels() as usize;
            ImageGrads {
                channels: (0..n)
                    .map(|_| [0; CHANNELS].map(|_| r.random_range(-1.0..1.0)))
                    .collect(),
                alpha: (0..n).map(|_| r.random_range(-1.0..1.0)).collect(),
            }
        })
        .collect()
}

/// Writes per-view upstream gradients into the rasterizer's buffers.
fn upload_upstream(ctx: &Context, raster: &Rasterizer, up: &[ImageGrads]) {
    let mut rgbd = Vec::new();
    let mut alpha = Vec::new();
    let mut query = Vec::new();
    for g in up {
        for (c, a) in g.channels.iter().zip(&g.alpha) {
            rgbd.extend(c[..4].iter().map(|&v| v as f32));
            query.extend(c[4..].iter().map(|&v| v as f32));
            alpha.push(*a as f32);
        }
    }
    let b = raster.image_grads().unwrap();
    ctx.upload(&b.rgbd, 0, &rgbd).unwrap();
    ctx.upload(&b.alpha, 0, &alpha).unwrap();
    ctx.upload(b.query().unwrap(), 0, &query).unwrap();
}

/// The six parameter kinds of `grads`, flattened.
fn kinds(g: &[Gaussian]) -> [(&'static str, Vec<f64>); 6] {
    [
        ("mean", g.iter().flat_map(|x| x.mean).collect()),
        ("log_scale", g.iter().flat_map(|x| x.log_scale).collect()),
        ("quat", g.iter().flat_map(|x| x.quat).collect()),
        ("color", g.iter().flat_map(|x| x.color).collect()),
        ("opacity_logit", g.iter().map(|x| x.opacity_logit).collect()),
        ("query", g.iter().flat_map(|x| x.query).collect()),
    ]
}

/// Relative error ‖a − b‖ / ‖b‖ (0 when both vanish).
fn rel_err(a: &[f64], b: &[f64]) -> f64 {
    let d: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt();
    let n: f64 = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    if n == 0.0 {
        d
    } else {
        d / n
    }
}

/// Which Gaussians' own blending decision sits within f32 rounding of a
/// threshold in some view (see [`reference::cutoffs::near_cutoffs`]): their
/// gradients may rightly jump by a finite amount.
fn gaussians_at_cutoffs(gs: &[Gaussian], cams: &[Camera]) -> Vec<bool> {
    let mut at_cutoff = vec![false; gs.len()];
    for cam in cams {
        let near = reference::cutoffs::near_cutoffs(gs, cam);
        at_cutoff
            .iter_mut()
            .zip(near.gaussians)
            .for_each(|(a, b)| *a |= b);
    }
    at_cutoff
}

/// Checks GPU gradients against the reference's, kind by kind, by relative
/// error over all Gaussians except those `at_cutoff` (from
/// [`gaussians_at_cutoffs`]).
fn assert_grads_match(got: &[Gaussian], want: &[Gaussian], at_cutoff: &[bool], what: &str) {
    let excluded = at_cutoff.iter().filter(|&&b| b).count();
    assert!(
        excluded * 20 <= at_cutoff.len(),
        "{what}: {excluded} of {} Gaussians at a cut-off: too degenerate to test",
        at_cutoff.len()
    );
    let keep = |v: &[Gaussian]| -> Vec<Gaussian> {
        v.iter()
            .zip(at_cutoff)
            .filter(|(_, &c)| !c)
            .map(|(g, _)| *g)
            .collect()
    };
    let (got, want) = (keep(got), keep(want));
    for ((name, a), (_, b)) in kinds(&got).into_iter().zip(kinds(&want)) {
        assert!(
            a.iter().all(|v| v.is_finite()),
            "{what}: {name}: non-finite gradient"
        );
        let e = rel_err(&a, &b);
        assert!(
            e < 2e-3,
            "{what}: {name} gradients differ from the reference: relative error {e:e}"
        );
    }
}

fn check_backward_vs_reference(ctx: &Context, seed_name: &str, detach: bool) {
    let mut r = rng(seed_name);
    let cams: Vec<Camera> = [(37, 29), (48, 32)]
        .iter()
        .map(|&(w, h)| random_camera(&mut r, w, h, 3.0))
        .collect();
    let n = 200;
    let host = awkward_scene(&mut r, n, &cams);
    let buf = upload(ctx, &host);
    let grads = GaussianBuffers::new(ctx, "test_grads", n as u64).unwrap();
    let up = random_upstream(&mut r, &cams);
    let gs = Gaussian::all(&host);
    let want = reference::backward(&gs, &cams, [0.3, 0.1, 0.7], &up, detach).grads;
    let at_cutoff = gaussians_at_cutoffs(&gs, &cams);
    for layout in LAYOUTS {
        let mut raster = Rasterizer::new(ctx);
        raster.settings.background = [0.3, 0.1, 0.7];
        raster.settings.detach_query_gradients = detach;
        raster.settings.layout = layout;
        raster.forward(&buf, n as u64, &cams).unwrap();
        upload_upstream(ctx, &raster, &up);
        let mut rec = ctx.recorder().unwrap();
        grads.record_fill(&mut rec, 0x7fc0_0000);
        rec.submit().unwrap().wait().unwrap();
        raster.backward(&buf, &grads).unwrap();
        let got = Gaussian::all(&grads.download(ctx, n as u64).unwrap());
        assert_grads_match(&got, &want, &at_cutoff, &format!("{layout:?}"));
    }
}

/// Coarse random label images over the batch's views: 4×3 blocks of 6
/// regions, some unlabelled, so regions have ragged borders across tiles.
fn random_regions(r: &mut impl Rng, batch: &BatchLayout) -> crate::latent::Regions {
    use crate::latent::{LabelImage, Regions, NO_REGION_LABEL};
    let mut regions = Regions::new(batch, 1);
    for v in 0..batch.views.len() {
        let labels: Vec<u16> = (0..12)
            .map(|_| {
                if r.random_bool(0.2) {
                    NO_REGION_LABEL
                } else {
                    r.random_range(0..6)
                }
            })
            .collect();
        let img = LabelImage {
            width: 4,
            height: 3,
            labels: &labels,
        };
        regions.add_labels(v, img, 6).unwrap();
    }
    regions
}

/// Each pixel's region, then the regions' CSR offsets (from index
/// `batch.pixels`), as the rasterizer's region kernels read them.
fn region_labels(ctx: &Context, regions: &crate::latent::Regions) -> latentam_gpu::Buffer {
    let mut data = regions.pixel_region().to_vec();
    data.extend_from_slice(regions.offsets());
    ctx.upload_new("test/labels", &data).unwrap()
}

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

/// Σ upstream · outputs, in f64, for a rendered batch.
fn linear_loss(images: &[reference::Image], up: &[ImageGrads]) -> f64 {
    let mut l = 0.0;
    for (img, g) in images.iter().zip(up) {
        for i in 0..img.alpha.len() {
            l += img.alpha[i] * g.alpha[i];
            for k in 0..CHANNELS {
                l += img.channels[i][k] * g.channels[i][k];
            }
        }
    }
    l
}

/// Parameter `k` (0..49 over all kinds) of a Gaussian, mutably.
fn param(g: &mut Gaussian, k: usize) -> &mut f64 {
    match k {
        0..=2 => &mut g.mean[k],
        3..=5 => &mut g.log_scale[k - 3],
        6..=9 => &mut g.quat[k - 6],
        10..=12 => &mut g.color[k - 10],
        13 => &mut g.opacity_logit,
        _ => &mut g.query[k - 14],
    }
}

/// The same parameter of a host set.
fn param_f32(h: &mut HostGaussians, gi: usize, k: usize) -> &mut f32 {
    match k {
        0..=2 => &mut h.means[gi][k],
        3..=5 => &mut h.log_scales[gi][k - 3],
        6..=9 => &mut h.quats[gi][k - 6],
        10..=12 => &mut h.colors[gi][k - 10],
        13 => &mut h.opacity_logits[gi],
        _ => &mut h.queries[gi][k - 14],
    }
}

const PARAMS: usize = 14 + QUERY_DIM;

#[test]
fn reference_backward_matches_its_finite_differences() {
    let mut r = rng("reference_backward_matches_its_finite_differences");
    let cams: Vec<Camera> = [(24, 20), (19, 17)]
        .iter()
        .map(|&(w, h)| random_camera(&mut r, w, h, 3.0))
        .collect();
    let host = random_gaussians(&mut r, 40, (-2.5, -1.2), (-1.0, 3.0));
    let gs = Gaussian::all(&host);
    let bg = [0.2, 0.4, 0.6];
    let up = random_upstream(&mut r, &cams);
    let render_all = |gs: &[Gaussian]| -> Vec<reference::Image> {
        cams.iter().map(|c| reference::render(gs, c, bg)).collect()
    };
    // With the query gradients detached, geometry sees the loss without the
    // query channels.
    let mut up_geom = up.clone();
    for g in &mut up_geom {
        for c in &mut g.channels {
            c[4..].iter_mut().for_each(|v| *v = 0.0);
        }
    }
    for detach in [false, true] {
        let grads = reference::backward(&gs, &cams, bg, &up, detach).grads;
        // A step can still move a pixel across the 1/255 cut-off, a jump the
        // analytic gradient rightly ignores; it is rare at this step, so a
        // couple of the ~3000 entries may disagree.
        let h = 1e-6;
        let mut outliers = Vec::new();
        let mut checked = 0;
        for gi in 0..gs.len() {
            if !cams
                .iter()
                .any(|c| reference::project(&gs[gi], c).is_some())
            {
                continue;
            }
            checked += 1;
            for k in 0..PARAMS {
                let geometry = !(10..=12).contains(&k) && k < 14;
                let loss_up = if detach && geometry { &up_geom } else { &up };
                let central = |h: f64| {
                    let mut plus = gs.clone();
                    *param(&mut plus[gi], k) += h;
                    let mut minus = gs.clone();
                    *param(&mut minus[gi], k) -= h;
                    (linear_loss(&render_all(&plus), loss_up)
                        - linear_loss(&render_all(&minus), loss_up))
                        / (2.0 * h)
                };
                let fd = central(h);
                let mut g = grads[gi];
                let an = *param(&mut g, k);
                let disagrees = |fd: f64| (fd - an).abs() > 1e-5 + 1e-4 * fd.abs().max(an.abs());
                // A jump within the step (a cut-off or a depth-order swap)
                // adds jump / 2h to the difference: a step ten times shorter
                // either leaves it out (and agrees) or makes it ten times
                // larger. A wrong gradient does neither.
                let jump = disagrees(fd) && {
                    let fine = central(h / 10.0);
                    !disagrees(fine) || fine.abs() > 3.0 * fd.abs()
                };
                if disagrees(fd) && !jump {
                    outliers.push(format!(
                        "Gaussian {gi} parameter {k}: finite difference {fd}, analytic {an}"
                    ));
                }
            }
        }
        assert!(
            outliers.len() <= 2,
            "detach={detach}: {} gradients disagree with finite differences:\n{}",
            outliers.len(),
            outliers.join("\n")
        );
        assert!(checked > 10, "too few visible Gaussians ({checked})");
    }
}

#[test]
fn backward_matches_finite_differences_of_the_gpu_forward() {
    with_context(|ctx| {
        let mut r = rng("backward_matches_finite_differences_of_the_gpu_forward");
        let cams: Vec<Camera> = [(32, 24), (27, 21)]
            .iter()
            .map(|&(w, h)| random_camera(&mut r, w, h, 3.0))
            .collect();
        // Few, large, fairly opaque Gaussians: smooth in their parameters
        // apart from the 1/255 fringe, whose effect stays around 1 %.
        let n = 12;
        let host = random_gaussians(&mut r, n, (-1.6, -1.0), (0.5, 1.5));
        // Geometry is checked on RGB, depth and alpha alone: fewer channels,
        // smaller cut-off jumps and less f32 noise. (The query channels' path
        // to geometry is checked against the reference, itself checked
        // against finite differences.)
        let up_full = random_upstream(&mut r, &cams);
        let mut up_geom = up_full.clone();
        for g in &mut up_geom {
            for c in &mut g.channels {
                c[4..].iter_mut().for_each(|v| *v = 0.0);
            }
        }
        let buf = upload(ctx, &host);
        let grads = GaussianBuffers::new(ctx, "test_grads", n as u64).unwrap();
        let mut raster = Rasterizer::new(ctx);
        raster.settings.detach_query_gradients = false;
        let mut analytic_for = |up: &[ImageGrads]| {
            raster.forward(&buf, n as u64, &cams).unwrap();
            upload_upstream(ctx, &raster, up);
            raster.backward(&buf, &grads).unwrap();
            Gaussian::all(&grads.download(ctx, n as u64).unwrap())
        };
        let analytic_full = analytic_for(&up_full);
        let analytic_geom = analytic_for(&up_geom);

        let gpu_loss = |raster: &mut Rasterizer, h: &HostGaussians, up: &[ImageGrads]| -> f64 {
            buf.upload(ctx, 0, h).unwrap();
            raster.forward(&buf, n as u64, &cams).unwrap();
            let imgs: Vec<reference::Image> = (0..cams.len())
                .map(|v| {
                    let d = raster.download_view(v).unwrap();
                    reference::Image {
                        width: d.width,
                        height: d.height,
                        channels: d
                            .rgbd
                            .iter()
                            .zip(&d.query)
                            .map(|(c, q)| {
                                let mut out = [0.0; CHANNELS];
                                for k in 0..4 {
                                    out[k] = c[k] as f64;
                                }
                                for k in 0..QUERY_DIM {
                                    out[4 + k] = q[k] as f64;
                                }
                                out
                            })
                            .collect(),
                        alpha: d.alpha.iter().map(|&a| a as f64).collect(),
                    }
                })
                .collect();
            linear_loss(&imgs, up)
        };
        // The loss jumps where a pixel crosses the 1/255 alpha cut-off or two
        // Gaussians swap depth order; the analytic gradient rightly ignores
        // those jumps, so steps stay small (f32 forward passes are precise
        // enough for that) and a few entries may still straddle a jump.
        // Colour and query do not move any cut-off: all must agree.
        let steps = [2e-5f32, 5e-5, 1e-4, 1e-3, 2e-4, 1e-3];
        let ranges = [0..3, 3..6, 6..10, 10..13, 13..14, 14..PARAMS];
        let names = [
            "mean",
            "log_scale",
            "quat",
            "color",
            "opacity_logit",
            "query",
        ];
        for (kind, (range, h)) in ranges.into_iter().zip(steps).enumerate() {
            let geometry = ![3, 5].contains(&kind);
            let (up, analytic) = if geometry {
                (&up_geom, &analytic_geom)
            } else {
                (&up_full, &analytic_full)
            };
            let mut fd = Vec::new();
            let mut an = Vec::new();
            for gi in 0..n {
                for k in range.clone() {
                    let mut plus = host.clone();
                    let mut minus = host.clone();
                    *param_f32(&mut plus, gi, k) += h;
                    *param_f32(&mut minus, gi, k) -= h;
                    let (xp, xm) = (*param_f32(&mut plus, gi, k), *param_f32(&mut minus, gi, k));
                    let lp = gpu_loss(&mut raster, &plus, up);
                    let lm = gpu_loss(&mut raster, &minus, up);
                    // The step actually taken, after f32 rounding.
                    fd.push((lp - lm) / (xp as f64 - xm as f64));
                    let mut g = analytic[gi];
                    an.push(*param(&mut g, k));
                }
            }
            let rms = (an.iter().map(|a| a * a).sum::<f64>() / an.len() as f64).sqrt();
            // Entries far off are jumps (or a broken term, if many); on the
            // rest, the least-squares slope of analytic against finite
            // differences must be 1, which averages the f32 noise out and
            // catches a gradient that is off by 5 % or more. Agreeing entries
            // are within ~3 % plus f32 noise of ~1 % of the RMS; a jump that
            // stayed below the cut would dominate the slope (a Gaussian whose
            // footprint crosses the alpha cut-off is 30-60 % off), so the cut
            // sits well under that.
            let far: Vec<usize> = (0..an.len())
                .filter(|&i| {
                    (an[i] - fd[i]).abs() > 0.1 * an[i].abs().max(fd[i].abs()) + 0.05 * rms
                })
                .collect();
            let allowed = if geometry { an.len() / 5 } else { 0 };
            assert!(
                far.len() <= allowed,
                "{}: {} of {} gradients disagree with finite differences of the GPU forward, \
                 e.g. entry {}: analytic {} vs {}",
                names[kind],
                far.len(),
                an.len(),
                far[0],
                an[far[0]],
                fd[far[0]]
            );
            let (mut num, mut den) = (0.0, 0.0);
            for i in (0..an.len()).filter(|i| !far.contains(i)) {
                num += an[i] * fd[i];
                den += fd[i] * fd[i];
            }
            let slope = num / den;
            assert!(
                (slope - 1.0).abs() < 0.05,
                "{}: analytic gradients are {slope} times the finite differences",
                names[kind]
            );
        }
    });
}

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
