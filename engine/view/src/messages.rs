//! Foxglove messages of a map, as Foxglove's own protobuf types (the
//! official crate's [`foxglove::messages`], which carry their schemas):
//! point clouds, poses, paths and images.
//!
//! Every cloud packs, per point, `x y z` (FLOAT32, metres), `red green
//! blue alpha` (UINT8) and one value named by the cloud (e.g. `opacity`,
//! `relevance`) for colouring by field in Foxglove, packed as
//! [`PointValue`] says.

use foxglove::bytes::Bytes;
use foxglove::messages::packed_element_field::NumericType;
use foxglove::messages::{
    PackedElementField, PointCloud, Pose, PoseInFrame, PosesInFrame, Quaternion, RawImage,
    Timestamp, Vector3,
};

use latentam_base::{Error, Result};
use latentam_io::CameraPose;

/// How a cloud packs its per-point value.
///
/// ```
/// use latentam_view::PointValue;
///
/// assert_eq!(PointValue::Float32.stride(), 20); // files: the value as computed
/// assert_eq!(PointValue::Unorm8.stride(), 17); // the live view: a byte
/// assert_eq!(PointValue::Unorm8.byte(0.5), 128);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PointValue {
    /// FLOAT32, exactly as given: 20 bytes a point. Files use it, where
    /// the value is read back for analysis.
    Float32,
    /// UINT8, `round(255 × clamp(value, 0, 1))`: 17 bytes a point. The
    /// live view uses it, where bandwidth matters and its values
    /// (opacity, relevance) lie in [0, 1]; Foxglove shows the field as
    /// 0–255.
    Unorm8,
}

impl PointValue {
    /// Bytes per packed point: `x y z`, `red green blue alpha`, the value.
    pub fn stride(self) -> usize {
        16 + match self {
            PointValue::Float32 => 4,
            PointValue::Unorm8 => 1,
        }
    }

    /// `value` as a [`PointValue::Unorm8`] byte (NaN is 0).
    pub fn byte(self, value: f32) -> u8 {
        let v = if value.is_nan() { 0.0 } else { value };
        (v.clamp(0.0, 1.0) * 255.0).round() as u8
    }

    fn numeric_type(self) -> NumericType {
        match self {
            PointValue::Float32 => NumericType::Float32,
            PointValue::Unorm8 => NumericType::Uint8,
        }
    }
}

/// One point cloud: a position, an RGBA colour and one named value per
/// point.
///
/// ```
/// use latentam_view::Cloud;
///
/// // Points coloured by their relevance to a query, the score kept as a field.
/// let positions = [[0.0, 0.0, 1.0], [0.5, 0.0, 1.0]];
/// let scores = [0.9f32, 0.1];
/// let colours: Vec<[u8; 4]> = scores.iter().map(|s| [(s * 255.0) as u8, 0, 0, 255]).collect();
/// let cloud = Cloud { positions: &positions, colours: &colours, value: ("relevance", &scores) };
/// assert_eq!(cloud.positions.len(), cloud.value.1.len());
/// ```
pub struct Cloud<'a> {
    /// World positions, metres.
    pub positions: &'a [[f32; 3]],
    /// Colour and alpha per point.
    pub colours: &'a [[u8; 4]],
    /// The per-point value's field name and values.
    pub value: (&'a str, &'a [f32]),
}

/// An 8-bit RGB image, row-major, no padding.
pub struct RgbImage<'a> {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// `width × height × 3` bytes.
    pub rgb: &'a [u8],
}

/// A stamp in nanoseconds as a Foxglove timestamp (whole seconds past
/// 2106, beyond its 32-bit seconds, saturate).
fn time(stamp_ns: u64) -> Timestamp {
    let sec = u32::try_from(stamp_ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (stamp_ns % 1_000_000_000) as u32)
}

fn pose(p: &CameraPose) -> Pose {
    let (t, q) = (p.translation, p.rotation);
    Pose {
        position: Some(Vector3 {
            x: t.x,
            y: t.y,
            z: t.z,
        }),
        orientation: Some(Quaternion {
            x: q.x,
            y: q.y,
            z: q.z,
            w: q.w,
        }),
    }
}

/// A `foxglove.PointCloud` of `cloud` in `frame_id`, its value packed as
/// `value`.
pub fn point_cloud(
    frame_id: &str,
    stamp_ns: u64,
    cloud: &Cloud<'_>,
    value: PointValue,
) -> Result<PointCloud> {
    let n = cloud.positions.len();
    if cloud.colours.len() != n || cloud.value.1.len() != n {
        return Err(Error::bad_input(
            "point cloud",
            format!(
                "a cloud of {n} positions, {} colours and {} values",
                cloud.colours.len(),
                cloud.value.1.len()
            ),
        ));
    }
    let mut data = Vec::with_capacity(n * value.stride());
    for ((p, c), &v) in cloud.positions.iter().zip(cloud.colours).zip(cloud.value.1) {
        for x in p {
            data.extend_from_slice(&x.to_le_bytes());
        }
        data.extend_from_slice(c);
        match value {
            PointValue::Float32 => data.extend_from_slice(&v.to_le_bytes()),
            PointValue::Unorm8 => data.push(value.byte(v)),
        }
    }
    let field = |name: &str, offset: u32, ty: NumericType| PackedElementField {
        name: name.to_string(),
        offset,
        r#type: ty as i32,
    };
    Ok(PointCloud {
        timestamp: Some(time(stamp_ns)),
        frame_id: frame_id.to_string(),
        // Points are in the frame itself.
        pose: Some(pose(&CameraPose {
            rotation: glam::DQuat::IDENTITY,
            translation: glam::DVec3::ZERO,
        })),
        point_stride: value.stride() as u32,
        fields: vec![
            field("x", 0, NumericType::Float32),
            field("y", 4, NumericType::Float32),
            field("z", 8, NumericType::Float32),
            field("red", 12, NumericType::Uint8),
            field("green", 13, NumericType::Uint8),
            field("blue", 14, NumericType::Uint8),
            field("alpha", 15, NumericType::Uint8),
            field(cloud.value.0, 16, value.numeric_type()),
        ],
        data: Bytes::from(data),
    })
}

/// A `foxglove.PosesInFrame` path of `poses` (camera-to-world, in order).
pub fn poses_in_frame(frame_id: &str, stamp_ns: u64, poses: &[CameraPose]) -> PosesInFrame {
    PosesInFrame {
        timestamp: Some(time(stamp_ns)),
        frame_id: frame_id.to_string(),
        poses: poses.iter().map(pose).collect(),
    }
}

/// A `foxglove.PoseInFrame` of one camera-to-world pose.
pub fn pose_in_frame(frame_id: &str, stamp_ns: u64, p: &CameraPose) -> PoseInFrame {
    PoseInFrame {
        timestamp: Some(time(stamp_ns)),
        frame_id: frame_id.to_string(),
        pose: Some(pose(p)),
    }
}

/// A `foxglove.RawImage` (`rgb8`) of `image`.
pub fn raw_image(frame_id: &str, stamp_ns: u64, image: &RgbImage<'_>) -> Result<RawImage> {
    let expected = image.width as usize * image.height as usize * 3;
    if image.rgb.len() != expected {
        return Err(Error::bad_input(
            "image",
            format!(
                "a {}x{} RGB image of {} bytes (expected {expected})",
                image.width,
                image.height,
                image.rgb.len()
            ),
        ));
    }
    Ok(RawImage {
        timestamp: Some(time(stamp_ns)),
        frame_id: frame_id.to_string(),
        width: image.width,
        height: image.height,
        encoding: "rgb8".to_string(),
        step: image.width * 3,
        data: Bytes::copy_from_slice(image.rgb),
    })
}

/// A topic-safe form of a vocabulary word: lowercase letters, digits and
/// `_`, unique among `taken` (which it joins).
///
/// ```
/// let mut taken = Vec::new();
/// assert_eq!(latentam_view::topic_word("Coffee mug", &mut taken), "coffee_mug");
/// assert_eq!(latentam_view::topic_word("coffee-mug", &mut taken), "coffee_mug_2");
/// ```
pub fn topic_word(word: &str, taken: &mut Vec<String>) -> String {
    let mut w: String = word
        .trim()
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '_'
            }
        })
        .collect();
    if w.is_empty() {
        w.push_str("word");
    }
    let mut unique = w.clone();
    let mut n = 2;
    while taken.contains(&unique) {
        unique = format!("{w}_{n}");
        n += 1;
    }
    taken.push(unique.clone());
    unique
}
