//! The bounded queue between [`LiveMapper::submit`](super::LiveMapper::submit)
//! and the worker, and which frames it gives up when it is full.
//!
//! A frame is a *keyframe candidate* when the mapper's keyframe rule could
//! make it one: under `interval(N)` the N-th frame since the last
//! candidate, under `overlap` any frame, and in both cases only if the
//! camera moved `min_translation` / `min_rotation_deg` since the last
//! candidate ([`KeyframeConfig::moved`]). Other frames would be skipped by
//! the mapper anyway.
//!
//! At most `keep_candidates` candidates wait (1 by default): a newer one
//! replaces the oldest, counted as [`DropCounts::superseded`], since a
//! robot wants the map of where it is now, and each waiting candidate
//! holds the map one keyframe further behind. When a frame does not fit
//! (too many frames or bytes queued), the queue drops, one at a time
//! until it fits:
//!
//! 1. the oldest frame that is no candidate (the incoming one included),
//!    counted as [`DropCounts::not_keyframe`];
//! 2. else the oldest candidate, counted as [`DropCounts::superseded`].
//!
//! A queue always admits one frame, however large. Every frame given up
//! is still counted by the mapper's keyframe rule
//! ([`KeyframeSelector::count_unseen`](crate::map::KeyframeSelector::count_unseen)),
//! so an interval policy proposes every N-th frame of the stream, not of
//! what got through.

use std::collections::VecDeque;
use std::time::Instant;

use latentam_io::{CameraPose, DepthData, Frame};

use crate::map::{KeyframeConfig, KeyframePolicy};

/// Frames given up, by reason.
///
/// ```
/// let drops = latentam_core::live::DropCounts { not_keyframe: 3, superseded: 1, ..Default::default() };
/// assert_eq!(drops.total(), 4);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DropCounts {
    /// Dropped from a full queue, and no keyframe candidate (the mapper
    /// would have skipped them).
    pub not_keyframe: u64,
    /// Keyframe candidates dropped from a full queue for a newer one.
    pub superseded: u64,
    /// Refused by the map for their content (a pose that is no rigid
    /// transform, embeddings of another model...): the map is unchanged,
    /// and the error is the status's `last_error`.
    pub rejected: u64,
    /// Still queued when the handle was aborted or dropped.
    pub aborted: u64,
}

impl DropCounts {
    /// All frames given up.
    pub fn total(&self) -> u64 {
        self.not_keyframe + self.superseded + self.rejected + self.aborted
    }
}

/// Bytes a frame holds (its images and embeddings), what the queue's byte
/// bound counts.
///
/// ```
/// # use latentam_io::*;
/// # let pose = CameraPose { rotation: glam::DQuat::IDENTITY, translation: glam::DVec3::ZERO };
/// let frame = Frame {
///     stamp_ns: 0,
///     pose,
///     intrinsics: Intrinsics { width: 4, height: 2, fx: 1.0, fy: 1.0, cx: 2.0, cy: 1.0 },
///     color: ColorImage { width: 4, height: 2, format: PixelFormat::Rgb8, data: vec![0; 24] },
///     depth: DepthImage { width: 4, height: 2, data: DepthData::Metres(vec![1.0; 8]) },
///     embeddings: None,
///     semantic: None,
/// };
/// assert_eq!(latentam_core::live::frame_bytes(&frame), 24 + 32);
/// ```
pub fn frame_bytes(frame: &Frame) -> u64 {
    let depth = match &frame.depth.data {
        DepthData::Units { values, .. } => values.len() * 2,
        DepthData::Metres(values) => values.len() * 4,
    };
    let embeddings = frame.embeddings.as_ref().map_or(0, |e| e.data.len());
    let semantic = frame.semantic.as_ref().map_or(0, |s| s.labels.len() * 2);
    (frame.color.data.len() + depth + embeddings + semantic) as u64
}

/// A frame waiting for the worker.
pub(crate) struct Queued {
    pub frame: Frame,
    pub bytes: u64,
    pub submitted: Instant,
    pub candidate: bool,
    /// Frames given up just before this one (the worker counts them).
    pub dropped_before: u32,
}

/// The queue and its keyframe-candidate rule.
pub(crate) struct FrameQueue {
    items: VecDeque<Queued>,
    bytes: u64,
    max_frames: usize,
    max_bytes: u64,
    /// Keyframe candidates that may wait; older ones beyond go.
    max_candidates: usize,
    rule: KeyframeConfig,
    /// The last candidate's pose, and frames submitted since.
    last_candidate: Option<CameraPose>,
    since_candidate: u32,
    /// Frames given up after the newest queued one (counted by the next).
    dropped_tail: u32,
}

impl FrameQueue {
    pub fn new(
        max_frames: usize,
        max_bytes: u64,
        max_candidates: usize,
        rule: KeyframeConfig,
    ) -> Self {
        FrameQueue {
            items: VecDeque::new(),
            bytes: 0,
            max_frames: max_frames.max(1),
            max_bytes,
            max_candidates: max_candidates.max(1),
            rule,
            last_candidate: None,
            since_candidate: 0,
            dropped_tail: 0,
        }
    }

    /// Starts the candidate rule from the map's last keyframe (a resumed
    /// map), so the first frames after it are judged as the mapper will.
    pub fn start_after(&mut self, last_keyframe: Option<CameraPose>, since: u32) {
        self.last_candidate = last_keyframe;
        self.since_candidate = since;
    }

    pub fn len(&self) -> usize {
        self.items.len()
    }

    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Whether `bytes` more fit without dropping anything.
    pub fn has_room(&self, bytes: u64) -> bool {
        self.items.is_empty()
            || (self.items.len() < self.max_frames && self.bytes + bytes <= self.max_bytes)
    }

    /// Whether any frame of `bytes` is admitted without dropping one:
    /// room, and room for one more keyframe candidate.
    pub fn takes_without_dropping(&self, bytes: u64) -> bool {
        self.has_room(bytes)
            && self.items.iter().filter(|q| q.candidate).count() < self.max_candidates
    }

    /// Whether the candidate rule makes `frame` a keyframe candidate
    /// (and moves the rule on as if it were submitted).
    fn classify(&mut self, frame: &Frame) -> bool {
        self.since_candidate = self.since_candidate.saturating_add(1);
        let candidate = match self.last_candidate {
            None => true,
            Some(last) => {
                let proposed = match self.rule.policy {
                    KeyframePolicy::Interval(n) => self.since_candidate >= n.max(1),
                    KeyframePolicy::Overlap { .. } => true,
                };
                proposed && self.rule.moved(&last, &frame.pose)
            }
        };
        if candidate {
            self.last_candidate = Some(frame.pose);
            self.since_candidate = 0;
        }
        candidate
    }

    /// Queues `frame`, dropping what the policy says to make room.
    pub fn admit(&mut self, frame: Frame, drops: &mut DropCounts) {
        let bytes = frame_bytes(&frame);
        let candidate = self.classify(&frame);
        if candidate {
            while self.items.iter().filter(|q| q.candidate).count() >= self.max_candidates {
                let oldest = self
                    .items
                    .iter()
                    .position(|q| q.candidate)
                    .expect("counted");
                drops.superseded += 1;
                self.remove(oldest);
            }
        }
        while !self.has_room(bytes) {
            if !candidate && !self.items.iter().any(|q| !q.candidate) {
                // The incoming frame is the oldest non-candidate there is.
                drops.not_keyframe += 1;
                self.dropped_tail += 1;
                return;
            }
            let oldest = match self.items.iter().position(|q| !q.candidate) {
                Some(i) => {
                    drops.not_keyframe += 1;
                    i
                }
                None => {
                    drops.superseded += 1;
                    0
                }
            };
            self.remove(oldest);
        }
        self.bytes += bytes;
        self.items.push_back(Queued {
            frame,
            bytes,
            submitted: Instant::now(),
            candidate,
            dropped_before: std::mem::take(&mut self.dropped_tail),
        });
    }

    /// Takes the frame at `i` out, handing its count of dropped frames,
    /// and itself, to the next one.
    fn remove(&mut self, i: usize) {
        let gone = self.items.remove(i).expect("in range");
        self.bytes -= gone.bytes;
        let carried = gone.dropped_before + 1;
        match self.items.get_mut(i) {
            Some(next) => next.dropped_before += carried,
            None => self.dropped_tail += carried,
        }
    }

    /// The oldest frame, for the worker.
    pub fn pop(&mut self) -> Option<Queued> {
        let q = self.items.pop_front()?;
        self.bytes -= q.bytes;
        Some(q)
    }

    /// Empties the queue; returns how many frames were in it.
    pub fn clear(&mut self) -> u64 {
        let n = self.items.len() as u64;
        self.items.clear();
        self.bytes = 0;
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam_io::{ColorImage, DepthImage, Intrinsics, PixelFormat};

    fn frame(stamp_ns: i64, x: f64) -> Frame {
        Frame {
            stamp_ns,
            pose: CameraPose {
                rotation: glam::DQuat::IDENTITY,
                translation: glam::DVec3::new(x, 0.0, 0.0),
            },
            intrinsics: Intrinsics {
                width: 2,
                height: 2,
                fx: 1.0,
                fy: 1.0,
                cx: 1.0,
                cy: 1.0,
            },
            color: ColorImage {
                width: 2,
                height: 2,
                format: PixelFormat::Rgb8,
                data: vec![0; 12],
            },
            depth: DepthImage {
                width: 2,
                height: 2,
                data: DepthData::Metres(vec![1.0; 4]),
            },
            embeddings: None,
            semantic: None,
        }
    }

    fn stamps(q: &FrameQueue) -> Vec<(i64, bool, u32)> {
        q.items
            .iter()
            .map(|q| (q.frame.stamp_ns, q.candidate, q.dropped_before))
            .collect()
    }

    #[test]
    fn a_full_queue_drops_non_candidates_first_then_the_oldest_candidate() {
        let rule = KeyframeConfig {
            policy: KeyframePolicy::Interval(2),
            ..Default::default()
        };
        let mut q = FrameQueue::new(3, u64::MAX, 3, rule);
        let mut drops = DropCounts::default();
        // 0 is a candidate (the first frame), then every second one.
        for s in 0..3 {
            q.admit(frame(s, 0.0), &mut drops);
        }
        assert_eq!(stamps(&q), [(0, true, 0), (1, false, 0), (2, true, 0)]);
        // 3 is no candidate and the queue is full: 1 goes (the oldest
        // non-candidate), and 2 carries its count.
        q.admit(frame(3, 0.0), &mut drops);
        assert_eq!(stamps(&q), [(0, true, 0), (2, true, 1), (3, false, 0)]);
        // 4 is a candidate: 3 goes, counted by the newcomer.
        q.admit(frame(4, 0.0), &mut drops);
        assert_eq!(stamps(&q), [(0, true, 0), (2, true, 1), (4, true, 1)]);
        assert_eq!(drops.not_keyframe, 2);
        // 5 is no candidate and every queued frame is: 5 itself goes.
        q.admit(frame(5, 0.0), &mut drops);
        assert_eq!(drops.not_keyframe, 3);
        assert_eq!(stamps(&q), [(0, true, 0), (2, true, 1), (4, true, 1)]);
        // 6 is a candidate: the oldest candidate (0) goes for it.
        q.admit(frame(6, 0.0), &mut drops);
        assert_eq!(drops.superseded, 1);
        assert_eq!(stamps(&q), [(2, true, 2), (4, true, 1), (6, true, 1)]);
        // The worker sees every frame of the stream counted once.
        let seen: u32 = q.items.iter().map(|i| i.dropped_before + 1).sum();
        assert_eq!(seen + q.dropped_tail, 7);
        assert_eq!(q.pop().unwrap().frame.stamp_ns, 2);
        assert_eq!(q.len(), 2);
    }

    #[test]
    fn the_byte_bound_holds_but_one_frame_always_fits() {
        let mut q = FrameQueue::new(100, 100, 100, KeyframeConfig::default());
        let mut drops = DropCounts::default();
        let f = frame(0, 0.0);
        let size = frame_bytes(&f);
        assert_eq!(size, 12 + 16);
        for s in 0..10 {
            q.admit(frame(s, 0.0), &mut drops);
            assert!(q.bytes() <= 100.max(size));
        }
        assert_eq!(q.len(), 3);
        assert_eq!(drops.total(), 7);
        let mut tiny = FrameQueue::new(100, 1, 1, KeyframeConfig::default());
        tiny.admit(frame(0, 0.0), &mut drops);
        assert_eq!(tiny.len(), 1);
    }

    #[test]
    fn a_newer_candidate_replaces_the_oldest_beyond_the_limit() {
        let rule = KeyframeConfig {
            policy: KeyframePolicy::Interval(2),
            ..Default::default()
        };
        let mut q = FrameQueue::new(10, u64::MAX, 1, rule);
        let mut drops = DropCounts::default();
        for s in 0..5 {
            q.admit(frame(s, 0.0), &mut drops);
        }
        // Candidates 0, 2, 4: only the newest waits, with the frames after
        // the one it replaced.
        assert_eq!(stamps(&q), [(1, false, 1), (3, false, 1), (4, true, 0)]);
        assert_eq!(drops.superseded, 2);
        assert_eq!(drops.not_keyframe, 0);
    }

    #[test]
    fn frames_that_did_not_move_are_no_candidates() {
        let rule = KeyframeConfig {
            policy: KeyframePolicy::Interval(1),
            min_translation: 0.5,
            min_rotation_deg: 90.0,
        };
        let mut q = FrameQueue::new(10, u64::MAX, 10, rule);
        let mut drops = DropCounts::default();
        for (s, x) in [(0, 0.0), (1, 0.1), (2, 0.6), (3, 0.7), (4, 1.2)] {
            q.admit(frame(s, x), &mut drops);
        }
        let candidates: Vec<bool> = q.items.iter().map(|i| i.candidate).collect();
        assert_eq!(candidates, [true, false, true, false, true]);
    }
}
