//! Frames straight from an MCAP log: the reader and the assembler in one
//! iterator.

use std::path::Path;

use super::frame::Frame;
use super::frames::{AssemblyConfig, FrameAssembler, PoseSource, Role, Topics};
use super::log::{Channel, McapLog, MessageReader, ReadFilter};
use super::report::IngestReport;
use super::schema::normalize_type_name;
use super::vocabulary::Vocabulary;
use super::InputError;

/// Frames from an MCAP log, in stamp order.
///
/// ```no_run
/// use latentam_io::{AssemblyConfig, McapFrames};
///
/// let mut frames = McapFrames::open("run.mcap".as_ref(), AssemblyConfig::default())?;
/// for frame in &mut frames {
///     let frame = frame?;
///     println!("{} ns: {}×{}", frame.stamp_ns, frame.color.width, frame.color.height);
/// }
/// eprintln!("{}", frames.report());
/// # Ok::<(), latentam_io::InputError>(())
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
    pub fn from_log(log: McapLog, config: AssemblyConfig) -> Result<Self, InputError> {
        let channels = log.channels();
        let planned = match (
            PlannedInput::new(&channels, config, "the log"),
            log.scan_problem(),
        ) {
            // Damage read before a missing topic's first message is the cause.
            (Err(InputError::Topic { topic, reason }), Some(e))
                if reason.starts_with("not in ") =>
            {
                return Err(InputError::Topic {
                    topic,
                    reason: format!("not found before the log became unreadable: {e}"),
                });
            }
            (planned, _) => planned?,
        };
        let PlannedInput {
            assembler,
            topics,
            plan,
        } = planned;
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

/// What reading a source of messages takes: the topics chosen by the
/// rules of [`plan_topics`](super::plan_topics) from the channels it has
/// (a log's, or a live ROS graph's), checked, and the assembler that
/// turns their messages into frames.
pub struct PlannedInput {
    /// Turns the messages of `topics` into frames.
    pub assembler: FrameAssembler,
    /// The topics to read.
    pub topics: Vec<String>,
    /// One line per stream whose topic was chosen (for the user).
    pub plan: Vec<String>,
}

impl PlannedInput {
    /// Plans reading `channels` (found in `source`, named in errors: "the
    /// log", "the ROS graph"): errors for a stream with no topic, a topic
    /// of the wrong type, or a choice that is not unique.
    pub fn new(
        channels: &[Channel],
        mut config: AssemblyConfig,
        source: &str,
    ) -> Result<Self, InputError> {
        let (topics, plan) = super::plan_topics(channels, &config)?;
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
            return Err(InputError::Topic {
                topic: missing.join(", "),
                reason: format!(
                    "not in {source}; it has: {}",
                    channels
                        .iter()
                        .map(|c| format!("{} ({})", c.topic, c.schema_name))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
        for c in channels {
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
        Ok(PlannedInput {
            assembler,
            topics,
            plan,
        })
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
