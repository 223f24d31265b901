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
    pub(super) map: &'a [(VoxelKey, Gaussian)],
    pub(super) guesses: &'a [u8],
    pub(super) head: Option<&'a SavedHead>,
    pub(super) history: Vec<&'a KeyframeRecord>,
    pub(super) trajectory: &'a [(i64, CameraPose)],
    pub(super) exposure: Vec<f32>,
    pub(super) window: Option<&'a SavedWindow>,
}

impl StateRef<'_> {
    pub(super) fn into_bytes(self) -> Result<Vec<u8>> {
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

        // Global map, in slot order.
        let n = self.map.len();
        w.tensor(
            "map/keys",
            &[n, 3],
            &keys_to_i32(self.map.iter().map(|(k, _)| *k)),
        );
        w.tensor("map/guess", &[self.guesses.len()], self.guesses);
        let gaussians: Vec<Gaussian> = self.map.iter().map(|(_, g)| *g).collect();
        w.tensor(
            "map/gaussians",
            &[n, GAUSSIAN_FLOATS],
            bytemuck::cast_slice::<Gaussian, f32>(&gaussians),
        );

        if let Some(win) = self.window {
            write_window(&mut w, win);
        }
        if let Some(head) = self.head {
            write_head(&mut w, head);
        }
        write_history(&mut w, &self.history);
        write_trajectory(&mut w, self.trajectory, &self.exposure);
        w.into_bytes()
    }
}

/// The window: resident keys in row order and the optimiser's rows.
fn write_window(w: &mut ArchiveWriter, win: &SavedWindow) {
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

/// The latent head: W, D, D⁰, the k-means weights and Adam's state.
fn write_head(w: &mut ArchiveWriter, head: &SavedHead) {
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

/// The keyframe history, each tensor concatenated over the keyframes.
fn write_history(w: &mut ArchiveWriter, history: &[&KeyframeRecord]) {
    let h = history.len();
    let mut stamps = Vec::with_capacity(h);
    let mut cams = Vec::with_capacity(h * CAMERA_FLOATS);
    let mut sizes = Vec::with_capacity(h * 2);
    let mut rgb = Vec::new();
    let mut depth = Vec::new();
    let mut info = Vec::with_capacity(h * 6);
    let mut labels = Vec::new();
    let mut vectors = Vec::new();
    for k in history {
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
            map: &self.map,
            guesses: &self.guesses,
            head: self.head.as_ref(),
            history: self.history.iter().collect(),
            trajectory: &self.trajectory,
            exposure: self.exposure.clone(),
            window: self.window.as_ref(),
        }
        .into_bytes()
    }
}
