//! Rasterizer tests: GPU forward and backward against the f64 reference, the
//! reference against its own finite differences, GPU gradients against
//! finite differences of the GPU forward, and degenerate inputs, one file per
//! subject; here, the scenes, renders and checks they share.

#![allow(clippy::needless_range_loop)]

use glam::DVec3;
use rand::Rng;

use super::*;
use latentam_gpu::testing::{rng, with_cas_atomics, with_context, with_options};
use latentam_gpu::{Context, ContextOptions};
use latentam_reference::raster::{self as reference, Gaussian, ImageGrads, CHANNELS};

mod backward;
mod degenerate;
mod finite_differences;
mod forward;
mod kernels;
mod regions;

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

/// Both pixel-to-invocation mappings of the blending kernels.
const LAYOUTS: [BlendLayout; 2] = [BlendLayout::Pixels, BlendLayout::Columns];

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
