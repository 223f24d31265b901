//! Maps for Foxglove: point clouds (`foxglove.PointCloud`) and a camera
//! trajectory (`foxglove.PosesInFrame`) as an MCAP file of JSON messages
//! with JSON Schema, so a robot team opens a map beside the bag it came
//! from, in the bag's world frame.
//!
//! Every cloud packs, per point, `x y z` (FLOAT32, metres), `red green
//! blue alpha` (UINT8) and one FLOAT32 value named by the cloud (e.g.
//! `opacity`, `relevance`) for colouring by field in Foxglove.

use std::collections::BTreeMap;
use std::io::{Seek, Write};
use std::path::Path;

use base64::Engine as _;
use serde_json::{json, Value};

use latentam_base::{Error, Result};
use latentam_io::CameraPose;

/// Bytes per packed point: `x y z`, `red green blue alpha`, the value.
pub const CLOUD_POINT_STRIDE: usize = 20;

/// `foxglove.NumericType` values used here.
const UINT8: u8 = 1;
const FLOAT32: u8 = 7;

/// Schema name of point clouds, as Foxglove recognises it.
pub const POINT_CLOUD_SCHEMA: &str = "foxglove.PointCloud";
/// Schema name of trajectories, as Foxglove recognises it.
pub const POSES_IN_FRAME_SCHEMA: &str = "foxglove.PosesInFrame";

fn number() -> Value {
    json!({ "type": "number" })
}

fn time_schema() -> Value {
    json!({
        "type": "object",
        "title": "time",
        "properties": {
            "sec": { "type": "integer", "minimum": 0 },
            "nsec": { "type": "integer", "minimum": 0, "maximum": 999_999_999 }
        }
    })
}

fn pose_schema() -> Value {
    json!({
        "title": "foxglove.Pose",
        "type": "object",
        "properties": {
            "position": {
                "title": "foxglove.Vector3",
                "type": "object",
                "properties": { "x": number(), "y": number(), "z": number() }
            },
            "orientation": {
                "title": "foxglove.Quaternion",
                "type": "object",
                "properties": { "x": number(), "y": number(), "z": number(), "w": number() }
            }
        }
    })
}

/// The JSON Schema of `foxglove.PointCloud` messages as written here.
pub fn point_cloud_schema() -> Value {
    let numeric_types: Vec<Value> = [
        "UNKNOWN", "UINT8", "INT8", "UINT16", "INT16", "UINT32", "INT32", "FLOAT32", "FLOAT64",
    ]
    .iter()
    .enumerate()
    .map(|(i, name)| json!({ "title": name, "const": i }))
    .collect();
    json!({
        "title": POINT_CLOUD_SCHEMA,
        "description": "Points with packed per-point fields",
        "type": "object",
        "properties": {
            "timestamp": time_schema(),
            "frame_id": { "type": "string" },
            "pose": pose_schema(),
            "point_stride": { "type": "integer", "minimum": 0 },
            "fields": {
                "type": "array",
                "items": {
                    "title": "foxglove.PackedElementField",
                    "type": "object",
                    "properties": {
                        "name": { "type": "string" },
                        "offset": { "type": "integer", "minimum": 0 },
                        "type": { "title": "foxglove.NumericType", "oneOf": numeric_types }
                    }
                }
            },
            "data": { "type": "string", "contentEncoding": "base64" }
        }
    })
}

/// The JSON Schema of `foxglove.PosesInFrame` messages as written here.
pub fn poses_in_frame_schema() -> Value {
    json!({
        "title": POSES_IN_FRAME_SCHEMA,
        "description": "Timestamped poses in one reference frame",
        "type": "object",
        "properties": {
            "timestamp": time_schema(),
            "frame_id": { "type": "string" },
            "poses": { "type": "array", "items": pose_schema() }
        }
    })
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

/// One point cloud: a position, an RGBA colour and one named value per
/// point.
///
/// ```
/// use latentam_io::foxglove::Cloud;
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

/// Writes Foxglove messages to an MCAP file.
///
/// ```
/// use latentam_io::foxglove::{Cloud, FoxgloveWriter};
///
/// let mut bytes = std::io::Cursor::new(Vec::new());
/// let mut out = FoxgloveWriter::new(&mut bytes, "map")?;
/// let cloud = Cloud {
///     positions: &[[0.0, 0.0, 1.0]],
///     colours: &[[255, 0, 0, 255]],
///     value: ("opacity", &[1.0]),
/// };
/// out.cloud("/latentam/map", 1_000, &cloud)?;
/// out.finish()?;
/// # Ok::<(), latentam_io::Error>(())
/// ```
pub struct FoxgloveWriter<W: Write + Seek> {
    inner: mcap::Writer<W>,
    frame_id: String,
    schemas: BTreeMap<&'static str, u16>,
    channels: BTreeMap<String, u16>,
    sequence: u32,
}

fn write_error(e: impl std::fmt::Display) -> Error {
    Error::InvalidArgument(format!("writing the Foxglove file: {e}"))
}

impl<W: Write + Seek> FoxgloveWriter<W> {
    /// Starts a file on `w` whose messages are in the `frame_id` frame.
    pub fn new(w: W, frame_id: &str) -> Result<Self> {
        let inner = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .library(concat!("latentam ", env!("CARGO_PKG_VERSION")))
            .create(w)
            .map_err(write_error)?;
        Ok(FoxgloveWriter {
            inner,
            frame_id: frame_id.to_string(),
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            sequence: 0,
        })
    }

    fn channel(&mut self, topic: &str, schema: &'static str) -> Result<u16> {
        if let Some(&id) = self.channels.get(topic) {
            return Ok(id);
        }
        let schema_id = match self.schemas.get(schema) {
            Some(&id) => id,
            None => {
                let text = match schema {
                    POINT_CLOUD_SCHEMA => point_cloud_schema(),
                    _ => poses_in_frame_schema(),
                }
                .to_string();
                let id = self
                    .inner
                    .add_schema(schema, "jsonschema", text.as_bytes())
                    .map_err(write_error)?;
                self.schemas.insert(schema, id);
                id
            }
        };
        let id = self
            .inner
            .add_channel(schema_id, topic, "json", &BTreeMap::new())
            .map_err(write_error)?;
        self.channels.insert(topic.to_string(), id);
        Ok(id)
    }

    fn message(
        &mut self,
        topic: &str,
        schema: &'static str,
        stamp_ns: u64,
        msg: &Value,
    ) -> Result<()> {
        let channel_id = self.channel(topic, schema)?;
        self.sequence = self.sequence.wrapping_add(1);
        let data = serde_json::to_vec(msg).map_err(write_error)?;
        self.inner
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id,
                    sequence: self.sequence,
                    log_time: stamp_ns,
                    publish_time: stamp_ns,
                },
                &data,
            )
            .map_err(write_error)
    }

    /// Writes `cloud` on `topic` at `stamp_ns`.
    pub fn cloud(&mut self, topic: &str, stamp_ns: u64, cloud: &Cloud<'_>) -> Result<()> {
        let n = cloud.positions.len();
        if cloud.colours.len() != n || cloud.value.1.len() != n {
            return Err(Error::InvalidArgument(format!(
                "cloud on {topic}: {n} positions, {} colours, {} values",
                cloud.colours.len(),
                cloud.value.1.len()
            )));
        }
        let mut data = Vec::with_capacity(n * CLOUD_POINT_STRIDE);
        for ((p, c), v) in cloud.positions.iter().zip(cloud.colours).zip(cloud.value.1) {
            for x in p {
                data.extend_from_slice(&x.to_le_bytes());
            }
            data.extend_from_slice(c);
            data.extend_from_slice(&v.to_le_bytes());
        }
        let field = |name: &str, offset: usize, ty: u8| json!({ "name": name, "offset": offset, "type": ty });
        let msg = json!({
            "timestamp": time(stamp_ns),
            "frame_id": self.frame_id,
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
            "data": base64::engine::general_purpose::STANDARD.encode(&data),
        });
        self.message(topic, POINT_CLOUD_SCHEMA, stamp_ns, &msg)
    }

    /// Writes `poses` (camera-to-world, in order) as one path on `topic`
    /// at `stamp_ns`.
    pub fn poses(&mut self, topic: &str, stamp_ns: u64, poses: &[CameraPose]) -> Result<()> {
        let msg = json!({
            "timestamp": time(stamp_ns),
            "frame_id": self.frame_id,
            "poses": poses.iter().map(pose).collect::<Vec<_>>(),
        });
        self.message(topic, POSES_IN_FRAME_SCHEMA, stamp_ns, &msg)
    }

    /// Writes the summary and footer; returns the output.
    pub fn finish(mut self) -> Result<W> {
        self.inner.finish().map_err(write_error)?;
        Ok(self.inner.into_inner())
    }
}

/// Writes a Foxglove file at `path` whole or not at all: `body` adds the
/// messages.
pub fn write_foxglove_file(
    path: &Path,
    frame_id: &str,
    body: impl FnOnce(&mut FoxgloveWriter<&mut std::io::BufWriter<std::fs::File>>) -> Result<()>,
) -> Result<()> {
    let mut failure = None;
    let written = latentam_base::files::write_atomically(path, |w| {
        let run = (|| {
            let mut out = FoxgloveWriter::new(&mut *w, frame_id)?;
            body(&mut out)?;
            out.finish()?;
            Ok(())
        })();
        run.map_err(|e: Error| {
            let message = e.to_string();
            failure = Some(e);
            std::io::Error::other(message)
        })
    });
    match (written, failure) {
        (Err(_), Some(e)) => Err(e),
        (r, _) => r,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cloud_reads_back_with_its_fields_and_schema() {
        let mut bytes = std::io::Cursor::new(Vec::new());
        let mut out = FoxgloveWriter::new(&mut bytes, "map").unwrap();
        let positions = [[1.0, -2.0, 3.5], [0.25, 0.5, 0.75]];
        let colours = [[1, 2, 3, 4], [250, 251, 252, 253]];
        let values = [0.5, -7.0];
        let cloud = Cloud {
            positions: &positions,
            colours: &colours,
            value: ("relevance", &values),
        };
        out.cloud("/c", 1_500_000_000, &cloud).unwrap();
        let pose = CameraPose {
            rotation: glam::DQuat::IDENTITY,
            translation: glam::DVec3::new(1.0, 2.0, 3.0),
        };
        out.poses("/p", 2_000_000_001, &[pose, pose]).unwrap();
        out.finish().unwrap();
        let bytes = bytes.into_inner();
        let messages: Vec<_> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(Result::unwrap)
            .collect();
        assert_eq!(messages.len(), 2);
        let cloud_msg = &messages[0];
        let schema = cloud_msg.channel.schema.as_ref().unwrap();
        assert_eq!(
            (schema.name.as_str(), schema.encoding.as_str()),
            (POINT_CLOUD_SCHEMA, "jsonschema")
        );
        assert_eq!(cloud_msg.channel.message_encoding, "json");
        let v: Value = serde_json::from_slice(&cloud_msg.data).unwrap();
        assert_eq!(v["timestamp"], json!({ "sec": 1, "nsec": 500_000_000 }));
        assert_eq!(v["frame_id"], "map");
        assert_eq!(v["point_stride"], CLOUD_POINT_STRIDE);
        let data = base64::engine::general_purpose::STANDARD
            .decode(v["data"].as_str().unwrap())
            .unwrap();
        assert_eq!(data.len(), 2 * CLOUD_POINT_STRIDE);
        let fields = v["fields"].as_array().unwrap();
        let at = |name: &str| {
            fields.iter().find(|f| f["name"] == name).unwrap()["offset"]
                .as_u64()
                .unwrap() as usize
        };
        let f32_at = |i: usize, off: usize| {
            f32::from_le_bytes(
                data[i * CLOUD_POINT_STRIDE + off..][..4]
                    .try_into()
                    .unwrap(),
            )
        };
        for i in 0..2 {
            assert_eq!(f32_at(i, at("x")), positions[i][0]);
            assert_eq!(f32_at(i, at("z")), positions[i][2]);
            assert_eq!(f32_at(i, at("relevance")), values[i]);
            assert_eq!(data[i * CLOUD_POINT_STRIDE + at("blue")], colours[i][2]);
            assert_eq!(data[i * CLOUD_POINT_STRIDE + at("alpha")], colours[i][3]);
        }
        let p: Value = serde_json::from_slice(&messages[1].data).unwrap();
        assert_eq!(
            messages[1].channel.schema.as_ref().unwrap().name,
            POSES_IN_FRAME_SCHEMA
        );
        assert_eq!(p["poses"].as_array().unwrap().len(), 2);
        assert_eq!(p["poses"][1]["position"]["z"], 3.0);
        assert_eq!(p["timestamp"], json!({ "sec": 2, "nsec": 1 }));
    }

    #[test]
    fn a_cloud_with_mismatched_lengths_is_refused() {
        let mut bytes = std::io::Cursor::new(Vec::new());
        let mut out = FoxgloveWriter::new(&mut bytes, "map").unwrap();
        let cloud = Cloud {
            positions: &[[0.0; 3]; 2],
            colours: &[[0; 4]],
            value: ("v", &[0.0, 0.0]),
        };
        assert!(out.cloud("/c", 0, &cloud).is_err());
    }
}
