//! Frame assembly: pairs colour, depth, intrinsics, pose and embeddings by
//! `header.stamp`, and checks each part, counting every message it cannot
//! use by reason.
//!
//! A colour image at stamp `t` is resolved once every stream it needs has
//! moved past `t + tolerance` (or ended): then the nearest depth and
//! embeddings within the tolerance are taken, the pose is interpolated at
//! `t`, and the intrinsics are the latest camera info. Messages that no
//! colour image claims are counted as unpaired; frames with a bad part are
//! skipped and counted, or stop the run, as [`BadInputPolicy`] says.

use std::collections::VecDeque;

use super::codec;
use super::frame::{ColorImage, DepthImage, Embeddings, Frame, Intrinsics, LabelImage};
use super::log::RawMessage;
use super::messages::{
    CameraInfo, CompressedImage, FeatureGrid, Image, MaskFeatures, Odometry, PoseStamped,
    RosMessage, TextEmbeddings, TfMessage,
};
use super::parts::{
    check_intrinsics, drop_bad_regions, grid_embeddings, intrinsics_of, mask_embeddings,
};
use super::pool::BufferPool;
use super::registration::DepthRegistration;
use super::report::IngestReport;
use super::schema::normalize_type_name;
use super::tf::{PoseTrack, TfBuffer};
use super::vocabulary::{vocabulary_of, Vocabulary};
use super::{CameraPose, InputError};
use latentam_base::Rejection;

mod config;
mod decode;
mod pairing;
mod queue;

pub use config::{AssemblyConfig, BadInputPolicy, PoseSource, TopicChoice, Topics};
use queue::Queue;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Role {
    Color,
    Depth,
    CameraInfo,
    DepthCameraInfo,
    Pose,
    Tf,
    TfStatic,
    Embeddings,
    Semantic,
    Vocabulary,
}

impl Role {
    pub(super) fn accepted_types(self) -> &'static [&'static str] {
        match self {
            Role::Color | Role::Depth => &[Image::TYPE_NAME, CompressedImage::TYPE_NAME],
            Role::CameraInfo | Role::DepthCameraInfo => &[CameraInfo::TYPE_NAME],
            Role::Pose => &[PoseStamped::TYPE_NAME, Odometry::TYPE_NAME],
            Role::Tf | Role::TfStatic => &[TfMessage::TYPE_NAME],
            Role::Embeddings => &[MaskFeatures::TYPE_NAME, FeatureGrid::TYPE_NAME],
            Role::Semantic => &[Image::TYPE_NAME],
            Role::Vocabulary => &[TextEmbeddings::TYPE_NAME],
        }
    }
    pub(super) fn stream(self) -> &'static str {
        match self {
            Role::Color => "colour",
            Role::Depth => "depth",
            Role::CameraInfo => "camera info",
            Role::DepthCameraInfo => "depth camera info",
            Role::Pose => "pose",
            Role::Tf | Role::TfStatic => "tf",
            Role::Embeddings => "embeddings",
            Role::Semantic => "semantic",
            Role::Vocabulary => "vocabulary",
        }
    }
}

/// A colour image waiting for its partners; compressed ones are decoded
/// only once the frame is complete.
enum PendingColor {
    Raw(Result<ColorImage, Rejection>),
    Compressed { format: String, data: Vec<u8> },
}

/// A colour image waiting for its partners, with the latest stamp each
/// partner stream has shown since it arrived: a stream whose stamps went
/// back in time can still deliver a partner after its watermark passed, so
/// only stamps seen after the colour image prove its partner is not coming.
struct PendingFrame {
    color: PendingColor,
    seen: SeenSince,
}

#[derive(Clone, Copy, Debug, Default)]
struct SeenSince {
    depth: Option<i64>,
    embeddings: Option<i64>,
    semantic: Option<i64>,
    pose: Option<i64>,
}

#[derive(Clone, Copy, Debug)]
enum Partner {
    Depth,
    Embeddings,
    Semantic,
    Pose,
}

/// Turns a stream of log messages into [`Frame`]s.
///
/// ```no_run
/// use latentam_io::{AssemblyConfig, Channel, FrameAssembler, RawMessage};
/// # use latentam_io::Frame;
/// # fn f(mut integrate: impl FnMut(&Frame) -> latentam_io::Result<()>, incoming: Vec<(Channel, u64, Vec<u8>)>) -> Result<(), Box<dyn std::error::Error>> {
/// // Messages as a live ROS 2 subscriber receives them: channel, receive time, CDR bytes.
/// let mut assembler = FrameAssembler::new(AssemblyConfig::default(), false, false);
/// for (channel, log_time, data) in &incoming {
///     assembler.push(RawMessage { channel, log_time: *log_time, data })?;
///     while let Some(frame) = assembler.pop() {
///         integrate(&frame)?; // `latentam::Mapper::integrate`
///     }
/// }
/// # Ok(())
/// # }
/// ```
pub struct FrameAssembler {
    pub(super) config: AssemblyConfig,
    color: Queue<PendingFrame>,
    depth: Queue<Result<DepthImage, Rejection>>,
    embeddings: Queue<Embeddings>,
    semantic: Queue<LabelImage>,
    /// The latest camera info (a bad one is kept so frames are rejected
    /// for the right reason).
    camera_info: Option<Result<Intrinsics, Rejection>>,
    poses: PoseTrack,
    tf: TfBuffer,
    /// A pose (or dynamic transform) came with a stamp before the latest.
    poses_went_back: bool,
    /// Stamp of the last colour image resolved.
    last_resolved: Option<i64>,
    /// Stamps of every colour image resolved (8 bytes a frame): a second
    /// image at a stamp already seen is a duplicate (overlapping bag files,
    /// a log recorded twice), not a new view.
    resolved_stamps: std::collections::HashSet<i64>,
    color_frame_id: Option<String>,
    /// The depth images' `header.frame_id`, to tell unregistered depth.
    depth_frame_id: Option<String>,
    /// The latest depth camera info (see [`Topics::depth_camera_info`]).
    depth_camera: Option<Result<Intrinsics, Rejection>>,
    /// The registration of depth to colour, once the depth camera info and
    /// the transform between the lenses were seen (both static).
    registration: Option<DepthRegistration>,
    has_embeddings: bool,
    has_semantic: bool,
    embedding_signature: Option<(u32, String)>,
    vocabulary: Option<Vocabulary>,
    ready: VecDeque<Frame>,
    report: IngestReport,
    ended: bool,
    pool: BufferPool,
}

impl FrameAssembler {
    /// An assembler for `config`; `has_embeddings` / `has_semantic` say
    /// whether the log carries those optional streams (frames wait for
    /// them only if so).
    pub fn new(config: AssemblyConfig, has_embeddings: bool, has_semantic: bool) -> Self {
        FrameAssembler {
            config,
            color: Queue::default(),
            depth: Queue::default(),
            embeddings: Queue::default(),
            semantic: Queue::default(),
            camera_info: None,
            poses: PoseTrack::default(),
            tf: TfBuffer::default(),
            poses_went_back: false,
            last_resolved: None,
            resolved_stamps: std::collections::HashSet::new(),
            color_frame_id: None,
            depth_frame_id: None,
            depth_camera: None,
            registration: None,
            has_embeddings,
            has_semantic,
            embedding_signature: None,
            vocabulary: None,
            ready: VecDeque::new(),
            report: IngestReport::default(),
            ended: false,
            pool: BufferPool::default(),
        }
    }

    /// The counts so far.
    pub fn report(&self) -> &IngestReport {
        &self.report
    }

    /// The latest vocabulary message, if the log has one.
    pub fn vocabulary(&self) -> Option<&Vocabulary> {
        self.vocabulary.as_ref()
    }

    /// The next complete frame.
    pub fn pop(&mut self) -> Option<Frame> {
        self.ready.pop_front()
    }

    /// Hands a frame that is no longer needed back, so its buffers are
    /// reused for the next frames instead of freshly allocated (which
    /// costs page faults; see `bench ingest`). Optional.
    pub fn recycle(&mut self, frame: Frame) {
        self.pool.recycle(frame);
    }

    pub(super) fn role(&self, topic: &str) -> Option<Role> {
        let t = &self.config.topics;
        if topic == t.color {
            Some(Role::Color)
        } else if topic == t.depth {
            Some(Role::Depth)
        } else if topic == t.camera_info && self.config.intrinsics.is_none() {
            Some(Role::CameraInfo)
        } else if topic == t.depth_camera_info && topic != t.camera_info {
            Some(Role::DepthCameraInfo)
        } else if matches!(&t.pose, PoseSource::Topic(p) if p == topic) {
            Some(Role::Pose)
        } else if matches!(t.pose, PoseSource::Tf { .. }) && topic == "/tf" {
            Some(Role::Tf)
        } else if topic == "/tf_static" {
            // Read with poses from a topic too: it places the depth lens.
            Some(Role::TfStatic)
        } else if topic == t.embeddings {
            Some(Role::Embeddings)
        } else if topic == t.semantic {
            Some(Role::Semantic)
        } else if topic == t.vocabulary {
            Some(Role::Vocabulary)
        } else {
            None
        }
    }

    /// The topics this configuration reads, for a [`ReadFilter`](crate::ReadFilter).
    pub fn topics(&self) -> Vec<String> {
        let t = &self.config.topics;
        let mut v = vec![t.color.clone(), t.depth.clone()];
        if self.config.intrinsics.is_none() {
            v.push(t.camera_info.clone());
        }
        if !t.depth_camera_info.is_empty() {
            v.push(t.depth_camera_info.clone());
        }
        match &t.pose {
            PoseSource::Topic(p) => v.push(p.clone()),
            PoseSource::Tf { .. } => v.push("/tf".to_string()),
        }
        v.push("/tf_static".to_string());
        v.extend([
            t.embeddings.clone(),
            t.semantic.clone(),
            t.vocabulary.clone(),
        ]);
        v
    }

    fn reject(&mut self, topic: &str, stamp: i64, r: Rejection) -> Result<(), InputError> {
        match self.config.on_bad_input {
            BadInputPolicy::Skip => {
                log::debug!("skipping {topic} at {stamp} ns: {r}");
                self.report.count(&r);
                Ok(())
            }
            BadInputPolicy::Stop => Err(InputError::Rejected {
                topic: topic.to_string(),
                stamp_ns: stamp,
                rejection: r,
            }),
        }
    }

    /// Takes one message. Errors only for undecodable messages under
    /// [`BadInputPolicy::Stop`] and for rejected frames under it.
    pub fn push(&mut self, msg: RawMessage<'_>) -> Result<(), InputError> {
        let Some(role) = self.role(&msg.channel.topic) else {
            return Ok(());
        };
        self.report.messages += 1;
        let topic = msg.channel.topic.as_str();
        let log_stamp = msg.log_time as i64;
        match self.decode(role, msg) {
            Ok(()) => {}
            Err(r) => self.reject(topic, log_stamp, r)?,
        }
        self.resolve(false)
    }

    /// Notes a partner message's stamp for every colour image waiting.
    fn saw(&mut self, partner: Partner, stamp: i64) {
        for pending in &mut self.color.items {
            let s = &mut pending.value.seen;
            let mark = match partner {
                Partner::Depth => &mut s.depth,
                Partner::Embeddings => &mut s.embeddings,
                Partner::Semantic => &mut s.semantic,
                Partner::Pose => &mut s.pose,
            };
            *mark = Some(mark.map_or(stamp, |m| m.max(stamp)));
        }
    }

    /// The image size the intrinsics state, when they state one.
    fn camera_size(&self) -> Option<(u32, u32)> {
        let k = match (&self.config.intrinsics, &self.camera_info) {
            (Some(k), _) | (None, Some(Ok(k))) => k,
            _ => return None,
        };
        (k.width > 0 && k.height > 0).then_some((k.width, k.height))
    }

    /// Whether the depth images are stamped in another optical frame than
    /// the colour images (a raw depth stream, not its registered twin).
    fn depth_in_another_frame(&self) -> Option<(&str, &str)> {
        let (Some(colour), Some(depth)) = (&self.color_frame_id, &self.depth_frame_id) else {
            return None;
        };
        (!colour.is_empty() && !depth.is_empty() && colour != depth)
            .then_some((colour.as_str(), depth.as_str()))
    }

    /// The registration of depth to colour when depth comes from another
    /// lens: built once from the depth camera info, the colour intrinsics
    /// and the static transform between the lenses. `None` when depth is
    /// in the colour frame, or, with a warning said once, when what the
    /// registration needs is missing: the mapper reads both images through
    /// one camera, so such depth puts every surface a few pixels off its
    /// colour (more at silhouettes); the map is still built.
    pub(super) fn registration(
        &mut self,
        t: i64,
        colour: &Intrinsics,
    ) -> Option<DepthRegistration> {
        let (colour_frame, depth_frame) = self
            .depth_in_another_frame()
            .map(|(c, d)| (c.to_string(), d.to_string()))?;
        if self.registration.is_some() {
            return self.registration;
        }
        let info = &self.config.topics.depth_camera_info;
        let lens = self.tf.lookup(&colour_frame, &depth_frame, t, 0);
        let missing = match (&self.depth_camera, lens) {
            (Some(Ok(d)), Ok(lens)) => {
                let reg = DepthRegistration {
                    depth: [d.fx, d.fy, d.cx, d.cy],
                    colour: [colour.fx, colour.fy, colour.cx, colour.cy],
                    rotation: lens.rotation,
                    translation: lens.translation,
                };
                self.report.note(format!(
                    "depth images in frame `{depth_frame}` registered to the colour camera \
                     (`{colour_frame}`) with {info} and /tf_static: depth lens f {:.1} c \
                     ({:.1}, {:.1}), {:.2} cm from the colour lens",
                    d.fx,
                    d.cx,
                    d.cy,
                    lens.translation.length() * 100.0
                ));
                self.registration = Some(reg);
                return self.registration;
            }
            (None, _) if info.is_empty() => "no depth camera info topic is set".to_string(),
            (None, _) => format!("the log has no camera info on {info}"),
            (Some(Err(r)), _) => format!("the depth camera info is unusable ({r})"),
            (Some(Ok(_)), Err(why)) => format!("/tf_static does not place it: {why}"),
        };
        let warning = format!(
            "depth images are in frame `{depth_frame}`, colour images in `{colour_frame}`, and \
             depth cannot be registered to colour ({missing}); record the driver's registered \
             stream (e.g. `aligned_depth_to_color` or `depth_registered`, named with \
             --depth-topic if the log has it) or the depth camera info and static transform; \
             mapping goes on as if they were one camera"
        );
        self.report.warn(warning);
        None
    }

    /// Declares the end of the log: every pending colour image is resolved
    /// with what arrived, and leftover messages are counted as unpaired.
    pub fn finish(&mut self) -> Result<(), InputError> {
        self.ended = true;
        self.resolve(true)?;
        for (kind, n) in [
            ("depth: unpaired", self.depth.items.len()),
            ("embeddings: unpaired", self.embeddings.items.len()),
            ("semantic: unpaired", self.semantic.items.len()),
        ] {
            for _ in 0..n {
                self.report.count(&Rejection::new(
                    kind,
                    "no colour image within the tolerance",
                ));
            }
        }
        self.depth.items.clear();
        self.embeddings.items.clear();
        self.semantic.items.clear();
        Ok(())
    }
}
