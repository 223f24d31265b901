//! A stream's messages waiting for their partners, sorted by stamp.

use std::collections::VecDeque;

/// A message's content with its stamp.
pub(super) struct Stamped<T> {
    pub(super) stamp: i64,
    pub(super) value: T,
}

/// A stream's pending messages, sorted by stamp, and the latest stamp seen.
pub(super) struct Queue<T> {
    pub(super) items: VecDeque<Stamped<T>>,
    pub(super) watermark: Option<i64>,
    /// A message came with a stamp before the watermark.
    pub(super) went_back: bool,
}

impl<T> Default for Queue<T> {
    fn default() -> Self {
        Queue {
            items: VecDeque::new(),
            watermark: None,
            went_back: false,
        }
    }
}

impl<T> Queue<T> {
    pub(super) fn push(&mut self, stamp: i64, value: T) {
        self.note(stamp);
        let i = self.items.partition_point(|s| s.stamp <= stamp);
        self.items.insert(i, Stamped { stamp, value });
    }

    /// Notes a message that was refused: the stream has moved on.
    pub(super) fn note(&mut self, stamp: i64) {
        self.went_back |= self.watermark.is_some_and(|w| stamp < w);
        self.watermark = Some(self.watermark.map_or(stamp, |w| w.max(stamp)));
    }

    /// Removes and returns the item nearest `t` within `tol`. (Stamps come
    /// from `Time::as_nanos`, within ±2.2·10¹⁸ ns, so their differences
    /// cannot overflow.)
    pub(super) fn take_nearest(&mut self, t: i64, tol: i64) -> Option<Stamped<T>> {
        let (i, _) = self
            .items
            .iter()
            .enumerate()
            .filter(|(_, s)| (s.stamp - t).abs() <= tol)
            .min_by_key(|(_, s)| (s.stamp - t).abs())?;
        self.items.remove(i)
    }

    /// Removes items no colour image at or after `t` can claim.
    pub(super) fn drain_older_than(&mut self, t: i64) -> usize {
        let n = self.items.partition_point(|s| s.stamp < t);
        self.items.drain(..n);
        n
    }
}
