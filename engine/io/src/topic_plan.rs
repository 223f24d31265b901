//! Choosing a log's topics by message type, so a robot's bag maps without
//! naming them: when a stream's configured topic is not in the log and the
//! caller allows it, the one topic of the right type is taken (with
//! preferences that settle the usual layouts of camera drivers), and an
//! ambiguous choice is an error listing the candidates and the flag that
//! settles it.

use super::frames::{AssemblyConfig, PoseSource, Topics};
use super::log::Channel;
use super::messages::{
    CameraInfo, CompressedImage, FeatureGrid, Image, MaskFeatures, Odometry, PoseStamped,
    RosMessage, TextEmbeddings, TfMessage,
};
use super::schema::normalize_type_name;
use super::InputError;

fn of_type<'a>(channels: &'a [Channel], types: &[&str]) -> Vec<&'a Channel> {
    channels
        .iter()
        .filter(|c| types.contains(&normalize_type_name(&c.schema_name).as_str()))
        .collect()
}

/// Narrows `candidates` by each preference in turn, keeping a preference
/// only when some candidate meets it.
fn prefer<'a>(
    mut candidates: Vec<&'a Channel>,
    preferences: &[&dyn Fn(&Channel) -> bool],
) -> Vec<&'a Channel> {
    for p in preferences {
        let kept: Vec<_> = candidates.iter().copied().filter(|c| p(c)).collect();
        if !kept.is_empty() {
            candidates = kept;
        }
    }
    candidates
}

/// Drops `X/compressed` (and `X/compressedDepth`) when `X` itself is a
/// candidate: drivers publish both, and the raw one needs no decoding.
fn drop_compressed_twins(candidates: Vec<&Channel>) -> Vec<&Channel> {
    let names: Vec<String> = candidates.iter().map(|c| c.topic.clone()).collect();
    candidates
        .into_iter()
        .filter(|c| {
            let base = c
                .topic
                .strip_suffix("/compressed")
                .or_else(|| c.topic.strip_suffix("/compressedDepth"));
            base.is_none_or(|b| !names.iter().any(|n| n == b))
        })
        .collect()
}

fn one<'a>(
    stream: &str,
    flag: &str,
    candidates: Vec<&'a Channel>,
) -> Result<Option<&'a Channel>, InputError> {
    match candidates.as_slice() {
        [] => Ok(None),
        [c] => Ok(Some(c)),
        many => Err(InputError::Topic {
            topic: stream.to_string(),
            reason: format!(
                "several topics could be the {stream}: {}; name one with {flag}",
                many.iter()
                    .map(|c| format!("{} ({})", c.topic, c.schema_name))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }),
    }
}

fn lower(c: &Channel) -> String {
    c.topic.to_ascii_lowercase()
}

/// A depth topic the driver registered to the colour camera (RealSense's
/// `aligned_depth_to_color`, the Kinect/OpenNI `depth_registered`).
fn registered_depth(topic: &str) -> bool {
    let t = topic.to_ascii_lowercase();
    t.contains("aligned_depth_to_color") || t.contains("depth_registered")
}

/// The topics to read from a log with `channels`, and one line per stream
/// chosen from the log (for the user to see): streams whose configured
/// topic is present, or that `config.choose` does not allow choosing, stay
/// as configured.
pub fn plan_topics(
    channels: &[Channel],
    config: &AssemblyConfig,
) -> Result<(Topics, Vec<String>), InputError> {
    let mut topics = config.topics.clone();
    let mut plan = Vec::new();
    let choose = config.choose;
    let present = |t: &str| channels.iter().any(|c| c.topic == t);
    if choose.color && !present(&topics.color) {
        choose_color(channels, &mut topics, &mut plan)?;
    }
    if choose.depth {
        choose_depth(channels, &mut topics, &mut plan)?;
    }
    if choose.camera_info && config.intrinsics.is_none() && !present(&topics.camera_info) {
        choose_camera_info(channels, &mut topics, &mut plan)?;
    }
    if choose.depth_camera_info && !present(&topics.depth_camera_info) {
        choose_depth_camera_info(channels, &mut topics, &mut plan)?;
    }
    if let (true, PoseSource::Topic(p)) = (choose.pose, &topics.pose) {
        if !present(p) {
            choose_pose(channels, &mut topics, &mut plan)?;
        }
    }
    if choose.embeddings && !present(&topics.embeddings) {
        let candidates = of_type(channels, &[MaskFeatures::TYPE_NAME, FeatureGrid::TYPE_NAME]);
        let chosen = one("region embeddings", "--embeddings-topic", candidates)?;
        take(&mut plan, "embeddings", &mut topics.embeddings, chosen);
    }
    if choose.vocabulary && !present(&topics.vocabulary) {
        let candidates = of_type(channels, &[TextEmbeddings::TYPE_NAME]);
        let chosen = one("vocabulary", "--vocabulary-topic", candidates)?;
        take(&mut plan, "vocabulary", &mut topics.vocabulary, chosen);
    }
    Ok((topics, plan))
}

/// Image types a colour or depth stream may have.
const IMAGES: [&str; 2] = [Image::TYPE_NAME, CompressedImage::TYPE_NAME];

/// Sets `slot` to the chosen topic, noting the choice in `plan`.
fn take(plan: &mut Vec<String>, stream: &str, slot: &mut String, chosen: Option<&Channel>) {
    if let Some(c) = chosen {
        plan.push(format!(
            "{stream}: {} ({}; {} is not in the log)",
            c.topic, c.schema_name, slot
        ));
        *slot = c.topic.clone();
    }
}

/// The colour images: an image topic that is no depth, infrared or label
/// stream, a `color`/`rgb` one first.
fn choose_color(
    channels: &[Channel],
    topics: &mut Topics,
    plan: &mut Vec<String>,
) -> Result<(), InputError> {
    let candidates = of_type(channels, &IMAGES)
        .into_iter()
        .filter(|c| {
            let t = lower(c);
            !["depth", "infra", "/ir", "semantic", "label", "mask"]
                .iter()
                .any(|w| t.contains(w))
        })
        .collect();
    let candidates = prefer(
        drop_compressed_twins(candidates),
        &[&|c| lower(c).contains("color") || lower(c).contains("rgb")],
    );
    let chosen = one("colour images", "--color-topic", candidates)?;
    take(plan, "colour", &mut topics.color, chosen);
    Ok(())
}

/// The depth images when the configured topic is absent, or a registered
/// depth topic recorded beside the configured raw one.
fn choose_depth(
    channels: &[Channel],
    topics: &mut Topics,
    plan: &mut Vec<String>,
) -> Result<(), InputError> {
    let present = |t: &str| channels.iter().any(|c| c.topic == t);
    let depth_images: Vec<&Channel> = of_type(channels, &IMAGES)
        .into_iter()
        .filter(|c| lower(c).contains("depth"))
        .collect();
    // A driver that records its registered depth beside the raw one
    // names the raw one `.../depth/image_raw`, the default: read through
    // the colour camera, that one would put every surface off its colour.
    let registered_beside = present(&topics.depth)
        && !registered_depth(&topics.depth)
        && depth_images.iter().any(|c| registered_depth(&c.topic));
    if !present(&topics.depth) || registered_beside {
        let candidates = prefer(
            drop_compressed_twins(depth_images),
            &[&|c| lower(c).contains("aligned_depth_to_color"), &|c| {
                lower(c).contains("depth_registered")
            }],
        );
        let chosen = one("depth images", "--depth-topic", candidates)?;
        if registered_beside {
            if let Some(c) = chosen {
                plan.push(format!(
                    "depth: {} ({}; registered to colour, preferred over {})",
                    c.topic, c.schema_name, topics.depth
                ));
                topics.depth = c.topic.clone();
            }
        } else {
            take(plan, "depth", &mut topics.depth, chosen);
        }
    }
    Ok(())
}

/// The calibration beside the colour images: its parent path is a prefix
/// of theirs.
fn choose_camera_info(
    channels: &[Channel],
    topics: &mut Topics,
    plan: &mut Vec<String>,
) -> Result<(), InputError> {
    // The calibration beside the colour images: its parent path is a
    // prefix of theirs.
    let color = topics.color.clone();
    let beside = move |c: &Channel| {
        c.topic
            .rsplit_once('/')
            .is_some_and(|(parent, _)| !parent.is_empty() && color.starts_with(parent))
    };
    let candidates = prefer(of_type(channels, &[CameraInfo::TYPE_NAME]), &[&beside]);
    let chosen = one("camera info", "--camera-info-topic", candidates)?;
    take(plan, "camera info", &mut topics.camera_info, chosen);
    Ok(())
}

/// The depth camera's own calibration, beside raw (unregistered) depth
/// images: its parent path is a prefix of theirs, and it is not the
/// colour camera's.
fn choose_depth_camera_info(
    channels: &[Channel],
    topics: &mut Topics,
    plan: &mut Vec<String>,
) -> Result<(), InputError> {
    if registered_depth(&topics.depth) {
        return Ok(());
    }
    let (depth, colour) = (topics.depth.clone(), topics.camera_info.clone());
    let candidates: Vec<&Channel> = of_type(channels, &[CameraInfo::TYPE_NAME])
        .into_iter()
        .filter(|c| {
            c.topic != colour
                && c.topic
                    .rsplit_once('/')
                    .is_some_and(|(parent, _)| !parent.is_empty() && depth.starts_with(parent))
        })
        .collect();
    if let Some(c) = one("depth camera info", "--depth-camera-info-topic", candidates)? {
        plan.push(format!(
            "depth camera info: {} (registers depth to colour, with /tf_static, if their \
             frames differ)",
            c.topic
        ));
        topics.depth_camera_info = c.topic.clone();
    }
    Ok(())
}

/// The camera poses: a pose or odometry topic (a `camera` one first), else
/// the TF tree when the log has one.
fn choose_pose(
    channels: &[Channel],
    topics: &mut Topics,
    plan: &mut Vec<String>,
) -> Result<(), InputError> {
    let PoseSource::Topic(p) = &topics.pose else {
        return Ok(());
    };
    let candidates = prefer(
        of_type(channels, &[PoseStamped::TYPE_NAME, Odometry::TYPE_NAME]),
        &[&|c| lower(c).contains("camera")],
    );
    let configured = p.clone();
    match one("camera poses", "--pose-topic or --tf-world", candidates)? {
        Some(c) => {
            plan.push(format!(
                "poses: {} ({}; {configured} is not in the log)",
                c.topic, c.schema_name
            ));
            topics.pose = PoseSource::Topic(c.topic.clone());
        }
        None if !of_type(channels, &[TfMessage::TYPE_NAME]).is_empty() => {
            plan.push(format!(
                "poses: /tf + /tf_static, from the root of the tree to the colour \
                     image's frame ({configured} is not in the log)"
            ));
            topics.pose = PoseSource::Tf {
                world_frame: String::new(),
                camera_frame: None,
            };
        }
        None => {}
    }
    Ok(())
}
