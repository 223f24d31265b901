//! The `latentam` Python package: [`latentam::LiveMapper`] on numpy
//! arrays. Every call checks shapes and dtypes before anything reaches the
//! engine and releases the GIL while the engine works, so a second Python
//! thread can query while the first submits.
//!
//! The module is `latentam._latentam`; `python/latentam/__init__.py`
//! re-exports it with the type stubs beside it.

use std::sync::{Arc, RwLock};

use latentam::frames::{AssemblyConfig, McapFrames};
use latentam::{LiveMapper, LiveOptions, MapSnapshot, TextQuery};
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

mod errors;
mod frames;

use errors::to_py;

/// The map, built on a worker thread while Python goes on.
#[pyclass(module = "latentam", frozen)]
struct Mapper {
    state: RwLock<State>,
}

enum State {
    Live(LiveMapper),
    /// After `finish`: the map, still saveable (a `Mapper` is used from
    /// one thread at a time).
    Finished(Box<std::sync::Mutex<latentam::Mapper>>),
    Gone,
}

fn options_from(queue_frames: usize, queue_bytes: u64, keep_candidates: usize) -> LiveOptions {
    LiveOptions {
        queue_frames,
        queue_bytes,
        keep_candidates,
        ..LiveOptions::default()
    }
}

#[pymethods]
impl Mapper {
    /// A mapper on the first suitable Vulkan device, every kernel compiled
    /// before it returns. `config` is a TOML string, a path to a TOML file
    /// (the keys of `latentam config --print-defaults`), or None for the
    /// defaults.
    #[new]
    #[pyo3(signature = (config=None, queue_frames=8, queue_bytes=512 << 20, keep_candidates=1))]
    fn new(
        py: Python<'_>,
        config: Option<&str>,
        queue_frames: usize,
        queue_bytes: u64,
        keep_candidates: usize,
    ) -> PyResult<Self> {
        let config = match config {
            None => latentam::Config::default(),
            Some(text) => {
                let path = std::path::Path::new(text);
                let toml = if !text.contains('=') && path.is_file() {
                    std::fs::read_to_string(path)
                        .map_err(|e| PyValueError::new_err(format!("{text}: {e}")))?
                } else {
                    text.to_string()
                };
                latentam::Config::from_toml(&toml).map_err(to_py)?
            }
        };
        let options = options_from(queue_frames, queue_bytes, keep_candidates);
        let live = py
            .allow_threads(|| LiveMapper::new(config, options))
            .map_err(to_py)?;
        Ok(Mapper {
            state: RwLock::new(State::Live(live)),
        })
    }

    /// A mapper that goes on with the map saved in the run folder `dir`.
    #[staticmethod]
    #[pyo3(signature = (dir, queue_frames=8, queue_bytes=512 << 20, keep_candidates=1))]
    fn load(
        py: Python<'_>,
        dir: std::path::PathBuf,
        queue_frames: usize,
        queue_bytes: u64,
        keep_candidates: usize,
    ) -> PyResult<Self> {
        let options = options_from(queue_frames, queue_bytes, keep_candidates);
        let live = py
            .allow_threads(|| LiveMapper::load(&dir, options))
            .map_err(to_py)?;
        Ok(Mapper {
            state: RwLock::new(State::Live(live)),
        })
    }

    /// Queues one RGB-D frame; returns at once (frames are dropped by
    /// policy when the mapper falls behind: see `status()["dropped"]`).
    ///
    /// rgb: uint8 [H, W, 3]; depth: uint16 millimetres or float32 metres
    /// [H, W] (0 or NaN: no measurement); K: [3, 3] pinhole intrinsics;
    /// T_world_camera: [4, 4] rigid camera-to-world transform (OpenCV
    /// camera axes: x right, y down, z forward); stamp_ns: the frame's
    /// time. regions: uint16 [H, W] region ids (65535: none) with
    /// embeddings: float16 or float32 [N, D], one row per region id.
    /// wait: block until the queue has room instead of dropping (for
    /// recorded data, whose every frame counts).
    #[pyo3(signature = (rgb, depth, K, T_world_camera, stamp_ns, regions=None, embeddings=None, model="unknown", wait=false))]
    #[allow(non_snake_case, clippy::too_many_arguments)]
    fn submit(
        &self,
        py: Python<'_>,
        rgb: &Bound<'_, PyAny>,
        depth: &Bound<'_, PyAny>,
        K: &Bound<'_, PyAny>,
        T_world_camera: &Bound<'_, PyAny>,
        stamp_ns: i64,
        regions: Option<&Bound<'_, PyAny>>,
        embeddings: Option<&Bound<'_, PyAny>>,
        model: &str,
        wait: bool,
    ) -> PyResult<()> {
        let frame = frames::frame_from_arrays(
            rgb,
            depth,
            K,
            T_world_camera,
            stamp_ns,
            regions,
            embeddings,
            model,
        )?;
        if !wait {
            return self.with_live(py, |live| live.submit(frame));
        }
        let mut waiting = Some(frame);
        while let Some(frame) = waiting.take() {
            // A second at a time, so Ctrl-C reaches Python between waits.
            let second = std::time::Duration::from_secs(1);
            waiting = self.with_live(py, |live| live.submit_waiting(frame, second))?;
            py.check_signals()?;
        }
        Ok(())
    }

    /// Where mapping stands: queue depth, frames dropped by reason,
    /// latencies (ms), the last error.
    fn status<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.with_live(py, |live| Ok(live.status()))?;
        let d = PyDict::new(py);
        d.set_item("queued_frames", s.queued_frames)?;
        d.set_item("queued_bytes", s.queued_bytes)?;
        d.set_item("submitted", s.submitted)?;
        d.set_item("integrated", s.integrated)?;
        d.set_item("keyframes", s.keyframes)?;
        d.set_item("gaussians", s.gaussians)?;
        d.set_item("gpu_bytes", s.gpu_bytes)?;
        d.set_item("snapshots", s.snapshots)?;
        let dropped = PyDict::new(py);
        dropped.set_item("not_keyframe", s.dropped.not_keyframe)?;
        dropped.set_item("superseded", s.dropped.superseded)?;
        dropped.set_item("rejected", s.dropped.rejected)?;
        dropped.set_item("aborted", s.dropped.aborted)?;
        d.set_item("dropped", dropped)?;
        d.set_item("mapping", s.mapping)?;
        d.set_item("last_keyframe_latency_ms", s.last_keyframe_latency_ms)?;
        d.set_item("last_keyframe_ms", s.last_keyframe_ms)?;
        d.set_item("keyframes_per_s", s.keyframes_per_s)?;
        d.set_item("last_error", s.last_error.map(|e| e.to_string()))?;
        d.set_item("stopped", s.stopped.map(|e| e.to_string()))?;
        d.set_item("ready_ms", s.ready_ms)?;
        Ok(d)
    }

    /// The map after the last keyframe: taken when asked, so it waits at
    /// most for the frame being mapped; after `finish` or `abort`, the
    /// whole final map.
    fn snapshot(&self, py: Python<'_>) -> PyResult<Snapshot> {
        let inner = py
            .allow_threads(|| {
                let state = self.state.read().unwrap_or_else(|e| e.into_inner());
                match &*state {
                    // Waited for without the lock, which `finish` and
                    // `abort` take.
                    State::Live(live) => {
                        let reader = live.reader();
                        drop(state);
                        Ok(reader.snapshot())
                    }
                    State::Finished(mapper) => mapper
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .snapshot()
                        .map(std::sync::Arc::new)
                        .map_err(Some),
                    State::Gone => Err(None),
                }
            })
            .map_err(py_error)?;
        Ok(Snapshot { inner })
    }

    /// Cosine relevance of every Gaussian of the newest indexed snapshot
    /// to `text_embedding` (float32 [D], or [M, D] for several: then
    /// [N, M]).
    fn query<'py>(
        &self,
        py: Python<'py>,
        text_embedding: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (values, texts) = frames::embedding_rows(text_embedding)?;
        let mut query = TextQuery::embedding(values);
        query.texts = texts; // cosines with each, as they are
        self.relevance(py, &query, texts)
    }

    /// Probability that each Gaussian shows `name` rather than any other
    /// word of the vocabulary (`names` with `vectors` float32 [M, D]): the
    /// softmax over the words' cosines at `temperature`.
    #[pyo3(signature = (names, vectors, name, temperature=0.1))]
    fn query_names<'py>(
        &self,
        py: Python<'py>,
        names: Vec<String>,
        vectors: &Bound<'py, PyAny>,
        name: &str,
        temperature: f32,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (vectors, texts) = frames::embedding_rows(vectors)?;
        if texts != names.len() {
            return Err(PyValueError::new_err(format!(
                "{} names for {texts} vectors",
                names.len()
            )));
        }
        let vocabulary = latentam::frames::Vocabulary {
            ids: (0..texts as u16).collect(),
            dim: (vectors.len() / texts) as u32,
            names,
            vectors,
            model: String::new(),
        };
        let query = TextQuery::vocabulary_word(&vocabulary, name, temperature).map_err(to_py)?;
        self.relevance(py, &query, 1)
    }

    /// Renders the map from a pose: {"color": float32 [H, W, 3], "depth":
    /// float32 [H, W] metres, "alpha": float32 [H, W]}. Served between
    /// keyframes: while one runs, this waits for the rest of it.
    #[pyo3(signature = (T_world_camera, K, width, height))]
    #[allow(non_snake_case)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        T_world_camera: &Bound<'py, PyAny>,
        K: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
    ) -> PyResult<Bound<'py, PyDict>> {
        let camera = frames::camera_from(T_world_camera, K, width, height)?;
        let view = self.with_live(py, |live| live.render(&camera))?;
        let (h, w) = (view.height as usize, view.width as usize);
        let color: Vec<f32> = view.rgbd.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
        let depth: Vec<f32> = view.rgbd.iter().map(|p| p[3]).collect();
        let d = PyDict::new(py);
        d.set_item(
            "color",
            PyArray1::from_vec(py, color).reshape(vec![h, w, 3])?,
        )?;
        d.set_item("depth", PyArray1::from_vec(py, depth).reshape(vec![h, w])?)?;
        d.set_item(
            "alpha",
            PyArray1::from_vec(py, view.alpha).reshape(vec![h, w])?,
        )?;
        Ok(d)
    }

    /// Saves the map into the run folder `dir` (what `latentam query`,
    /// `eval` and `export` read); returns the state file's path.
    fn save(&self, py: Python<'_>, dir: std::path::PathBuf) -> PyResult<String> {
        let path = py.allow_threads(|| {
            let mut state = self.state.write().unwrap_or_else(|e| e.into_inner());
            match &mut *state {
                State::Live(live) => live.save(&dir).map_err(Some),
                State::Finished(mapper) => mapper
                    .get_mut()
                    .unwrap_or_else(|e| e.into_inner())
                    .save(&dir)
                    .map_err(Some),
                State::Gone => Err(None),
            }
        });
        Ok(path.map_err(py_error)?.display().to_string())
    }

    /// Maps every queued frame and stops the worker; the map can still be
    /// saved. Further frames are refused.
    fn finish(&self, py: Python<'_>) -> PyResult<()> {
        self.close(py, LiveMapper::finish)
    }

    /// Stops at once: the keyframe in progress hurries, queued frames are
    /// dropped. The map can still be saved.
    fn abort(&self, py: Python<'_>) -> PyResult<()> {
        self.close(py, LiveMapper::abort)
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        py.allow_threads(|| self.describe())
    }
}

impl Mapper {
    fn describe(&self) -> String {
        let state = self.state.read().unwrap_or_else(|e| e.into_inner());
        match &*state {
            State::Live(live) => {
                let s = live.status();
                format!(
                    "latentam.Mapper(live, {} keyframes, {} queued)",
                    s.keyframes, s.queued_frames
                )
            }
            State::Finished(m) => format!(
                "latentam.Mapper(finished, {} keyframes)",
                m.lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .stats()
                    .keyframes
            ),
            State::Gone => "latentam.Mapper(failed)".into(),
        }
    }

    /// Runs `f` on the live handle with the GIL released. Every lock is
    /// taken without the GIL: a thread waiting for one never holds the GIL
    /// that the holder needs to give the lock back.
    fn with_live<R: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&LiveMapper) -> latentam::Result<R> + Send,
    ) -> PyResult<R> {
        py.allow_threads(|| {
            let state = self.state.read().unwrap_or_else(|e| e.into_inner());
            match &*state {
                State::Live(live) => f(live).map_err(Some),
                _ => Err(None),
            }
        })
        .map_err(py_error)
    }

    /// Ends the live handle with `how` (finish or abort), keeping the map.
    fn close(
        &self,
        py: Python<'_>,
        how: fn(LiveMapper) -> latentam::Result<latentam::Mapper>,
    ) -> PyResult<()> {
        py.allow_threads(|| {
            let mut state = self.state.write().unwrap_or_else(|e| e.into_inner());
            let State::Live(live) = std::mem::replace(&mut *state, State::Gone) else {
                return Ok(());
            };
            let mapper = how(live)?;
            *state = State::Finished(Box::new(std::sync::Mutex::new(mapper)));
            Ok(())
        })
        .map_err(to_py)
    }

    fn relevance<'py>(
        &self,
        py: Python<'py>,
        query: &TextQuery,
        columns: usize,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let answer = self.with_live(py, |live| live.relevance(query))?;
        scores_array(py, answer.scores, columns)
    }
}

/// Gaussians × `columns` scores as [N] (one column) or [N, columns].
fn scores_array(
    py: Python<'_>,
    scores: Vec<f32>,
    columns: usize,
) -> PyResult<Bound<'_, PyArrayDyn<f32>>> {
    let n = scores.len() / columns.max(1);
    let shape = if columns == 1 {
        vec![n]
    } else {
        vec![n, columns]
    };
    PyArray1::from_vec(py, scores).reshape(shape)
}

fn gone() -> PyErr {
    errors::StoppedError::new_err("the mapper was finished or aborted, or failed to finish")
}

/// An engine error, or (None) a mapper no longer live.
fn py_error(e: Option<latentam::Error>) -> PyErr {
    e.map_or_else(gone, to_py)
}

/// The map as it stood after one keyframe, as numpy arrays.
#[pyclass(module = "latentam", frozen)]
struct Snapshot {
    inner: Arc<MapSnapshot>,
}

#[pymethods]
impl Snapshot {
    /// Keyframes mapped when it was taken.
    #[getter]
    fn keyframes(&self) -> u64 {
        self.inner.keyframes
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// Centres, float32 [N, 3], world frame, metres.
    #[getter]
    fn means<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        rows(py, &self.inner.gaussians.means)
    }

    /// Per-axis standard deviations, float32 [N, 3], metres.
    #[getter]
    fn scales<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let s: Vec<[f32; 3]> = self
            .inner
            .gaussians
            .log_scales
            .iter()
            .map(|l| l.map(f32::exp))
            .collect();
        rows(py, &s)
    }

    /// Rotations, float32 [N, 4] unit quaternions (w, x, y, z).
    #[getter]
    fn rotations<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        // The map keeps them as optimised; the renderer normalises them.
        let unit: Vec<[f32; 4]> = self
            .inner
            .gaussians
            .quats
            .iter()
            .map(|q| {
                let n = q.iter().map(|x| x * x).sum::<f32>().sqrt();
                if n > 0.0 {
                    q.map(|x| x / n)
                } else {
                    [1.0, 0.0, 0.0, 0.0]
                }
            })
            .collect();
        rows(py, &unit)
    }

    /// Colours, float32 [N, 3], RGB in 0..1.
    #[getter]
    fn colors<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        rows(py, &self.inner.gaussians.colors)
    }

    /// Opacities, float32 [N], 0..1.
    #[getter]
    fn opacities<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let o: Vec<f32> = self
            .inner
            .gaussians
            .opacity_logits
            .iter()
            .map(|l| 1.0 / (1.0 + (-l).exp()))
            .collect();
        Ok(PyArray1::from_vec(py, o).to_dyn().clone())
    }

    /// Latent queries, float32 [N, 32].
    #[getter]
    fn queries<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        rows(py, &self.inner.gaussians.queries)
    }

    /// Keyframe stamps (ns), int64 [K].
    #[getter]
    fn keyframe_stamps<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        PyArray1::from_vec(py, self.inner.trajectory.iter().map(|(s, _)| *s).collect())
    }

    /// Keyframe camera-to-world transforms, float64 [K, 4, 4].
    #[getter]
    fn keyframe_poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let mut flat = Vec::with_capacity(self.inner.trajectory.len() * 16);
        for (_, pose) in &self.inner.trajectory {
            flat.extend(pose.to_matrix());
        }
        let k = self.inner.trajectory.len();
        PyArray1::from_vec(py, flat).reshape(vec![k, 4, 4])
    }

    /// Cosine relevance of every Gaussian to `text_embedding` (float32 [D]
    /// or [M, D]).
    fn query<'py>(
        &self,
        py: Python<'py>,
        text_embedding: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (values, texts) = frames::embedding_rows(text_embedding)?;
        let inner = self.inner.clone();
        let scores = py.allow_threads(|| inner.cosines(&values)).map_err(to_py)?;
        scores_array(py, scores, texts)
    }

    fn __repr__(&self) -> String {
        format!(
            "latentam.Snapshot({} Gaussians, {} keyframes)",
            self.inner.len(),
            self.inner.keyframes
        )
    }
}

fn rows<'py, const C: usize>(
    py: Python<'py>,
    values: &[[f32; C]],
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let flat: Vec<f32> = values.iter().flatten().copied().collect();
    PyArray1::from_vec(py, flat).reshape(vec![values.len(), C])
}

/// The frames of an MCAP log or a rosbag2 folder, as dicts of numpy
/// arrays ready for `Mapper.submit(**frame)`.
#[pyclass(module = "latentam", unsendable)]
struct LogFrames {
    inner: McapFrames,
}

#[pymethods]
impl LogFrames {
    #[new]
    fn new(py: Python<'_>, path: std::path::PathBuf) -> PyResult<Self> {
        let inner = py
            .allow_threads(|| McapFrames::open(&path, AssemblyConfig::default()))
            .map_err(|e| to_py(e.into()))?;
        Ok(LogFrames { inner })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__<'py>(&mut self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        match self.inner.next() {
            None => Ok(None),
            Some(Err(e)) => Err(to_py(e.into())),
            Some(Ok(frame)) => frames::arrays_from_frame(py, &frame).map(Some),
        }
    }
}

#[pymodule]
fn _latentam(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Mapper>()?;
    m.add_class::<Snapshot>()?;
    m.add_class::<LogFrames>()?;
    errors::register(m)?;
    Ok(())
}
