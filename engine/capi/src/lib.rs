//! latentam's C API: an opaque live mapper handle ([`LatentamMapper`]),
//! functions returning a [`LatentamStatus`] (with
//! [`latentam_last_error_message`] for the words), and plain structs for
//! frames. The header, `include/latentam.h`, is generated from this file
//! by cbindgen; `include/latentam.hpp` wraps it in RAII for C++.
//!
//! Ownership: every pointer the caller passes is only read during the
//! call (a submitted frame is copied); every handle a `*_new`/`*_open`
//! function returns is freed by its `*_free` function, which accepts
//! NULL; a frame filled by [`latentam_log_next`] points into the log
//! handle's buffers, valid until the next call on that handle or its
//! free. Handles are checked against a registry of live ones, so NULL, a
//! freed handle or a stray pointer gives [`LatentamStatus::InvalidHandle`]
//! instead of a crash. A mapper handle may be used from several threads at
//! once (submit from one, query from another); a log handle from one.

use std::cell::RefCell;
use std::collections::HashSet;
use std::ffi::{c_char, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Mutex, RwLock};

use latentam::frames::{
    AssemblyConfig, CameraPose, ColorImage, DepthData, DepthImage, Dtype, EmbeddingLayout,
    Embeddings, Frame, Intrinsics, LabelImage, McapFrames, PixelFormat,
};
use latentam::{LiveMapper, LiveOptions, TextQuery};

/// What a call did.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LatentamStatus {
    /// It worked.
    Ok = 0,
    /// A NULL, freed or unknown handle.
    InvalidHandle = 1,
    /// An argument out of range, or a NULL pointer where one is needed.
    InvalidArgument = 2,
    /// A frame that does not hold together (sizes, pose, intrinsics).
    BadFrame = 3,
    /// The map has no embeddings yet: nothing to query.
    NoEmbeddings = 4,
    /// Embeddings of another dimension or model than the map's.
    EmbeddingMismatch = 5,
    /// No usable Vulkan device, a lost device, a failed Vulkan call.
    Device = 6,
    /// GPU memory ran out, or the budget is too small.
    GpuMemory = 7,
    /// The mapper stopped (on the error in the message) or was finished.
    Stopped = 8,
    /// A file, log or run folder that cannot be read or written.
    Io = 9,
    /// The output buffer is too small; the count needed was written.
    BufferTooSmall = 10,
    /// The log has no more frames.
    EndOfLog = 11,
    /// A bug in the engine (a caught panic): please report the message.
    Internal = 12,
    /// The queue stayed full for the time given; the frame was not queued.
    Busy = 13,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

/// The message of the last failed call on this thread ("" after none);
/// valid until the next failed call on this thread.
#[no_mangle]
pub extern "C" fn latentam_last_error_message() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

fn fail(status: LatentamStatus, message: impl Into<String>) -> LatentamStatus {
    let text = message.into().replace('\0', " ");
    LAST_ERROR.with(|e| *e.borrow_mut() = CString::new(text).unwrap_or_default());
    status
}

fn engine_error(e: latentam::Error) -> LatentamStatus {
    use latentam::Error as E;
    let status = match &e {
        E::InvalidArgument(_) => LatentamStatus::InvalidArgument,
        E::BadFrame { .. } => LatentamStatus::BadFrame,
        E::NoEmbeddings => LatentamStatus::NoEmbeddings,
        E::EmbeddingDimension { .. } | E::EmbeddingModel { .. } => {
            LatentamStatus::EmbeddingMismatch
        }
        E::OutOfMemory(_) => LatentamStatus::GpuMemory,
        E::NoVulkan(_)
        | E::Vulkan { .. }
        | E::KernelBuild { .. }
        | E::DeviceLost { .. }
        | E::Unsupported(_) => LatentamStatus::Device,
        E::Stopped(_) => LatentamStatus::Stopped,
        E::Input(_) | E::Io { .. } | E::Locked { .. } => LatentamStatus::Io,
        _ => LatentamStatus::Internal,
    };
    fail(status, e.to_string())
}

/// Runs `f`, turning a panic into [`LatentamStatus::Internal`].
fn guard(f: impl FnOnce() -> LatentamStatus) -> LatentamStatus {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(status) => status,
        Err(p) => {
            let m = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            fail(LatentamStatus::Internal, format!("latentam panicked: {m}"))
        }
    }
}

/// Addresses of the handles alive now.
static HANDLES: Mutex<Option<HashSet<usize>>> = Mutex::new(None);

fn register<T>(b: Box<T>) -> *mut T {
    let p = Box::into_raw(b);
    let mut h = HANDLES.lock().unwrap_or_else(|e| e.into_inner());
    h.get_or_insert_with(HashSet::new).insert(p as usize);
    p
}

fn is_live<T>(p: *const T) -> bool {
    let h = HANDLES.lock().unwrap_or_else(|e| e.into_inner());
    !p.is_null() && h.as_ref().is_some_and(|s| s.contains(&(p as usize)))
}

fn unregister<T>(p: *mut T) -> Option<Box<T>> {
    let mut h = HANDLES.lock().unwrap_or_else(|e| e.into_inner());
    let removed = h.as_mut().is_some_and(|s| s.remove(&(p as usize)));
    // SAFETY: registered pointers come from Box::into_raw and are removed
    // from the registry exactly once, here.
    removed.then(|| unsafe { Box::from_raw(p) })
}

/// A live mapper (opaque).
pub struct LatentamMapper {
    state: RwLock<State>,
}

enum State {
    Live(LiveMapper),
    Finished(Box<Mutex<latentam::Mapper>>),
    Gone,
}

fn with_mapper(
    m: *const LatentamMapper,
    f: impl FnOnce(&LatentamMapper) -> LatentamStatus,
) -> LatentamStatus {
    guard(|| {
        if !is_live(m) {
            return fail(
                LatentamStatus::InvalidHandle,
                "not a live latentam mapper handle (NULL or freed)",
            );
        }
        // SAFETY: registered, so a live Box; freeing it while another
        // thread uses it is the caller's error, as with any C handle.
        f(unsafe { &*m })
    })
}

fn with_live(
    m: *const LatentamMapper,
    f: impl FnOnce(&LiveMapper) -> LatentamStatus,
) -> LatentamStatus {
    with_mapper(m, |m| {
        match &*m.state.read().unwrap_or_else(|e| e.into_inner()) {
            State::Live(live) => f(live),
            _ => fail(LatentamStatus::Stopped, "the mapper was finished"),
        }
    })
}

/// A C string argument, or an error for NULL or invalid UTF-8.
unsafe fn text<'a>(p: *const c_char, what: &str) -> Result<&'a str, LatentamStatus> {
    if p.is_null() {
        return Err(fail(
            LatentamStatus::InvalidArgument,
            format!("{what} is NULL"),
        ));
    }
    // SAFETY: the caller passes a NUL-terminated string.
    unsafe { CStr::from_ptr(p) }.to_str().map_err(|_| {
        fail(
            LatentamStatus::InvalidArgument,
            format!("{what} is not UTF-8"),
        )
    })
}

fn store(out: *mut *mut LatentamMapper, live: latentam::Result<LiveMapper>) -> LatentamStatus {
    match live {
        Ok(live) => {
            let handle = register(Box::new(LatentamMapper {
                state: RwLock::new(State::Live(live)),
            }));
            // SAFETY: checked non-null by the caller of `store`.
            unsafe { *out = handle };
            LatentamStatus::Ok
        }
        Err(e) => engine_error(e),
    }
}

/// Creates a mapper on the first suitable Vulkan device, every kernel
/// compiled before it returns. `config_toml`: the settings as TOML (the
/// keys of `latentam config --print-defaults`), or NULL for the defaults.
/// On success `*out` holds the handle; free it with
/// [`latentam_mapper_free`].
///
/// # Safety
/// `config_toml` is NULL or a NUL-terminated string; `out` is writable.
#[no_mangle]
pub unsafe extern "C" fn latentam_mapper_new(
    config_toml: *const c_char,
    out: *mut *mut LatentamMapper,
) -> LatentamStatus {
    guard(|| {
        if out.is_null() {
            return fail(LatentamStatus::InvalidArgument, "out is NULL");
        }
        let config = if config_toml.is_null() {
            latentam::Config::default()
        } else {
            // SAFETY: the caller's string.
            let toml = match unsafe { text(config_toml, "config_toml") } {
                Ok(t) => t,
                Err(s) => return s,
            };
            match latentam::Config::from_toml(toml) {
                Ok(c) => c,
                Err(e) => return engine_error(e),
            }
        };
        store(out, LiveMapper::new(config, LiveOptions::default()))
    })
}

/// Creates a mapper that goes on with the map saved in the run folder
/// `dir`.
///
/// # Safety
/// `dir` is a NUL-terminated string; `out` is writable.
#[no_mangle]
pub unsafe extern "C" fn latentam_mapper_load(
    dir: *const c_char,
    out: *mut *mut LatentamMapper,
) -> LatentamStatus {
    guard(|| {
        if out.is_null() {
            return fail(LatentamStatus::InvalidArgument, "out is NULL");
        }
        // SAFETY: the caller's string.
        let dir = match unsafe { text(dir, "dir") } {
            Ok(d) => d,
            Err(s) => return s,
        };
        store(out, LiveMapper::load(dir, LiveOptions::default()))
    })
}

/// Frees a mapper: a live one is aborted first (the keyframe in progress
/// hurries, queued frames are dropped). NULL and unknown pointers are
/// ignored.
#[no_mangle]
pub extern "C" fn latentam_mapper_free(mapper: *mut LatentamMapper) {
    let _ = guard(|| {
        drop(unregister(mapper));
        LatentamStatus::Ok
    });
}

/// One RGB-D frame, as the caller holds it: nothing is owned, everything
/// is copied by [`latentam_submit`].
#[repr(C)]
pub struct LatentamFrame {
    /// The frame's time, nanoseconds.
    pub stamp_ns: i64,
    /// Image columns.
    pub width: u32,
    /// Image rows.
    pub height: u32,
    /// RGB8 pixels: `height` rows of `rgb_stride` bytes (0: `width * 3`).
    pub rgb: *const u8,
    /// Bytes from one row of `rgb` to the next (0: packed).
    pub rgb_stride: usize,
    /// Depth in millimetres (0: none), or NULL when `depth_m` is given.
    pub depth_mm: *const u16,
    /// Depth in metres (0 or NaN: none), or NULL when `depth_mm` is given.
    pub depth_m: *const f32,
    /// Bytes from one row of depth to the next (0: packed).
    pub depth_stride: usize,
    /// Pinhole intrinsics, row-major 3×3: `[fx, 0, cx, 0, fy, cy, 0, 0, 1]`.
    pub k: [f64; 9],
    /// Camera-to-world transform, row-major 4×4, rigid (camera axes: x
    /// right, y down, z forward).
    pub t_world_camera: [f64; 16],
    /// Region ids (65535: none), `height` rows of `regions_stride` bytes,
    /// or NULL for a frame without embeddings.
    pub regions: *const u16,
    /// Bytes from one row of `regions` to the next (0: packed).
    pub regions_stride: usize,
    /// `embedding_count × embedding_dim` floats, one row per region id, or
    /// NULL.
    pub embeddings: *const f32,
    /// Rows of `embeddings`.
    pub embedding_count: u32,
    /// Columns of `embeddings`.
    pub embedding_dim: u32,
    /// The embedding model's id (NULL: "unknown").
    pub model: *const c_char,
}

/// Copies `height` rows of `width` elements, `stride` bytes apart.
///
/// # Safety
/// `p` points to `height` rows of at least `stride` bytes.
unsafe fn rows<T: Copy>(p: *const T, width: usize, height: usize, stride: usize) -> Vec<T> {
    let row_bytes = width * std::mem::size_of::<T>();
    let stride = if stride == 0 { row_bytes } else { stride };
    let mut out = Vec::with_capacity(width * height);
    for r in 0..height {
        // SAFETY: the caller's rows; `stride` is a multiple of the element
        // alignment (checked by the caller of `rows`).
        let row = unsafe {
            std::slice::from_raw_parts((p as *const u8).add(r * stride) as *const T, width)
        };
        out.extend_from_slice(row);
    }
    out
}

fn stride_ok<T>(stride: usize, width: usize) -> bool {
    stride == 0
        || (stride >= width * std::mem::size_of::<T>()
            && stride.is_multiple_of(std::mem::align_of::<T>()))
}

/// # Safety
/// The frame's pointers are as documented on [`LatentamFrame`].
unsafe fn frame_of(f: &LatentamFrame) -> Result<Frame, LatentamStatus> {
    let bad = |m: String| Err(fail(LatentamStatus::BadFrame, m));
    let (w, h) = (f.width as usize, f.height as usize);
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return bad(format!(
            "a {w}×{h} frame; 1 to 16384 pixels a side are taken"
        ));
    }
    if f.rgb.is_null() || (f.depth_mm.is_null() == f.depth_m.is_null()) {
        return bad("a frame needs rgb and exactly one of depth_mm and depth_m".into());
    }
    let depth_ok = if f.depth_mm.is_null() {
        stride_ok::<f32>(f.depth_stride, w)
    } else {
        stride_ok::<u16>(f.depth_stride, w)
    };
    let regions_ok = f.regions.is_null() || stride_ok::<u16>(f.regions_stride, w);
    if !stride_ok::<u8>(f.rgb_stride, w * 3) || !depth_ok || !regions_ok {
        return bad(
            "a row stride shorter than a row, or not a multiple of the element size".into(),
        );
    }
    // SAFETY: the caller's buffers, of the sizes the frame states.
    let rgb = unsafe { rows(f.rgb, w * 3, h, f.rgb_stride) };
    let depth = if f.depth_mm.is_null() {
        // SAFETY: as above.
        let m = unsafe { rows(f.depth_m, w, h, f.depth_stride) };
        DepthData::Metres(
            m.into_iter()
                .map(|z| if z.is_finite() { z } else { 0.0 })
                .collect(),
        )
    } else {
        // SAFETY: as above.
        DepthData::Units {
            values: unsafe { rows(f.depth_mm, w, h, f.depth_stride) },
            metres_per_unit: 0.001,
        }
    };
    let k = f.k;
    if [k[1], k[3], k[6], k[7]] != [0.0; 4] || k[8] != 1.0 || !(k[0] > 0.0 && k[4] > 0.0) {
        return bad(format!(
            "k must be a pinhole camera [fx, 0, cx, 0, fy, cy, 0, 0, 1] with fx, fy > 0, not {k:?}"
        ));
    }
    let pose = match CameraPose::from_matrix(&f.t_world_camera) {
        Ok(p) => p,
        Err(why) => return bad(why),
    };
    // SAFETY: the caller's buffers, as above.
    let embeddings = unsafe { embeddings_of(f)? };
    Ok(Frame {
        stamp_ns: f.stamp_ns,
        pose,
        intrinsics: Intrinsics {
            width: f.width,
            height: f.height,
            fx: k[0],
            fy: k[4],
            cx: k[2],
            cy: k[5],
        },
        color: ColorImage {
            width: f.width,
            height: f.height,
            format: PixelFormat::Rgb8,
            data: rgb,
        },
        depth: DepthImage {
            width: f.width,
            height: f.height,
            data: depth,
        },
        embeddings,
        semantic: None,
    })
}

/// The frame's region embeddings, if it has them.
///
/// # Safety
/// As [`frame_of`].
unsafe fn embeddings_of(f: &LatentamFrame) -> Result<Option<Embeddings>, LatentamStatus> {
    let bad = |m: String| Err(fail(LatentamStatus::BadFrame, m));
    match (f.regions.is_null(), f.embeddings.is_null()) {
        (true, true) => return Ok(None),
        (false, false) => {}
        _ => return bad("regions and embeddings come together, or not at all".into()),
    }
    let model = if f.model.is_null() {
        "unknown".to_string()
    } else {
        // SAFETY: the caller's string.
        unsafe { text(f.model, "model") }?.to_string()
    };
    let (n, d) = (f.embedding_count as usize, f.embedding_dim as usize);
    if n == 0 || d == 0 {
        return bad(format!("{n} embeddings of {d} values"));
    }
    let (w, h) = (f.width as usize, f.height as usize);
    // SAFETY: the caller's `height` rows of region ids.
    let labels = unsafe { rows(f.regions, w, h, f.regions_stride) };
    // SAFETY: the caller's `n × d` floats.
    let values = unsafe { std::slice::from_raw_parts(f.embeddings, n * d) };
    Ok(Some(Embeddings {
        layout: EmbeddingLayout::Regions(LabelImage {
            width: f.width,
            height: f.height,
            labels,
        }),
        count: n as u32,
        dim: d as u32,
        dtype: Dtype::F32,
        data: values.iter().flat_map(|x| x.to_le_bytes()).collect(),
        model,
    }))
}

/// Queues a copy of `frame` and returns at once (frames are dropped by
/// policy when the mapper falls behind: see [`LatentamMapperStatus`]).
///
/// # Safety
/// `frame` points to a [`LatentamFrame`] whose pointers are as documented.
#[no_mangle]
pub unsafe extern "C" fn latentam_submit(
    mapper: *const LatentamMapper,
    frame: *const LatentamFrame,
) -> LatentamStatus {
    with_live(mapper, |live| {
        if frame.is_null() {
            return fail(LatentamStatus::InvalidArgument, "frame is NULL");
        }
        // SAFETY: the caller's frame.
        match unsafe { frame_of(&*frame) } {
            Ok(f) => live
                .submit(f)
                .map_or_else(engine_error, |()| LatentamStatus::Ok),
            Err(s) => s,
        }
    })
}

/// Queues a copy of `frame`, waiting up to `max_wait_ms` for room
/// instead of dropping anything (for recorded logs, whose every frame
/// counts); [`LatentamStatus::Busy`] if there was none.
///
/// # Safety
/// As [`latentam_submit`].
#[no_mangle]
pub unsafe extern "C" fn latentam_submit_waiting(
    mapper: *const LatentamMapper,
    frame: *const LatentamFrame,
    max_wait_ms: u32,
) -> LatentamStatus {
    with_live(mapper, |live| {
        if frame.is_null() {
            return fail(LatentamStatus::InvalidArgument, "frame is NULL");
        }
        // SAFETY: the caller's frame.
        let f = match unsafe { frame_of(&*frame) } {
            Ok(f) => f,
            Err(s) => return s,
        };
        let wait = std::time::Duration::from_millis(max_wait_ms as u64);
        match live.submit_waiting(f, wait) {
            Ok(None) => LatentamStatus::Ok,
            Ok(Some(_)) => fail(
                LatentamStatus::Busy,
                format!("no room in the queue within {max_wait_ms} ms"),
            ),
            Err(e) => engine_error(e),
        }
    })
}

/// Where mapping stands.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct LatentamMapperStatus {
    /// Frames submitted.
    pub submitted: u64,
    /// Frames the mapper went through.
    pub integrated: u64,
    /// Keyframes mapped.
    pub keyframes: u64,
    /// Frames waiting.
    pub queued_frames: u64,
    /// Frames dropped from a full queue that could not become keyframes.
    pub dropped_not_keyframe: u64,
    /// Keyframe candidates dropped for a newer one.
    pub dropped_superseded: u64,
    /// Frames the map refused (see the message of `last_error`).
    pub dropped_rejected: u64,
    /// Gaussians in the latest snapshot.
    pub gaussians: u64,
    /// The last keyframe's time from submission to its snapshot, ms (-1: none yet).
    pub last_keyframe_latency_ms: f64,
    /// 1 once the mapper stopped on an error (the message says which).
    pub stopped: u32,
}

/// Fills `*out` with where mapping stands.
///
/// # Safety
/// `out` is writable.
#[no_mangle]
pub unsafe extern "C" fn latentam_status(
    mapper: *const LatentamMapper,
    out: *mut LatentamMapperStatus,
) -> LatentamStatus {
    with_live(mapper, |live| {
        if out.is_null() {
            return fail(LatentamStatus::InvalidArgument, "out is NULL");
        }
        let s = live.status();
        if let Some(e) = s.stopped.as_ref().or(s.last_error.as_ref()) {
            let _ = fail(LatentamStatus::Ok, e.to_string());
        }
        let status = LatentamMapperStatus {
            submitted: s.submitted,
            integrated: s.integrated,
            keyframes: s.keyframes,
            queued_frames: s.queued_frames as u64,
            dropped_not_keyframe: s.dropped.not_keyframe,
            dropped_superseded: s.dropped.superseded,
            dropped_rejected: s.dropped.rejected,
            gaussians: live.snapshot().len() as u64,
            last_keyframe_latency_ms: s.last_keyframe_latency_ms.unwrap_or(-1.0),
            stopped: s.stopped.is_some() as u32,
        };
        // SAFETY: checked non-null.
        unsafe { *out = status };
        LatentamStatus::Ok
    })
}

/// Cosine relevance of every Gaussian of the newest indexed snapshot to a
/// `dim`-float text embedding, written to `scores` (room for `capacity`);
/// `*count` receives the number of Gaussians. With too little room,
/// nothing is written but `*count`, and the call returns
/// [`LatentamStatus::BufferTooSmall`].
///
/// # Safety
/// `text` holds `dim` floats; `scores` has room for `capacity`; `count`
/// is writable.
#[no_mangle]
pub unsafe extern "C" fn latentam_query(
    mapper: *const LatentamMapper,
    text: *const f32,
    dim: usize,
    scores: *mut f32,
    capacity: usize,
    count: *mut usize,
) -> LatentamStatus {
    with_live(mapper, |live| {
        if text.is_null() || count.is_null() || (scores.is_null() && capacity > 0) || dim == 0 {
            return fail(
                LatentamStatus::InvalidArgument,
                "NULL text or count, or dim 0",
            );
        }
        // SAFETY: the caller's `dim` floats.
        let t = unsafe { std::slice::from_raw_parts(text, dim) }.to_vec();
        match live.relevance(&TextQuery::embedding(t)) {
            Ok(answer) => {
                let n = answer.scores.len();
                // SAFETY: checked non-null.
                unsafe { *count = n };
                if n > capacity {
                    return fail(
                        LatentamStatus::BufferTooSmall,
                        format!("{n} Gaussians, room for {capacity}"),
                    );
                }
                // SAFETY: room for `capacity` ≥ n floats.
                unsafe { std::ptr::copy_nonoverlapping(answer.scores.as_ptr(), scores, n) };
                LatentamStatus::Ok
            }
            Err(e) => engine_error(e),
        }
    })
}

/// Saves the map into the run folder `dir` (what `latentam query`, `eval`
/// and `export` read), between keyframes.
///
/// # Safety
/// `dir` is a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn latentam_save(
    mapper: *const LatentamMapper,
    dir: *const c_char,
) -> LatentamStatus {
    with_mapper(mapper, |m| {
        // SAFETY: the caller's string.
        let dir = match unsafe { text(dir, "dir") } {
            Ok(d) => d,
            Err(s) => return s,
        };
        let mut state = m.state.write().unwrap_or_else(|e| e.into_inner());
        let saved = match &mut *state {
            State::Live(live) => live.save(dir),
            State::Finished(mapper) => mapper
                .get_mut()
                .unwrap_or_else(|e| e.into_inner())
                .save(dir),
            State::Gone => return fail(LatentamStatus::Stopped, "the mapper failed to finish"),
        };
        saved.map_or_else(engine_error, |_| LatentamStatus::Ok)
    })
}

/// Maps every queued frame and stops the worker; the handle can still
/// save and must still be freed. Further frames are refused.
#[no_mangle]
pub extern "C" fn latentam_finish(mapper: *const LatentamMapper) -> LatentamStatus {
    with_mapper(mapper, |m| {
        let mut state = m.state.write().unwrap_or_else(|e| e.into_inner());
        let State::Live(live) = std::mem::replace(&mut *state, State::Gone) else {
            return LatentamStatus::Ok;
        };
        match live.finish() {
            Ok(mapper) => {
                *state = State::Finished(Box::new(Mutex::new(mapper)));
                LatentamStatus::Ok
            }
            Err(e) => engine_error(e),
        }
    })
}

/// The frames of an MCAP log or rosbag2 folder (opaque).
pub struct LatentamLog {
    frames: McapFrames,
    current: Option<Frame>,
    rgb: Vec<u8>,
    depth: Vec<f32>,
    embeddings: Vec<f32>,
    model: CString,
}

/// Opens a log; `*out` receives the handle, freed by [`latentam_log_free`].
///
/// # Safety
/// `path` is a NUL-terminated string; `out` is writable.
#[no_mangle]
pub unsafe extern "C" fn latentam_log_open(
    path: *const c_char,
    out: *mut *mut LatentamLog,
) -> LatentamStatus {
    guard(|| {
        if out.is_null() {
            return fail(LatentamStatus::InvalidArgument, "out is NULL");
        }
        // SAFETY: the caller's string.
        let path = match unsafe { text(path, "path") } {
            Ok(p) => p,
            Err(s) => return s,
        };
        match McapFrames::open(path.as_ref(), AssemblyConfig::default()) {
            Ok(frames) => {
                let log = register(Box::new(LatentamLog {
                    frames,
                    current: None,
                    rgb: Vec::new(),
                    depth: Vec::new(),
                    embeddings: Vec::new(),
                    model: CString::default(),
                }));
                // SAFETY: checked non-null.
                unsafe { *out = log };
                LatentamStatus::Ok
            }
            Err(e) => engine_error(e.into()),
        }
    })
}

/// Fills `*frame` with the log's next frame (RGB8, depth in metres, region
/// embeddings when the log has them), pointing into the log handle's
/// buffers until the next call or [`latentam_log_free`]; returns
/// [`LatentamStatus::EndOfLog`] after the last.
///
/// # Safety
/// `log` was returned by [`latentam_log_open`] and is used by one thread;
/// `frame` is writable.
#[no_mangle]
pub unsafe extern "C" fn latentam_log_next(
    log: *mut LatentamLog,
    frame: *mut LatentamFrame,
) -> LatentamStatus {
    guard(|| {
        if !is_live(log) {
            return fail(
                LatentamStatus::InvalidHandle,
                "not a live latentam log handle (NULL or freed)",
            );
        }
        if frame.is_null() {
            return fail(LatentamStatus::InvalidArgument, "frame is NULL");
        }
        // SAFETY: registered, so a live Box, used by one thread.
        let log = unsafe { &mut *log };
        let f = match log.frames.next() {
            None => return fail(LatentamStatus::EndOfLog, "the log has no more frames"),
            Some(Err(e)) => return engine_error(e.into()),
            Some(Ok(f)) => f,
        };
        log.rgb = f.color.to_rgb8();
        log.depth = f.depth.to_metres();
        let (mut regions, mut count, mut dim) = (std::ptr::null(), 0, 0);
        log.embeddings.clear();
        log.model = CString::default();
        if let Some(e) = &f.embeddings {
            if let EmbeddingLayout::Regions(mask) = &e.layout {
                log.embeddings = e.to_f32();
                regions = mask.labels.as_ptr();
                (count, dim) = (e.count, e.dim);
                log.model = CString::new(e.model.replace('\0', " ")).unwrap_or_default();
            }
        }
        let k = &f.intrinsics;
        let out = LatentamFrame {
            stamp_ns: f.stamp_ns,
            width: f.color.width,
            height: f.color.height,
            rgb: log.rgb.as_ptr(),
            rgb_stride: 0,
            depth_mm: std::ptr::null(),
            depth_m: log.depth.as_ptr(),
            depth_stride: 0,
            k: [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
            t_world_camera: f.pose.to_matrix(),
            regions,
            regions_stride: 0,
            embeddings: if regions.is_null() {
                std::ptr::null()
            } else {
                log.embeddings.as_ptr()
            },
            embedding_count: count,
            embedding_dim: dim,
            model: log.model.as_ptr(),
        };
        log.current = Some(f); // keeps the region mask alive
                               // SAFETY: checked non-null.
        unsafe { *frame = out };
        LatentamStatus::Ok
    })
}

/// Frees a log handle (NULL and unknown pointers are ignored).
#[no_mangle]
pub extern "C" fn latentam_log_free(log: *mut LatentamLog) {
    let _ = guard(|| {
        drop(unregister(log));
        LatentamStatus::Ok
    });
}
