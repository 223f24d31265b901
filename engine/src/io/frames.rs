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
use super::report::{IngestReport, Rejection};
use super::schema::normalize_type_name;
use super::tf::{PoseTrack, TfBuffer};
use super::vocabulary::{vocabulary_of, Vocabulary};
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
pub(super) enum Role {
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
    pub(super) fn accepted_types(self) -> &'static [&'static str] {
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
    pub(super) fn stream(self) -> &'static str {
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

/// Turns a stream of log messages into [`Frame`]s.
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

    pub(super) fn role(&self, topic: &str) -> Option<Role> {
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
