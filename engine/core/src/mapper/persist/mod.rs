//! Saving and loading the whole mapper state, so a run can be resumed or
//! queried later: the global map (by voxel key), the window's resident set
//! with its Adam state, the latent head (W, D, D⁰, their Adam state, the
//! k-means weights), the keyframe history, the keyframe selector and the
//! counters. One archive file ([`super::archive`]), written atomically.
//!
//! A save streams the global map into the file block by block (spilled
//! blocks read from disk one at a time), and a resume reads it back a
//! chunk at a time, spilling to the host budget as it goes: neither holds
//! the whole map in memory.
//!
//! Loading is two steps: [`SavedState::parse`] reads and checks the whole
//! file on the CPU (any file: it returns an error for anything malformed
//! and never panics), then `Mapper::from_saved` creates the GPU
//! buffers and uploads.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use glam::{DAffine3, DMat3, DQuat, DVec3};

use super::archive::{Archive, ArchiveWriter, Sink, FORMAT, VERSION};
use super::config::{MapperConfig, WHOLE_CONFIGURATION};
use super::history::{KeyframeRecord, RegionTargets};
use super::progress::Counters;
use crate::latent::NO_REGION_LABEL;
use crate::map::{Gaussian, VoxelKey, EXPOSURE_RANGE};
use crate::splat::{Camera, FIELD_WIDTHS, QUERY_DIM};
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context};
use latentam_io::CameraPose;

const GAUSSIAN_FLOATS: usize = std::mem::size_of::<Gaussian>() / 4;
const CAMERA_FLOATS: usize = 18;
const POSE_FLOATS: usize = 7;

/// Most rows a saved window may have.
pub(crate) const MAX_WINDOW_ROWS: u64 = 1 << 31;
/// Most pixels of a saved view (keyframe image, label image, workspace).
pub(crate) const MAX_VIEW_PIXELS: u64 = 1 << 31;
/// Largest embedding dimension of a saved map.
pub(crate) const MAX_EMBEDDING_DIM: u32 = 1 << 20;

/// A Gaussian seeded from depth filled in from neighbouring pixels, which
/// no later keyframe measured yet (`map/guess`).
pub(super) const GUESSED: u8 = 1;
/// A guess a later keyframe saw in front of the surface it measured,
/// removed at the next pruning.
pub(super) const SUPERSEDED: u8 = 2;

/// What a state lacks of what every state this version writes carries,
/// if anything: a run id (a state is saved into a run folder version,
/// whose id ties it to the decoder and report beside it) and, once frames
/// were mapped, the last frame's stamp (`--resume` skips the log up to
/// it). One rule for both sides: the writer refuses to write such a state,
/// and the reader refuses a sealed file that lacks either, since only an
/// edit makes one.
pub(super) fn missing_from(run_id: Option<&str>, counters: &Counters) -> Option<String> {
    if run_id.is_none() {
        Some("no run id".into())
    } else if counters.stamp_missing() {
        Some(format!(
            "{} frames mapped but no last_stamp_ns",
            counters.frames
        ))
    } else {
        None
    }
}

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

/// What is wrong with a saved configuration (an error of
/// [`MapperConfig::from_toml`]), for a message that names the file.
fn config_message(e: Error) -> String {
    match e {
        Error::Config { setting, reason } if setting == WHOLE_CONFIGURATION => reason,
        e => e.to_string(),
    }
}

/// A saved global map left in its file, read a chunk at a time and
/// checked as [`SavedState::parse`] checks it (finite, plausible, flags in
/// range; duplicates are found where the chunks are inserted).
pub(crate) struct StreamedMap {
    archive: Archive<'static>,
    /// Gaussians in it.
    len: usize,
}

/// A chunk of a streamed map: keys, Gaussians and guess flags.
pub(super) type MapChunk = (Vec<VoxelKey>, Vec<Gaussian>, Vec<u8>);

impl StreamedMap {
    /// Calls `visit` with every chunk of at most `rows` Gaussians, in the
    /// file's order, each checked.
    pub(super) fn for_each_chunk(
        &self,
        rows: usize,
        mut visit: impl FnMut(MapChunk) -> Result<()>,
    ) -> Result<()> {
        let a = &self.archive;
        let n = self.len;
        let has_flags = a.has("map/guess");
        if has_flags {
            a.exact_shape::<u8>("map/guess", &[n])?;
        }
        a.exact_shape::<f32>("map/gaussians", &[n, GAUSSIAN_FLOATS])?;
        for first in (0..n).step_by(rows.max(1)) {
            let count = rows.max(1).min(n - first);
            let keys = keys_from_i32(&a.rows::<i32>("map/keys", first, count)?);
            let floats = a.rows::<f32>("map/gaussians", first, count)?;
            let flags = if has_flags {
                a.rows::<u8>("map/guess", first, count)?
            } else {
                vec![0; count]
            };
            read::check_flags(a, &flags)?;
            let gaussians = keys
                .iter()
                .zip(floats.chunks_exact(GAUSSIAN_FLOATS))
                .map(|(key, g)| read::checked_gaussian(a, key, g))
                .collect::<Result<Vec<_>>>()?;
            visit((keys, gaussians, flags))?;
        }
        Ok(())
    }
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
/// `Mapper::load` then puts on the GPU. [`SavedState::parse`]
/// accepts any bytes: whatever is malformed or inconsistent (metadata,
/// tensor types and shapes, counts, duplicate or unknown voxel keys,
/// non-finite cameras and poses, sizes too large to allocate) is an
/// [`Error::Damaged`] naming the file; it never panics, and
/// allocates only in proportion to the bytes it is given.
///
/// ```no_run
/// use latentam_core::mapper::SavedState;
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
    /// [`super::RunFolder`]); `None` only in a version 1 state from
    /// before run ids, which is written again only through a run folder
    /// (which gives it one).
    pub(super) run_id: Option<String>,
    pub(super) config: MapperConfig,
    pub(super) counters: Counters,
    pub(super) model: Option<String>,
    pub(super) selector: (Option<CameraPose>, u32),
    pub(super) last_sync: Option<DVec3>,
    pub(super) map: Vec<(VoxelKey, Gaussian)>,
    /// Per Gaussian of `map`: [`GUESSED`], [`SUPERSEDED`] or 0 (measured).
    pub(super) guesses: Vec<u8>,
    pub(super) head: Option<SavedHead>,
    pub(super) history: Vec<KeyframeRecord>,
    pub(super) trajectory: Vec<(i64, CameraPose)>,
    /// The exposure of each keyframe on the trajectory.
    pub(super) exposure: Vec<f32>,
    pub(super) window: Option<SavedWindow>,
}

impl SavedState {
    /// Reads and checks a state saved by `Mapper::save` from
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

    /// [`SavedState::read`] but for the global map, which stays in the
    /// file, to be read a chunk at a time ([`StreamedMap`]): what loading a
    /// map larger than the host budget holds at once. The file's checksum
    /// is verified here, reading it once in pieces.
    pub(crate) fn read_streaming(path: &Path) -> Result<(Self, StreamedMap)> {
        let archive = Archive::open_streaming(path)?;
        let state = Self::from_archive_parts(&archive, false)?;
        let bad = |why: String| archive.corrupt(why);
        let len = match archive.shape::<i32>("map/keys")? {
            &[n, 3] => n,
            s => return Err(bad(format!("map/keys has shape {s:?}, expected [n, 3]"))),
        };
        Ok((state, StreamedMap { archive, len }))
    }

    /// A small, valid state built on the CPU: six Gaussians, four of them
    /// resident, a 3-d latent head and two keyframes (label regions and a
    /// feature grid). For tests and fuzzing.
    //
    // Long because it is data: every section of a saved state spelled out
    // once, so the persistence tests and the fuzz target start from it.
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
                exposure: 1.0 + 0.1 * i as f32,
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
            run_id: Some("000000000000001f00000001".into()),
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
            guesses: vec![0, 1, 0, 2, 0, 0],
            head: Some(head),
            history,
            trajectory: (0..3).map(|i| (1_000 * i, pose(i as f64 * 0.1))).collect(),
            exposure: vec![1.0, 1.25, 0.8],
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
}

mod gpu;
mod read;
mod write;
