//! Past keyframes kept for replay: each Stage I batch is the new keyframe
//! plus `B` of these, sampled uniformly without replacement (paper
//! Alg. 1). Images are kept compact (RGB bytes, millimetre depth) and
//! expanded when a batch is built.

use std::collections::HashMap;

use crate::latent::{LabelImage, RegionSource};
use crate::splat::Camera;
use latentam_base::random::SplitMix;
use latentam_io::{EmbeddingLayout, Frame};

/// Region targets of a keyframe.
///
/// ```
/// # fn f(record: &latentam_core::mapper::KeyframeRecord) {
/// if let Some(r) = &record.regions {
///     let kind = if r.grid { "grid cells" } else { "regions" };
///     println!("{} {kind} on a {}×{} label image, {}-d targets", r.count, r.width, r.height, r.dim);
/// }
/// # }
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct RegionTargets {
    /// Label image columns.
    pub width: u32,
    /// Label image rows.
    pub height: u32,
    /// Region per label pixel (65535 = none); for grids, the cell index
    /// per grid cell (`width × height` = columns × rows).
    pub labels: Vec<u16>,
    /// Whether `labels` is a feature grid (one region per cell).
    pub grid: bool,
    /// Number of regions.
    pub count: u32,
    /// `count × dim` unit-norm target embeddings (zero rows for regions
    /// whose embedding was zero: they get no weight).
    pub vectors: Vec<f32>,
    /// Embedding dimension.
    pub dim: u32,
}

impl RegionTargets {
    /// The regions as laid over the keyframe's view.
    pub fn source(&self) -> RegionSource<'_> {
        if self.grid {
            RegionSource::Grid {
                rows: self.height,
                cols: self.width,
            }
        } else {
            RegionSource::Labels {
                image: LabelImage {
                    width: self.width,
                    height: self.height,
                    labels: &self.labels,
                },
                count: self.count,
            }
        }
    }
}

/// One keyframe as kept for replay.
///
/// ```
/// use latentam_core::mapper::KeyframeRecord;
/// # fn f(frame: &latentam_io::Frame) {
/// let record = KeyframeRecord::from_frame(frame); // RGB bytes, millimetre depth
/// println!("{} ns: {} pixels with depth, {} bytes kept", record.stamp_ns, record.valid_depth(), record.bytes());
/// # }
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframeRecord {
    /// Stamp of the frame.
    pub stamp_ns: i64,
    /// The view (pose and intrinsics).
    pub camera: Camera,
    /// Packed RGB.
    pub rgb: Vec<u8>,
    /// Depth in millimetres, 0 where invalid (or beyond 65.5 m).
    pub depth_mm: Vec<u16>,
    /// Region targets, when the frame had embeddings.
    pub regions: Option<RegionTargets>,
    /// The camera's gain over the map when it took the frame
    /// (`map::relative_exposure`; 1 without exposure compensation): the
    /// frame's colours divided by it are in the map's brightness.
    pub exposure: f32,
}

/// The camera of a frame (its pose and intrinsics; default depth range).
pub fn camera_of(frame: &Frame) -> Camera {
    let k = frame.intrinsics;
    let mut cam = Camera::at_origin(k.width, k.height);
    cam.cam_to_world =
        glam::DAffine3::from_rotation_translation(frame.pose.rotation, frame.pose.translation);
    cam.fx = k.fx;
    cam.fy = k.fy;
    cam.cx = k.cx;
    cam.cy = k.cy;
    cam
}

fn unit_rows(mut v: Vec<f32>, dim: usize) -> Vec<f32> {
    for row in v.chunks_mut(dim) {
        let n = row.iter().map(|x| x * x).sum::<f32>().sqrt();
        if n > 1e-12 && n.is_finite() {
            row.iter_mut().for_each(|x| *x /= n);
        } else {
            row.iter_mut().for_each(|x| *x = 0.0);
        }
    }
    v
}

impl KeyframeRecord {
    /// Keeps what replaying `frame` needs.
    pub fn from_frame(frame: &Frame) -> Self {
        let depth_mm = (0..frame.depth.len())
            .map(|i| {
                frame.depth.metres(i).map_or(0, |m| {
                    (m * 1000.0).round().clamp(0.0, u16::MAX as f32) as u16
                })
            })
            .collect();
        // Embeddings with no usable vector (all zero or non-finite: zero
        // once made unit) teach nothing; the keyframe maps geometry only.
        let regions = frame.embeddings.as_ref().and_then(|e| {
            let vectors = unit_rows(e.to_f32(), e.dim as usize);
            if vectors.iter().all(|&x| x == 0.0) {
                return None;
            }
            let (width, height, labels, grid) = match &e.layout {
                EmbeddingLayout::Regions(l) => (l.width, l.height, l.labels.clone(), false),
                EmbeddingLayout::Grid { rows, cols } => (
                    *cols,
                    *rows,
                    (0..rows * cols).map(|c| c as u16).collect(),
                    true,
                ),
            };
            Some(RegionTargets {
                width,
                height,
                labels,
                grid,
                count: e.count,
                vectors,
                dim: e.dim,
            })
        });
        KeyframeRecord {
            stamp_ns: frame.stamp_ns,
            camera: camera_of(frame),
            rgb: frame.color.to_rgb8(),
            depth_mm,
            regions,
            exposure: 1.0,
        }
    }

    /// The supervision image: RGB in 0..1 and depth in metres (0 =
    /// invalid), one `[r, g, b, z]` per pixel.
    pub fn target_rgbd(&self) -> Vec<[f32; 4]> {
        // Divided, not multiplied by a reciprocal: at exposure 1 the same
        // values as the colour bytes over 255.
        let scale = 255.0 * self.exposure;
        self.rgb
            .chunks_exact(3)
            .zip(&self.depth_mm)
            .map(|(c, &d)| {
                [
                    c[0] as f32 / scale,
                    c[1] as f32 / scale,
                    c[2] as f32 / scale,
                    d as f32 * 0.001,
                ]
            })
            .collect()
    }

    /// Pixels with valid depth.
    pub fn valid_depth(&self) -> u32 {
        self.depth_mm.iter().filter(|&&d| d > 0).count() as u32
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> u64 {
        let r = self
            .regions
            .as_ref()
            .map_or(0, |r| r.labels.len() * 2 + r.vectors.len() * 4);
        (self.rgb.len() + self.depth_mm.len() * 2 + r) as u64
    }
}

/// What names a kept keyframe's targets on the GPU (see
/// [`Trainer::submit_stage_one`](super::Trainer::submit_stage_one)): unique
/// in the process, so a key never names two keyframes, even across
/// histories, loads and mappers.
///
/// ```
/// use latentam_core::mapper::ReplayKey;
/// assert_ne!(ReplayKey::fresh(), ReplayKey::fresh());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ReplayKey(u64);

impl ReplayKey {
    /// A key no other keyframe has.
    pub fn fresh() -> ReplayKey {
        use std::sync::atomic::{AtomicU64, Ordering};
        static NEXT: AtomicU64 = AtomicU64::new(0);
        ReplayKey(NEXT.fetch_add(1, Ordering::Relaxed))
    }
}

/// Where a keyframe was taken from: a cell of the camera position and a
/// bin of its viewing direction (8 azimuths × 3 elevations).
type ViewBin = (i64, i64, i64, u8);

fn view_bin(camera: &Camera, cell: f64) -> ViewBin {
    let t = camera.cam_to_world.translation / cell;
    let forward = camera.cam_to_world.matrix3.z_axis;
    let azimuth = forward.y.atan2(forward.x);
    let a = ((azimuth / std::f64::consts::FRAC_PI_4).round() as i64).rem_euclid(8) as u8;
    let e = if forward.z < -0.5 {
        0
    } else if forward.z > 0.5 {
        2
    } else {
        1
    };
    (
        t.x.floor() as i64,
        t.y.floor() as i64,
        t.z.floor() as i64,
        a * 3 + e,
    )
}

/// The keyframes kept for replay. With a cell size, a keyframe taken from
/// the same place (cell) looking the same way (direction bin) as an
/// earlier one replaces it, so the history grows with the space explored,
/// not with time: a robot circling a room for hours keeps a bounded set of
/// views of it. With cell 0 every keyframe is kept (the paper's setting).
///
/// ```
/// use latentam_core::mapper::{History, KeyframeRecord};
/// # fn f(keyframes: &[latentam_io::Frame]) {
/// let mut history = History::with_cell(0.5); // one view per 0.5 m cell and direction
/// for frame in keyframes {
///     history.push(KeyframeRecord::from_frame(frame));
/// }
/// for i in history.sample(4, 42) { // a replay batch of 4 past keyframes
///     println!("replaying keyframe at {} ns", history.get(i).expect("sampled").stamp_ns);
/// }
/// # }
/// ```
#[derive(Debug, Default)]
pub struct History {
    records: Vec<KeyframeRecord>,
    keys: Vec<ReplayKey>,
    bytes: u64,
    cell: f64,
    bins: HashMap<ViewBin, usize>,
}

impl History {
    /// A history replacing keyframes per `cell` metres and view direction
    /// (0: keep every keyframe).
    pub fn with_cell(cell: f64) -> Self {
        History {
            cell,
            ..Default::default()
        }
    }

    /// Adds a keyframe, replacing the one from the same cell and direction
    /// when there is one; returns its index.
    pub fn push(&mut self, record: KeyframeRecord) -> usize {
        self.push_keyed(record, ReplayKey::fresh())
    }

    /// [`History::push`] under `key`: the key the keyframe's targets were
    /// kept on the GPU under when it trained as the new keyframe, so that
    /// replaying it finds them there.
    pub fn push_keyed(&mut self, record: KeyframeRecord, key: ReplayKey) -> usize {
        self.bytes += record.bytes();
        if self.cell > 0.0 {
            let bin = view_bin(&record.camera, self.cell);
            if let Some(&i) = self.bins.get(&bin) {
                self.bytes -= self.records[i].bytes();
                self.records[i] = record;
                self.keys[i] = key;
                return i;
            }
            self.bins.insert(bin, self.records.len());
        }
        self.records.push(record);
        self.keys.push(key);
        self.records.len() - 1
    }

    /// The key of keyframe `i` (see [`ReplayKey`]).
    pub fn key(&self, i: usize) -> Option<ReplayKey> {
        self.keys.get(i).copied()
    }

    /// Number of keyframes.
    pub fn len(&self) -> usize {
        self.records.len()
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    /// Keyframe `i`.
    pub fn get(&self, i: usize) -> Option<&KeyframeRecord> {
        self.records.get(i)
    }

    /// The newest keyframe kept.
    pub fn last(&self) -> Option<&KeyframeRecord> {
        self.records.last()
    }

    /// Heap bytes held by all keyframes.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// `b` distinct keyframe indices drawn uniformly (all of them when
    /// there are at most `b`), in drawing order; the same `seed` draws the
    /// same keyframes.
    pub fn sample(&self, b: usize, seed: u64) -> Vec<usize> {
        draw((0..self.records.len()).collect(), b, seed)
    }

    /// Like [`History::sample`], among the keyframes whose camera lies
    /// within `radius` of `centre` (those the local window can render).
    pub fn sample_near(&self, b: usize, seed: u64, centre: glam::DVec3, radius: f64) -> Vec<usize> {
        let near = (0..self.records.len())
            .filter(|&i| {
                self.records[i]
                    .camera
                    .cam_to_world
                    .translation
                    .distance(centre)
                    <= radius
            })
            .collect();
        draw(near, b, seed)
    }
}

/// `b` distinct entries of `idx` drawn uniformly, in drawing order.
fn draw(mut idx: Vec<usize>, b: usize, seed: u64) -> Vec<usize> {
    let mut rng = SplitMix(seed);
    let n = idx.len();
    let take = b.min(n);
    // Partial Fisher–Yates.
    for i in 0..take {
        let j = i + (rng.next_u64() % (n - i) as u64) as usize;
        idx.swap(i, j);
    }
    idx.truncate(take);
    idx
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keyframes_from_the_same_place_and_direction_replace_each_other() {
        let record = |x: f64, yaw: f64| {
            let mut camera = Camera::at_origin(2, 2);
            camera.cam_to_world = glam::DAffine3::from_rotation_translation(
                glam::DQuat::from_rotation_z(yaw) * glam::DQuat::from_rotation_y(1.5),
                glam::DVec3::new(x, 0.0, 1.4),
            );
            KeyframeRecord {
                stamp_ns: (x * 1000.0) as i64,
                camera,
                rgb: vec![0; 12],
                depth_mm: vec![0; 4],
                regions: None,
                exposure: 1.0,
            }
        };
        let mut h = History::with_cell(0.5);
        assert_eq!(h.push(record(0.1, 0.0)), 0);
        assert_eq!(h.push(record(0.2, 0.1)), 0, "same cell, same direction");
        assert_eq!(h.get(0).unwrap().stamp_ns, 200);
        assert_eq!(h.push(record(0.3, 3.0)), 1, "same cell, other direction");
        assert_eq!(h.push(record(0.7, 0.0)), 2, "next cell");
        assert_eq!(h.len(), 3);
        assert_eq!(h.bytes(), 3 * record(0.0, 0.0).bytes());
        let mut all = History::with_cell(0.0);
        for i in 0..5 {
            assert_eq!(all.push(record(0.1, 0.0)), i);
        }
    }

    #[test]
    fn near_sampling_draws_only_keyframes_within_the_radius() {
        let mut h = History::default();
        for i in 0..20 {
            let mut camera = Camera::at_origin(2, 2);
            camera.cam_to_world.translation = glam::DVec3::new(i as f64, 0.0, 0.0);
            h.push(KeyframeRecord {
                stamp_ns: i,
                camera,
                rgb: vec![0; 12],
                depth_mm: vec![0; 4],
                regions: None,
                exposure: 1.0,
            });
        }
        for seed in 0..50 {
            let picks = h.sample_near(4, seed, glam::DVec3::new(10.0, 0.0, 0.0), 3.0);
            assert_eq!(picks.len(), 4);
            assert!(picks.iter().all(|&i| (7..=13).contains(&i)), "{picks:?}");
            let distinct: std::collections::HashSet<_> = picks.iter().collect();
            assert_eq!(distinct.len(), 4);
        }
        assert!(h
            .sample_near(4, 1, glam::DVec3::new(100.0, 0.0, 0.0), 3.0)
            .is_empty());
        assert_eq!(h.sample_near(9, 1, glam::DVec3::ZERO, 1.5).len(), 2);
    }

    #[test]
    fn records_keep_targets_compact_and_normalise_embeddings() {
        use glam::{DQuat, DVec3};
        use latentam_io::*;
        let frame = Frame {
            stamp_ns: 5,
            pose: CameraPose {
                rotation: DQuat::from_rotation_z(0.5),
                translation: DVec3::new(1.0, 2.0, 3.0),
            },
            intrinsics: Intrinsics {
                width: 2,
                height: 2,
                fx: 10.0,
                fy: 11.0,
                cx: 0.5,
                cy: 0.5,
            },
            color: ColorImage {
                width: 2,
                height: 2,
                format: PixelFormat::Bgr8,
                data: vec![0, 0, 255, 0, 255, 0, 255, 0, 0, 1, 2, 3],
            },
            depth: DepthImage {
                width: 2,
                height: 2,
                data: DepthData::Metres(vec![1.2344, f32::NAN, -1.0, 70.0]),
            },
            embeddings: Some(Embeddings {
                layout: EmbeddingLayout::Grid { rows: 1, cols: 2 },
                count: 2,
                dim: 2,
                dtype: Dtype::F32,
                data: encode_floats(&[3.0, 4.0, 0.0, 0.0], Dtype::F32),
                model: "m".into(),
            }),
            semantic: None,
        };
        let r = KeyframeRecord::from_frame(&frame);
        assert_eq!(r.depth_mm, vec![1234, 0, 0, 65535]);
        assert_eq!(r.valid_depth(), 2);
        let t = r.target_rgbd();
        assert_eq!(t[0][..3], [1.0, 0.0, 0.0]);
        assert!((t[0][3] - 1.234).abs() < 1e-6);
        assert_eq!(t[3][..3], [3.0 / 255.0, 2.0 / 255.0, 1.0 / 255.0]);
        let g = r.regions.as_ref().unwrap();
        assert!(g.grid && g.labels == vec![0, 1] && (g.width, g.height) == (2, 1));
        assert_eq!(
            g.vectors,
            vec![0.6, 0.8, 0.0, 0.0],
            "unit rows; a zero row stays zero"
        );
        let cam = r.camera;
        assert_eq!((cam.fx, cam.fy, cam.width), (10.0, 11.0, 2));
        let p = cam.cam_to_world.transform_point3(DVec3::ZERO);
        assert!((p - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
    }

    #[test]
    fn sampling_is_uniform_without_replacement() {
        let mut h = History::default();
        for i in 0..10 {
            h.push(KeyframeRecord {
                stamp_ns: i,
                camera: Camera::at_origin(4, 4),
                rgb: vec![0; 48],
                depth_mm: vec![1000; 16],
                regions: None,
                exposure: 1.0,
            });
        }
        assert_eq!(h.bytes(), 10 * (48 + 32));
        let mut hits = [0u32; 10];
        for seed in 0..20_000 {
            let s = h.sample(5, seed);
            let mut sorted = s.clone();
            sorted.sort_unstable();
            sorted.dedup();
            assert_eq!(sorted.len(), 5, "distinct");
            for i in s {
                hits[i] += 1;
            }
        }
        // Each keyframe is in half the batches: 10 000 ± 4σ (σ ≈ 71).
        for (i, &c) in hits.iter().enumerate() {
            assert!((9_700..=10_300).contains(&c), "keyframe {i}: {c}");
        }
        assert_eq!(h.sample(50, 1).len(), 10);
        assert_eq!(h.sample(5, 7), h.sample(5, 7));
        assert!(History::default().sample(5, 1).is_empty());
    }
}
