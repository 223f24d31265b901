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
use std::path::Path;

use super::codec;
use super::frame::{
    ColorImage, DepthImage, Dtype, EmbeddingLayout, Embeddings, Frame, Intrinsics, LabelImage,
};
use super::log::{Channel, McapLog, MessageReader, RawMessage, ReadFilter};
use super::messages::{
    CameraInfo, CompressedImage, FeatureGrid, Image, MaskFeatures, Odometry, PoseStamped,
    RosMessage, TextEmbeddings, TfMessage,
};
use super::pool::BufferPool;
use super::report::{IngestReport, Rejection};
use super::schema::normalize_type_name;
use super::tf::{PoseTrack, TfBuffer};
use super::{CameraPose, InputError};

/// Where camera poses come from.
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

/// Topic names (DESIGN §3 defaults).
#[derive(Clone, Debug, PartialEq)]
pub struct Topics {
    /// Colour images.
    pub color: String,
    /// Depth images registered to the colour images.
    pub depth: String,
    /// Colour camera calibration (ignored when intrinsics are given in
    /// [`AssemblyConfig::intrinsics`]).
    pub camera_info: String,
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
            pose: PoseSource::Topic("/camera/pose".into()),
            embeddings: "/camera/embeddings".into(),
            semantic: "/camera/semantic".into(),
            vocabulary: "/vocabulary".into(),
        }
    }
}

/// What to do with a frame or message that is malformed or inconsistent.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BadInputPolicy {
    /// Skip it, count it in the [`IngestReport`] and go on.
    #[default]
    Skip,
    /// Stop with an error naming the message.
    Stop,
}

/// How frames are assembled.
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
    /// [`super::plan_topics`]).
    pub choose: super::TopicChoice,
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
            choose: super::TopicChoice::default(),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Color,
    Depth,
    CameraInfo,
    Pose,
    Tf,
    TfStatic,
    Embeddings,
    Semantic,
    Vocabulary,
}

impl Role {
    fn accepted_types(self) -> &'static [&'static str] {
        match self {
            Role::Color | Role::Depth => &[Image::TYPE_NAME, CompressedImage::TYPE_NAME],
            Role::CameraInfo => &[CameraInfo::TYPE_NAME],
            Role::Pose => &[PoseStamped::TYPE_NAME, Odometry::TYPE_NAME],
            Role::Tf | Role::TfStatic => &[TfMessage::TYPE_NAME],
            Role::Embeddings => &[MaskFeatures::TYPE_NAME, FeatureGrid::TYPE_NAME],
            Role::Semantic => &[Image::TYPE_NAME],
            Role::Vocabulary => &[TextEmbeddings::TYPE_NAME],
        }
    }
    fn stream(self) -> &'static str {
        match self {
            Role::Color => "colour",
            Role::Depth => "depth",
            Role::CameraInfo => "camera info",
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

struct Stamped<T> {
    stamp: i64,
    value: T,
}

/// A stream's pending messages, sorted by stamp, and the latest stamp seen.
struct Queue<T> {
    items: VecDeque<Stamped<T>>,
    watermark: Option<i64>,
    /// A message came with a stamp before the watermark.
    went_back: bool,
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
    fn push(&mut self, stamp: i64, value: T) {
        self.note(stamp);
        let i = self.items.partition_point(|s| s.stamp <= stamp);
        self.items.insert(i, Stamped { stamp, value });
    }
    /// Notes a message that was refused: the stream has moved on.
    fn note(&mut self, stamp: i64) {
        self.went_back |= self.watermark.is_some_and(|w| stamp < w);
        self.watermark = Some(self.watermark.map_or(stamp, |w| w.max(stamp)));
    }
    /// Removes and returns the item nearest `t` within `tol`. (Stamps come
    /// from `Time::as_nanos`, within ±2.2·10¹⁸ ns, so their differences
    /// cannot overflow.)
    fn take_nearest(&mut self, t: i64, tol: i64) -> Option<Stamped<T>> {
        let (i, _) = self
            .items
            .iter()
            .enumerate()
            .filter(|(_, s)| (s.stamp - t).abs() <= tol)
            .min_by_key(|(_, s)| (s.stamp - t).abs())?;
        self.items.remove(i)
    }
    /// Removes items no colour image at or after `t` can claim.
    fn drain_older_than(&mut self, t: i64) -> usize {
        let n = self.items.partition_point(|s| s.stamp < t);
        self.items.drain(..n);
        n
    }
}

/// The vocabulary found in a log.
#[derive(Clone, Debug, PartialEq)]
pub struct Vocabulary {
    /// Class names.
    pub names: Vec<String>,
    /// Class id of each name.
    pub ids: Vec<u16>,
    /// Embedding dimension.
    pub dim: u32,
    /// `names.len() × dim` vectors.
    pub vectors: Vec<f32>,
    /// Embedding model id.
    pub model: String,
}

/// Turns a stream of log messages into [`Frame`]s.
pub struct FrameAssembler {
    config: AssemblyConfig,
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

    fn role(&self, topic: &str) -> Option<Role> {
        let t = &self.config.topics;
        if topic == t.color {
            Some(Role::Color)
        } else if topic == t.depth {
            Some(Role::Depth)
        } else if topic == t.camera_info && self.config.intrinsics.is_none() {
            Some(Role::CameraInfo)
        } else if matches!(&t.pose, PoseSource::Topic(p) if p == topic) {
            Some(Role::Pose)
        } else if matches!(t.pose, PoseSource::Tf { .. }) && topic == "/tf" {
            Some(Role::Tf)
        } else if matches!(t.pose, PoseSource::Tf { .. }) && topic == "/tf_static" {
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

    /// The topics this configuration reads, for a [`ReadFilter`].
    pub fn topics(&self) -> Vec<String> {
        let t = &self.config.topics;
        let mut v = vec![t.color.clone(), t.depth.clone()];
        if self.config.intrinsics.is_none() {
            v.push(t.camera_info.clone());
        }
        match &t.pose {
            PoseSource::Topic(p) => v.push(p.clone()),
            PoseSource::Tf { .. } => v.extend(["/tf".to_string(), "/tf_static".to_string()]),
        }
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

    fn decode(&mut self, role: Role, msg: RawMessage<'_>) -> Result<(), Rejection> {
        let ty = normalize_type_name(&msg.channel.schema_name);
        let undecodable = |e: super::cdr::CdrError| {
            Rejection::new(
                match role {
                    Role::Color => "colour: undecodable message",
                    Role::Depth => "depth: undecodable message",
                    Role::CameraInfo => "camera info: undecodable message",
                    Role::Pose => "pose: undecodable message",
                    Role::Tf | Role::TfStatic => "tf: undecodable message",
                    Role::Embeddings => "embeddings: undecodable message",
                    Role::Semantic => "semantic: undecodable message",
                    Role::Vocabulary => "vocabulary: undecodable message",
                },
                e.to_string(),
            )
        };
        let data = msg.data;
        match role {
            Role::Color if ty == CompressedImage::TYPE_NAME => {
                let m = CompressedImage::decode(data).map_err(undecodable)?;
                self.note_color_frame(m.header.frame_id);
                self.color.push(
                    m.header.stamp.as_nanos(),
                    PendingFrame {
                        color: PendingColor::Compressed {
                            format: m.format.to_string(),
                            data: m.data.to_vec(),
                        },
                        seen: SeenSince::default(),
                    },
                );
            }
            Role::Color => {
                let m = Image::decode(data).map_err(undecodable)?;
                self.note_color_frame(m.header.frame_id);
                let color = PendingColor::Raw(codec::color_from_image_into(
                    &m,
                    self.pool.bytes(m.data.len()),
                ));
                self.color.push(
                    m.header.stamp.as_nanos(),
                    PendingFrame {
                        color,
                        seen: SeenSince::default(),
                    },
                );
            }
            Role::Depth => {
                let scale = self.config.depth_metres_per_unit;
                let (stamp, depth) = if ty == CompressedImage::TYPE_NAME {
                    let m = CompressedImage::decode(data).map_err(undecodable)?;
                    let expected = self
                        .camera_size()
                        .map(|(width, height)| codec::ExpectedSize {
                            width,
                            height,
                            kind: "depth: size mismatch",
                            from: "the camera info",
                        });
                    (
                        m.header.stamp.as_nanos(),
                        codec::depth_from_compressed(&m, scale, expected),
                    )
                } else {
                    let m = Image::decode(data).map_err(undecodable)?;
                    (
                        m.header.stamp.as_nanos(),
                        codec::depth_from_image_into(&m, scale, self.pool.words(m.data.len() / 2)),
                    )
                };
                // A bad depth image is kept as such so the colour image it
                // belongs to is rejected for the right reason.
                self.depth.push(stamp, depth);
                self.saw(Partner::Depth, stamp);
            }
            Role::CameraInfo => {
                let m = CameraInfo::decode(data).map_err(undecodable)?;
                self.camera_info = Some(intrinsics_of(&m));
            }
            Role::Pose => {
                let (stamp, pose) = if ty == Odometry::TYPE_NAME {
                    let m = Odometry::decode(data).map_err(undecodable)?;
                    (m.header.stamp.as_nanos(), m.pose)
                } else {
                    let m = PoseStamped::decode(data).map_err(undecodable)?;
                    (m.header.stamp.as_nanos(), m.pose)
                };
                let pose = pose.checked()?;
                self.poses_went_back |= self.poses.latest().is_some_and(|l| stamp < l);
                self.poses.insert(stamp, pose);
                self.saw(Partner::Pose, stamp);
            }
            Role::Tf | Role::TfStatic => {
                let m = TfMessage::decode(data).map_err(undecodable)?;
                for t in &m.transforms {
                    self.tf.insert(t, role == Role::TfStatic)?;
                    if role == Role::Tf {
                        let stamp = t.header.stamp.as_nanos();
                        self.saw(Partner::Pose, stamp);
                    }
                }
            }
            Role::Embeddings => {
                let (stamp, e) = if ty == FeatureGrid::TYPE_NAME {
                    let m = FeatureGrid::decode(data).map_err(undecodable)?;
                    (
                        m.header.stamp.as_nanos(),
                        grid_embeddings(&m, &mut self.pool)?,
                    )
                } else {
                    let m = MaskFeatures::decode(data).map_err(undecodable)?;
                    (
                        m.header.stamp.as_nanos(),
                        mask_embeddings(&m, &mut self.pool)?,
                    )
                };
                self.check_signature(&e)?;
                let mut e = e;
                let refused = drop_bad_regions(&mut e, stamp);
                if let (Some(first), BadInputPolicy::Stop) =
                    (refused.first(), self.config.on_bad_input)
                {
                    return Err(first.clone());
                }
                for r in &refused {
                    self.report.count(r);
                }
                if refused.len() < e.count as usize {
                    self.embeddings.push(stamp, e);
                } else {
                    // Nothing left to learn from: the frame maps geometry
                    // only, as if it had no embeddings.
                    self.embeddings.note(stamp);
                    self.pool.recycle_embeddings(e);
                }
                self.saw(Partner::Embeddings, stamp);
            }
            Role::Semantic => {
                let m = Image::decode(data).map_err(undecodable)?;
                let labels = codec::labels_from_image(&m)?;
                let stamp = m.header.stamp.as_nanos();
                self.semantic.push(stamp, labels);
                self.saw(Partner::Semantic, stamp);
            }
            Role::Vocabulary => {
                let m = TextEmbeddings::decode(data).map_err(undecodable)?;
                self.vocabulary = Some(vocabulary_of(&m)?);
            }
        }
        Ok(())
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

    fn note_color_frame(&mut self, frame_id: &str) {
        if self.color_frame_id.as_deref() != Some(frame_id) {
            self.color_frame_id = Some(frame_id.to_string());
        }
    }

    fn check_signature(&mut self, e: &Embeddings) -> Result<(), Rejection> {
        let model = super::embedding_space(&e.model).to_string();
        match &self.embedding_signature {
            None => {
                self.embedding_signature = Some((e.dim, model));
                Ok(())
            }
            Some((dim, _)) if *dim != e.dim => Err(Rejection::new(
                "embeddings: dimension changed",
                format!(
                    "dimension {} after earlier messages of dimension {dim}",
                    e.dim
                ),
            )),
            Some((_, m)) if *m != model => Err(Rejection::new(
                "embeddings: model changed",
                format!("model `{model}` after earlier messages from `{m}`"),
            )),
            Some(_) => Ok(()),
        }
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

    /// Whether everything a colour image at `t` waits for has arrived: each
    /// partner stream has moved past `t` plus the tolerance since the image
    /// arrived or, while its stamps have only gone forward, at all.
    fn can_resolve(&self, t: i64, seen: &SeenSince) -> bool {
        if self.ended {
            return true;
        }
        let tol = self.config.tolerance_ns;
        let past = |w: Option<i64>, until: i64| w.is_some_and(|w| w >= until);
        let ready = |since: Option<i64>, watermark: Option<i64>, went_back: bool, until: i64| {
            past(since, until) || (!went_back && past(watermark, until))
        };
        let latest_pose = match &self.config.topics.pose {
            PoseSource::Topic(_) => self.poses.latest(),
            PoseSource::Tf { .. } => self.tf.latest(),
        };
        let pose_ready = ready(seen.pose, latest_pose, self.poses_went_back, t);
        // Saturating: the tolerance is the user's (`--tolerance-ms`).
        let until = t.saturating_add(tol);
        let partner = |q_watermark: Option<i64>, went_back: bool, since: Option<i64>| {
            ready(since, q_watermark, went_back, until)
        };
        partner(self.depth.watermark, self.depth.went_back, seen.depth)
            && (self.config.intrinsics.is_some() || self.camera_info.is_some())
            && pose_ready
            && (!self.has_embeddings
                || partner(
                    self.embeddings.watermark,
                    self.embeddings.went_back,
                    seen.embeddings,
                ))
            && (!self.has_semantic
                || partner(
                    self.semantic.watermark,
                    self.semantic.went_back,
                    seen.semantic,
                ))
    }

    fn resolve(&mut self, all: bool) -> Result<(), InputError> {
        while let Some(front) = self.color.items.front() {
            let t = front.stamp;
            let forced = all || self.color.items.len() > self.config.max_pending;
            if !forced && !self.can_resolve(t, &front.value.seen) {
                break;
            }
            // `front()` was `Some` just above.
            let pending = self.color.items.pop_front().expect("front exists");
            let late = self
                .last_resolved
                .filter(|&last| t < last.saturating_sub(self.config.tolerance_ns));
            // A duplicate takes no partners: they belong to the first.
            let assembled = if self.resolved_stamps.insert(t) {
                self.assemble(t, pending.value.color)
            } else {
                Err(Rejection::new(
                    "frame: duplicate stamp",
                    format!(
                        "a second colour image at {t} ns (overlapping bag files, or a log \
                         recorded twice?)"
                    ),
                ))
            };
            let result = match (assembled, late) {
                // Its partners went with the frames resolved before it.
                (Err(r), Some(last)) if r.kind.starts_with("frame: no ") => Err(Rejection::new(
                    "frame: out of order",
                    format!(
                        "colour image at {t} ns arrived after the frame at {last} ns was \
                         assembled ({})",
                        r.kind
                    ),
                )),
                (result, _) => result,
            };
            self.last_resolved = Some(self.last_resolved.map_or(t, |l| l.max(t)));
            // Saturating: tolerance and pose gap are the user's settings.
            let oldest = t.saturating_sub(self.config.tolerance_ns);
            // Whatever is now too old for any later colour image is unpaired.
            for (kind, n) in [
                ("depth: unpaired", self.depth.drain_older_than(oldest)),
                (
                    "embeddings: unpaired",
                    self.embeddings.drain_older_than(oldest),
                ),
                ("semantic: unpaired", self.semantic.drain_older_than(oldest)),
            ] {
                for _ in 0..n {
                    self.report.count(&Rejection::new(
                        kind,
                        "no colour image within the tolerance",
                    ));
                }
            }
            let pose_horizon = t.saturating_sub(self.config.max_pose_gap_ns);
            self.poses.forget_before(pose_horizon);
            self.tf.forget_before(pose_horizon);
            match result {
                Ok(frame) => {
                    self.report.frames += 1;
                    self.report.frames_with_embeddings += frame.embeddings.is_some() as u64;
                    self.ready.push_back(frame);
                }
                Err(r) => {
                    let topic = self.config.topics.color.clone();
                    self.reject(&topic, t, r)?;
                }
            }
        }
        // Bound the partner queues too.
        let max = self.config.max_pending;
        while self.depth.items.len() > max {
            self.depth.items.pop_front();
            self.report.count(&Rejection::new(
                "depth: unpaired",
                "no colour image arrived for it before the queue filled",
            ));
        }
        while self.embeddings.items.len() > max {
            self.embeddings.items.pop_front();
            self.report.count(&Rejection::new(
                "embeddings: unpaired",
                "no colour image arrived for it before the queue filled",
            ));
        }
        while self.semantic.items.len() > max {
            self.semantic.items.pop_front();
        }
        Ok(())
    }

    fn assemble(&mut self, t: i64, pending: PendingColor) -> Result<Frame, Rejection> {
        let tol = self.config.tolerance_ns;
        let depth = self.depth.take_nearest(t, tol);
        let embeddings = self.embeddings.take_nearest(t, tol);
        let semantic = self.semantic.take_nearest(t, tol);
        let Some(depth) = depth else {
            return Err(Rejection::new(
                "frame: no depth within tolerance",
                format!("colour image at {t} ns"),
            ));
        };
        let depth = depth.value?;
        let intrinsics = match (&self.config.intrinsics, &self.camera_info) {
            (Some(k), _) => *k,
            (None, Some(k)) => k.clone()?,
            (None, None) => {
                return Err(Rejection::new(
                    "frame: no camera info",
                    format!("colour image at {t} ns arrived before any camera info"),
                ))
            }
        };
        let pose = self.pose_at(t)?;
        let color = match pending {
            PendingColor::Raw(c) => c?,
            PendingColor::Compressed { format, data } => codec::color_from_compressed(
                &CompressedImage {
                    header: Default::default(),
                    format: &format,
                    data: &data,
                },
                Some(codec::ExpectedSize {
                    width: depth.width,
                    height: depth.height,
                    kind: "frame: depth size differs from colour",
                    from: "the depth image",
                }),
            )?,
        };
        if (depth.width, depth.height) != (color.width, color.height) {
            return Err(Rejection::new(
                "frame: depth size differs from colour",
                format!(
                    "depth {}×{}, colour {}×{} (depth must be registered to the colour image)",
                    depth.width, depth.height, color.width, color.height
                ),
            ));
        }
        let intrinsics = Intrinsics {
            width: color.width,
            height: color.height,
            ..match (intrinsics.width, intrinsics.height) {
                (0, 0) => intrinsics,
                (w, h) if (w, h) == (color.width, color.height) => intrinsics,
                (w, h) => {
                    return Err(Rejection::new(
                        "frame: intrinsics size differs from colour",
                        format!(
                            "camera info is for {w}×{h}, colour image is {}×{}",
                            color.width, color.height
                        ),
                    ))
                }
            }
        };
        check_intrinsics(&intrinsics)?;
        let extent = self.config.max_extent_m;
        if pose.translation.abs().max_element() > extent {
            return Err(Rejection::new(
                "frame: position beyond the world extent",
                format!(
                    "camera at {:?} m, beyond ±{extent} m (--max-extent)",
                    pose.translation.to_array()
                ),
            ));
        }
        let mut depth = depth;
        depth.invalidate_beyond(self.config.max_depth_m);
        if !depth.has_valid_sample() {
            return Err(Rejection::new(
                "frame: no valid depth",
                format!(
                    "every depth sample of the image at {t} ns is 0, invalid or beyond {} m \
                     (--max-depth)",
                    self.config.max_depth_m
                ),
            ));
        }
        Ok(Frame {
            stamp_ns: t,
            pose,
            intrinsics,
            color,
            depth,
            embeddings: embeddings.map(|e| e.value),
            semantic: semantic.map(|s| s.value),
        })
    }

    fn pose_at(&self, t: i64) -> Result<CameraPose, Rejection> {
        let gap = self.config.max_pose_gap_ns;
        let pose = match &self.config.topics.pose {
            PoseSource::Topic(_) => self
                .poses
                .at(t, self.config.tolerance_ns, gap)
                .map_err(|why| Rejection::new("frame: no pose", format!("at {t} ns: {why}")))?,
            PoseSource::Tf {
                world_frame,
                camera_frame,
            } => {
                let camera = camera_frame
                    .as_deref()
                    .or(self.color_frame_id.as_deref())
                    .unwrap_or_default();
                self.tf
                    .lookup(world_frame, camera, t, gap)
                    .map_err(|why| Rejection::new("frame: no pose", format!("at {t} ns: {why}")))?
            }
        };
        Ok(CameraPose {
            rotation: pose.rotation,
            translation: pose.translation,
        })
    }
}

/// Refuses intrinsics no real camera has: the principal point outside the
/// image, or a focal length outside 0.05 to 50 image widths (a field of
/// view from about 1° to 170°), the signs of mis-scaled or garbage
/// calibration.
pub(crate) fn check_intrinsics(k: &Intrinsics) -> Result<(), Rejection> {
    let (w, h) = (k.width as f64, k.height as f64);
    let focal = 0.05 * w..=50.0 * w;
    if !(0.0..=w).contains(&k.cx) || !(0.0..=h).contains(&k.cy) {
        return Err(Rejection::new(
            "frame: implausible intrinsics",
            format!(
                "principal point ({}, {}) outside the {}×{} image",
                k.cx, k.cy, k.width, k.height
            ),
        ));
    }
    if !focal.contains(&k.fx) || !focal.contains(&k.fy) {
        return Err(Rejection::new(
            "frame: implausible intrinsics",
            format!(
                "focal length ({}, {}) px outside 0.05 to 50 times the width of {} px",
                k.fx, k.fy, k.width
            ),
        ));
    }
    Ok(())
}

fn intrinsics_of(m: &CameraInfo<'_>) -> Result<Intrinsics, Rejection> {
    let [fx, _, cx, _, fy, cy, ..] = m.k;
    if ![fx, fy, cx, cy].iter().all(|v| v.is_finite()) || fx <= 0.0 || fy <= 0.0 {
        return Err(Rejection::new(
            "camera info: invalid intrinsics",
            format!("fx {fx}, fy {fy}, cx {cx}, cy {cy}"),
        ));
    }
    if m.d.iter().any(|c| c != 0.0) {
        return Err(Rejection::new(
            "camera info: distortion not supported",
            format!(
                "`{}` coefficients {:?}; rectify the images first (undistortion is not implemented)",
                m.distortion_model,
                m.d.to_vec()
            ),
        ));
    }
    if m.binning_x > 1 || m.binning_y > 1 || m.roi.0 != [0; 4] {
        return Err(Rejection::new(
            "camera info: binning or ROI not supported",
            format!("binning {}×{}, roi {:?}", m.binning_x, m.binning_y, m.roi.0),
        ));
    }
    Ok(Intrinsics {
        width: m.width,
        height: m.height,
        fx,
        fy,
        cx,
        cy,
    })
}

/// The largest embedding dimension accepted (far beyond any model's; the
/// latent head's buffers are sized by it).
pub const MAX_EMBEDDING_DIM: u32 = 65536;

fn check_vectors(
    kind: &'static str,
    count: u64,
    dim: u32,
    dtype: &str,
    len: usize,
) -> Result<Dtype, Rejection> {
    let dt = Dtype::parse(dtype).ok_or_else(|| {
        Rejection::new(
            "embeddings: unknown dtype",
            format!("dtype `{dtype}` (accepted: f16, f32)"),
        )
    })?;
    if dim == 0 {
        return Err(Rejection::new(kind, "dim is 0"));
    }
    if dim > MAX_EMBEDDING_DIM {
        // With no vectors (count 0) any dim matches the empty data; the
        // mapper sizes buffers by it, so it is bounded here.
        return Err(Rejection::new(
            kind,
            format!("dim {dim} is beyond the {MAX_EMBEDDING_DIM} supported"),
        ));
    }
    let need = count
        .saturating_mul(dim as u64)
        .saturating_mul(dt.size() as u64);
    if need != len as u64 {
        return Err(Rejection::new(
            kind,
            format!("{count} vectors × {dim} × {dtype} need {need} bytes, data has {len}"),
        ));
    }
    Ok(dt)
}

fn mask_embeddings(m: &MaskFeatures<'_>, pool: &mut BufferPool) -> Result<Embeddings, Rejection> {
    let kind = "embeddings: size mismatch";
    let dtype = check_vectors(kind, m.count as u64, m.dim, m.dtype, m.data.len())?;
    let pixels = m.width as u64 * m.height as u64;
    if pixels == 0
        || pixels > codec::MAX_IMAGE_PIXELS
        || m.width > codec::MAX_IMAGE_SIDE
        || m.height > codec::MAX_IMAGE_SIDE
    {
        return Err(Rejection::new(
            kind,
            format!("label image {}×{}", m.width, m.height),
        ));
    }
    if m.labels.len() as u64 != pixels {
        return Err(Rejection::new(
            kind,
            format!(
                "{} labels for a {}×{} label image",
                m.labels.len(),
                m.width,
                m.height
            ),
        ));
    }
    let labels = pool.copy_words(&m.labels);
    if let Some(&bad) = labels
        .iter()
        .find(|&&l| l != u16::MAX && l as u32 >= m.count)
    {
        pool.recycle_words(labels);
        return Err(Rejection::new(
            "embeddings: label out of range",
            format!("region label {bad} with only {} regions", m.count),
        ));
    }
    Ok(Embeddings {
        layout: EmbeddingLayout::Regions(LabelImage {
            width: m.width,
            height: m.height,
            labels,
        }),
        count: m.count,
        dim: m.dim,
        dtype,
        data: pool.copy_bytes(m.data),
        model: m.model.to_string(),
    })
}

/// Refuses, one by one, region embeddings that hold a NaN or an infinity
/// or are all zero (no direction to learn): their vectors are zeroed, which
/// gives them no weight, and their pixels unlabelled. Returns one
/// rejection per region refused.
fn drop_bad_regions(e: &mut Embeddings, stamp: i64) -> Vec<Rejection> {
    let dim = e.dim as usize;
    let row_bytes = dim * e.dtype.size();
    let values = e.to_f32();
    let mut refused = Vec::new();
    let mut bad_ids = Vec::new();
    for (i, (row, v)) in e
        .data
        .chunks_exact_mut(row_bytes.max(1))
        .zip(values.chunks_exact(dim.max(1)))
        .enumerate()
    {
        let (kind, what) = if v.iter().any(|x| !x.is_finite()) {
            (
                "embeddings: region with non-finite values",
                "NaN or infinite values",
            )
        } else if v.iter().all(|&x| x == 0.0) {
            ("embeddings: region with zero norm", "all zeros")
        } else {
            continue;
        };
        row.fill(0);
        bad_ids.push(i as u16);
        refused.push(Rejection::new(
            kind,
            format!("region {i} of {} at {stamp} ns holds {what}", e.count),
        ));
    }
    if let (EmbeddingLayout::Regions(labels), false) = (&mut e.layout, bad_ids.is_empty()) {
        for l in labels.labels.iter_mut() {
            if bad_ids.binary_search(l).is_ok() {
                *l = u16::MAX;
            }
        }
    }
    refused
}

fn grid_embeddings(m: &FeatureGrid<'_>, pool: &mut BufferPool) -> Result<Embeddings, Rejection> {
    let cells = m.rows as u64 * m.cols as u64;
    if cells == 0 || cells > u32::MAX as u64 {
        return Err(Rejection::new(
            "embeddings: size mismatch",
            format!("grid of {}×{} cells", m.rows, m.cols),
        ));
    }
    let dtype = check_vectors(
        "embeddings: size mismatch",
        cells,
        m.dim,
        m.dtype,
        m.data.len(),
    )?;
    Ok(Embeddings {
        layout: EmbeddingLayout::Grid {
            rows: m.rows,
            cols: m.cols,
        },
        count: cells as u32,
        dim: m.dim,
        dtype,
        data: pool.copy_bytes(m.data),
        model: m.model.to_string(),
    })
}

/// The first query vocabulary (`TextEmbeddings`) on `topic` of the log at
/// `path`, without assembling frames: `Ok(None)` when the topic carries
/// none. A vocabulary message that does not decode is an error, since the
/// caller asked for exactly that message.
///
/// ```no_run
/// let vocab = latentam::io::read_vocabulary("scene.mcap".as_ref(), "/vocabulary")?;
/// if let Some(v) = vocab {
///     println!("{} classes of {}-d {} embeddings", v.names.len(), v.dim, v.model);
/// }
/// # Ok::<(), latentam::io::InputError>(())
/// ```
pub fn read_vocabulary(path: &Path, topic: &str) -> Result<Option<Vocabulary>, InputError> {
    let log = McapLog::open(path)?;
    let mut reader = log.reader(ReadFilter {
        topics: Some(vec![topic.to_string()]),
        ..Default::default()
    });
    let Some(next) = reader.next_with(|m| {
        let reject = |rejection| InputError::Rejected {
            topic: topic.to_string(),
            stamp_ns: m.log_time as i64,
            rejection,
        };
        let msg = TextEmbeddings::decode(m.data).map_err(|e| {
            reject(Rejection::new(
                "vocabulary: undecodable message",
                e.to_string(),
            ))
        })?;
        vocabulary_of(&msg).map_err(reject)
    }) else {
        return Ok(None);
    };
    Ok(Some(next??))
}

fn vocabulary_of(m: &TextEmbeddings<'_>) -> Result<Vocabulary, Rejection> {
    if m.names.len() != m.ids.len() {
        return Err(Rejection::new(
            "vocabulary: size mismatch",
            format!("{} names but {} ids", m.names.len(), m.ids.len()),
        ));
    }
    let dtype = check_vectors(
        "vocabulary: size mismatch",
        m.names.len() as u64,
        m.dim,
        m.dtype,
        m.data.len(),
    )?;
    let names: Vec<String> = m.names.iter().map(|s| s.to_string()).collect();
    let mut seen = std::collections::HashSet::new();
    if let Some(twice) = names.iter().find(|n| !seen.insert(n.as_str())) {
        return Err(Rejection::new(
            "vocabulary: duplicate name",
            format!("`{twice}` appears more than once"),
        ));
    }
    let vectors = super::frame::decode_floats(m.data, dtype);
    for (name, v) in names.iter().zip(vectors.chunks_exact(m.dim as usize)) {
        if v.iter().any(|x| !x.is_finite()) || v.iter().all(|&x| x == 0.0) {
            return Err(Rejection::new(
                "vocabulary: unusable vector",
                format!("the embedding of `{name}` is zero or holds NaN or infinite values"),
            ));
        }
    }
    Ok(Vocabulary {
        names,
        ids: m.ids.to_vec(),
        dim: m.dim,
        vectors,
        model: m.model.to_string(),
    })
}

/// Frames from an MCAP log, in stamp order.
///
/// ```no_run
/// use latentam::io::{AssemblyConfig, McapFrames};
///
/// let mut frames = McapFrames::open("run.mcap".as_ref(), AssemblyConfig::default())?;
/// for frame in &mut frames {
///     let frame = frame?;
///     println!("{} ns: {}×{}", frame.stamp_ns, frame.color.width, frame.color.height);
/// }
/// eprintln!("{}", frames.report());
/// # Ok::<(), latentam::io::InputError>(())
/// ```
pub struct McapFrames {
    reader: MessageReader,
    assembler: FrameAssembler,
    done: bool,
    plan: Vec<String>,
}

impl McapFrames {
    /// Opens a log and checks that the topics the configuration needs are
    /// there with accepted message types.
    pub fn open(path: &Path, config: AssemblyConfig) -> Result<Self, InputError> {
        Self::from_log(McapLog::open(path)?, config)
    }

    /// Frames from an already opened log.
    pub fn from_log(log: McapLog, mut config: AssemblyConfig) -> Result<Self, InputError> {
        let channels = log.channels();
        let (topics, plan) = super::plan_topics(&channels, &config)?;
        config.topics = topics;
        let probe = FrameAssembler::new(config.clone(), false, false);
        let find = |topic: &str| channels.iter().find(|c| c.topic == topic);
        let mut required = vec![config.topics.color.as_str(), config.topics.depth.as_str()];
        if config.intrinsics.is_none() {
            required.push(&config.topics.camera_info);
        }
        match &config.topics.pose {
            PoseSource::Topic(p) => required.push(p),
            PoseSource::Tf { .. } => {
                if find("/tf").is_none() && find("/tf_static").is_none() {
                    required.push("/tf");
                }
            }
        }
        let missing: Vec<&str> = required
            .iter()
            .copied()
            .filter(|t| find(t).is_none())
            .collect();
        if !missing.is_empty() {
            // Damage read before the topic's first message is the cause.
            if let Some(e) = log.scan_problem() {
                return Err(InputError::Topic {
                    topic: missing.join(", "),
                    reason: format!("not found before the log became unreadable: {e}"),
                });
            }
            return Err(InputError::Topic {
                topic: missing.join(", "),
                reason: format!(
                    "not in the log; it has: {}",
                    channels
                        .iter()
                        .map(|c| format!("{} ({})", c.topic, c.schema_name))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
        for c in &channels {
            if let Some(role) = probe.role(&c.topic) {
                check_channel(c, role)?;
            }
        }
        let topics = probe.topics();
        let assembler = FrameAssembler::new(
            config.clone(),
            find(&config.topics.embeddings).is_some(),
            find(&config.topics.semantic).is_some(),
        );
        Ok(McapFrames {
            reader: log.reader(ReadFilter {
                topics: Some(topics),
                ..Default::default()
            }),
            assembler,
            done: false,
            plan,
        })
    }

    /// The streams whose topic was chosen from the log, one line each
    /// (empty when every topic was as configured).
    pub fn topic_plan(&self) -> &[String] {
        &self.plan
    }

    /// The topics being read.
    pub fn topics(&self) -> &Topics {
        &self.assembler.config.topics
    }

    /// Counts so far (complete once the iterator has ended).
    pub fn report(&self) -> &IngestReport {
        self.assembler.report()
    }

    /// Hands a frame that is no longer needed back for its buffers to be
    /// reused ([`FrameAssembler::recycle`]).
    pub fn recycle(&mut self, frame: Frame) {
        self.assembler.recycle(frame);
    }

    /// The log's vocabulary, once its message has been read.
    pub fn vocabulary(&self) -> Option<&Vocabulary> {
        self.assembler.vocabulary()
    }
}

fn check_channel(c: &Channel, role: Role) -> Result<(), InputError> {
    let ty = normalize_type_name(&c.schema_name);
    let accepted = role.accepted_types();
    if !accepted.contains(&ty.as_str()) {
        return Err(InputError::Topic {
            topic: c.topic.clone(),
            reason: format!(
                "carries `{}` but the {} stream needs one of {}",
                c.schema_name,
                role.stream(),
                accepted.join(", ")
            ),
        });
    }
    if c.message_encoding != "cdr" {
        return Err(InputError::Topic {
            topic: c.topic.clone(),
            reason: format!(
                "message encoding `{}`, only `cdr` is read",
                c.message_encoding
            ),
        });
    }
    Ok(())
}

impl Iterator for McapFrames {
    type Item = Result<Frame, InputError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(frame) = self.assembler.pop() {
                return Some(Ok(frame));
            }
            if self.done {
                return None;
            }
            let assembler = &mut self.assembler;
            match self.reader.next_with(|m| assembler.push(m)) {
                None => {
                    self.done = true;
                    if let Err(e) = self.assembler.finish() {
                        return Some(Err(e));
                    }
                }
                Some(Err(e)) | Some(Ok(Err(e))) => return Some(Err(e)),
                Some(Ok(Ok(()))) => {}
            }
        }
    }
}
