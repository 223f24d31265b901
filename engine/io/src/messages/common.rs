//! The parts messages share: stamps, headers and rigid transforms.

use glam::{DQuat, DVec3};

use crate::cdr::{CdrError, CdrReader, CdrWriter};

/// `builtin_interfaces/Time`.
///
/// ```
/// use latentam_io::Time;
///
/// let t = Time::from_nanos(1_500_000_000);
/// assert_eq!((t.sec, t.nanosec), (1, 500_000_000));
/// assert_eq!(t.as_nanos(), 1_500_000_000);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
pub struct Time {
    /// Seconds (may be negative in principle).
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// Nanoseconds since the epoch: within ±2.2·10¹⁸ (an `i32` of seconds),
    /// so this and differences of two stamps cannot overflow an `i64`.
    pub fn as_nanos(self) -> i64 {
        self.sec as i64 * 1_000_000_000 + self.nanosec as i64
    }
    /// The time `ns` nanoseconds after the epoch (saturating at the `i32`
    /// seconds range).
    pub fn from_nanos(ns: i64) -> Self {
        let sec = ns.div_euclid(1_000_000_000);
        Time {
            sec: sec.clamp(i32::MIN as i64, i32::MAX as i64) as i32,
            nanosec: ns.rem_euclid(1_000_000_000) as u32,
        }
    }
}

/// `std_msgs/Header`.
///
/// ```
/// use latentam_io::Header;
///
/// let header = Header::at(1_700_000_000_123_000_000, "camera_color_optical_frame");
/// assert_eq!(header.stamp.nanosec, 123_000_000);
/// assert_eq!(header.stamp.as_nanos(), 1_700_000_000_123_000_000);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Header<'a> {
    /// Acquisition time.
    pub stamp: Time,
    /// Coordinate frame of the data.
    pub frame_id: &'a str,
}

impl<'a> Header<'a> {
    /// A header at `ns` nanoseconds in frame `frame_id`.
    pub fn at(ns: i64, frame_id: &'a str) -> Self {
        Header {
            stamp: Time::from_nanos(ns),
            frame_id,
        }
    }
    pub(super) fn decode(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        let sec = r.read("header.stamp.sec")?;
        let nanosec: u32 = r.read("header.stamp.nanosec")?;
        if nanosec >= 1_000_000_000 {
            return Err(r.invalid(
                "header.stamp.nanosec",
                format!("{nanosec} is not below 10^9"),
            ));
        }
        Ok(Header {
            stamp: Time { sec, nanosec },
            frame_id: r.string("header.frame_id")?,
        })
    }
    pub(super) fn encode(&self, w: &mut CdrWriter) {
        w.put(self.stamp.sec);
        w.put(self.stamp.nanosec);
        w.string(self.frame_id);
    }
}

/// A rigid transform (rotation then translation), in double precision:
/// `geometry_msgs/Pose` and `geometry_msgs/Transform` alike.
///
/// ```
/// use glam::DVec3;
/// use latentam_io::Pose;
///
/// let base_in_map = Pose { translation: DVec3::new(2.0, 0.0, 0.0), ..Pose::IDENTITY };
/// let camera_in_base = Pose { translation: DVec3::new(0.0, 0.0, 0.3), ..Pose::IDENTITY };
/// let camera_in_map = base_in_map.compose(&camera_in_base).checked()?; // finite, unit quaternion
/// assert_eq!(camera_in_map.translation, DVec3::new(2.0, 0.0, 0.3));
/// # Ok::<(), latentam_io::Rejection>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Position / translation.
    pub translation: DVec3,
    /// Orientation / rotation, as read (not normalised).
    pub rotation: DQuat,
}

impl Pose {
    /// The identity.
    pub const IDENTITY: Pose = Pose {
        translation: DVec3::ZERO,
        rotation: DQuat::IDENTITY,
    };

    pub(super) fn decode(r: &mut CdrReader<'_>, field: &'static str) -> Result<Self, CdrError> {
        let [x, y, z] = r.fixed::<f64, 3>(field)?;
        let [qx, qy, qz, qw] = r.fixed::<f64, 4>(field)?;
        Ok(Pose {
            translation: DVec3::new(x, y, z),
            rotation: DQuat::from_xyzw(qx, qy, qz, qw),
        })
    }
    pub(super) fn encode(&self, w: &mut CdrWriter) {
        w.array(&self.translation.to_array());
        let q = self.rotation;
        w.array(&[q.x, q.y, q.z, q.w]);
    }
}
