//! Writing a state: every part of the mapper as one archive's metadata
//! and tensors, whether it comes from a live mapper (`gpu.rs`) or from a
//! [`SavedState`] read earlier.

use super::*;

/// What one archive holds, borrowed: written by both
/// `Mapper::save` and [`SavedState::to_bytes`].
pub(super) struct StateRef<'a> {
    pub(super) run_id: Option<&'a str>,
    pub(super) config: &'a MapperConfig,
    pub(super) counters: Counters,
    pub(super) model: Option<&'a str>,
    pub(super) selector: (Option<CameraPose>, u32),
    pub(super) last_sync: Option<DVec3>,
    pub(super) map: &'a dyn MapRows,
    pub(super) head: Option<&'a SavedHead>,
    pub(super) history: Vec<&'a KeyframeRecord>,
    pub(super) trajectory: &'a [(i64, CameraPose)],
    pub(super) exposure: Vec<f32>,
    pub(super) window: Option<&'a SavedWindow>,
}

/// The global map as a state writes it: every Gaussian with its voxel key
/// and guess flag, visited in chunks in one fixed order, as many times as
/// the writer needs (once per tensor), so that it streams from wherever
/// the map lives.
pub(super) trait MapRows {
    /// Gaussians in the map.
    fn len(&self) -> usize;
    /// Guess flags: one per Gaussian.
    fn guesses_len(&self) -> usize {
        self.len()
    }
    /// Calls `visit(keys, gaussians, flags)` for every chunk of the map,
    /// in the same order on every call; each flag is [`GUESSED`],
    /// [`SUPERSEDED`] or 0. Stops at the first error.
    fn for_each_chunk(&self, visit: &mut ChunkVisitor<'_>) -> Result<()>;
}

/// What [`MapRows::for_each_chunk`] calls.
pub(super) type ChunkVisitor<'v> = dyn FnMut(&[VoxelKey], &[Gaussian], &[u8]) -> Result<()> + 'v;

/// A loaded state's map and guess flags, in slot order.
struct SavedRows<'a> {
    map: &'a [(VoxelKey, Gaussian)],
    guesses: &'a [u8],
}

impl MapRows for SavedRows<'_> {
    fn len(&self) -> usize {
        self.map.len()
    }

    fn guesses_len(&self) -> usize {
        self.guesses.len()
    }

    fn for_each_chunk(&self, visit: &mut ChunkVisitor<'_>) -> Result<()> {
        const CHUNK: usize = 4096;
        // Written as held, even when the two lengths differ (a test's
        // state that the reader must refuse).
        let part = |len: usize, i: usize| i.min(len)..(i + CHUNK).min(len);
        for i in (0..self.map.len().max(self.guesses.len())).step_by(CHUNK) {
            let rows = &self.map[part(self.map.len(), i)];
            let flags = &self.guesses[part(self.guesses.len(), i)];
            let keys: Vec<VoxelKey> = rows.iter().map(|(k, _)| *k).collect();
            let gaussians: Vec<Gaussian> = rows.iter().map(|(_, g)| *g).collect();
            visit(&keys, &gaussians, flags)?;
        }
        Ok(())
    }
}

impl<'a> StateRef<'a> {
    /// The state as an archive to write: the global map and the
    /// history's images stream from where they are, nothing is copied.
    pub(super) fn into_archive(self) -> Result<ArchiveWriter<'a>> {
        // Never a file the reader would refuse.
        if let Some(what) = missing_from(self.run_id, &self.counters) {
            return Err(Error::bad_input(
                "the state to save",
                format!(
                    "a state with {what} cannot be saved: every state this version writes \
                     carries both (save a loaded state through a run folder, which gives it a \
                     run id)"
                ),
            ));
        }
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

        // Global map, one pass over it per tensor.
        let map = self.map;
        let n = map.len();
        w.stream::<i32>("map/keys", &[n, 3], move |sink| {
            map.for_each_chunk(&mut |keys, _, _| {
                sink.put(bytemuck::cast_slice(&keys_to_i32(keys.iter().copied())))
            })
        });
        w.stream::<u8>("map/guess", &[map.guesses_len()], move |sink| {
            map.for_each_chunk(&mut |_, _, flags| sink.put(flags))
        });
        w.stream::<f32>("map/gaussians", &[n, GAUSSIAN_FLOATS], move |sink| {
            map.for_each_chunk(&mut |_, gaussians, _| sink.put(bytemuck::cast_slice(gaussians)))
        });

        if let Some(win) = self.window {
            write_window(&mut w, win);
        }
        if let Some(head) = self.head {
            write_head(&mut w, head);
        }
        write_history(&mut w, &self.history);
        write_trajectory(&mut w, self.trajectory, &self.exposure);
        Ok(w)
    }
}

/// The window: resident keys in row order and the optimiser's rows.
fn write_window<'a>(w: &mut ArchiveWriter<'a>, win: &'a SavedWindow) {
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
        w.bytes(&format!("window/state/{i}"), n, row, bytes);
    }
}

/// The latent head: W, D, D⁰, the k-means weights and Adam's state.
fn write_head<'a>(w: &mut ArchiveWriter<'a>, head: &'a SavedHead) {
    let d = head.dim as usize;
    w.meta("head_dim", d);
    w.meta("head_atoms", head.used);
    let rows = |v: &[f32]| v.len().checked_div(d).unwrap_or(0);
    w.tensor_ref("head/W", &[rows(&head.w), d], &head.w);
    w.tensor_ref("head/D", &[rows(&head.atoms), d], &head.atoms);
    w.tensor_ref("head/D0", &[rows(&head.anchors), d], &head.anchors);
    w.tensor_ref("head/kmeans_weights", &[head.weights.len()], &head.weights);
    for (i, bytes) in head.adam.iter().enumerate() {
        w.bytes(&format!("head/adam/{i}"), 1, bytes.len(), bytes);
    }
}

/// The keyframe history, each tensor concatenated over the keyframes
/// (the images and region targets streamed from the records).
fn write_history<'a>(w: &mut ArchiveWriter<'a>, history: &[&'a KeyframeRecord]) {
    let h = history.len();
    let mut stamps = Vec::with_capacity(h);
    let mut cams = Vec::with_capacity(h * CAMERA_FLOATS);
    let mut sizes = Vec::with_capacity(h * 2);
    let mut info = Vec::with_capacity(h * 6);
    let (mut rgb, mut depth, mut labels, mut vectors) = (0, 0, 0, 0);
    for k in history {
        stamps.push(k.stamp_ns);
        cams.extend(camera_to_f64(&k.camera));
        sizes.extend([k.camera.width, k.camera.height]);
        rgb += k.rgb.len();
        depth += k.depth_mm.len();
        match &k.regions {
            Some(r) => {
                info.extend([1, r.width, r.height, r.grid as u32, r.count, r.dim]);
                labels += r.labels.len();
                vectors += r.vectors.len();
            }
            None => info.extend([0u32; 6]),
        }
    }
    w.meta("history", h);
    w.tensor("history/stamp", &[h], &stamps);
    w.tensor("history/camera", &[h, CAMERA_FLOATS], &cams);
    w.tensor("history/size", &[h, 2], &sizes);
    /// Streams one part of every record, in history order.
    fn each<'a>(
        history: &[&'a KeyframeRecord],
        part: impl Fn(&'a KeyframeRecord) -> &'a [u8] + 'a,
    ) -> impl FnOnce(&mut Sink<'_>) -> Result<()> + 'a {
        let history = history.to_vec();
        move |sink| history.iter().try_for_each(|k| sink.put(part(k)))
    }
    w.stream::<u8>("history/rgb", &[rgb], each(history, |k| &k.rgb));
    let depth_of = |k: &'a KeyframeRecord| bytemuck::cast_slice(&k.depth_mm);
    w.stream::<u16>("history/depth_mm", &[depth], each(history, depth_of));
    w.tensor("history/regions", &[h, 6], &info);
    let labels_of = |k: &'a KeyframeRecord| {
        k.regions
            .as_ref()
            .map_or(&[][..], |r| bytemuck::cast_slice(&r.labels))
    };
    w.stream::<u16>("history/labels", &[labels], each(history, labels_of));
    let vectors_of = |k: &'a KeyframeRecord| {
        k.regions
            .as_ref()
            .map_or(&[][..], |r| bytemuck::cast_slice(&r.vectors))
    };
    w.stream::<f32>("history/vectors", &[vectors], each(history, vectors_of));
    let exposure: Vec<f32> = history.iter().map(|k| k.exposure).collect();
    w.tensor("history/exposure", &[h], &exposure);
}

/// Every keyframe's pose and exposure (the history may have let some go).
fn write_trajectory(w: &mut ArchiveWriter, trajectory: &[(i64, CameraPose)], exposure: &[f32]) {
    let n = trajectory.len();
    let stamps: Vec<i64> = trajectory.iter().map(|t| t.0).collect();
    let poses: Vec<f64> = trajectory
        .iter()
        .flat_map(|(_, p)| pose_to_f64(p))
        .collect();
    w.tensor("trajectory/stamp", &[n], &stamps);
    w.tensor("trajectory/pose", &[n, POSE_FLOATS], &poses);
    w.tensor("trajectory/exposure", &[exposure.len()], exposure);
}

impl SavedState {
    /// The file as `Mapper::save` writes it.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        StateRef {
            run_id: self.run_id.as_deref(),
            config: &self.config,
            counters: self.counters,
            model: self.model.as_deref(),
            selector: self.selector,
            last_sync: self.last_sync,
            map: &SavedRows {
                map: &self.map,
                guesses: &self.guesses,
            },
            head: self.head.as_ref(),
            history: self.history.iter().collect(),
            trajectory: &self.trajectory,
            exposure: self.exposure.clone(),
            window: self.window.as_ref(),
        }
        .into_archive()?
        .into_bytes()
    }
}
