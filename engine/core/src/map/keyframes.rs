//! Which frames become keyframes.

use glam::DVec3;

use super::global::GlobalMap;
use latentam_base::settings;
use latentam_base::settings::{join, KeyDoc, Kind, OutOfRange, Setting, MAX_DISTANCE};
use latentam_io::{CameraPose, Frame};

/// The rule that proposes keyframes.
///
/// ```
/// use latentam_core::map::KeyframePolicy;
///
/// // A tracker that hands over every frame: a keyframe whenever less than
/// // 80 % of the view (every 8th pixel) lies on mapped surface.
/// let mut config = latentam_core::mapper::MapperConfig::default();
/// config.keyframes.policy = KeyframePolicy::Overlap { min_overlap: 0.8, stride: 8 };
/// ```
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum KeyframePolicy {
    /// Every `n`-th frame (ORB-SLAM3-style trackers; the paper reports
    /// n ≈ 4 to 10).
    Interval(u32),
    /// When the share of the frame's back-projected depth points (every
    /// `stride`-th pixel) on mapped surface ([`GlobalMap::is_near_occupied`])
    /// drops below `min_overlap` (GS-ICP-style).
    Overlap {
        /// Keyframe when the overlap is below this (0..1).
        min_overlap: f32,
        /// Pixel subsampling of the check.
        stride: u32,
    },
}

settings! {
    /// Keyframe selection settings.
    ///
    /// ```
    /// use latentam_core::map::{KeyframeConfig, KeyframePolicy};
    ///
    /// // Every 5th frame, once the camera moved 10 cm or turned 10°.
    /// let policy = KeyframePolicy::Interval(5);
    /// let keyframes = KeyframeConfig { policy, min_translation: 0.1, min_rotation_deg: 10.0 };
    /// let config = latentam_core::mapper::MapperConfig { keyframes, ..Default::default() };
    /// ```
    #[derive(Copy)]
    pub struct KeyframeConfig {
        /// The rule that proposes keyframes; a proposal is then kept only
        /// if the camera moved enough (min_translation, min_rotation_deg).
        pub policy: KeyframePolicy = KeyframePolicy::Interval(4) => choice(),
        /// A proposed keyframe is dropped unless the camera moved at least
        /// this far (metres) or turned at least min_rotation_deg since the
        /// last keyframe; with both at 0 every proposal is kept.
        pub min_translation: f64 = 0.0 => value().range(0.0, MAX_DISTANCE).unit("metres"),
        /// See min_translation: the rotation (degrees) since the last
        /// keyframe that is enough on its own.
        pub min_rotation_deg: f64 = 0.0 => value().range(0.0, 360.0).unit("degrees"),
    }
}

impl KeyframeConfig {
    /// Whether the camera at `pose` moved far enough from `last` (the
    /// last keyframe's pose) for a proposal to be kept: `min_translation`
    /// metres or `min_rotation_deg` degrees, either one.
    ///
    /// ```
    /// use latentam_core::map::KeyframeConfig;
    /// use latentam_io::CameraPose;
    ///
    /// let config = KeyframeConfig { min_translation: 0.1, min_rotation_deg: 10.0, ..Default::default() };
    /// let at = |x| CameraPose { rotation: glam::DQuat::IDENTITY, translation: glam::DVec3::new(x, 0.0, 0.0) };
    /// assert!(!config.moved(&at(0.0), &at(0.05)));
    /// assert!(config.moved(&at(0.0), &at(0.2)));
    /// ```
    pub fn moved(&self, last: &CameraPose, pose: &CameraPose) -> bool {
        (pose.translation - last.translation).length() >= self.min_translation
            || pose.rotation.angle_between(last.rotation).to_degrees() >= self.min_rotation_deg
    }
}

/// Documented and checked by hand: the variants are the keys below it.
impl Setting for KeyframePolicy {
    fn nested_docs(prefix: &str, out: &mut Vec<KeyDoc>) {
        let mut doc = |key: &str, kind, text: &str| {
            out.push(KeyDoc {
                key: join(prefix, key),
                kind,
                text: text.into(),
            })
        };
        doc(
            "interval",
            Kind::Variant { payload: "4" },
            "Every N-th frame, N an integer >= 1 (for ORB-SLAM3-style \
             trackers; the paper reports N from 4 to 10).",
        );
        doc(
            "overlap",
            Kind::Variant {
                payload: "{ min_overlap = 0.9, stride = 8 }",
            },
            "When the share of the frame's back-projected depth points that \
             lie on already mapped surface drops below min_overlap \
             (GS-ICP-style). The values shown are a starting point, not \
             defaults.",
        );
        doc(
            "overlap.min_overlap",
            Kind::VariantField,
            "a keyframe when the overlap is below this; range 0 to 1.",
        );
        doc(
            "overlap.stride",
            Kind::VariantField,
            "the check uses every stride-th pixel along rows and columns; \
             integer >= 1.",
        );
    }

    fn check_nested(&self, prefix: &str) -> Result<(), OutOfRange> {
        match *self {
            KeyframePolicy::Interval(0) => Err(OutOfRange {
                key: join(prefix, "interval"),
                reason: "0 must be at least 1".into(),
            }),
            KeyframePolicy::Overlap {
                min_overlap,
                stride,
            } if !(0.0..=1.0).contains(&min_overlap) || stride == 0 => Err(OutOfRange {
                key: join(prefix, "overlap"),
                reason: format!(
                    "min_overlap {min_overlap} must be within 0..1 and stride {stride} at least 1"
                ),
            }),
            _ => Ok(()),
        }
    }
}

/// The decision for one frame, with what it was based on.
///
/// ```
/// # fn f(selector: &mut latentam_core::map::KeyframeSelector, frame: &latentam_io::Frame, map: &latentam_core::map::GlobalMap) {
/// let decision = selector.decide(frame, map);
/// if let (false, Some(o)) = (decision.keyframe, decision.overlap) {
///     println!("skipped: {:.0} % of the view is already mapped", 100.0 * o);
/// }
/// # }
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeyframeDecision {
    /// Whether the frame is a keyframe.
    pub keyframe: bool,
    /// Overlap with the map, when the policy measured it.
    pub overlap: Option<f32>,
}

/// Decides frame by frame.
///
/// ```
/// use latentam_core::map::{GlobalMap, KeyframeConfig, KeyframeSelector};
/// # fn f(frames: &[latentam_io::Frame], map: &GlobalMap) {
/// let mut selector = KeyframeSelector::new(KeyframeConfig::default()); // every 4th frame
/// for frame in frames {
///     if selector.decide(frame, map).keyframe {
///         println!("keyframe at {} ns", frame.stamp_ns);
///     }
/// }
/// # }
/// ```
#[derive(Clone, Debug)]
pub struct KeyframeSelector {
    config: KeyframeConfig,
    last: Option<CameraPose>,
    since_last: u32,
}

/// Share of `frame`'s subsampled valid depth points on mapped surface
/// ([`GlobalMap::is_near_occupied`]); 1 for a frame without valid depth.
pub fn overlap(frame: &Frame, map: &GlobalMap, stride: u32) -> f32 {
    let k = frame.intrinsics;
    let (w, h) = (frame.color.width, frame.color.height);
    let stride = stride.max(1) as usize;
    let (mut hits, mut total) = (0u32, 0u32);
    for v in (0..h).step_by(stride) {
        for u in (0..w).step_by(stride) {
            let Some(z) = frame.depth.metres((v * w + u) as usize) else {
                continue;
            };
            let z = z as f64;
            let cam = DVec3::new(
                (u as f64 - k.cx) / k.fx * z,
                (v as f64 - k.cy) / k.fy * z,
                z,
            );
            let p = frame.pose.rotation * cam + frame.pose.translation;
            total += 1;
            hits += map.is_near_occupied(p) as u32;
        }
    }
    if total == 0 {
        1.0
    } else {
        hits as f32 / total as f32
    }
}

impl KeyframeSelector {
    /// A selector with no keyframe yet (the first frame always is one).
    pub fn new(config: KeyframeConfig) -> Self {
        KeyframeSelector {
            config,
            last: None,
            since_last: 0,
        }
    }

    /// Decides whether `frame` is a keyframe given the current map, and
    /// remembers it if so.
    pub fn decide(&mut self, frame: &Frame, map: &GlobalMap) -> KeyframeDecision {
        self.since_last += 1;
        let Some(last) = self.last else {
            self.accept(frame);
            return KeyframeDecision {
                keyframe: true,
                overlap: None,
            };
        };
        let (proposed, overlap) = match self.config.policy {
            KeyframePolicy::Interval(n) => (self.since_last >= n.max(1), None),
            KeyframePolicy::Overlap {
                min_overlap,
                stride,
            } => {
                let o = overlap(frame, map, stride);
                (o < min_overlap, Some(o))
            }
        };
        let keyframe = proposed && self.config.moved(&last, &frame.pose);
        if keyframe {
            self.accept(frame);
        }
        KeyframeDecision { keyframe, overlap }
    }

    /// The pose of the last keyframe and the frames offered since (what
    /// a saved map keeps).
    pub fn state(&self) -> (Option<CameraPose>, u32) {
        (self.last, self.since_last)
    }

    /// Counts `n` frames offered elsewhere that were not keyframes (a live
    /// handle's dropped frames), so an interval policy still proposes
    /// every N-th frame of the stream rather than of what reached it.
    pub fn count_unseen(&mut self, n: u32) {
        if self.last.is_some() {
            self.since_last = self.since_last.saturating_add(n);
        }
    }

    /// Restores [`KeyframeSelector::state`].
    pub fn restore(&mut self, last: Option<CameraPose>, since_last: u32) {
        self.last = last;
        self.since_last = since_last;
    }

    fn accept(&mut self, frame: &Frame) {
        self.last = Some(frame.pose);
        self.since_last = 0;
    }
}
