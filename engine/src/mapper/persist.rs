//! Saving and loading the whole mapper state, so a run can be resumed or
//! queried later: the global map (by voxel key), the window's resident set
//! with its Adam state, the latent head (W, D, D⁰, their Adam state, the
//! k-means weights), the keyframe history, the keyframe selector and the
//! counters. One archive file ([`super::archive`]), written atomically.

use std::path::Path;

use glam::{DAffine3, DMat3, DQuat, DVec3};

use super::archive::{Archive, ArchiveWriter};
use super::history::{KeyframeRecord, RegionTargets};
use super::online::{MapperConfig, OnlineMapper};
use crate::error::{Error, Result};
use crate::gpu::{Buffer, Context};
use crate::io::CameraPose;
use crate::map::{Gaussian, VoxelKey};
use crate::splat::Camera;

const GAUSSIAN_FLOATS: usize = std::mem::size_of::<Gaussian>() / 4;
const CAMERA_FLOATS: usize = 18;

fn keys_to_i32(keys: &[VoxelKey]) -> Vec<i32> {
    keys.iter().flat_map(|k| [k.x, k.y, k.z]).collect()
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

fn camera_from_f64(v: &[f64], width: u32, height: u32) -> Camera {
    let mut c = Camera::at_origin(width, height);
    c.cam_to_world = DAffine3 {
        matrix3: DMat3::from_cols_array(&v[..9].try_into().expect("9 values")),
        translation: DVec3::new(v[9], v[10], v[11]),
    };
    (c.fx, c.fy, c.cx, c.cy, c.near, c.far) = (v[12], v[13], v[14], v[15], v[16], v[17]);
    c
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
        self.flush()?;
        let ctx = self.ctx.clone();
        let mut w = ArchiveWriter::default();
        w.meta("config", self.cfg.to_toml());
        w.meta("frames", self.frames);
        w.meta("keyframes", self.stats.keyframes);
        w.meta("evicted", self.stats.evicted);
        w.meta("fetched", self.stats.fetched);
        w.meta("over_capacity", self.stats.over_capacity);
        if let Some(model) = &self.model {
            w.meta("model", model);
        }
        let (last, since) = self.selector.state();
        w.meta("selector_since", since);
        if let Some(p) = last {
            let q = p.rotation;
            let t = p.translation;
            w.tensor("selector/pose", &[7], &[q.x, q.y, q.z, q.w, t.x, t.y, t.z]);
        }
        if let Some(p) = self.last_sync {
            w.tensor("state/last_sync", &[3], &[p.x, p.y, p.z]);
        }

        // Global map, in slot order.
        let (keys, gaussians): (Vec<VoxelKey>, Vec<Gaussian>) =
            self.global.iter().map(|(k, g)| (k, *g)).unzip();
        w.tensor("map/keys", &[keys.len(), 3], &keys_to_i32(&keys));
        w.tensor(
            "map/gaussians",
            &[keys.len(), GAUSSIAN_FLOATS],
            bytemuck::cast_slice::<Gaussian, f32>(&gaussians),
        );

        // Window: resident keys in row order and the optimiser's rows.
        if let (Some(window), Some(trainer), Some(sized)) =
            (&self.window, &self.trainer, &self.window_budget)
        {
            let n = window.len();
            w.meta("window_capacity", sized.capacity);
            w.tensor("window/keys", &[n, 3], &keys_to_i32(window.keys()));
            for (i, (buf, row)) in trainer.optimizer().state().into_iter().enumerate() {
                let bytes = download_bytes(&ctx, buf, n as u64 * row)?;
                w.bytes(&format!("window/state/{i}"), n, row as usize, bytes);
            }
            let view = self.history.get(0).map(|k| k.camera.pixels()).unwrap_or(0);
            w.meta("view_pixels", view);
        }

        // Latent head.
        if let Some(head) = &self.head {
            let d = head.config().dim as usize;
            let k = head.config().atoms as usize;
            w.meta("head_dim", d);
            w.meta("head_atoms", head.atom_count());
            let w_host: Vec<f32> = ctx.download(head.w())?;
            w.tensor("head/W", &[w_host.len() / d, d], &w_host);
            let atoms: Vec<f32> = ctx.download(head.atoms())?;
            w.tensor("head/D", &[k, d], &atoms[..k * d]);
            let anchor: Vec<f32> = ctx.download(head.anchor())?;
            w.tensor("head/D0", &[k, d], &anchor[..k * d]);
            let weights: Vec<f32> = ctx.download(head.kmeans().weights())?;
            let used = head.atom_count() as usize;
            w.tensor("head/kmeans_weights", &[used], &weights[..used]);
            for (i, (buf, _)) in head.optimizer_state().into_iter().enumerate() {
                let bytes: Vec<u8> = ctx.download(buf)?;
                w.bytes(&format!("head/adam/{i}"), 1, bytes.len(), bytes);
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
        for i in 0..h {
            let k = self.history.get(i).expect("in range");
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
            .flat_map(|(_, p)| {
                let (q, t) = (p.rotation, p.translation);
                [q.x, q.y, q.z, q.w, t.x, t.y, t.z]
            })
            .collect();
        w.tensor("trajectory/stamp", &[n], &stamps);
        w.tensor("trajectory/pose", &[n, 7], &poses);
        w.write(path)
    }

    /// Loads a state saved by [`OnlineMapper::save`] onto `ctx`, ready to
    /// integrate more frames or to be queried. `overrides` replaces the
    /// saved configuration's run-time settings (budget, learning rates...)
    /// when given; the settings that shape the saved state (voxel size,
    /// dictionary size, replay count, window capacity) are kept.
    pub fn load(ctx: &Context, path: &Path, overrides: Option<MapperConfig>) -> Result<Self> {
        let a = Archive::open(path)?;
        let saved = MapperConfig::from_toml(a.meta("config")?)?;
        let mut cfg = overrides.unwrap_or_else(|| saved.clone());
        cfg.voxel_size = saved.voxel_size;
        cfg.atoms = saved.atoms;
        cfg.max_regions = saved.max_regions;
        cfg.replay = saved.replay;
        cfg.history_cell = saved.history_cell;
        cfg.seed = saved.seed;
        let corrupt = |why: String| Error::InvalidArgument(format!("{}: {why}", path.display()));
        if a.has("window/keys") {
            cfg.window_capacity = Some(a.meta_parse("window_capacity")?);
        }
        let mut m = OnlineMapper::new(ctx, cfg)?;
        m.frames = a.meta_parse("frames")?;
        m.stats.keyframes = a.meta_parse("keyframes")?;
        m.stats.evicted = a.meta_parse("evicted")?;
        m.stats.fetched = a.meta_parse("fetched")?;
        m.stats.over_capacity = a.meta_parse("over_capacity")?;
        m.model = a.meta("model").ok().map(str::to_string);
        let since: u32 = a.meta_parse("selector_since")?;
        let pose = if a.has("selector/pose") {
            let v = a.rows::<f64>("selector/pose", 7, 0)?;
            Some(CameraPose {
                rotation: DQuat::from_xyzw(v[0], v[1], v[2], v[3]),
                translation: DVec3::new(v[4], v[5], v[6]),
            })
        } else {
            None
        };
        m.selector.restore(pose, since);
        if a.has("state/last_sync") {
            let v = a.rows::<f64>("state/last_sync", 3, 0)?;
            m.last_sync = Some(DVec3::new(v[0], v[1], v[2]));
        }

        // Global map.
        let (shape, keys) = a.tensor::<i32>("map/keys")?;
        let n = *shape.first().unwrap_or(&0);
        let gaussians = a.rows::<f32>("map/gaussians", n, GAUSSIAN_FLOATS)?;
        if keys.len() != n * 3 {
            return Err(corrupt(format!("map/keys has shape {shape:?}")));
        }
        for (key, g) in keys_from_i32(&keys)
            .into_iter()
            .zip(gaussians.chunks_exact(GAUSSIAN_FLOATS))
        {
            let g: Gaussian = bytemuck::pod_read_unaligned(bytemuck::cast_slice(g));
            if !m.global.insert_at(key, g) {
                return Err(corrupt(format!("voxel {key:?} appears twice in the map")));
            }
        }

        // Latent head.
        if a.has("head/W") {
            let d: u32 = a.meta_parse("head_dim")?;
            let used: u32 = a.meta_parse("head_atoms")?;
            let head = m.make_head(d)?;
            let k = head.config().atoms as usize;
            let w = a.rows::<f32>("head/W", crate::splat::QUERY_DIM, d as usize)?;
            ctx.upload(head.w(), 0, &w)?;
            ctx.upload(head.atoms(), 0, &a.rows::<f32>("head/D", k, d as usize)?)?;
            ctx.upload(head.anchor(), 0, &a.rows::<f32>("head/D0", k, d as usize)?)?;
            let weights = a.rows::<f32>("head/kmeans_weights", used as usize, 1)?;
            head.kmeans().restore(ctx, used, &weights)?;
            for (i, (buf, _)) in head.optimizer_state().into_iter().enumerate() {
                let bytes = a.rows::<u8>(&format!("head/adam/{i}"), 1, buf.bytes() as usize)?;
                ctx.upload(buf, 0, &bytes)?;
            }
            m.head = Some(head);
        }

        // History.
        let h: usize = a.meta_parse("history")?;
        let stamps = a.rows::<i64>("history/stamp", h, 1)?;
        let cams = a.rows::<f64>("history/camera", h, CAMERA_FLOATS)?;
        let sizes = a.rows::<u32>("history/size", h, 2)?;
        let info = a.rows::<u32>("history/regions", h, 6)?;
        let (_, rgb) = a.tensor::<u8>("history/rgb")?;
        let (_, depth) = a.tensor::<u16>("history/depth_mm")?;
        let (_, labels) = a.tensor::<u16>("history/labels")?;
        let (_, vectors) = a.tensor::<f32>("history/vectors")?;
        let (mut o_rgb, mut o_depth, mut o_labels, mut o_vec) = (0usize, 0usize, 0usize, 0usize);
        let take =
            |v: usize, o: &mut usize, len: usize, what: &str| -> Result<std::ops::Range<usize>> {
                let r = *o..*o + len;
                if r.end > v {
                    return Err(corrupt(format!("history/{what} is too short")));
                }
                *o = r.end;
                Ok(r)
            };
        for i in 0..h {
            let (width, height) = (sizes[2 * i], sizes[2 * i + 1]);
            let px = width as usize * height as usize;
            let camera = camera_from_f64(
                &cams[i * CAMERA_FLOATS..(i + 1) * CAMERA_FLOATS],
                width,
                height,
            );
            let rgb_r = take(rgb.len(), &mut o_rgb, px * 3, "rgb")?;
            let depth_r = take(depth.len(), &mut o_depth, px, "depth_mm")?;
            let r = &info[i * 6..i * 6 + 6];
            let regions = if r[0] == 1 {
                let (rw, rh, grid, count, dim) = (r[1], r[2], r[3] == 1, r[4], r[5]);
                let lab = take(
                    labels.len(),
                    &mut o_labels,
                    rw as usize * rh as usize,
                    "labels",
                )?;
                let vec = take(
                    vectors.len(),
                    &mut o_vec,
                    count as usize * dim as usize,
                    "vectors",
                )?;
                Some(RegionTargets {
                    width: rw,
                    height: rh,
                    labels: labels[lab].to_vec(),
                    grid,
                    count,
                    vectors: vectors[vec].to_vec(),
                    dim,
                })
            } else {
                None
            };
            m.history.push(KeyframeRecord {
                stamp_ns: stamps[i],
                camera,
                rgb: rgb[rgb_r].to_vec(),
                depth_mm: depth[depth_r].to_vec(),
                regions,
            });
        }
        if a.has("trajectory/stamp") {
            let (shape, stamps) = a.tensor::<i64>("trajectory/stamp")?;
            let n = *shape.first().unwrap_or(&0);
            let poses = a.rows::<f64>("trajectory/pose", n, 7)?;
            m.trajectory = stamps
                .iter()
                .zip(poses.chunks_exact(7))
                .map(|(&s, v)| {
                    let pose = CameraPose {
                        rotation: DQuat::from_xyzw(v[0], v[1], v[2], v[3]),
                        translation: DVec3::new(v[4], v[5], v[6]),
                    };
                    (s, pose)
                })
                .collect();
        } else {
            m.trajectory = (0..m.history.len())
                .filter_map(|i| m.history.get(i))
                .map(|k| {
                    let (_, rotation, translation) =
                        k.camera.cam_to_world.to_scale_rotation_translation();
                    let pose = CameraPose {
                        rotation,
                        translation,
                    };
                    (k.stamp_ns, pose)
                })
                .collect();
        }

        // Window: the same residents in the same rows, with their Adam
        // state.
        if a.has("window/keys") {
            let pixels: u64 = a.meta_parse("view_pixels")?;
            let dim = m.head.as_ref().map_or(1, |h| h.config().dim);
            m.ensure_workspace(pixels, dim)?;
            let (shape, wk) = a.tensor::<i32>("window/keys")?;
            let rows = *shape.first().unwrap_or(&0);
            let keys = keys_from_i32(&wk);
            if keys.len() != rows {
                return Err(corrupt(format!("window/keys has shape {shape:?}")));
            }
            m.append(&keys)?;
            let trainer = m.trainer.as_ref().expect("ensured");
            for (i, (buf, row)) in trainer.optimizer().state().into_iter().enumerate() {
                let bytes = a.rows::<u8>(&format!("window/state/{i}"), rows, row as usize)?;
                ctx.upload(buf, 0, &bytes)?;
            }
        }
        Ok(m)
    }
}
