//! Saving and loading the whole mapper state, so a run can be resumed or
//! queried later: the global map (by voxel key), the window's resident set
//! with its Adam state, the latent head (W, D, D⁰, their Adam state, the
//! k-means weights), the keyframe history, the keyframe selector and the
//! counters. One archive file ([`super::archive`]), written atomically.
//!
//! Loading is two steps: [`SavedState::parse`] reads and checks the whole
//! file on the CPU (any file: it returns an error for anything malformed
//! and never panics), then [`OnlineMapper::from_saved`] creates the GPU
//! buffers and uploads.

use std::borrow::Cow;
use std::collections::HashSet;
use std::path::{Path, PathBuf};

use glam::{DAffine3, DMat3, DQuat, DVec3};

use super::archive::{Archive, ArchiveWriter, FORMAT, VERSION};
use super::config::MapperConfig;
use super::history::{KeyframeRecord, RegionTargets};
use super::online::OnlineMapper;
use crate::error::{Error, Result};
use crate::gpu::{Buffer, Context};
use crate::io::CameraPose;
use crate::latent::NO_REGION_LABEL;
use crate::map::{Gaussian, VoxelKey};
use crate::splat::{Camera, FIELD_WIDTHS, QUERY_DIM};

const GAUSSIAN_FLOATS: usize = std::mem::size_of::<Gaussian>() / 4;
const CAMERA_FLOATS: usize = 18;
const POSE_FLOATS: usize = 7;

/// Most rows a saved window may have.
pub(crate) const MAX_WINDOW_ROWS: u64 = 1 << 31;
/// Most pixels of a saved view (keyframe image, label image, workspace).
pub(crate) const MAX_VIEW_PIXELS: u64 = 1 << 31;
/// Largest embedding dimension of a saved map.
pub(crate) const MAX_EMBEDDING_DIM: u32 = 1 << 20;

fn keys_to_i32(keys: impl Iterator<Item = VoxelKey>) -> Vec<i32> {
    keys.flat_map(|k| [k.x, k.y, k.z]).collect()
}

fn keys_from_i32(v: &[i32]) -> Vec<VoxelKey> {
    v.chunks_exact(3)
        .map(|c| VoxelKey {
            x: c[0],
            y: c[1],
            z: c[2],
        })
        .collect()
}

fn camera_to_f64(c: &Camera) -> [f64; CAMERA_FLOATS] {
    let m = c.cam_to_world.matrix3.to_cols_array();
    let t = c.cam_to_world.translation;
    let mut out = [0.0; CAMERA_FLOATS];
    out[..9].copy_from_slice(&m);
    out[9..12].copy_from_slice(&[t.x, t.y, t.z]);
    out[12..].copy_from_slice(&[c.fx, c.fy, c.cx, c.cy, c.near, c.far]);
    out
}

fn camera_from_f64(v: &[f64; CAMERA_FLOATS], width: u32, height: u32) -> Camera {
    let mut m = [0.0; 9];
    m.copy_from_slice(&v[..9]);
    let mut c = Camera::at_origin(width, height);
    c.cam_to_world = DAffine3 {
        matrix3: DMat3::from_cols_array(&m),
        translation: DVec3::new(v[9], v[10], v[11]),
    };
    (c.fx, c.fy, c.cx, c.cy, c.near, c.far) = (v[12], v[13], v[14], v[15], v[16], v[17]);
    c
}

fn pose_to_f64(p: &CameraPose) -> [f64; POSE_FLOATS] {
    let (q, t) = (p.rotation, p.translation);
    [q.x, q.y, q.z, q.w, t.x, t.y, t.z]
}

/// A pose from 7 values (quaternion x, y, z, w, translation), which must
/// be finite, with a quaternion that is not zero.
fn pose_from_f64(v: &[f64]) -> Option<CameraPose> {
    let [qx, qy, qz, qw, tx, ty, tz] = <[f64; POSE_FLOATS]>::try_from(v).ok()?;
    let rotation = DQuat::from_xyzw(qx, qy, qz, qw);
    let translation = DVec3::new(tx, ty, tz);
    let ok = rotation.is_finite() && translation.is_finite() && rotation.length() > 1e-6;
    ok.then_some(CameraPose {
        rotation,
        translation,
    })
}

/// Refuses a tensor holding NaN or an infinity: loaded, it would turn
/// every render and score it touches into NaN.
fn finite(values: &[f32], name: &str) -> std::result::Result<(), String> {
    match values.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) => Err(format!(
            "{name} holds a non-finite value ({} at {i})",
            values[i]
        )),
    }
}

/// [`finite`] for f32 values stored as bytes.
fn finite_bytes(bytes: &[u8], name: &str) -> std::result::Result<(), String> {
    let values: Vec<f32> = bytemuck::allocation::pod_collect_to_vec(bytes);
    finite(&values, name)
}

/// Bytes per row of each `window/state/{i}` tensor, in the order of
/// `GaussianOptimizer::state`: per field, both Adam
/// moments then the step count.
fn window_state_row_bytes() -> Vec<u64> {
    FIELD_WIDTHS
        .iter()
        .flat_map(|&w| [w * 4, w * 4, 4])
        .collect()
}

/// Bytes of each `head/adam/{i}` tensor, in the order of
/// `LatentHead::optimizer_state`: W's moments and step
/// counts (`QUERY_DIM` rows), then D's (`atoms` rows).
fn head_state_bytes(dim: u64, atoms: u64) -> Option<[u64; 6]> {
    let w = (QUERY_DIM as u64).checked_mul(dim)?.checked_mul(4)?;
    let d = atoms.checked_mul(dim)?.checked_mul(4)?;
    Some([w, w, QUERY_DIM as u64 * 4, d, d, atoms.checked_mul(4)?])
}

/// The message of an error, without its kind.
fn message(e: Error) -> String {
    match e {
        Error::InvalidArgument(m) => m,
        e => e.to_string(),
    }
}

/// Running counters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Counters {
    pub frames: u64,
    pub keyframes: u64,
    pub evicted: u64,
    pub fetched: u64,
    pub over_capacity: u64,
    /// Stamp of the last frame integrated (absent in states written before
    /// it was kept).
    pub last_stamp_ns: Option<i64>,
}

/// The latent head as saved.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct SavedHead {
    /// Embedding dimension.
    pub dim: u32,
    /// Atoms in use.
    pub used: u32,
    /// W, `QUERY_DIM × dim`.
    pub w: Vec<f32>,
    /// D, `atoms × dim` (the configuration's dictionary size).
    pub atoms: Vec<f32>,
    /// D⁰, like D.
    pub anchors: Vec<f32>,
    /// k-means weights of the atoms in use.
    pub weights: Vec<f32>,
    /// Adam state buffers ([`head_state_bytes`]).
    pub adam: Vec<Vec<u8>>,
}

/// The GPU window as saved.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct SavedWindow {
    /// Rows.
    pub capacity: u64,
    /// Pixels of the largest view the trainer's workspace holds.
    pub view_pixels: u64,
    /// Resident keys in row order.
    pub keys: Vec<VoxelKey>,
    /// The Gaussian optimiser's per-row state, `keys.len()` rows each
    /// ([`window_state_row_bytes`]).
    pub state: Vec<Vec<u8>>,
}

/// A saved mapper state, read from a file and checked on the CPU: what
/// [`OnlineMapper::load`] then puts on the GPU. [`SavedState::parse`]
/// accepts any bytes: whatever is malformed or inconsistent (metadata,
/// tensor types and shapes, counts, duplicate or unknown voxel keys,
/// non-finite cameras and poses, sizes too large to allocate) is an
/// [`Error::InvalidArgument`] naming the file; it never panics, and
/// allocates only in proportion to the bytes it is given.
///
/// ```no_run
/// use latentam::mapper::SavedState;
///
/// let path = std::path::Path::new("out/state.latentam");
/// let state = SavedState::parse(&std::fs::read(path)?, path)?;
/// println!("{} Gaussians, {} keyframes", state.gaussians(), state.keyframes());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct SavedState {
    pub(super) origin: PathBuf,
    /// The id of the run folder version the state was saved in (see
    /// [`super::RunFolder`]); `None` for a state saved on its own.
    pub(super) run_id: Option<String>,
    pub(super) config: MapperConfig,
    pub(super) counters: Counters,
    pub(super) model: Option<String>,
    pub(super) selector: (Option<CameraPose>, u32),
    pub(super) last_sync: Option<DVec3>,
    pub(super) map: Vec<(VoxelKey, Gaussian)>,
    pub(super) head: Option<SavedHead>,
    pub(super) history: Vec<KeyframeRecord>,
    pub(super) trajectory: Vec<(i64, CameraPose)>,
    pub(super) window: Option<SavedWindow>,
}

/// What one archive holds, borrowed: written by both
/// [`OnlineMapper::save`] and [`SavedState::to_bytes`].
struct StateRef<'a> {
    run_id: Option<&'a str>,
    config: &'a MapperConfig,
    counters: Counters,
    model: Option<&'a str>,
    selector: (Option<CameraPose>, u32),
    last_sync: Option<DVec3>,
    map: &'a [(VoxelKey, Gaussian)],
    head: Option<&'a SavedHead>,
    history: Vec<&'a KeyframeRecord>,
    trajectory: &'a [(i64, CameraPose)],
    window: Option<&'a SavedWindow>,
}

impl StateRef<'_> {
    fn into_bytes(self) -> Result<Vec<u8>> {
        let mut w = ArchiveWriter::default();
        if let Some(id) = self.run_id {
            w.meta("run_id", id);
        }
        w.meta("config", self.config.to_toml());
        let c = self.counters;
        w.meta("frames", c.frames);
        w.meta("keyframes", c.keyframes);
        w.meta("evicted", c.evicted);
        w.meta("fetched", c.fetched);
        w.meta("over_capacity", c.over_capacity);
        if let Some(stamp) = c.last_stamp_ns {
            w.meta("last_stamp_ns", stamp);
        }
        if let Some(model) = self.model {
            w.meta("model", model);
        }
        let (last, since) = self.selector;
        w.meta("selector_since", since);
        if let Some(p) = last {
            w.tensor("selector/pose", &[POSE_FLOATS], &pose_to_f64(&p));
        }
        if let Some(p) = self.last_sync {
            w.tensor("state/last_sync", &[3], &[p.x, p.y, p.z]);
        }

        // Global map, in slot order.
        let n = self.map.len();
        w.tensor(
            "map/keys",
            &[n, 3],
            &keys_to_i32(self.map.iter().map(|(k, _)| *k)),
        );
        let gaussians: Vec<Gaussian> = self.map.iter().map(|(_, g)| *g).collect();
        w.tensor(
            "map/gaussians",
            &[n, GAUSSIAN_FLOATS],
            bytemuck::cast_slice::<Gaussian, f32>(&gaussians),
        );

        // Window: resident keys in row order and the optimiser's rows.
        if let Some(win) = self.window {
            let n = win.keys.len();
            w.meta("window_capacity", win.capacity);
            w.meta("view_pixels", win.view_pixels);
            w.tensor(
                "window/keys",
                &[n, 3],
                &keys_to_i32(win.keys.iter().copied()),
            );
            let rows = window_state_row_bytes();
            for (i, bytes) in win.state.iter().enumerate() {
                // The row size comes from the layout, not the bytes: an
                // empty window still records it (and loading checks it).
                let row = rows
                    .get(i)
                    .map_or_else(|| bytes.len().checked_div(n).unwrap_or(0), |&r| r as usize);
                w.bytes(&format!("window/state/{i}"), n, row, bytes.clone());
            }
        }

        // Latent head.
        if let Some(head) = self.head {
            let d = head.dim as usize;
            w.meta("head_dim", d);
            w.meta("head_atoms", head.used);
            let rows = |v: &[f32]| v.len().checked_div(d).unwrap_or(0);
            w.tensor("head/W", &[rows(&head.w), d], &head.w);
            w.tensor("head/D", &[rows(&head.atoms), d], &head.atoms);
            w.tensor("head/D0", &[rows(&head.anchors), d], &head.anchors);
            w.tensor("head/kmeans_weights", &[head.weights.len()], &head.weights);
            for (i, bytes) in head.adam.iter().enumerate() {
                w.bytes(&format!("head/adam/{i}"), 1, bytes.len(), bytes.clone());
            }
        }

        // Keyframe history, concatenated.
        let h = self.history.len();
        let mut stamps = Vec::with_capacity(h);
        let mut cams = Vec::with_capacity(h * CAMERA_FLOATS);
        let mut sizes = Vec::with_capacity(h * 2);
        let mut rgb = Vec::new();
        let mut depth = Vec::new();
        let mut info = Vec::with_capacity(h * 6);
        let mut labels = Vec::new();
        let mut vectors = Vec::new();
        for k in &self.history {
            stamps.push(k.stamp_ns);
            cams.extend(camera_to_f64(&k.camera));
            sizes.extend([k.camera.width, k.camera.height]);
            rgb.extend_from_slice(&k.rgb);
            depth.extend_from_slice(&k.depth_mm);
            match &k.regions {
                Some(r) => {
                    info.extend([1, r.width, r.height, r.grid as u32, r.count, r.dim]);
                    labels.extend_from_slice(&r.labels);
                    vectors.extend_from_slice(&r.vectors);
                }
                None => info.extend([0u32; 6]),
            }
        }
        w.meta("history", h);
        w.tensor("history/stamp", &[h], &stamps);
        w.tensor("history/camera", &[h, CAMERA_FLOATS], &cams);
        w.tensor("history/size", &[h, 2], &sizes);
        w.tensor("history/rgb", &[rgb.len()], &rgb);
        w.tensor("history/depth_mm", &[depth.len()], &depth);
        w.tensor("history/regions", &[h, 6], &info);
        w.tensor("history/labels", &[labels.len()], &labels);
        w.tensor("history/vectors", &[vectors.len()], &vectors);

        // Every keyframe's pose (the history may have let some go).
        let n = self.trajectory.len();
        let stamps: Vec<i64> = self.trajectory.iter().map(|t| t.0).collect();
        let poses: Vec<f64> = self
            .trajectory
            .iter()
            .flat_map(|(_, p)| pose_to_f64(p))
            .collect();
        w.tensor("trajectory/stamp", &[n], &stamps);
        w.tensor("trajectory/pose", &[n, POSE_FLOATS], &poses);
        w.into_bytes()
    }
}

impl SavedState {
    /// Reads and checks a state saved by [`OnlineMapper::save`] from
    /// `bytes`, the contents of `origin` (which only names it in errors).
    /// Nothing touches the GPU; see the type's documentation for what is
    /// checked.
    pub fn parse(bytes: &[u8], origin: &Path) -> Result<Self> {
        let a = Archive::parse_as(Cow::Borrowed(bytes), origin, FORMAT, VERSION, "map")?;
        Self::from_archive(&a)
    }

    /// Reads and checks the state saved in `path` ([`SavedState::parse`]).
    pub fn read(path: &Path) -> Result<Self> {
        Self::from_archive(&Archive::open(path)?)
    }

    /// The file as [`OnlineMapper::save`] writes it.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        StateRef {
            run_id: self.run_id.as_deref(),
            config: &self.config,
            counters: self.counters,
            model: self.model.as_deref(),
            selector: self.selector,
            last_sync: self.last_sync,
            map: &self.map,
            head: self.head.as_ref(),
            history: self.history.iter().collect(),
            trajectory: &self.trajectory,
            window: self.window.as_ref(),
        }
        .into_bytes()
    }

    /// A small, valid state built on the CPU: six Gaussians, four of them
    /// resident, a 3-d latent head and two keyframes (label regions and a
    /// feature grid). For tests and fuzzing.
    #[doc(hidden)]
    pub fn example() -> Self {
        let config = MapperConfig {
            atoms: 4,
            max_regions: 8,
            replay: 1,
            history_cell: 0.0,
            window_capacity: Some(16),
            ..MapperConfig::default()
        };
        let pose = |x: f64| CameraPose {
            rotation: DQuat::from_rotation_y(x),
            translation: DVec3::new(x, 0.5, -x),
        };
        let map = (0..6)
            .map(|i| {
                let key = VoxelKey {
                    x: i,
                    y: -i,
                    z: 2 * i,
                };
                let f = i as f32;
                let g = Gaussian {
                    mean: [0.01 * f, -0.01 * f, 0.02 * f],
                    log_scale: [-4.0; 3],
                    quat: [1.0, 0.0, 0.0, 0.0],
                    color: [0.1 * f, 0.5, 0.9],
                    opacity_logit: f - 2.0,
                    query: [0.25 * f; QUERY_DIM],
                };
                (key, g)
            })
            .collect::<Vec<_>>();
        let (dim, k) = (3u32, config.atoms);
        let floats = |n: usize, scale: f32| (0..n).map(|i| i as f32 * scale).collect::<Vec<_>>();
        let adam = head_state_bytes(dim as u64, k as u64)
            .unwrap_or_default()
            .iter()
            .enumerate()
            .map(|(i, &n)| {
                bytemuck::cast_slice(&floats(n as usize / 4, 0.01 * (i + 1) as f32)).to_vec()
            })
            .collect();
        let head = SavedHead {
            dim,
            used: 2,
            w: floats(QUERY_DIM * dim as usize, 0.01),
            atoms: floats((k * dim) as usize, 0.1),
            anchors: floats((k * dim) as usize, 0.2),
            weights: vec![3.0, 1.0],
            adam,
        };
        let (width, height) = (4u32, 3u32);
        let px = (width * height) as usize;
        let record = |i: usize, regions: Option<RegionTargets>| {
            let mut camera = Camera::at_origin(width, height);
            camera.cam_to_world = DAffine3::from_rotation_translation(
                pose(i as f64 * 0.1).rotation,
                pose(i as f64 * 0.1).translation,
            );
            KeyframeRecord {
                stamp_ns: 1_000 * i as i64,
                camera,
                rgb: (0..px * 3).map(|j| (j * 7 + i) as u8).collect(),
                depth_mm: (0..px).map(|j| 1000 + j as u16).collect(),
                regions,
            }
        };
        let history = vec![
            record(
                0,
                Some(RegionTargets {
                    width,
                    height,
                    labels: (0..px)
                        .map(|j| {
                            if j == 5 {
                                NO_REGION_LABEL
                            } else {
                                (j % 2) as u16
                            }
                        })
                        .collect(),
                    grid: false,
                    count: 2,
                    vectors: vec![1.0, 0.0, 0.0, 0.0, 0.6, 0.8],
                    dim,
                }),
            ),
            record(
                2,
                Some(RegionTargets {
                    width: 2,
                    height: 1,
                    labels: vec![0, 1],
                    grid: true,
                    count: 2,
                    vectors: vec![0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
                    dim,
                }),
            ),
        ];
        let window_keys: Vec<VoxelKey> = [4, 1, 0, 3].iter().map(|&i| map[i].0).collect();
        let rows = window_keys.len() as u64;
        let state = window_state_row_bytes()
            .iter()
            .enumerate()
            .map(|(i, &row)| {
                let values: Vec<f32> = (0..rows * row / 4)
                    .map(|j| (j + i as u64) as f32 * 0.01)
                    .collect();
                bytemuck::cast_slice(&values).to_vec()
            })
            .collect();
        SavedState {
            origin: PathBuf::from("example.latentam"),
            run_id: None,
            config,
            counters: Counters {
                frames: 12,
                keyframes: 3,
                evicted: 2,
                fetched: 6,
                over_capacity: 0,
                last_stamp_ns: Some(11_000),
            },
            model: Some("example-model".into()),
            selector: (Some(pose(0.2)), 4),
            last_sync: Some(DVec3::new(0.1, 0.2, 0.3)),
            map,
            head: Some(head),
            history,
            trajectory: (0..3).map(|i| (1_000 * i, pose(i as f64 * 0.1))).collect(),
            window: Some(SavedWindow {
                capacity: 16,
                view_pixels: px as u64,
                keys: window_keys,
                state,
            }),
        }
    }

    /// The saved configuration.
    pub fn config(&self) -> &MapperConfig {
        &self.config
    }

    /// Gaussians in the global map.
    pub fn gaussians(&self) -> usize {
        self.map.len()
    }

    /// Keyframes mapped.
    pub fn keyframes(&self) -> u64 {
        self.counters.keyframes
    }

    /// Keyframes kept for replay.
    pub fn history_len(&self) -> usize {
        self.history.len()
    }

    /// Gaussians resident in the GPU window (0 before the first keyframe).
    pub fn resident(&self) -> usize {
        self.window.as_ref().map_or(0, |w| w.keys.len())
    }

    /// The id of the run folder version the state was saved in (see
    /// [`super::RunFolder`]), when it was saved in one.
    pub fn run_id(&self) -> Option<&str> {
        self.run_id.as_deref()
    }

    /// Embedding dimension of the latent head, when the map has one.
    pub fn embedding_dim(&self) -> Option<u32> {
        self.head.as_ref().map(|h| h.dim)
    }

    fn from_archive(a: &Archive<'_>) -> Result<Self> {
        let bad = |why: String| a.corrupt(why);
        let config = MapperConfig::from_toml(a.meta("config")?)
            .map_err(|e| bad(format!("saved {}", message(e))))?;

        // Sizes that shape GPU allocations, before anything is read.
        let window_meta = if a.has("window/keys") {
            let capacity: u64 = a.meta_parse("window_capacity")?;
            if capacity == 0 || capacity > MAX_WINDOW_ROWS {
                return Err(bad(format!(
                    "window capacity {capacity} is outside 1..={MAX_WINDOW_ROWS}"
                )));
            }
            let view_pixels: u64 = a.meta_parse("view_pixels")?;
            if view_pixels > MAX_VIEW_PIXELS {
                return Err(bad(format!(
                    "view of {view_pixels} pixels; at most {MAX_VIEW_PIXELS}"
                )));
            }
            Some((capacity, view_pixels))
        } else {
            None
        };

        let counters = Counters {
            frames: a.meta_parse("frames")?,
            keyframes: a.meta_parse("keyframes")?,
            evicted: a.meta_parse("evicted")?,
            fetched: a.meta_parse("fetched")?,
            over_capacity: a.meta_parse("over_capacity")?,
            last_stamp_ns: match a.meta("last_stamp_ns") {
                Ok(_) => Some(a.meta_parse("last_stamp_ns")?),
                Err(_) => None,
            },
        };
        if counters.keyframes > counters.frames {
            return Err(bad(format!(
                "{} keyframes among {} frames",
                counters.keyframes, counters.frames
            )));
        }
        let model = a.meta("model").ok().map(str::to_string);
        let since: u32 = a.meta_parse("selector_since")?;
        let last = if a.has("selector/pose") {
            let v = a.exact::<f64>("selector/pose", &[POSE_FLOATS])?;
            Some(
                pose_from_f64(&v)
                    .ok_or_else(|| bad(format!("selector/pose {v:?} is not a pose")))?,
            )
        } else {
            None
        };
        let last_sync = if a.has("state/last_sync") {
            let v = a.exact::<f64>("state/last_sync", &[3])?;
            let p = DVec3::new(v[0], v[1], v[2]);
            if !p.is_finite() {
                return Err(bad(format!("state/last_sync {v:?} is not finite")));
            }
            Some(p)
        } else {
            None
        };

        // Global map.
        let n = match a.shape::<i32>("map/keys")? {
            &[n, 3] => n,
            s => return Err(bad(format!("map/keys has shape {s:?}, expected [n, 3]"))),
        };
        let gaussians = a.exact::<f32>("map/gaussians", &[n, GAUSSIAN_FLOATS])?;
        let keys = keys_from_i32(&a.exact::<i32>("map/keys", &[n, 3])?);
        let mut seen = HashSet::with_capacity(n);
        let mut map = Vec::with_capacity(n);
        for (key, g) in keys
            .into_iter()
            .zip(gaussians.chunks_exact(GAUSSIAN_FLOATS))
        {
            if !seen.insert(key) {
                return Err(bad(format!("voxel {key:?} appears twice in the map")));
            }
            if !g.iter().all(|x| x.is_finite()) {
                return Err(bad(format!(
                    "the Gaussian of voxel {key:?} holds non-finite values"
                )));
            }
            let g: Gaussian = bytemuck::pod_read_unaligned(bytemuck::cast_slice(g));
            map.push((key, g));
        }

        let head = Self::parse_head(a, &config)?;
        let history = Self::parse_history(a, head.as_ref().map(|h| h.dim))?;
        if history.len() as u64 > counters.keyframes {
            return Err(bad(format!(
                "{} keyframes in the history of a map of {} keyframes",
                history.len(),
                counters.keyframes
            )));
        }

        // Every keyframe's pose; files from before it was saved rebuild it
        // from the history.
        let trajectory = if a.has("trajectory/stamp") || a.has("trajectory/pose") {
            let n = match a.shape::<i64>("trajectory/stamp")? {
                &[n] => n,
                s => return Err(bad(format!("trajectory/stamp has shape {s:?}"))),
            };
            if n as u64 != counters.keyframes {
                return Err(bad(format!(
                    "a trajectory of {n} poses for {} keyframes",
                    counters.keyframes
                )));
            }
            let poses = a.exact::<f64>("trajectory/pose", &[n, POSE_FLOATS])?;
            let stamps = a.exact::<i64>("trajectory/stamp", &[n])?;
            stamps
                .into_iter()
                .zip(poses.chunks_exact(POSE_FLOATS))
                .enumerate()
                .map(|(i, (s, v))| {
                    pose_from_f64(v)
                        .map(|p| (s, p))
                        .ok_or_else(|| bad(format!("trajectory pose {i} {v:?} is not a pose")))
                })
                .collect::<Result<Vec<_>>>()?
        } else {
            history
                .iter()
                .map(|k| {
                    let (_, rotation, translation) =
                        k.camera.cam_to_world.to_scale_rotation_translation();
                    let pose = CameraPose {
                        rotation,
                        translation,
                    };
                    (k.stamp_ns, pose)
                })
                .collect()
        };

        // Window: the same residents in the same rows, with their Adam
        // state.
        let window = match window_meta {
            None => None,
            Some((capacity, view_pixels)) => {
                let rows = match a.shape::<i32>("window/keys")? {
                    &[r, 3] => r,
                    s => return Err(bad(format!("window/keys has shape {s:?}, expected [n, 3]"))),
                };
                if rows as u64 > capacity {
                    return Err(bad(format!(
                        "{rows} resident Gaussians in a window of {capacity}"
                    )));
                }
                let keys = keys_from_i32(&a.exact::<i32>("window/keys", &[rows, 3])?);
                let mut resident = HashSet::with_capacity(rows);
                for k in &keys {
                    if !seen.contains(k) {
                        return Err(bad(format!("window voxel {k:?} is not in the map")));
                    }
                    if !resident.insert(*k) {
                        return Err(bad(format!("voxel {k:?} is resident twice")));
                    }
                }
                let state = window_state_row_bytes()
                    .into_iter()
                    .enumerate()
                    .map(|(i, row)| {
                        let name = format!("window/state/{i}");
                        let t = a.exact::<u8>(&name, &[rows, row as usize])?;
                        if i % 3 != 2 {
                            finite_bytes(&t, &name).map_err(bad)?;
                        }
                        Ok(t)
                    })
                    .collect::<Result<Vec<_>>>()?;
                Some(SavedWindow {
                    capacity,
                    view_pixels,
                    keys,
                    state,
                })
            }
        };

        Ok(SavedState {
            origin: a.path().to_path_buf(),
            run_id: a.meta("run_id").ok().map(str::to_string),
            config,
            counters,
            model,
            selector: (last, since),
            last_sync,
            map,
            head,
            history,
            trajectory,
            window,
        })
    }

    fn parse_head(a: &Archive<'_>, config: &MapperConfig) -> Result<Option<SavedHead>> {
        if !a.has("head/W") {
            return Ok(None);
        }
        let bad = |why: String| a.corrupt(why);
        let dim: u32 = a.meta_parse("head_dim")?;
        let used: u32 = a.meta_parse("head_atoms")?;
        if dim == 0 || dim > MAX_EMBEDDING_DIM {
            return Err(bad(format!(
                "embedding dimension {dim} is outside 1..={MAX_EMBEDDING_DIM}"
            )));
        }
        let k = config.atoms;
        if used > k {
            return Err(bad(format!("{used} atoms in use of a dictionary of {k}")));
        }
        let (d, k) = (dim as usize, k as usize);
        let w = a.exact::<f32>("head/W", &[QUERY_DIM, d])?;
        let atoms = a.exact::<f32>("head/D", &[k, d])?;
        let anchors = a.exact::<f32>("head/D0", &[k, d])?;
        let weights = a.exact::<f32>("head/kmeans_weights", &[used as usize])?;
        for (name, values) in [
            ("head/W", &w),
            ("head/D", &atoms),
            ("head/D0", &anchors),
            ("head/kmeans_weights", &weights),
        ] {
            finite(values, name).map_err(bad)?;
        }
        let sizes = head_state_bytes(dim as u64, k as u64)
            .ok_or_else(|| bad(format!("a head of {k} atoms of {dim} dimensions")))?;
        let adam = sizes
            .iter()
            .enumerate()
            .map(|(i, &bytes)| {
                let bytes = usize::try_from(bytes)
                    .map_err(|_| bad(format!("head/adam/{i} of {bytes} bytes")))?;
                let t = a.exact::<u8>(&format!("head/adam/{i}"), &[1, bytes])?;
                // Moments; every third tensor counts steps.
                if i % 3 != 2 {
                    finite_bytes(&t, &format!("head/adam/{i}")).map_err(bad)?;
                }
                Ok(t)
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Some(SavedHead {
            dim,
            used,
            w,
            atoms,
            anchors,
            weights,
            adam,
        }))
    }

    fn parse_history(a: &Archive<'_>, head_dim: Option<u32>) -> Result<Vec<KeyframeRecord>> {
        let bad = |why: String| a.corrupt(why);
        let h: usize = a.meta_parse("history")?;
        // Shapes first: `h` is checked against the bytes present before
        // anything is sized by it.
        let stamps = a.exact::<i64>("history/stamp", &[h])?;
        let cams = a.exact::<f64>("history/camera", &[h, CAMERA_FLOATS])?;
        let sizes = a.exact::<u32>("history/size", &[h, 2])?;
        let info = a.exact::<u32>("history/regions", &[h, 6])?;
        let rgb = a.flat::<u8>("history/rgb")?;
        let depth = a.flat::<u16>("history/depth_mm")?;
        let labels = a.flat::<u16>("history/labels")?;
        let vectors = a.flat::<f32>("history/vectors")?;
        let (mut o_rgb, mut o_depth, mut o_labels, mut o_vec) = (0usize, 0usize, 0usize, 0usize);
        // The next `len` values of a tensor of `total`.
        let take =
            |total: usize, o: &mut usize, len: u64, what: &str| -> Result<std::ops::Range<usize>> {
                let end = usize::try_from(len)
                    .ok()
                    .and_then(|len| o.checked_add(len))
                    .filter(|&end| end <= total)
                    .ok_or_else(|| bad(format!("history/{what} is too short")))?;
                let r = *o..end;
                *o = end;
                Ok(r)
            };
        let mut records = Vec::with_capacity(h);
        for i in 0..h {
            let keyframe = |why: String| bad(format!("history keyframe {i}: {why}"));
            let (width, height) = (sizes[2 * i], sizes[2 * i + 1]);
            let px = width as u64 * height as u64;
            if px == 0 || px > MAX_VIEW_PIXELS {
                return Err(keyframe(format!("image of {width}x{height}")));
            }
            let mut c = [0.0; CAMERA_FLOATS];
            c.copy_from_slice(&cams[i * CAMERA_FLOATS..(i + 1) * CAMERA_FLOATS]);
            let (fx, fy, near, far) = (c[12], c[13], c[16], c[17]);
            let ok =
                c.iter().all(|x| x.is_finite()) && fx > 0.0 && fy > 0.0 && near > 0.0 && far > near;
            if !ok {
                return Err(keyframe(format!("camera {c:?} is malformed")));
            }
            let camera = camera_from_f64(&c, width, height);
            let rgb_r = take(rgb.len(), &mut o_rgb, px * 3, "rgb")?;
            let depth_r = take(depth.len(), &mut o_depth, px, "depth_mm")?;
            let r = &info[i * 6..i * 6 + 6];
            let regions = match r[0] {
                0 if r[1..].iter().all(|&x| x == 0) => None,
                1 => {
                    let (rw, rh, grid, count, dim) = (r[1], r[2], r[3], r[4], r[5]);
                    let cells = rw as u64 * rh as u64;
                    if cells == 0 || cells > MAX_VIEW_PIXELS || grid > 1 {
                        return Err(keyframe(format!("regions of {rw}x{rh} (grid flag {grid})")));
                    }
                    if dim == 0 || Some(dim) != head_dim {
                        return Err(keyframe(match head_dim {
                            Some(d) => format!("{dim}-d embeddings; the map's are {d}-d"),
                            None => "region embeddings but the map has no latent head".into(),
                        }));
                    }
                    let grid = grid == 1;
                    if grid && count as u64 != cells {
                        return Err(keyframe(format!(
                            "a {rw}x{rh} feature grid of {count} regions"
                        )));
                    }
                    let lab = take(labels.len(), &mut o_labels, cells, "labels")?;
                    let vec = take(
                        vectors.len(),
                        &mut o_vec,
                        count as u64 * dim as u64,
                        "vectors",
                    )?;
                    let labels = labels[lab].to_vec();
                    if let Some(&l) = labels
                        .iter()
                        .find(|&&l| l != NO_REGION_LABEL && l as u32 >= count)
                    {
                        return Err(keyframe(format!("region label {l} of {count} regions")));
                    }
                    let vectors = vectors[vec].to_vec();
                    if !vectors.iter().all(|x| x.is_finite()) {
                        return Err(keyframe("non-finite region embeddings".into()));
                    }
                    Some(RegionTargets {
                        width: rw,
                        height: rh,
                        labels,
                        grid,
                        count,
                        vectors,
                        dim,
                    })
                }
                _ => return Err(keyframe(format!("region record {r:?} is malformed"))),
            };
            records.push(KeyframeRecord {
                stamp_ns: stamps[i],
                camera,
                rgb: rgb[rgb_r].to_vec(),
                depth_mm: depth[depth_r].to_vec(),
                regions,
            });
        }
        for (what, used, total) in [
            ("rgb", o_rgb, rgb.len()),
            ("depth_mm", o_depth, depth.len()),
            ("labels", o_labels, labels.len()),
            ("vectors", o_vec, vectors.len()),
        ] {
            if used != total {
                return Err(bad(format!(
                    "history/{what} holds {total} values; the keyframes use {used}"
                )));
            }
        }
        Ok(records)
    }
}

/// Reads a whole device buffer as bytes (first `bytes` kept).
fn download_bytes(ctx: &Context, buf: &Buffer, bytes: u64) -> Result<Vec<u8>> {
    let mut v: Vec<u8> = ctx.download(buf)?;
    v.truncate(bytes as usize);
    Ok(v)
}

impl OnlineMapper {
    /// Saves the whole state to `path` (one file, replaced atomically).
    /// The window is written back to the global map first.
    pub fn save(&mut self, path: &Path) -> Result<()> {
        self.save_as(path, None)
    }

    /// [`OnlineMapper::save`], recording `run_id`: the id of the run folder
    /// version the file belongs to (see [`super::RunStaging::run_id`]).
    pub fn save_as(&mut self, path: &Path, run_id: Option<&str>) -> Result<()> {
        self.check_consistent()?;
        self.flush()?;
        let ctx = self.ctx.clone();
        let map: Vec<(VoxelKey, Gaussian)> = self.global.iter().map(|(k, g)| (k, *g)).collect();
        let window = match (&self.window, &self.trainer, &self.window_budget) {
            (Some(window), Some(trainer), Some(sized)) => {
                let n = window.len() as u64;
                let state = trainer
                    .optimizer()
                    .state()
                    .into_iter()
                    .map(|(buf, row)| download_bytes(&ctx, buf, n * row))
                    .collect::<Result<Vec<_>>>()?;
                Some(SavedWindow {
                    capacity: sized.capacity,
                    view_pixels: self.history.get(0).map_or(0, |k| k.camera.pixels()),
                    keys: window.keys().to_vec(),
                    state,
                })
            }
            _ => None,
        };
        let head = match &self.head {
            Some(head) => {
                let d = head.config().dim as usize;
                let k = head.config().atoms as usize;
                let used = head.atom_count();
                let mut atoms: Vec<f32> = ctx.download(head.atoms())?;
                atoms.truncate(k * d);
                let mut anchors: Vec<f32> = ctx.download(head.anchor())?;
                anchors.truncate(k * d);
                let mut weights: Vec<f32> = ctx.download(head.kmeans().weights())?;
                weights.truncate(used as usize);
                let adam = head
                    .optimizer_state()
                    .into_iter()
                    .map(|(buf, _)| ctx.download::<u8>(buf))
                    .collect::<Result<Vec<_>>>()?;
                Some(SavedHead {
                    dim: d as u32,
                    used,
                    w: ctx.download(head.w())?,
                    atoms,
                    anchors,
                    weights,
                    adam,
                })
            }
            None => None,
        };
        // Loading refuses non-finite values; refusing them here too keeps a
        // diverged map from replacing a good save.
        let diverged = |why: String| {
            Error::InvalidArgument(format!(
                "the map has diverged and is not saved (it would not load): {why}"
            ))
        };
        for (key, g) in &map {
            if !bytemuck::cast_slice::<Gaussian, f32>(std::slice::from_ref(g))
                .iter()
                .all(|x| x.is_finite())
            {
                return Err(diverged(format!(
                    "the Gaussian of voxel {key:?} is not finite"
                )));
            }
        }
        if let Some(h) = &head {
            for (name, v) in [
                ("head/W", &h.w),
                ("head/D", &h.atoms),
                ("head/D0", &h.anchors),
            ] {
                finite(v, name).map_err(diverged)?;
            }
            for (i, t) in h.adam.iter().enumerate().filter(|(i, _)| i % 3 != 2) {
                finite_bytes(t, &format!("head/adam/{i}")).map_err(diverged)?;
            }
        }
        if let Some(w) = &window {
            for (i, t) in w.state.iter().enumerate().filter(|(i, _)| i % 3 != 2) {
                finite_bytes(t, &format!("window/state/{i}")).map_err(diverged)?;
            }
        }
        let bytes = StateRef {
            run_id,
            config: &self.cfg,
            counters: Counters {
                frames: self.frames,
                keyframes: self.stats.keyframes,
                evicted: self.stats.evicted,
                fetched: self.stats.fetched,
                over_capacity: self.stats.over_capacity,
                last_stamp_ns: self.last_stamp_ns,
            },
            model: self.model.as_deref(),
            selector: self.selector.state(),
            last_sync: self.last_sync,
            map: &map,
            head: head.as_ref(),
            history: (0..self.history.len())
                .filter_map(|i| self.history.get(i))
                .collect(),
            trajectory: &self.trajectory,
            window: window.as_ref(),
        }
        .into_bytes()?;
        drop(map);
        crate::files::write_bytes_atomically(path, &bytes)
    }

    /// Loads a state saved by [`OnlineMapper::save`] onto `ctx`, ready to
    /// integrate more frames or to be queried. `overrides` replaces the
    /// saved configuration's run-time settings (budget, learning rates...)
    /// when given; the settings that shape the saved state (voxel size,
    /// dictionary size, replay count, window capacity) are kept.
    ///
    /// The file is read and checked on the CPU first
    /// ([`SavedState::read`]), then put on the GPU
    /// ([`OnlineMapper::from_saved`]).
    pub fn load(ctx: &Context, path: &Path, overrides: Option<MapperConfig>) -> Result<Self> {
        let state = SavedState::read(path)?;
        Self::from_saved(ctx, state, overrides)
    }

    /// A mapper on `ctx` with the state `saved` (see
    /// [`OnlineMapper::load`] for `overrides`): creates the GPU buffers and
    /// uploads the window, the latent head and their optimiser state.
    pub fn from_saved(
        ctx: &Context,
        saved: SavedState,
        overrides: Option<MapperConfig>,
    ) -> Result<Self> {
        let SavedState {
            origin,
            run_id,
            config: kept,
            counters,
            model,
            selector,
            last_sync,
            map,
            head,
            history,
            trajectory,
            window,
        } = saved;
        let corrupt = |why: String| Error::InvalidArgument(format!("{}: {why}", origin.display()));
        let mut cfg = overrides.unwrap_or_else(|| kept.clone());
        cfg.keep_shape_of(&kept);
        if let Some(w) = &window {
            cfg.window_capacity = Some(w.capacity);
        }
        let mut m = OnlineMapper::new(ctx, cfg)?;
        m.frames = counters.frames;
        m.stats.keyframes = counters.keyframes;
        m.stats.evicted = counters.evicted;
        m.stats.fetched = counters.fetched;
        m.stats.over_capacity = counters.over_capacity;
        m.last_stamp_ns = counters.last_stamp_ns;
        m.model = model;
        m.run_id = run_id;
        m.selector.restore(selector.0, selector.1);
        m.last_sync = last_sync;
        for (key, g) in map {
            if !m.global.insert_at(key, g) {
                return Err(corrupt(format!("voxel {key:?} appears twice in the map")));
            }
        }

        // Latent head.
        if let Some(h) = head {
            let head = m.make_head(h.dim)?;
            ctx.upload(head.w(), 0, &h.w)?;
            ctx.upload(head.atoms(), 0, &h.atoms)?;
            ctx.upload(head.anchor(), 0, &h.anchors)?;
            head.kmeans().restore(ctx, h.used, &h.weights)?;
            let expected: Vec<u64> = head
                .optimizer_state()
                .iter()
                .map(|(b, _)| b.bytes())
                .collect();
            upload_state(
                ctx,
                head.optimizer_state(),
                &h.adam,
                &expected,
                "head/adam",
                &corrupt,
            )?;
            m.head = Some(head);
        }

        for record in history {
            m.history.push(record);
        }
        m.trajectory = trajectory;

        // Window: the same residents in the same rows, with their Adam
        // state.
        if let Some(w) = window {
            let dim = m.head.as_ref().map(|h| h.config().dim);
            m.ensure_workspace(w.view_pixels, dim)?;
            m.append(&w.keys)?;
            let rows = w.keys.len() as u64;
            let trainer = m
                .trainer
                .as_ref()
                .ok_or_else(|| corrupt("no trainer for the window".into()))?;
            let buffers = trainer.optimizer().state();
            let expected: Vec<u64> = buffers.iter().map(|(_, row)| rows * row).collect();
            upload_state(ctx, buffers, &w.state, &expected, "window/state", &corrupt)?;
        }
        Ok(m)
    }
}

/// Uploads saved optimiser tensors into `buffers`, each of exactly
/// `expected` bytes (`what` names them in errors).
fn upload_state(
    ctx: &Context,
    buffers: Vec<(&Buffer, u64)>,
    saved: &[Vec<u8>],
    expected: &[u64],
    what: &str,
    corrupt: &dyn Fn(String) -> Error,
) -> Result<()> {
    if buffers.len() != saved.len() {
        return Err(corrupt(format!(
            "{} {what} tensors; this build has {}",
            saved.len(),
            buffers.len()
        )));
    }
    for (i, (((buf, _), bytes), &want)) in buffers.into_iter().zip(saved).zip(expected).enumerate()
    {
        if bytes.len() as u64 != want {
            return Err(corrupt(format!(
                "{what}/{i} holds {} bytes, {want} expected",
                bytes.len()
            )));
        }
        ctx.upload(buf, 0, bytes)?;
    }
    Ok(())
}
