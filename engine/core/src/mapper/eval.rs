//! Quality of a map on a view (paper Sec. IV-A, Performance Metrics): the view is rendered
//! from the global map's Gaussians near the camera and compared with the
//! frame's colour (PSNR over all pixels), depth (L1 over valid pixels) and,
//! per pixel (the paper's protocol, [`super::pixel_metrics`], decoded on
//! the device), with the
//! region embeddings (cosine loss of each pixel's decoded query against its
//! region's target) and, with a vocabulary, the true classes (each pixel
//! classified among the vocabulary; mIoU over its classes). Without
//! semantic labels the true class of a region is the one its target
//! embedding is closest to (the teacher/student variant).
//!
//! The region-pooled figures of the same view, each region's mean rendered
//! query decoded once and given to all its pixels (what training
//! supervises), are kept as a second, more lenient set
//! ([`ViewMetrics::region_pooled`]) for debugging.

use std::collections::BTreeMap;

pub use super::class_iou::{add_iou, count_pixel, mean_iou, ClassCounts};
use super::history::{camera_of, KeyframeRecord, RegionTargets};
use super::pixel_metrics::{pixel_metrics_on_device, PixelInputs};
use crate::latent::{DevicePixelDecoder, LatentHead, RelevanceScorer, NO_REGION};
use crate::map::{push_gaussian, ExposureTrack, GlobalMap};
use crate::splat::{Camera, GaussianBuffers, HostGaussians, Rasterizer, RenderedView, QUERY_DIM};
use latentam_base::{Error, Result};
use latentam_gpu::Context;
use latentam_io::{Frame, Vocabulary};

/// What a view is rendered and scored from: a map's Gaussians (its GPU
/// window written back), the camera's exposure over time, and the latent
/// head once there is one.
#[derive(Clone, Copy)]
pub struct MapParts<'a> {
    /// Every Gaussian, by voxel.
    pub global: &'a GlobalMap,
    /// The camera's exposure at each keyframe.
    pub exposure: &'a ExposureTrack,
    /// W and D, once the map has embeddings.
    pub head: Option<&'a LatentHead>,
}

/// Metrics of one view.
///
/// ```no_run
/// use latentam_core::mapper::eval::mean_iou;
/// # fn f(mapper: &mut latentam_core::mapper::Mapper, frame: &latentam_io::Frame, vocabulary: &latentam_io::Vocabulary) -> latentam_core::Result<()> {
/// let m = mapper.evaluate(frame, Some(vocabulary), 2)?; // every 2nd pixel and row
/// println!("PSNR {:.2} dB, depth L1 {:.3} m, coverage {:.0} %", m.psnr, m.depth_l1, 100.0 * m.coverage);
/// if let Some(miou) = mean_iou(&m.class_iou) {
///     println!("mIoU {miou:.3} ({} classes)", m.class_iou.len());
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct ViewMetrics {
    /// Colour PSNR (dB), colours clamped to 0..1.
    pub psnr: f64,
    /// Mean absolute error (metres) of the rendered depth (Σ w·z / α, 0
    /// where nothing renders) over every pixel with a valid measured depth.
    pub depth_l1: f64,
    /// Share of pixels with α > 0.5.
    pub coverage: f64,
    /// Mean over pixels with a region target of 1 − cos(decoded query at
    /// the pixel, target).
    pub cosine_loss: Option<f64>,
    /// Mean over the same pixels of the L2 distance between the
    /// unit-normalised decoded query and the (unit) target, √(2 − 2 cos).
    pub l2: Option<f64>,
    /// Pixels in `cosine_loss` (to weigh views by).
    pub cosine_pixels: u64,
    /// Where the true classes of `class_iou` come from: `"labels"` (the
    /// frame's semantic image) or `"teacher"` (no labels: each region's
    /// class is the vocabulary entry closest to its target embedding,
    /// the teacher/student variant of Feature-3DGS's segmentation metric).
    pub segmentation: Option<&'static str>,
    /// Per vocabulary class id: pixel counts of the predicted and true
    /// class masks, each pixel classified on its own. Only pixels whose
    /// true class is in the vocabulary count: no query word can predict
    /// the others.
    pub class_iou: BTreeMap<u16, ClassCounts>,
    /// Every `pixel_stride`-th pixel and row were evaluated.
    pub pixel_stride: usize,
    /// The region-pooled figures (debugging).
    pub region_pooled: Option<RegionPooled>,
    /// Gaussians rendered.
    pub gaussians: usize,
}

/// A view's figures with each region's mean rendered query decoded once
/// and given to all its pixels: more lenient than the per-pixel protocol
/// (it hides boundary errors inside the ground-truth masks).
///
/// ```
/// # fn f(m: &latentam_core::mapper::eval::ViewMetrics) {
/// let pooled = m.region_pooled.as_ref().and_then(|r| r.cosine_loss);
/// if let (Some(pixel), Some(pooled)) = (m.cosine_loss, pooled) {
///     println!("cosine loss {pixel:.3} per pixel, {pooled:.3} region-pooled");
/// }
/// # }
/// ```
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RegionPooled {
    /// Mean over regions of 1 − cos(decoded pooled query, target).
    pub cosine_loss: Option<f64>,
    /// Mean over regions of √(2 − 2 cos).
    pub l2: Option<f64>,
    /// Regions compared.
    pub regions: usize,
    /// Per vocabulary class: pixel counts with each region's pixels given
    /// its pooled class.
    pub class_iou: BTreeMap<u16, ClassCounts>,
}

/// Renders and scores views of a map: what [`Mapper::render`] and
/// [`Mapper::evaluate`] run on.
///
/// [`Mapper::render`]: super::Mapper::render
/// [`Mapper::evaluate`]: super::Mapper::evaluate
pub(crate) struct Evaluator {
    ctx: Context,
    raster: Rasterizer,
    /// The rendered Gaussians (grown as views need).
    gaussians: Option<GaussianBuffers>,
    scorer: Option<RelevanceScorer>,
    /// The per-pixel decoder, updated to the head at every view.
    decoder: Option<DevicePixelDecoder>,
    /// Gaussians within this distance of the camera are rendered (metres);
    /// [`Evaluator::evaluate`] reaches further when the frame measures
    /// depth further away, so that every surface in view is rendered.
    pub radius: f64,
    /// Every `pixel_stride`-th pixel of every `pixel_stride`-th row is
    /// evaluated per pixel (1, the default: all). PSNR and depth use all.
    pub pixel_stride: usize,
}

impl Evaluator {
    /// An evaluator on `ctx` whose renders use the blending `layout`
    /// (the mapper's `blend_layout`).
    pub fn with_layout(ctx: &Context, layout: crate::splat::BlendLayout) -> Self {
        Evaluator {
            ctx: ctx.clone(),
            raster: {
                // Renders only: no gradient images.
                let mut r = Rasterizer::new(ctx);
                r.settings.query_gradient_image = false;
                r.settings.layout = layout;
                r
            },
            gaussians: None,
            scorer: None,
            decoder: None,
            radius: 8.0,
            pixel_stride: 1,
        }
    }

    /// Renders `camera`'s view of `map` from
    /// the Gaussians within [`Evaluator::radius`] of the camera; returns
    /// the view and the number of Gaussians rendered.
    pub fn render(&mut self, map: MapParts<'_>, camera: &Camera) -> Result<(RenderedView, usize)> {
        self.render_within(map, camera, self.radius)
    }

    /// Renders the view of `frame`'s camera, reaching at least as far as
    /// the frame measured depth (so every surface it saw is rendered), at
    /// the camera's exposure of the frame's time; returns the view and the
    /// number of Gaussians rendered.
    pub fn render_frame(
        &mut self,
        map: MapParts<'_>,
        frame: &Frame,
    ) -> Result<(RenderedView, usize)> {
        self.render_record(map, frame, &KeyframeRecord::from_frame(frame))
    }

    fn render_record(
        &mut self,
        map: MapParts<'_>,
        frame: &Frame,
        record: &KeyframeRecord,
    ) -> Result<(RenderedView, usize)> {
        let camera = camera_of(frame);
        // The farthest measured surface (a corner of the view lies further
        // than the depth along the axis), so nothing in view is left out.
        let k = frame.intrinsics;
        let corner2 = (k.width as f64 / k.fx).powi(2) + (k.height as f64 / k.fy).powi(2);
        let farthest = record.depth_mm.iter().copied().max().unwrap_or(0) as f64 * 1e-3;
        let reach = farthest * (1.0 + corner2).sqrt() + 0.5;
        let radius = if reach.is_finite() {
            self.radius.max(reach)
        } else {
            self.radius
        };
        let (mut view, n) = self.render_within(map, &camera, radius)?;
        // The map holds colours at its own brightness: the view is shown at
        // the camera's exposure of its time, from the keyframes around it.
        let gain = map.exposure.at(frame.stamp_ns);
        for p in &mut view.rgbd {
            p[..3].iter_mut().for_each(|c| *c *= gain);
        }
        Ok((view, n))
    }

    fn render_within(
        &mut self,
        map: MapParts<'_>,
        camera: &Camera,
        radius: f64,
    ) -> Result<(RenderedView, usize)> {
        let global = map.global;
        let mut host = HostGaussians::default();
        // Spilled blocks are read from disk for the render, not kept;
        // in key order, as the same view of the same map always was.
        for (_, g) in global.gaussians_within(camera.cam_to_world.translation, radius)? {
            push_gaussian(&mut host, &g);
        }
        let n = host.means.len();
        if n == 0 {
            return Err(Error::bad_input(
                "the view",
                "no Gaussians near it: nothing to render",
            ));
        }
        if self
            .gaussians
            .as_ref()
            .is_none_or(|b| b.capacity() < n as u64)
        {
            self.gaussians = None;
            self.gaussians = Some(GaussianBuffers::new(&self.ctx, "eval/gaussians", n as u64)?);
        }
        let buffers = self.gaussians.as_ref().expect("sized above");
        buffers.upload(&self.ctx, 0, &host)?;
        self.raster
            .forward(buffers, n as u64, std::slice::from_ref(camera))?;
        Ok((self.raster.download_view(0)?, n))
    }

    /// Metrics of `frame` rendered from `map`. Segmentation needs `vocabulary` and the frame's semantic
    /// labels; embeddings need the latent head.
    pub fn evaluate(
        &mut self,
        map: MapParts<'_>,
        frame: &Frame,
        vocabulary: Option<&Vocabulary>,
    ) -> Result<ViewMetrics> {
        let record = KeyframeRecord::from_frame(frame);
        let (view, n) = self.render_record(map, frame, &record)?;
        let mut m = image_metrics(&view, &record.target_rgbd());
        m.gaussians = n;
        m.pixel_stride = self.pixel_stride.max(1);

        // Embedding figures need a dictionary and something to score.
        let texts_needed = vocabulary
            .map_or(0, |v| v.names.len())
            .max(record.regions.as_ref().map_or(0, |r| r.count as usize));
        let Some(head) = map.head.filter(|h| h.atom_count() > 0 && texts_needed > 0) else {
            return Ok(m);
        };
        let scorer =
            RelevanceScorer::ensure(&mut self.scorer, &self.ctx, head, texts_needed as u32)?;
        let (w, h) = (view.width as usize, view.height as usize);

        // Regions: pooled rendered queries against their targets and, with a
        // vocabulary, classified (the class scoring highest) for the
        // region's pixels — the same mask pooling that training supervises.
        let Some(r) = record.regions.as_ref().filter(|r| !r.grid) else {
            return Ok(m);
        };
        let dim = r.dim as usize;
        let regions = pixel_regions(r, w, h);
        let (sums, counts) = region_sums(&view.query, &regions, r.count as usize);
        let (used, pooled) = pooled_queries(&sums, &counts);
        if used.is_empty() {
            return Ok(m);
        }
        let targets_of_pixels: Vec<u32> = regions
            .iter()
            .map(|&l| if l < sums.len() { l as u32 } else { NO_REGION })
            .collect();
        let vocab = vocabulary.filter(|v| v.dim == head.config().dim && !v.names.is_empty());
        let mut pooled_m =
            pooled_target_metrics(scorer, &self.ctx, head, &pooled, &used, &r.vectors, dim)?;
        // Each pixel's true class: its label, or without labels its
        // region's teacher class (targets are unit-norm, so the cosine
        // ranking is the dot product with the normalised class vectors).
        let truth_of_pixels = match vocab {
            Some(vocab) => {
                let teacher = frame
                    .semantic
                    .is_none()
                    .then(|| teacher_classes(vocab, &r.vectors, dim, sums.len()));
                m.segmentation = Some(["labels", "teacher"][teacher.is_some() as usize]);
                pixel_truth(frame, teacher.as_deref(), &regions, vocab, w, h)
            }
            None => vec![0u16; w * h],
        };
        // Per pixel, the paper's protocol, decoded on the device.
        let decoder = DevicePixelDecoder::ensure(&mut self.decoder, &self.ctx, head)?;
        let pixels = pixel_metrics_on_device(
            &self.ctx,
            decoder,
            &PixelInputs {
                width: w,
                height: h,
                queries: &view.query,
                region: &targets_of_pixels,
                targets: &r.vectors,
                truth: &truth_of_pixels,
                vocabulary: vocab.map(|v| (&v.ids[..], &v.vectors[..])),
                stride: self.pixel_stride,
            },
        )?;
        m.cosine_loss = pixels.cosine_loss();
        m.l2 = pixels.l2();
        m.cosine_pixels = pixels.cosine_pixels;
        m.class_iou = pixels.class_iou;
        // Pooled: each region's mean query classified once for its pixels.
        if let Some(vocab) = vocab {
            let scores = scorer.score(&self.ctx, head, &pooled, &vocab.vectors)?;
            let predicted = pooled_classes(vocab, &scores, &used, sums.len());
            for (&truth, &region) in truth_of_pixels.iter().zip(&regions) {
                if truth != 0 {
                    let pred = predicted.get(region).copied().flatten();
                    count_pixel(&mut pooled_m.class_iou, truth, pred);
                }
            }
        }
        m.region_pooled = Some(pooled_m);
        Ok(m)
    }
}

/// The regions with pixels and each one's mean rendered query.
fn pooled_queries(
    sums: &[[f64; QUERY_DIM]],
    counts: &[u64],
) -> (Vec<usize>, Vec<[f32; QUERY_DIM]>) {
    let used: Vec<usize> = (0..sums.len()).filter(|&i| counts[i] > 0).collect();
    let pooled = used
        .iter()
        .map(|&i| std::array::from_fn(|c| (sums[i][c] / counts[i] as f64) as f32))
        .collect();
    (used, pooled)
}

/// Each pixel's region in a `w` × `h` view: the label image scaled to it.
fn pixel_regions(r: &RegionTargets, w: usize, h: usize) -> Vec<usize> {
    (0..w * h)
        .map(|p| {
            let ly = (p / w) * r.height as usize / h;
            let lx = (p % w) * r.width as usize / w;
            r.labels[ly * r.width as usize + lx] as usize
        })
        .collect()
}

/// The class each region's pooled query scores highest, by region index
/// (`None` for regions without pixels): `scores` holds one row of
/// `vocab`'s classes per region of `used`.
fn pooled_classes(
    vocab: &Vocabulary,
    scores: &[f32],
    used: &[usize],
    regions: usize,
) -> Vec<Option<u16>> {
    let c = vocab.names.len();
    let mut predicted = vec![None; regions];
    for (j, &i) in used.iter().enumerate() {
        predicted[i] = Some(vocab.ids[argmax(&scores[j * c..(j + 1) * c])]);
    }
    predicted
}

/// Each pixel's true class: its label scaled to the view, or without
/// labels its region's teacher class; 0 (not evaluated) for unlabelled
/// pixels and for classes no word of `vocab` names.
fn pixel_truth(
    frame: &Frame,
    teacher: Option<&[Option<u16>]>,
    regions: &[usize],
    vocab: &Vocabulary,
    w: usize,
    h: usize,
) -> Vec<u16> {
    (0..w * h)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            let truth = match (&frame.semantic, teacher) {
                (Some(sem), _) => {
                    let sy = y * sem.height as usize / h;
                    let sx = x * sem.width as usize / w;
                    sem.labels[sy * sem.width as usize + sx]
                }
                (None, Some(t)) => t.get(regions[p]).copied().flatten().unwrap_or(0),
                (None, None) => 0,
            };
            if vocab.ids.contains(&truth) {
                truth
            } else {
                0
            }
        })
        .collect()
}

/// Per region, the sum of its pixels' rendered queries and their count
/// (pixels whose region is `count` or more belong to none).
fn region_sums(
    queries: &[[f32; QUERY_DIM]],
    regions: &[usize],
    count: usize,
) -> (Vec<[f64; QUERY_DIM]>, Vec<u64>) {
    let mut sums = vec![[0.0f64; QUERY_DIM]; count];
    let mut counts = vec![0u64; count];
    for (q, &l) in queries.iter().zip(regions) {
        if l < count {
            counts[l] += 1;
            for (s, v) in sums[l].iter_mut().zip(q) {
                *s += *v as f64;
            }
        }
    }
    (sums, counts)
}

/// Colour PSNR over every pixel, depth L1 over the pixels with a measured
/// depth, and the share of pixels the map covers.
fn image_metrics(view: &RenderedView, target: &[[f32; 4]]) -> ViewMetrics {
    let mut se = 0.0f64;
    let (mut l1, mut valid) = (0.0f64, 0u64);
    for ((p, t), &a) in view.rgbd.iter().zip(target).zip(&view.alpha) {
        for c in 0..3 {
            se += (p[c].clamp(0.0, 1.0) as f64 - t[c] as f64).powi(2);
        }
        // Every pixel with a measured depth counts: where the map renders
        // nothing the error is the whole depth.
        if t[3] > 0.0 && t[3].is_finite() {
            let rendered = if a > 1e-6 {
                p[3] as f64 / a as f64
            } else {
                0.0
            };
            l1 += (rendered - t[3] as f64).abs();
            valid += 1;
        }
    }
    let mse = se / (3 * target.len()).max(1) as f64;
    let covered = view.alpha.iter().filter(|&&a| a > 0.5).count();
    ViewMetrics {
        coverage: covered as f64 / view.alpha.len().max(1) as f64,
        psnr: -10.0 * mse.max(1e-12).log10(),
        depth_l1: if valid > 0 { l1 / valid as f64 } else { 0.0 },
        ..ViewMetrics::default()
    }
}

/// Each region's pooled query decoded once against its target (the
/// regions whose target is not all zero): mean cosine loss and L2.
fn pooled_target_metrics(
    scorer: &RelevanceScorer,
    ctx: &Context,
    head: &crate::latent::LatentHead,
    pooled: &[[f32; QUERY_DIM]],
    used: &[usize],
    vectors: &[f32],
    dim: usize,
) -> Result<RegionPooled> {
    let mut m = RegionPooled::default();
    let target_of = |j: usize| &vectors[used[j] * dim..(used[j] + 1) * dim];
    let with_target: Vec<usize> = (0..used.len())
        .filter(|&j| target_of(j).iter().any(|&x| x != 0.0))
        .collect();
    if with_target.is_empty() {
        return Ok(m);
    }
    let targets: Vec<f32> = with_target
        .iter()
        .flat_map(|&j| target_of(j).iter().copied())
        .collect();
    let q: Vec<[f32; QUERY_DIM]> = with_target.iter().map(|&j| pooled[j]).collect();
    let s = scorer.score(ctx, head, &q, &targets)?;
    let k = q.len();
    m.cosine_loss = Some((0..k).map(|i| 1.0 - s[i * k + i] as f64).sum::<f64>() / k as f64);
    m.l2 = Some(
        (0..k)
            .map(|i| (2.0 - 2.0 * s[i * k + i] as f64).max(0.0).sqrt())
            .sum::<f64>()
            / k as f64,
    );
    m.regions = k;
    Ok(m)
}

/// Without semantic labels, each region's true class is its teacher
/// class: the vocabulary word whose normalised vector is closest to the
/// region's target (targets are unit-norm, so the cosine ranking is the
/// dot product). Regions without a target have none.
fn teacher_classes(
    vocab: &Vocabulary,
    vectors: &[f32],
    dim: usize,
    regions: usize,
) -> Vec<Option<u16>> {
    let texts: Vec<Vec<f32>> = vocab
        .vectors
        .chunks_exact(dim)
        .map(|t| {
            let n = t.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
            t.iter().map(|x| x / n).collect()
        })
        .collect();
    (0..regions)
        .map(|i| {
            let target = &vectors[i * dim..(i + 1) * dim];
            if target.iter().all(|&x| x == 0.0) {
                return None;
            }
            let row: Vec<f32> = texts
                .iter()
                .map(|t| t.iter().zip(target).map(|(a, b)| a * b).sum())
                .collect();
            Some(vocab.ids[argmax(&row)])
        })
        .collect()
}

/// The index of a row's largest value.
fn argmax(row: &[f32]) -> usize {
    (0..row.len())
        .max_by(|&a, &b| row[a].total_cmp(&row[b]))
        .expect("a non-empty row")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn miou_averages_the_classes_of_the_ground_truth() {
        let mut c = BTreeMap::new();
        // Class 1: 3 true pixels, 2 found; one pixel of class 2 taken for 1.
        count_pixel(&mut c, 1, Some(1));
        count_pixel(&mut c, 1, Some(1));
        count_pixel(&mut c, 1, None);
        count_pixel(&mut c, 2, Some(1));
        // Class 3 is only ever predicted (never true): not averaged.
        count_pixel(&mut c, 2, Some(3));
        assert_eq!(
            c[&1],
            ClassCounts {
                intersection: 2,
                union: 4,
                truth: 3
            }
        );
        assert_eq!(c[&2].iou(), 0.0);
        assert_eq!(c[&3].truth, 0);
        let m = mean_iou(&c).unwrap();
        assert!((m - (0.5 + 0.0) / 2.0).abs() < 1e-12, "{m}");
        let mut sum = BTreeMap::new();
        add_iou(&mut sum, &c);
        add_iou(&mut sum, &c);
        assert_eq!(sum[&1].union, 8);
        assert_eq!(mean_iou(&sum), Some(m));
        assert_eq!(mean_iou(&BTreeMap::new()), None);
    }
}
