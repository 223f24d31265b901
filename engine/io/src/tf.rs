//! Poses over time: checked rigid transforms, interpolation, and a TF tree
//! (`/tf` + `/tf_static`) that chains transforms to the camera frame.

use std::collections::HashMap;

use glam::DQuat;

use super::messages::{Pose, TransformStamped};
use latentam_base::Rejection;

/// How far a quaternion's norm may be from 1 before it is rejected rather
/// than re-normalised (logs written in single precision drift by ~1e-7;
/// anything near this bound is a bug upstream).
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-2;

impl Pose {
    /// `self ∘ other`: the pose of `other`'s child in `self`'s parent.
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose {
            translation: self.translation + self.rotation * other.translation,
            rotation: (self.rotation * other.rotation).normalize(),
        }
    }
    /// The inverse transform.
    pub fn inverse(&self) -> Pose {
        let r = self.rotation.conjugate();
        Pose {
            translation: -(r * self.translation),
            rotation: r,
        }
    }
    /// Linear interpolation of the translation and spherical interpolation
    /// of the rotation, `s` ∈ [0, 1].
    pub fn interpolate(&self, other: &Pose, s: f64) -> Pose {
        Pose {
            translation: self.translation.lerp(other.translation, s),
            rotation: self.rotation.slerp(other.rotation, s).normalize(),
        }
    }
    /// The pose with a unit quaternion, or a rejection if it has a
    /// non-finite value or a quaternion too far from unit length to be a
    /// rounding error.
    pub fn checked(&self) -> Result<Pose, Rejection> {
        let q = self.rotation;
        if !self.translation.is_finite() || !q.is_finite() {
            return Err(Rejection::new(
                "pose: not finite",
                format!("translation {:?}, quaternion {:?}", self.translation, q),
            ));
        }
        let norm = q.length();
        if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
            return Err(Rejection::new(
                "pose: non-unit quaternion",
                format!("quaternion {q:?} has norm {norm:.4}"),
            ));
        }
        Ok(Pose {
            translation: self.translation,
            rotation: DQuat::from_vec4(q.into()) / norm,
        })
    }
}

/// Time-stamped poses of one thing, interpolated between samples.
///
/// ```
/// use glam::DVec3;
/// use latentam_io::{Pose, PoseTrack};
///
/// let mut track = PoseTrack::default();
/// track.insert(0, Pose::IDENTITY);
/// track.insert(100_000_000, Pose { translation: DVec3::X, ..Pose::IDENTITY });
/// // Halfway between two samples 100 ms apart (exact match only, gaps up to 200 ms).
/// let p = track.at(50_000_000, 0, 200_000_000).expect("interpolated");
/// assert!((p.translation.x - 0.5).abs() < 1e-9);
/// ```
#[derive(Clone, Debug, Default)]
pub struct PoseTrack {
    samples: Vec<(i64, Pose)>,
}

impl PoseTrack {
    /// Adds a checked sample (out-of-order stamps are placed in order; a
    /// repeated stamp replaces the earlier sample).
    pub fn insert(&mut self, stamp: i64, pose: Pose) {
        match self.samples.binary_search_by_key(&stamp, |s| s.0) {
            Ok(i) => self.samples[i].1 = pose,
            Err(i) => self.samples.insert(i, (stamp, pose)),
        }
    }
    /// Latest stamp held.
    pub fn latest(&self) -> Option<i64> {
        self.samples.last().map(|s| s.0)
    }
    /// Drops samples older than `stamp`, keeping the one just before it so
    /// `stamp` itself can still be interpolated.
    pub fn forget_before(&mut self, stamp: i64) {
        let i = self.samples.partition_point(|s| s.0 < stamp);
        if i > 1 {
            self.samples.drain(..i - 1);
        }
    }
    /// The pose at `stamp`: a sample within `tolerance` ns, else the
    /// interpolation between the samples around it when they are at most
    /// `max_gap` ns apart.
    ///
    /// Stamps are message header times (`Time::as_nanos`, within
    /// ±2.2·10¹⁸ ns), so the differences taken here cannot overflow.
    pub fn at(&self, stamp: i64, tolerance: i64, max_gap: i64) -> Result<Pose, String> {
        let i = self.samples.partition_point(|s| s.0 < stamp);
        let before = i.checked_sub(1).map(|j| self.samples[j]);
        let after = self.samples.get(i).copied();
        let near = [before, after]
            .into_iter()
            .flatten()
            .filter(|s| (s.0 - stamp).abs() <= tolerance)
            .min_by_key(|s| (s.0 - stamp).abs());
        if let (Some(a), Some(b)) = (before, after) {
            if b.0 - a.0 <= max_gap && b.0 > a.0 {
                let s = (stamp - a.0) as f64 / (b.0 - a.0) as f64;
                return Ok(a.1.interpolate(&b.1, s));
            }
        }
        if let Some(s) = near {
            return Ok(s.1);
        }
        Err(match (before, after) {
            (None, None) => "no pose received yet".to_string(),
            (Some(a), None) => format!(
                "latest pose is {:.3} s earlier",
                (stamp - a.0) as f64 * 1e-9
            ),
            (None, Some(b)) => format!("first pose is {:.3} s later", (b.0 - stamp) as f64 * 1e-9),
            (Some(a), Some(b)) => format!(
                "poses around it are {:.3} s apart (more than the {:.3} s allowed)",
                (b.0 - a.0) as f64 * 1e-9,
                max_gap as f64 * 1e-9
            ),
        })
    }
}

struct Edge {
    parent: String,
    fixed: Option<Pose>,
    track: PoseTrack,
}

/// A TF tree: for each child frame, its parent and the transform from
/// child to parent, static or over time.
///
/// ```
/// use glam::DVec3;
/// use latentam_io::{Header, Pose, TfBuffer, TransformStamped};
///
/// let mut tf = TfBuffer::default();
/// let mount = Pose { translation: DVec3::new(0.0, 0.0, 0.3), ..Pose::IDENTITY };
/// let edge = |parent, child, ns, transform| TransformStamped {
///     header: Header::at(ns, parent), child_frame_id: child, transform,
/// };
/// tf.insert(&edge("base_link", "camera", 0, mount), true)?; // `/tf_static`
/// tf.insert(&edge("map", "base_link", 1_000, Pose::IDENTITY), false)?; // `/tf`
/// let camera_in_map = tf.lookup("map", "camera", 1_000, 200_000_000)?;
/// assert!((camera_in_map.translation.z - 0.3).abs() < 1e-12);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Default)]
pub struct TfBuffer {
    edges: HashMap<String, Edge>,
    latest: Option<i64>,
}

fn strip(frame: &str) -> &str {
    frame.trim_start_matches('/')
}

impl TfBuffer {
    /// Adds one transform from `/tf` (`is_static = false`) or `/tf_static`.
    pub fn insert(&mut self, t: &TransformStamped<'_>, is_static: bool) -> Result<(), Rejection> {
        let pose = t.transform.checked()?;
        let child = strip(t.child_frame_id);
        let parent = strip(t.header.frame_id);
        if child.is_empty() || parent.is_empty() || child == parent {
            return Err(Rejection::new(
                "tf: bad frame ids",
                format!("transform from `{parent}` to `{child}`"),
            ));
        }
        let edge = self.edges.entry(child.to_string()).or_insert_with(|| Edge {
            parent: parent.to_string(),
            fixed: None,
            track: PoseTrack::default(),
        });
        if edge.parent != parent {
            return Err(Rejection::new(
                "tf: frame has two parents",
                format!(
                    "`{child}` is a child of `{}` and of `{parent}`",
                    edge.parent
                ),
            ));
        }
        if is_static {
            edge.fixed = Some(pose);
        } else {
            let stamp = t.header.stamp.as_nanos();
            edge.track.insert(stamp, pose);
            self.latest = Some(self.latest.map_or(stamp, |l| l.max(stamp)));
        }
        Ok(())
    }

    /// Latest stamp of any dynamic transform.
    pub fn latest(&self) -> Option<i64> {
        self.latest
    }

    /// Forgets dynamic samples older than `stamp` (keeping what
    /// interpolation at `stamp` needs), so memory stays bounded on long logs.
    pub fn forget_before(&mut self, stamp: i64) {
        for e in self.edges.values_mut() {
            e.track.forget_before(stamp);
        }
    }

    fn to_root(&self, frame: &str, stamp: i64, max_gap: i64) -> Result<(String, Pose), String> {
        let mut pose = Pose::IDENTITY;
        let mut cur = strip(frame).to_string();
        for _ in 0..=self.edges.len() {
            let Some(e) = self.edges.get(&cur) else {
                return Ok((cur, pose));
            };
            let step = match e.fixed {
                Some(p) => p,
                None => e
                    .track
                    .at(stamp, 0, max_gap)
                    .map_err(|why| format!("`{}` → `{cur}`: {why}", e.parent))?,
            };
            pose = step.compose(&pose);
            cur = e.parent.clone();
        }
        Err(format!("the TF tree has a cycle through `{frame}`"))
    }

    /// Pose of `frame` in `target` at `stamp` (dynamic edges interpolated
    /// between samples at most `max_gap` ns apart); an empty `target` is
    /// the root of the tree `frame` belongs to.
    pub fn lookup(
        &self,
        target: &str,
        frame: &str,
        stamp: i64,
        max_gap: i64,
    ) -> Result<Pose, String> {
        let (root_b, frame_in_root) = self.to_root(frame, stamp, max_gap)?;
        if target.is_empty() {
            if root_b == strip(frame) {
                return Err(format!("`{frame}` has no parent in the TF tree"));
            }
            return Ok(frame_in_root);
        }
        let (root_a, target_in_root) = self.to_root(target, stamp, max_gap)?;
        if root_a != root_b {
            return Err(format!(
                "`{frame}` and `{target}` are not connected in the TF tree (roots `{root_b}` and `{root_a}`)"
            ));
        }
        Ok(target_in_root.inverse().compose(&frame_in_root))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::Header;
    use glam::DVec3;

    fn tf<'a>(parent: &'a str, child: &'a str, ns: i64, p: Pose) -> TransformStamped<'a> {
        TransformStamped {
            header: Header::at(ns, parent),
            child_frame_id: child,
            transform: p,
        }
    }

    #[test]
    fn chains_static_and_dynamic_transforms_with_interpolation() {
        let mut tf_buf = TfBuffer::default();
        let optical = Pose {
            translation: DVec3::new(0.1, 0.0, 0.0),
            rotation: DQuat::from_rotation_y(0.5),
        };
        tf_buf
            .insert(&tf("base", "/camera_optical", 0, optical), true)
            .unwrap();
        let at = |x: f64, yaw: f64| Pose {
            translation: DVec3::new(x, 0.0, 0.0),
            rotation: DQuat::from_rotation_z(yaw),
        };
        tf_buf
            .insert(&tf("odom", "base", 1_000, at(0.0, 0.0)), false)
            .unwrap();
        tf_buf
            .insert(&tf("odom", "base", 3_000, at(2.0, 0.4)), false)
            .unwrap();
        let got = tf_buf
            .lookup("odom", "camera_optical", 2_000, 10_000)
            .unwrap();
        let want = at(1.0, 0.2).compose(&optical);
        assert!((got.translation - want.translation).length() < 1e-12);
        assert!(got.rotation.angle_between(want.rotation) < 1e-9);
        // Inverse direction.
        let back = tf_buf
            .lookup("camera_optical", "odom", 2_000, 10_000)
            .unwrap();
        assert!((back.compose(&got).translation).length() < 1e-12);
        // Outside the samples, too wide a gap, unknown or disconnected frames.
        assert!(tf_buf
            .lookup("odom", "camera_optical", 4_000, 10_000)
            .is_err());
        assert!(tf_buf
            .lookup("odom", "camera_optical", 2_000, 1_000)
            .is_err());
        assert!(tf_buf
            .lookup("map", "camera_optical", 2_000, 10_000)
            .is_err());
        // A second parent for a frame and a non-unit quaternion are rejected.
        assert!(tf_buf
            .insert(&tf("map", "base", 0, at(0.0, 0.0)), false)
            .is_err());
        let mut bad = at(0.0, 0.0);
        bad.rotation = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.5);
        assert_eq!(
            tf_buf
                .insert(&tf("odom", "base", 5_000, bad), false)
                .unwrap_err()
                .kind,
            "pose: non-unit quaternion"
        );
        bad.rotation = DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0);
        assert_eq!(bad.checked().unwrap_err().kind, "pose: not finite");
    }

    #[test]
    fn pose_track_prefers_interpolation_then_nearest() {
        let mut t = PoseTrack::default();
        let p = |x: f64| Pose {
            translation: DVec3::splat(x),
            rotation: DQuat::IDENTITY,
        };
        t.insert(100, p(1.0));
        t.insert(300, p(3.0));
        assert_eq!(t.at(200, 0, 1000).unwrap().translation.x, 2.0);
        assert_eq!(t.at(310, 20, 1000).unwrap().translation.x, 3.0);
        assert!(t.at(200, 50, 100).is_err());
        t.forget_before(300);
        assert_eq!(t.at(200, 0, 1000).unwrap().translation.x, 2.0);
        t.forget_before(1000);
        assert_eq!(t.latest(), Some(300));
    }
}
