//! How a live handle queues frames and serves readers.

use std::time::Duration;

use crate::mapper::IndexSettings;

/// How a [`LiveMapper`](super::LiveMapper) queues frames and serves readers.
///
/// ```
/// use latentam_core::live::LiveOptions;
/// // A deeper queue for a 60 Hz camera; at most 1 GiB of frames waiting.
/// let options = LiveOptions { queue_frames: 16, queue_bytes: 1 << 30, ..Default::default() };
/// assert!(!options.stop_on_rejected);
/// ```
#[derive(Clone, Debug)]
pub struct LiveOptions {
    /// Frames that may wait for the worker (at least 1); beyond, the
    /// drop policy applies (see [`DropCounts`](super::DropCounts) and the `queue` module).
    pub queue_frames: usize,
    /// Keyframe candidates that may wait (at least 1): a newer one
    /// replaces the oldest beyond this. Each one waiting puts the map one
    /// keyframe's time further behind the camera.
    pub keep_candidates: usize,
    /// Bytes of frames that may wait (images and embeddings, see
    /// [`frame_bytes`](super::frame_bytes)); one frame always fits, however large.
    pub queue_bytes: u64,
    /// What the relevance index keeps of each Gaussian's attention.
    pub index: IndexSettings,
    /// Also take a snapshot every this many keyframes, read or not (1:
    /// after each). 0, the default: only when a reader asks for one
    /// ([`LiveReader::snapshot`](super::LiveReader::snapshot)). A snapshot
    /// reads back every Gaussian the GPU changed and copies the map: tens
    /// of milliseconds at a few hundred thousand Gaussians, more than a
    /// keyframe's own work on a discrete GPU, so it is not taken for
    /// nobody.
    pub snapshot_every: u64,
    /// Stop taking frames after one the map refuses for its content
    /// (what mapping a log wants); by default it is counted and dropped
    /// and mapping goes on (what a robot wants).
    pub stop_on_rejected: bool,
    /// How long dropping the handle waits for the worker to end before
    /// leaving it to end on its own.
    pub drop_timeout: Duration,
    /// Keep each keyframe's report (about 4 kB) until
    /// [`LiveReader::take_keyframe_reports`](super::LiveReader::take_keyframe_reports)
    /// takes it, for a run folder's `report.json`; off by default, so a
    /// handle nobody reads does not grow.
    pub keep_keyframe_reports: bool,
}

impl Default for LiveOptions {
    fn default() -> Self {
        LiveOptions {
            queue_frames: 8,
            queue_bytes: 512 << 20,
            keep_candidates: 1,
            index: IndexSettings::default(),
            snapshot_every: 0,
            stop_on_rejected: false,
            drop_timeout: Duration::from_secs(10),
            keep_keyframe_reports: false,
        }
    }
}
