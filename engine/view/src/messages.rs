//! Foxglove messages of a map, as JSON (the encoding the schemas in
//! [`crate::schemas`] describe): point clouds, poses, paths and images.
//!
//! Every cloud packs, per point, `x y z` (FLOAT32, metres), `red green
//! blue alpha` (UINT8) and one FLOAT32 value named by the cloud (e.g.
//! `opacity`, `relevance`) for colouring by field in Foxglove.

use base64::Engine as _;
use serde_json::{json, Value};

use latentam_base::{Error, Result};
use latentam_io::CameraPose;

/// Bytes per packed point: `x y z`, `red green blue alpha`, the value.
pub const CLOUD_POINT_STRIDE: usize = 20;

/// `foxglove.NumericType` values used here.
const UINT8: u8 = 1;
const FLOAT32: u8 = 7;

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

fn time(stamp_ns: u64) -> Value {
    json!({ "sec": stamp_ns / 1_000_000_000, "nsec": stamp_ns % 1_000_000_000 })
}

fn pose(p: &CameraPose) -> Value {
    let (t, q) = (p.translation, p.rotation);
    json!({
        "position": { "x": t.x, "y": t.y, "z": t.z },
        "orientation": { "x": q.x, "y": q.y, "z": q.z, "w": q.w }
    })
}

fn base64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// A `foxglove.PointCloud` of `cloud` in `frame_id`.
pub fn point_cloud(frame_id: &str, stamp_ns: u64, cloud: &Cloud<'_>) -> Result<Value> {
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
    let mut data = Vec::with_capacity(n * CLOUD_POINT_STRIDE);
    for ((p, c), v) in cloud.positions.iter().zip(cloud.colours).zip(cloud.value.1) {
        for x in p {
            data.extend_from_slice(&x.to_le_bytes());
        }
        data.extend_from_slice(c);
        data.extend_from_slice(&v.to_le_bytes());
    }
    let field =
        |name: &str, offset: usize, ty: u8| json!({ "name": name, "offset": offset, "type": ty });
    Ok(json!({
        "timestamp": time(stamp_ns),
        "frame_id": frame_id,
        // Points are in the frame itself.
        "pose": pose(&CameraPose {
            rotation: glam::DQuat::IDENTITY,
            translation: glam::DVec3::ZERO,
        }),
        "point_stride": CLOUD_POINT_STRIDE,
        "fields": [
            field("x", 0, FLOAT32),
            field("y", 4, FLOAT32),
            field("z", 8, FLOAT32),
            field("red", 12, UINT8),
            field("green", 13, UINT8),
            field("blue", 14, UINT8),
            field("alpha", 15, UINT8),
            field(cloud.value.0, 16, FLOAT32),
        ],
        "data": base64(&data),
    }))
}

/// A `foxglove.PosesInFrame` path of `poses` (camera-to-world, in order).
pub fn poses_in_frame(frame_id: &str, stamp_ns: u64, poses: &[CameraPose]) -> Value {
    json!({
        "timestamp": time(stamp_ns),
        "frame_id": frame_id,
        "poses": poses.iter().map(pose).collect::<Vec<_>>(),
    })
}

/// A `foxglove.PoseInFrame` of one camera-to-world pose.
pub fn pose_in_frame(frame_id: &str, stamp_ns: u64, p: &CameraPose) -> Value {
    json!({
        "timestamp": time(stamp_ns),
        "frame_id": frame_id,
        "pose": pose(p),
    })
}

/// A `foxglove.RawImage` (`rgb8`) of `image`.
pub fn raw_image(frame_id: &str, stamp_ns: u64, image: &RgbImage<'_>) -> Result<Value> {
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
    Ok(json!({
        "timestamp": time(stamp_ns),
        "frame_id": frame_id,
        "width": image.width,
        "height": image.height,
        "encoding": "rgb8",
        "step": image.width * 3,
        "data": base64(image.rgb),
    }))
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
