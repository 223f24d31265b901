//! The built-in demo scene (`latentam gen-scene`, and the input of
//! `latentam demo`): two textured rooms joined by a corridor with fourteen
//! labelled objects, ray cast on the CPU along a path that leaves and
//! re-enters the rooms, written as a ROS 2 MCAP log in the layout the
//! engine reads.
//!
//! The region embeddings are **synthetic**: each class gets a seeded random
//! unit vector, each instance a perturbed copy of its class vector, and
//! each view a fresh perturbation of the instance vector (cosine ≈ 0.85 to
//! it by default, about what a vision-language model gives one object
//! across views); every visible instance is one region, and its mask, as a
//! segmenter's would, misses or spills over some pixels along its
//! boundary. They exercise the mapper the way real vision-language
//! embeddings would (a shared space, classes far apart, views of one thing
//! close but never equal) without a model. The log's metadata says so, and
//! the vocabulary message carries the class vectors so that
//! open-vocabulary queries and mIoU can be evaluated; the semantic images
//! stay exact.

mod building;
mod geometry;
mod layout;
mod render;
mod trajectory;

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{bail, Context};
use glam::{DQuat, Mat3};
use latentam_io::{
    cdr, encode_floats, CameraInfo, Compression, Dtype, Header, Image, LogWriter, MaskFeatures,
    Pose, PoseStamped, TextEmbeddings,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub use building::{building, MAX_ROOMS, MIN_ROOMS};
pub use layout::{Scene, CLASSES};
pub use render::{intrinsics, render, View};
pub use trajectory::{camera_pose, camera_pose_laps, CameraPath};

/// What to generate.
#[derive(Clone, Debug)]
pub struct SceneConfig {
    /// Number of frames.
    pub frames: usize,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Embedding dimension.
    pub dim: usize,
    /// Embedding element type.
    pub dtype: Dtype,
    /// Seed of the embeddings.
    pub seed: u64,
    /// Frame rate (stamps are `1/fps` apart).
    pub fps: f64,
    /// Instances covering fewer pixels in a view are not made regions.
    pub min_region_pixels: usize,
    /// Size of the per-instance perturbation relative to the class vector.
    pub instance_spread: f32,
    /// Size of the per-view perturbation relative to the instance vector
    /// ([`spread_for_cosine`]).
    pub view_spread: f32,
    /// Probability that a pixel on a mask's boundary is mislabelled: left
    /// out of its mask or given to the neighbouring one (half each).
    pub mask_noise: f32,
    /// Chunk compression.
    pub compression: Compression,
    /// Traversals of the path, alternately forwards and backwards (long
    /// runs that keep revisiting the same rooms).
    pub laps: usize,
    /// Auto-exposure: the camera's gain swings between `exp(-swing)` and
    /// `exp(swing)` over the run ([`exposure_gain`]); 0 keeps it at 1.
    pub exposure_swing: f32,
    /// A building of this many rooms ([`building`]) instead of the demo
    /// world's two.
    pub rooms: Option<usize>,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig {
            frames: 300,
            width: 160,
            height: 120,
            dim: 512,
            dtype: Dtype::F16,
            seed: 7,
            fps: 10.0,
            min_region_pixels: 16,
            instance_spread: 0.35,
            view_spread: spread_for_cosine(0.85),
            mask_noise: 0.5,
            compression: Compression::Zstd,
            laps: 1,
            exposure_swing: 0.0,
            rooms: None,
        }
    }
}

/// The camera's gain at frame `i`: one and a half slow swings of
/// `exp(±exposure_swing)` over the run, as auto-exposure moves between
/// bright and dark parts of a scene. Colour channels are multiplied by it
/// (and clipped at 255).
pub fn exposure_gain(config: &SceneConfig, i: usize) -> f32 {
    let phase = 3.0 * std::f32::consts::PI * i as f32 / config.frames.max(1) as f32;
    (config.exposure_swing * phase.sin()).exp()
}

/// Model id written in the embedding messages.
pub const MODEL: &str = "synthetic:latentam-gen-scene-1";
/// Stamp of the first frame: 2023-11-14T22:13:20Z.
pub const START_NS: i64 = 1_700_000_000_000_000_000;

/// Slowest synthetic frame rate (frames per second) a log is stamped at:
/// a frame every 1000 s keeps 7 million frames' stamps within i64.
pub const MIN_FPS: f64 = 1e-3;
/// Fastest synthetic frame rate: a frame every microsecond, far apart in
/// nanosecond stamps (at 1e300 every frame had the same stamp).
pub const MAX_FPS: f64 = 1e6;

/// What was written.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SceneSummary {
    /// Frames written.
    pub frames: usize,
    /// Regions over all frames.
    pub regions: usize,
    /// Labelled objects in the world.
    pub objects: usize,
    /// Classes in the vocabulary (without "unlabelled").
    pub classes: usize,
    /// Length of one traversal of the camera path, metres.
    pub path_metres: f32,
}

fn unit_gaussian(rng: &mut ChaCha8Rng, dim: usize) -> Vec<f32> {
    // Box–Muller; the pairs' second value is used too.
    let mut v = Vec::with_capacity(dim + 1);
    while v.len() < dim {
        let u1: f32 = rng.random_range(f32::EPSILON..1.0);
        let u2: f32 = rng.random();
        let r = (-2.0 * u1.ln()).sqrt();
        v.push(r * (std::f32::consts::TAU * u2).cos());
        v.push(r * (std::f32::consts::TAU * u2).sin());
    }
    v.truncate(dim);
    normalized(v)
}

fn normalized(mut v: Vec<f32>) -> Vec<f32> {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
    v.iter_mut().for_each(|x| *x /= n);
    v
}

/// The perturbation size that leaves a unit vector at cosine `c` to its
/// perturbed copy (in high dimensions, where the noise is nearly
/// orthogonal to it): `1 / √(1 + s²) = c`.
pub fn spread_for_cosine(c: f32) -> f32 {
    let c = c.clamp(1e-3, 1.0);
    (1.0 / (c * c) - 1.0).max(0.0).sqrt()
}

fn perturbed(base: &[f32], spread: f32, rng: &mut ChaCha8Rng) -> Vec<f32> {
    let noise = unit_gaussian(rng, base.len());
    normalized(
        base.iter()
            .zip(&noise)
            .map(|(b, n)| b + spread * n)
            .collect(),
    )
}

/// The embedding of every class (index = class id; index 0 unused) and
/// every instance (index = instance id), from the seed.
pub fn embedding_tables(scene: &Scene, config: &SceneConfig) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let classes: Vec<Vec<f32>> = (0..CLASSES.len())
        .map(|_| unit_gaussian(&mut rng, config.dim))
        .collect();
    let instances = scene
        .instances
        .iter()
        .map(|i| perturbed(&classes[i.class as usize], config.instance_spread, &mut rng))
        .collect();
    (classes, instances)
}

/// Regions of one view: the label image (region per pixel, 65535 = none)
/// and the instance id of each region, in order of first appearance.
pub fn regions(instance: &[u16], min_pixels: usize) -> (Vec<u16>, Vec<u16>) {
    let mut counts: BTreeMap<u16, usize> = BTreeMap::new();
    for &i in instance {
        *counts.entry(i).or_default() += 1;
    }
    let mut order = Vec::new();
    let mut index = BTreeMap::new();
    for &i in instance {
        if i != 0 && counts[&i] >= min_pixels && !index.contains_key(&i) {
            index.insert(i, order.len() as u16);
            order.push(i);
        }
    }
    let labels = instance
        .iter()
        .map(|i| index.get(i).copied().unwrap_or(u16::MAX))
        .collect();
    (labels, order)
}

/// Instance masks as a segmenter would give them: each pixel on a boundary
/// between two instances (a 4-neighbour belongs to the other) is, with
/// probability `rate`, left out of every mask (0) or given to that
/// neighbour (a spill), half each. Decided from the exact masks, so the
/// noise is at most one pixel deep.
pub fn imperfect_masks(
    instance: &[u16],
    width: u32,
    height: u32,
    rate: f32,
    rng: &mut ChaCha8Rng,
) -> Vec<u16> {
    let (w, h) = (width as usize, height as usize);
    let mut out = instance.to_vec();
    if rate <= 0.0 {
        return out;
    }
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let own = instance[i];
            let mut other = None;
            if x > 0 && instance[i - 1] != own {
                other = Some(instance[i - 1]);
            } else if x + 1 < w && instance[i + 1] != own {
                other = Some(instance[i + 1]);
            } else if y > 0 && instance[i - w] != own {
                other = Some(instance[i - w]);
            } else if y + 1 < h && instance[i + w] != own {
                other = Some(instance[i + w]);
            }
            let Some(other) = other else {
                continue;
            };
            if rng.random::<f32>() < rate {
                out[i] = if rng.random::<bool>() { 0 } else { other };
            }
        }
    }
    out
}

fn check(config: &SceneConfig) -> anyhow::Result<()> {
    if config.frames == 0 {
        bail!("--frames must be at least 1");
    }
    if !(16..=4096).contains(&config.width) || !(16..=4096).contains(&config.height) {
        bail!(
            "image size {}×{} outside 16…4096 per side",
            config.width,
            config.height
        );
    }
    if config.dim == 0 || config.dim > 8192 {
        bail!("embedding dimension {} outside 1…8192", config.dim);
    }
    if !(MIN_FPS..=MAX_FPS).contains(&config.fps) {
        bail!(
            "frame rate {:?} outside {MIN_FPS}…{MAX_FPS} frames per second",
            config.fps
        );
    }
    let last_ns = config.frames.saturating_sub(1) as f64 * 1e9 / config.fps;
    if START_NS as f64 + last_ns >= i64::MAX as f64 {
        bail!(
            "{} frames at {:?} frames per second run past the largest stamp",
            config.frames,
            config.fps
        );
    }
    if !(0.0..=1.0).contains(&config.mask_noise) {
        bail!("mask noise {} outside 0…1", config.mask_noise);
    }
    if let Some(n) = config.rooms {
        if !(MIN_ROOMS..=MAX_ROOMS).contains(&n) {
            bail!("--rooms {n} outside {MIN_ROOMS}…{MAX_ROOMS}");
        }
    }
    if !(config.view_spread >= 0.0 && config.view_spread.is_finite()) {
        bail!("view spread {} must be finite and ≥ 0", config.view_spread);
    }
    Ok(())
}

fn bytes_u16(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

type SceneLog = LogWriter<std::io::BufWriter<std::fs::File>>;

/// The vocabulary: every class but "unlabelled".
fn write_vocabulary(
    log: &mut SceneLog,
    config: &SceneConfig,
    class_vecs: &[Vec<f32>],
) -> anyhow::Result<()> {
    let names: Vec<&str> = CLASSES[1..].to_vec();
    let ids: Vec<u16> = (1..CLASSES.len() as u16).collect();
    let vocab_data = encode_floats(&class_vecs[1..].concat(), config.dtype);
    let ids_bytes = bytes_u16(&ids);
    log.write(
        "/vocabulary",
        START_NS as u64,
        &TextEmbeddings {
            header: Header::at(START_NS, "map"),
            names,
            ids: cdr::Seq::new(&ids_bytes, cdr::Endian::Little),
            dim: config.dim as u32,
            dtype: config.dtype.name(),
            data: &vocab_data,
            model: MODEL,
        },
    )?;
    Ok(())
}

/// Frame `i`'s region embeddings: its instances' masks made imperfect,
/// one vector each, perturbed per view. Returns the number of regions.
fn write_embeddings(
    log: &mut SceneLog,
    config: &SceneConfig,
    view: &View,
    instance_vecs: &[Vec<f32>],
    i: usize,
    header: Header<'_>,
) -> anyhow::Result<usize> {
    let (w, h) = (config.width, config.height);
    let mut rng = ChaCha8Rng::seed_from_u64(
        config.seed ^ (0x5851_f42d_4c95_7f2d_u64.wrapping_mul(i as u64 + 1)),
    );
    let masks = imperfect_masks(&view.instance, w, h, config.mask_noise, &mut rng);
    let (labels, order) = regions(&masks, config.min_region_pixels);
    let vectors: Vec<f32> = order
        .iter()
        .flat_map(|&inst| perturbed(&instance_vecs[inst as usize], config.view_spread, &mut rng))
        .collect();
    let data = encode_floats(&vectors, config.dtype);
    let label_bytes = bytes_u16(&labels);
    log.write(
        "/camera/embeddings",
        header.stamp.as_nanos() as u64,
        &MaskFeatures {
            header,
            height: h,
            width: w,
            labels: cdr::Seq::new(&label_bytes, cdr::Endian::Little),
            count: order.len() as u32,
            dim: config.dim as u32,
            dtype: config.dtype.name(),
            data: &data,
            model: MODEL,
        },
    )?;
    Ok(order.len())
}

/// Writes the scene to `out`, calling `progress(frames_done)` after each
/// frame.
pub fn generate(
    config: &SceneConfig,
    out: &Path,
    mut progress: impl FnMut(usize),
) -> anyhow::Result<SceneSummary> {
    check(config)?;
    let (scene, path) = match config.rooms {
        Some(n) => building(n),
        None => (Scene::two_rooms(), CameraPath::demo()),
    };
    let (class_vecs, instance_vecs) = embedding_tables(&scene, config);
    let partial = latentam_base::files::PartialFile::new(out)?;
    let mut log = LogWriter::create(partial.path(), config.compression)
        .with_context(|| format!("creating {}", partial.path().display()))?;
    let (w, h) = (config.width, config.height);
    let k = intrinsics(w, h);
    let frame_id = "camera_color_optical_frame";

    write_vocabulary(&mut log, config, &class_vecs)?;

    let mut regions_total = 0;
    for i in 0..config.frames {
        let stamp = START_NS + (i as f64 * 1e9 / config.fps).round() as i64;
        let t = stamp as u64;
        let header = Header::at(stamp, frame_id);
        let (rotation, position) = path.pose(i, config.frames, config.laps);
        let mut view = render(&scene, rotation, position, w, h);
        let gain = exposure_gain(config, i);
        if gain != 1.0 {
            for c in &mut view.color {
                *c = (*c as f32 * gain).round().min(255.0) as u8;
            }
        }

        log.write(
            "/camera/color/camera_info",
            t,
            &CameraInfo::pinhole(header, w, h, k),
        )?;
        log.write(
            "/camera/pose",
            t,
            &PoseStamped {
                header: Header::at(stamp, "map"),
                pose: Pose {
                    translation: position.as_dvec3(),
                    rotation: DQuat::from_mat3(&Mat3::as_dmat3(&rotation)).normalize(),
                },
            },
        )?;
        let image = |encoding, data| Image::packed(header, w, h, encoding, data);
        log.write("/camera/color/image_raw", t, &image("rgb8", &view.color))?;
        let depth = bytes_u16(&view.depth_mm);
        log.write("/camera/depth/image_raw", t, &image("16UC1", &depth))?;
        let class = bytes_u16(&view.class);
        log.write("/camera/semantic", t, &image("16UC1", &class))?;
        let instance = bytes_u16(&view.instance);
        log.write("/camera/instances", t, &image("16UC1", &instance))?;

        regions_total += write_embeddings(&mut log, config, &view, &instance_vecs, i, header)?;
        progress(i + 1);
    }
    let meta = BTreeMap::from([
        (
            "generator".to_string(),
            format!("latentam gen-scene {}", env!("CARGO_PKG_VERSION")),
        ),
        (
            "embeddings".to_string(),
            format!(
                "synthetic: seeded class vectors, perturbed per instance and per view \
                 (spread {:.3}); boundary mask noise {:.2}",
                config.view_spread, config.mask_noise
            ),
        ),
        ("seed".to_string(), config.seed.to_string()),
        ("frames".to_string(), config.frames.to_string()),
        ("size".to_string(), format!("{w}x{h}")),
        ("dim".to_string(), config.dim.to_string()),
    ]);
    let mut meta = meta;
    if let Some(n) = config.rooms {
        meta.insert("rooms".to_string(), n.to_string());
    }
    log.metadata("latentam", meta)?;
    log.finish()?;
    partial.commit()?;
    Ok(SceneSummary {
        frames: config.frames,
        regions: regions_total,
        objects: scene.object_count(),
        classes: CLASSES.len() - 1,
        path_metres: path.length(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_keep_first_appearance_order_and_drop_small_ones() {
        let inst = [0, 5, 5, 3, 3, 3, 9, 5];
        let (labels, order) = regions(&inst, 2);
        assert_eq!(order, [5, 3]);
        assert_eq!(labels, [u16::MAX, 0, 0, 1, 1, 1, u16::MAX, 0]);
    }

    #[test]
    fn imperfect_masks_change_only_boundary_pixels_and_both_ways() {
        // Two instances split down the middle of a 20×10 image.
        let (w, h) = (20u32, 10u32);
        let exact: Vec<u16> = (0..w * h).map(|i| if i % w < 10 { 1 } else { 2 }).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (mut missed, mut spilled) = (0, 0);
        for _ in 0..50 {
            let noisy = imperfect_masks(&exact, w, h, 0.5, &mut rng);
            for (i, (&a, &b)) in exact.iter().zip(&noisy).enumerate() {
                let x = i as u32 % w;
                if a == b {
                    continue;
                }
                assert!(x == 9 || x == 10, "pixel {i} is not on the boundary");
                if b == 0 {
                    missed += 1;
                } else {
                    assert_eq!(b, 3 - a, "spills take the neighbour's label");
                    spilled += 1;
                }
            }
        }
        // 50 × 20 boundary pixels at rate 0.5, half each way: 250 ± 3σ.
        for n in [missed, spilled] {
            assert!(
                (200..=300).contains(&n),
                "missed {missed}, spilled {spilled}"
            );
        }
        assert_eq!(imperfect_masks(&exact, w, h, 0.0, &mut rng), exact);
    }

    #[test]
    fn per_view_embeddings_sit_at_the_asked_cosine() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let base = unit_gaussian(&mut rng, 768);
        for c in [0.85f32, 0.95] {
            let v = perturbed(&base, spread_for_cosine(c), &mut rng);
            let got: f32 = v.iter().zip(&base).map(|(a, b)| a * b).sum();
            assert!((got - c).abs() < 0.03, "asked {c}, got {got}");
        }
    }

    #[test]
    fn views_see_the_rooms_with_valid_depth_and_labels() {
        let scene = Scene::two_rooms();
        assert_eq!(scene.object_count(), 14);
        let frames = 60;
        let mut seen = std::collections::BTreeSet::new();
        for i in (0..frames).step_by(6) {
            let (r, p) = camera_pose(i, frames);
            let v = render(&scene, r, p, 64, 48);
            // Closed rooms: every ray hits something within the building.
            let valid = v.depth_mm.iter().filter(|&&d| d > 0).count();
            assert_eq!(valid, v.depth_mm.len(), "frame {i}: holes in depth");
            assert!(v.depth_mm.iter().all(|&d| d < 15_000));
            assert!(v
                .class
                .iter()
                .all(|&c| (1..CLASSES.len() as u16).contains(&c)));
            seen.extend(v.instance.iter().copied());
            // Textures vary: not a flat image.
            let distinct: std::collections::BTreeSet<_> = v.color.chunks(3).collect();
            assert!(distinct.len() > 50, "frame {i}: {} colours", distinct.len());
        }
        let objects = seen
            .iter()
            .filter(|&&i| scene.instances[i as usize].class >= 4)
            .count();
        assert!(objects >= 8, "only {objects} objects ever visible");
    }

    #[test]
    fn embeddings_are_close_within_a_class_and_far_across() {
        let scene = Scene::two_rooms();
        let config = SceneConfig::default();
        let (classes, instances) = embedding_tables(&scene, &config);
        let cos = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>();
        for (id, inst) in scene.instances.iter().enumerate().skip(1) {
            let own = cos(&instances[id], &classes[inst.class as usize]);
            assert!(own > 0.9, "{}: {own}", inst.name);
            for (c, v) in classes.iter().enumerate().skip(1) {
                if c != inst.class as usize {
                    assert!(cos(&instances[id], v).abs() < 0.3);
                }
            }
        }
        let (again, _) = embedding_tables(&scene, &config);
        assert_eq!(again, classes, "deterministic for a seed");
    }
}
