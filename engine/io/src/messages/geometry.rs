//! Poses: `geometry_msgs/PoseStamped`, `nav_msgs/Odometry` and the TF tree.

use super::common::{Header, Pose};
use super::message::RosMessage;
use crate::cdr::{CdrError, CdrReader, CdrWriter};

/// `geometry_msgs/PoseStamped`.
///
/// ```no_run
/// use latentam_io::{Header, LogWriter, PoseStamped};
/// # fn f(log: &mut LogWriter<std::io::BufWriter<std::fs::File>>, stamp_ns: i64, pose: latentam_io::CameraPose) -> Result<(), latentam_io::InputError> {
/// // Record the robot's camera pose beside its images.
/// let msg = PoseStamped { header: Header::at(stamp_ns, "map"), pose: pose.into() };
/// log.write("/camera/pose", stamp_ns as u64, &msg)?;
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug)]
pub struct PoseStamped<'a> {
    /// Stamp and the frame the pose is expressed in.
    pub header: Header<'a>,
    /// The pose.
    pub pose: Pose,
}

cdr_message! {
    PoseStamped = "geometry_msgs/msg/PoseStamped" {
        header: header,
        pose: pose,
    }
}

/// `nav_msgs/Odometry` (the twist is read past, not kept).
///
/// ```
/// use latentam_io::{Header, Odometry, Pose, RosMessage};
///
/// let header = Header::at(1_000, "odom");
/// let odom = Odometry { header, child_frame_id: "camera_optical", pose: Pose::IDENTITY };
/// let bytes = odom.encode(); // the twist is written as zeros
/// let back = Odometry::decode(&bytes)?;
/// assert_eq!((back.header.frame_id, back.child_frame_id), ("odom", "camera_optical"));
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Odometry<'a> {
    /// Stamp and the parent frame.
    pub header: Header<'a>,
    /// The frame whose pose this is.
    pub child_frame_id: &'a str,
    /// Pose of `child_frame_id` in `header.frame_id`.
    pub pose: Pose,
}

cdr_message! {
    Odometry = "nav_msgs/msg/Odometry" {
        header: header,
        child_frame_id: string,
        pose: pose as "pose.pose",
        skip [f64; 36] as "pose.covariance",
        skip [f64; 6 + 36] as "twist",
    }
}

/// `geometry_msgs/TransformStamped`.
///
/// ```
/// use glam::DVec3;
/// use latentam_io::{Header, Pose, TfBuffer, TransformStamped};
///
/// // The camera mounted 30 cm above the robot's base (a `/tf_static` entry).
/// let mount = TransformStamped {
///     header: Header::at(0, "base_link"),
///     child_frame_id: "camera_color_optical_frame",
///     transform: Pose { translation: DVec3::new(0.0, 0.0, 0.3), ..Pose::IDENTITY },
/// };
/// TfBuffer::default().insert(&mount, true)?;
/// # Ok::<(), latentam_io::Rejection>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct TransformStamped<'a> {
    /// Stamp and the parent frame.
    pub header: Header<'a>,
    /// The child frame.
    pub child_frame_id: &'a str,
    /// Pose of the child in the parent.
    pub transform: Pose,
}

/// `tf2_msgs/TFMessage` (on `/tf` and `/tf_static`).
///
/// ```
/// use latentam_io::{Header, Pose, RosMessage, TfBuffer, TfMessage, TransformStamped};
///
/// # let t = TransformStamped { header: Header::at(5, "odom"), child_frame_id: "base_link", transform: Pose::IDENTITY };
/// # let bytes = TfMessage { transforms: vec![t] }.encode();
/// let mut tf = TfBuffer::default();
/// for t in &TfMessage::decode(&bytes)?.transforms { // one `/tf` message
///     tf.insert(t, false)?;
/// }
/// assert_eq!(tf.latest(), Some(5));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug)]
pub struct TfMessage<'a> {
    /// The transforms.
    pub transforms: Vec<TransformStamped<'a>>,
}

cdr_message! {
    TfMessage = "tf2_msgs/msg/TFMessage" {
        transforms: transforms,
    }
}

impl<'a> TransformStamped<'a> {
    /// A `TransformStamped[]` sequence.
    pub(super) fn decode_all(r: &mut CdrReader<'a>) -> Result<Vec<Self>, CdrError> {
        // header (≥ 12 bytes) + child string (≥ 4) + 7 doubles.
        let count = r.sequence_len("transforms", 12 + 4 + 56)?;
        let mut transforms = Vec::with_capacity(count);
        for _ in 0..count {
            transforms.push(TransformStamped {
                header: Header::decode(r)?,
                child_frame_id: r.string("transforms.child_frame_id")?,
                transform: Pose::decode(r, "transforms.transform")?,
            });
        }
        Ok(transforms)
    }

    pub(super) fn encode_all(transforms: &[Self], w: &mut CdrWriter) {
        w.put(transforms.len() as u32);
        for t in transforms {
            t.header.encode(w);
            w.string(t.child_frame_id);
            t.transform.encode(w);
        }
    }
}
