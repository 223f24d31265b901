//! Reading frames from an MCAP log or rosbag2 folder ([`LatentamLog`]),
//! filled into [`LatentamFrame`]s that point into the handle's buffers.

use std::ffi::{c_char, CString};

use latentam::frames::{AssemblyConfig, EmbeddingLayout, Frame, McapFrames};

use crate::frame::LatentamFrame;
use crate::registry::{is_live, register, unregister};
use crate::status::{engine_error, fail, guard, text, LatentamStatus};

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
