//! Reading a saved state: every section of the archive checked against
//! the others (sizes, ranges, finiteness) before anything reaches the GPU.

use std::collections::HashSet;

use super::*;

/// The keyframe selector's last keyframe pose and the frames since.
type Selector = (Option<CameraPose>, u32);

/// The voxels of the global map.
type Voxels = HashSet<VoxelKey>;

impl SavedState {
    pub(super) fn from_archive(a: &Archive<'_>) -> Result<Self> {
        Self::from_archive_parts(a, true)
    }

    /// [`SavedState::from_archive`], the global map read (and its window
    /// keys checked against it) only when `with_map`; else the map is left
    /// in the archive for [`StreamedMap`].
    pub(super) fn from_archive_parts(a: &Archive<'_>, with_map: bool) -> Result<Self> {
        let config = MapperConfig::from_toml(a.meta("config")?)
            .map_err(|e| a.corrupt(format!("saved mapper configuration: {}", config_message(e))))?;
        // Sizes that shape GPU allocations, before anything is read.
        let window_meta = Self::parse_window_meta(a)?;
        let counters = Self::parse_counters(a)?;
        let model = a.meta("model").ok().map(str::to_string);
        let (selector, last_sync) = Self::parse_selector(a)?;
        let (map, seen, guesses) = if with_map {
            let (map, seen) = Self::parse_map(a)?;
            let guesses = Self::parse_guesses(a, map.len())?;
            (map, Some(seen), guesses)
        } else {
            (Vec::new(), None, Vec::new())
        };
        let head = Self::parse_head(a, &config)?;
        let history = Self::parse_history(a, head.as_ref().map(|h| h.dim))?;
        if history.len() as u64 > counters.keyframes {
            return Err(a.corrupt(format!(
                "{} keyframes in the history of a map of {} keyframes",
                history.len(),
                counters.keyframes
            )));
        }
        let trajectory = Self::parse_trajectory(a, counters.keyframes, &history)?;
        let run_id = a.run_id()?;
        let counters = Self::brought_up_to_date(a, counters, run_id.as_deref(), &trajectory)?;
        let exposure = read_exposure(a, "trajectory/exposure", trajectory.len())?;
        let window = match window_meta {
            None => None,
            Some((capacity, view_pixels)) => {
                Some(Self::parse_window(a, capacity, view_pixels, seen.as_ref())?)
            }
        };
        Ok(SavedState {
            origin: a.path().to_path_buf(),
            run_id,
            config,
            counters,
            model,
            selector,
            last_sync,
            map,
            guesses,
            head,
            history,
            trajectory,
            exposure,
            window,
        })
    }

    /// The window's capacity and view size, when the state has a window.
    fn parse_window_meta(a: &Archive<'_>) -> Result<Option<(u64, u64)>> {
        let bad = |why: String| a.corrupt(why);
        if !a.has("window/keys") {
            return Ok(None);
        }
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
        Ok(Some((capacity, view_pixels)))
    }

    fn parse_counters(a: &Archive<'_>) -> Result<Counters> {
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
            return Err(a.corrupt(format!(
                "{} keyframes among {} frames",
                counters.keyframes, counters.frames
            )));
        }
        Ok(counters)
    }

    /// The counters as a state of this version keeps them. A sealed file
    /// lacking what every state this version writes carries was edited
    /// ([`missing_from`]). A version 1 file from before the checksum may
    /// have mapped frames without keeping the last one's stamp: it takes
    /// its last keyframe's, so that it can be saved again and `--resume`
    /// re-reads only the frames after that keyframe (frames that were not
    /// keyframes, counted again) instead of the whole log.
    fn brought_up_to_date(
        a: &Archive<'_>,
        mut counters: Counters,
        run_id: Option<&str>,
        trajectory: &[(i64, CameraPose)],
    ) -> Result<Counters> {
        if a.sealed() {
            if let Some(what) = missing_from(run_id, &counters) {
                return Err(a.corrupt(format!(
                    "{what}, which every state this version saves carries; the file was edited"
                )));
            }
        } else if counters.stamp_missing() {
            match trajectory.iter().map(|(stamp, _)| *stamp).max() {
                Some(last) => counters.last_stamp_ns = Some(last),
                None => {
                    return Err(a.corrupt(format!(
                        "{} frames mapped but no last_stamp_ns, and no keyframe to take one from",
                        counters.frames
                    )))
                }
            }
        }
        Ok(counters)
    }

    /// The keyframe selector's last pose and frames since, and where the
    /// window was last synchronised.
    fn parse_selector(a: &Archive<'_>) -> Result<(Selector, Option<DVec3>)> {
        let bad = |why: String| a.corrupt(why);
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

        Ok(((last, since), last_sync))
    }

    /// The global map's Gaussians by voxel, and the set of its voxels.
    fn parse_map(a: &Archive<'_>) -> Result<(Vec<(VoxelKey, Gaussian)>, Voxels)> {
        let bad = |why: String| a.corrupt(why);
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
            map.push((key, checked_gaussian(a, &key, g)?));
        }

        Ok((map, seen))
    }

    /// Which Gaussians are guesses; files from before guesses were kept
    /// have every Gaussian measured.
    fn parse_guesses(a: &Archive<'_>, n: usize) -> Result<Vec<u8>> {
        if !a.has("map/guess") {
            return Ok(vec![0; n]);
        }
        let flags = a.exact::<u8>("map/guess", &[n])?;
        check_flags(a, &flags)?;
        Ok(flags)
    }

    /// Every keyframe's pose; files from before it was saved rebuild it
    /// from the history.
    fn parse_trajectory(
        a: &Archive<'_>,
        keyframes: u64,
        history: &[KeyframeRecord],
    ) -> Result<Vec<(i64, CameraPose)>> {
        let bad = |why: String| a.corrupt(why);
        let trajectory = if a.has("trajectory/stamp") || a.has("trajectory/pose") {
            let n = match a.shape::<i64>("trajectory/stamp")? {
                &[n] => n,
                s => return Err(bad(format!("trajectory/stamp has shape {s:?}"))),
            };
            if n as u64 != keyframes {
                return Err(bad(format!(
                    "a trajectory of {n} poses for {} keyframes",
                    keyframes
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
        Ok(trajectory)
    }

    /// The window: the same residents in the same rows, with their Adam
    /// state.
    fn parse_window(
        a: &Archive<'_>,
        capacity: u64,
        view_pixels: u64,
        seen: Option<&HashSet<VoxelKey>>,
    ) -> Result<SavedWindow> {
        let bad = |why: String| a.corrupt(why);
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
            if seen.is_some_and(|seen| !seen.contains(k)) {
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
        Ok(SavedWindow {
            capacity,
            view_pixels,
            keys,
            state,
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
        let mut rgb = Consumed::new(&rgb, "rgb");
        let mut depth = Consumed::new(&depth, "depth_mm");
        let mut labels = Consumed::new(&labels, "labels");
        let mut vectors = Consumed::new(&vectors, "vectors");
        // Files from before exposure compensation: every keyframe at 1.
        let exposure = read_exposure(a, "history/exposure", h)?;
        let mut records = Vec::with_capacity(h);
        for i in 0..h {
            let keyframe = |why: String| a.corrupt(format!("history keyframe {i}: {why}"));
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
            let rgb_i = rgb.next(a, px * 3)?.to_vec();
            let depth_i = depth.next(a, px)?.to_vec();
            let r = &info[i * 6..i * 6 + 6];
            let regions =
                parse_regions(a, r, head_dim, &mut labels, &mut vectors).map_err(|e| match e {
                    RegionsError::Keyframe(why) => keyframe(why),
                    RegionsError::File(e) => e,
                })?;
            records.push(KeyframeRecord {
                stamp_ns: stamps[i],
                camera,
                rgb: rgb_i,
                depth_mm: depth_i,
                regions,
                exposure: exposure[i],
            });
        }
        rgb.all_used(a)?;
        depth.all_used(a)?;
        labels.all_used(a)?;
        vectors.all_used(a)?;
        Ok(records)
    }
}

/// A keyframe exposure per entry of `name` (`len` of them), each a gain
/// within [`EXPOSURE_RANGE`]; every one 1 when the file has none (saved
/// before exposure compensation).
fn read_exposure(a: &Archive<'_>, name: &str, len: usize) -> Result<Vec<f32>> {
    if !a.has(name) {
        return Ok(vec![1.0; len]);
    }
    let gains = a.exact::<f32>(name, &[len])?;
    match gains
        .iter()
        .find(|g| !(EXPOSURE_RANGE.0..=EXPOSURE_RANGE.1).contains(*g))
    {
        Some(g) => Err(a.corrupt(format!("{name} holds the gain {g}"))),
        None => Ok(gains),
    }
}

/// A flat tensor of the history read keyframe after keyframe.
struct Consumed<'t, T> {
    data: &'t [T],
    used: usize,
    what: &'static str,
}

impl<'t, T> Consumed<'t, T> {
    fn new(data: &'t [T], what: &'static str) -> Self {
        Consumed {
            data,
            used: 0,
            what,
        }
    }

    /// The next `len` values; an error when the tensor is shorter.
    fn next(&mut self, a: &Archive<'_>, len: u64) -> Result<&'t [T]> {
        let end = usize::try_from(len)
            .ok()
            .and_then(|len| self.used.checked_add(len))
            .filter(|&end| end <= self.data.len())
            .ok_or_else(|| a.corrupt(format!("history/{} is too short", self.what)))?;
        let r = &self.data[self.used..end];
        self.used = end;
        Ok(r)
    }

    /// An error unless the keyframes used every value.
    fn all_used(&self, a: &Archive<'_>) -> Result<()> {
        if self.used == self.data.len() {
            return Ok(());
        }
        Err(a.corrupt(format!(
            "history/{} holds {} values; the keyframes use {}",
            self.what,
            self.data.len(),
            self.used
        )))
    }
}

/// Why a keyframe's regions could not be read.
enum RegionsError {
    /// The keyframe's own record is wrong (the caller names the keyframe).
    Keyframe(String),
    /// The file is (a tensor too short).
    File(Error),
}

impl From<Error> for RegionsError {
    fn from(e: Error) -> Self {
        RegionsError::File(e)
    }
}

/// A keyframe's region targets from its record `r` (`[present, width,
/// height, grid, count, dim]`), its labels and vectors taken from the
/// history's tensors.
fn parse_regions(
    a: &Archive<'_>,
    r: &[u32],
    head_dim: Option<u32>,
    labels: &mut Consumed<'_, u16>,
    vectors: &mut Consumed<'_, f32>,
) -> std::result::Result<Option<RegionTargets>, RegionsError> {
    let bad = |why: String| Err(RegionsError::Keyframe(why));
    match r[0] {
        0 if r[1..].iter().all(|&x| x == 0) => Ok(None),
        1 => {
            let (rw, rh, grid, count, dim) = (r[1], r[2], r[3], r[4], r[5]);
            let cells = rw as u64 * rh as u64;
            if cells == 0 || cells > MAX_VIEW_PIXELS || grid > 1 {
                return bad(format!("regions of {rw}x{rh} (grid flag {grid})"));
            }
            if dim == 0 || Some(dim) != head_dim {
                return bad(match head_dim {
                    Some(d) => format!("{dim}-d embeddings; the map's are {d}-d"),
                    None => "region embeddings but the map has no latent head".into(),
                });
            }
            let grid = grid == 1;
            if grid && count as u64 != cells {
                return bad(format!("a {rw}x{rh} feature grid of {count} regions"));
            }
            let labels = labels.next(a, cells)?.to_vec();
            let vectors = vectors.next(a, count as u64 * dim as u64)?.to_vec();
            if let Some(&l) = labels
                .iter()
                .find(|&&l| l != NO_REGION_LABEL && l as u32 >= count)
            {
                return bad(format!("region label {l} of {count} regions"));
            }
            if !vectors.iter().all(|x| x.is_finite()) {
                return bad("non-finite region embeddings".into());
            }
            Ok(Some(RegionTargets {
                width: rw,
                height: rh,
                labels,
                grid,
                count,
                vectors,
                dim,
            }))
        }
        _ => bad(format!("region record {r:?} is malformed")),
    }
}

/// Saved Gaussian `g` of voxel `key` (its floats), when it is finite and
/// plausible ([`implausible`]).
pub(super) fn checked_gaussian(a: &Archive<'_>, key: &VoxelKey, g: &[f32]) -> Result<Gaussian> {
    if !g.iter().all(|x| x.is_finite()) {
        return Err(a.corrupt(format!(
            "the Gaussian of voxel {key:?} holds non-finite values"
        )));
    }
    let g: Gaussian = bytemuck::pod_read_unaligned(bytemuck::cast_slice(g));
    if let Some(why) = implausible(&g) {
        return Err(a.corrupt(format!("the Gaussian of voxel {key:?} {why}")));
    }
    Ok(g)
}

/// Refuses guess flags other than measured, [`GUESSED`] and [`SUPERSEDED`].
pub(super) fn check_flags(a: &Archive<'_>, flags: &[u8]) -> Result<()> {
    match flags.iter().find(|&&f| f > SUPERSEDED) {
        Some(f) => Err(a.corrupt(format!("map/guess holds the flag {f}"))),
        None => Ok(()),
    }
}

/// Why a saved Gaussian cannot be one the mapper made, if it cannot: a
/// rotation of (near) zero length, or a scale beyond what any map holds (a
/// log-scale outside [`LOG_SCALE_RANGE`]; e⁸⁸ overflows f32). Any finite
/// opacity logit is an opacity.
fn implausible(g: &Gaussian) -> Option<String> {
    let q = g.quat.iter().map(|x| x * x).sum::<f32>().sqrt();
    if !(1e-6..=1e6).contains(&q) {
        return Some(format!(
            "has a rotation of length {q} (a unit quaternion is expected)"
        ));
    }
    if let Some(s) = g.log_scale.iter().find(|s| !LOG_SCALE_RANGE.contains(*s)) {
        return Some(format!(
            "has a log-scale of {s}, outside {LOG_SCALE_RANGE:?} (e^{s} metres)"
        ));
    }
    None
}

/// Log-scales a saved Gaussian may have: 10⁻²² m to 5·10⁸ m, far beyond
/// any surface, short of overflow when squared in the covariance.
const LOG_SCALE_RANGE: std::ops::RangeInclusive<f32> = -50.0..=20.0;
