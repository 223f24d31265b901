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

mod frame;
mod log;
mod registry;
mod status;

use std::ffi::c_char;
use std::sync::{Mutex, RwLock};

use latentam::{LiveMapper, LiveOptions, TextQuery};

use frame::frame_of;
pub use frame::LatentamFrame;
pub use log::{latentam_log_free, latentam_log_next, latentam_log_open, LatentamLog};
use registry::{is_live, register, unregister};
use status::{engine_error, fail, guard, text};
pub use status::{latentam_last_error_message, LatentamStatus};

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
    /// Gaussians in the map after the last keyframe.
    pub gaussians: u64,
    /// The last keyframe's time from submission to the end of its mapping, ms (-1: none yet).
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
            gaussians: s.gaussians as u64,
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
