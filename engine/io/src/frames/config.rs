//! How a log's messages become frames: the topics, where poses come
//! from, the pairing tolerance and what to do with a bad part.

use super::*;

/// Where camera poses come from.
///
/// ```
/// use latentam_io::{AssemblyConfig, PoseSource};
///
/// let mut config = AssemblyConfig::default();
/// // Camera poses from the TF tree of a robot localised in `map`.
/// config.topics.pose = PoseSource::Tf { world_frame: "map".into(), camera_frame: None };
/// ```
#[derive(Clone, Debug, PartialEq)]
pub enum PoseSource {
    /// `geometry_msgs/PoseStamped` or `nav_msgs/Odometry` messages giving
    /// the camera optical frame in the world (camera-to-world).
    Topic(String),
    /// `/tf` + `/tf_static`, chained from `world_frame` to the camera
    /// frame (the colour image's `header.frame_id` unless given).
    Tf {
        /// The fixed frame poses are expressed in, e.g. `map` or `odom`.
        world_frame: String,
        /// The camera optical frame; `None` = the colour image's frame.
        camera_frame: Option<String>,
    },
}

/// Topic names (the defaults of docs/input-logs.md).
///
/// ```
/// use latentam_io::{AssemblyConfig, Topics};
///
/// // A RealSense driver's topic names.
/// let topics = Topics {
///     color: "/camera/camera/color/image_raw".into(),
///     depth: "/camera/camera/aligned_depth_to_color/image_raw".into(),
///     camera_info: "/camera/camera/color/camera_info".into(),
///     ..Topics::default()
/// };
/// let config = AssemblyConfig { topics, ..AssemblyConfig::default() };
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Topics {
    /// Colour images.
    pub color: String,
    /// Depth images registered to the colour images.
    pub depth: String,
    /// Colour camera calibration (ignored when intrinsics are given in
    /// [`AssemblyConfig::intrinsics`]).
    pub camera_info: String,
    /// The depth camera's own calibration, used when the depth images are
    /// stamped in another optical frame than the colour images (a raw
    /// depth stream): with the `/tf_static` transform between the two
    /// frames, each depth image is re-projected into the colour camera
    /// ([`crate::DepthRegistration`]). Empty: never.
    pub depth_camera_info: String,
    /// Camera poses.
    pub pose: PoseSource,
    /// Region embeddings (`MaskFeatures` or `FeatureGrid`); used when the
    /// log has the topic.
    pub embeddings: String,
    /// Semantic class-id images for evaluation; used when present.
    pub semantic: String,
    /// The query vocabulary; used when present.
    pub vocabulary: String,
}

impl Default for Topics {
    fn default() -> Self {
        Topics {
            color: "/camera/color/image_raw".into(),
            depth: "/camera/depth/image_raw".into(),
            camera_info: "/camera/color/camera_info".into(),
            depth_camera_info: "/camera/depth/camera_info".into(),
            pose: PoseSource::Topic("/camera/pose".into()),
            embeddings: "/camera/embeddings".into(),
            semantic: "/camera/semantic".into(),
            vocabulary: "/vocabulary".into(),
        }
    }
}

/// What to do with a frame or message that is malformed or inconsistent.
///
/// ```no_run
/// use latentam_io::{AssemblyConfig, BadInputPolicy, McapFrames};
///
/// // Check a recording: stop at the first bad message instead of skipping it.
/// let config = AssemblyConfig { on_bad_input: BadInputPolicy::Stop, ..AssemblyConfig::default() };
/// for frame in McapFrames::open("run.mcap".as_ref(), config)? {
///     frame?;
/// }
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BadInputPolicy {
    /// Skip it, count it in the [`IngestReport`] and go on.
    #[default]
    Skip,
    /// Stop with an error naming the message.
    Stop,
}

/// How frames are assembled.
///
/// ```no_run
/// use latentam_io::{AssemblyConfig, Intrinsics, McapFrames};
///
/// let config = AssemblyConfig {
///     tolerance_ns: 5_000_000,       // pair depth within 5 ms
///     depth_metres_per_unit: 0.0001, // a sensor in 0.1 mm units
///     intrinsics: Some(Intrinsics { width: 640, height: 480, fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 }),
///     ..AssemblyConfig::default()
/// };
/// let frames = McapFrames::open("run.mcap".as_ref(), config)?;
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct AssemblyConfig {
    /// Topic names.
    pub topics: Topics,
    /// Largest stamp difference between a colour image and the depth or
    /// embeddings paired with it, nanoseconds (default 20 ms).
    pub tolerance_ns: i64,
    /// Largest gap between the two poses a frame's pose is interpolated
    /// from, nanoseconds (default 200 ms).
    pub max_pose_gap_ns: i64,
    /// Metres per unit of integer depth (default 0.001: millimetres).
    pub depth_metres_per_unit: f32,
    /// Intrinsics to use instead of the camera-info topic.
    pub intrinsics: Option<Intrinsics>,
    /// Bad frames: skip and count, or stop.
    pub on_bad_input: BadInputPolicy,
    /// Messages held per stream while waiting for partners; beyond it the
    /// oldest is resolved as if its partners had ended (bounds memory when
    /// a stream stalls).
    pub max_pending: usize,
    /// Depth samples beyond this many metres are invalid (default 1000: no
    /// RGB-D sensor measures that far, so such values are corrupt or
    /// mis-scaled); a frame with no valid sample is refused.
    pub max_depth_m: f32,
    /// Camera positions farther than this from the world origin along any
    /// axis refuse their frame (default 10 km: beyond it, f32 map
    /// coordinates lose centimetre precision).
    pub max_extent_m: f64,
    /// Streams whose topic may be chosen from the log by message type when
    /// the configured one is absent (none by default; see
    /// [`plan_topics`](crate::plan_topics)).
    pub choose: TopicChoice,
}

impl Default for AssemblyConfig {
    fn default() -> Self {
        AssemblyConfig {
            topics: Topics::default(),
            tolerance_ns: 20_000_000,
            max_pose_gap_ns: 200_000_000,
            depth_metres_per_unit: 0.001,
            intrinsics: None,
            on_bad_input: BadInputPolicy::Skip,
            max_pending: 64,
            max_depth_m: 1000.0,
            max_extent_m: 10_000.0,
            choose: TopicChoice::default(),
        }
    }
}

/// The streams that may be chosen from the log when their configured topic
/// is absent (the command line allows it for every topic flag not given).
///
/// ```no_run
/// use latentam_io::{plan_topics, AssemblyConfig, McapLog, TopicChoice};
///
/// // Map a robot's bag without naming its topics.
/// let log = McapLog::open("robot_bag/".as_ref())?;
/// let config = AssemblyConfig { choose: TopicChoice::all(), ..AssemblyConfig::default() };
/// let (topics, plan) = plan_topics(&log.channels(), &config)?;
/// println!("colour images from {}", topics.color);
/// plan.iter().for_each(|line| println!("{line}"));
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TopicChoice {
    /// Colour images.
    pub color: bool,
    /// Depth images.
    pub depth: bool,
    /// Camera info.
    pub camera_info: bool,
    /// The depth camera's calibration (beside the depth images).
    pub depth_camera_info: bool,
    /// Poses: a `PoseStamped`/`Odometry` topic, else the TF tree from its
    /// root to the colour image's frame.
    pub pose: bool,
    /// Region embeddings.
    pub embeddings: bool,
    /// The query vocabulary.
    pub vocabulary: bool,
}

impl TopicChoice {
    /// Every stream may be chosen.
    pub fn all() -> Self {
        TopicChoice {
            color: true,
            depth: true,
            camera_info: true,
            depth_camera_info: true,
            pose: true,
            embeddings: true,
            vocabulary: true,
        }
    }
}
