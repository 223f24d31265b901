//! The JSON Schemas of the Foxglove message types latentam publishes, as
//! Foxglove documents them (<https://docs.foxglove.dev/docs/visualization/message-schemas>):
//! a reader validates every message against the schema its file or
//! channel carries, and Foxglove recognises the types by name.

use serde_json::{json, Value};

/// `foxglove.PointCloud`: points with packed per-point fields.
pub const POINT_CLOUD: &str = "foxglove.PointCloud";
/// `foxglove.PosesInFrame`: a path of poses.
pub const POSES_IN_FRAME: &str = "foxglove.PosesInFrame";
/// `foxglove.PoseInFrame`: one pose.
pub const POSE_IN_FRAME: &str = "foxglove.PoseInFrame";
/// `foxglove.RawImage`: an uncompressed image.
pub const RAW_IMAGE: &str = "foxglove.RawImage";

/// The schema named `name` (one of the constants above).
pub fn schema(name: &str) -> Option<Value> {
    Some(match name {
        POINT_CLOUD => point_cloud(),
        POSES_IN_FRAME => poses_in_frame(),
        POSE_IN_FRAME => pose_in_frame(),
        RAW_IMAGE => raw_image(),
        _ => return None,
    })
}

fn number() -> Value {
    json!({ "type": "number" })
}

fn time() -> Value {
    json!({
        "type": "object",
        "title": "time",
        "properties": {
            "sec": { "type": "integer", "minimum": 0 },
            "nsec": { "type": "integer", "minimum": 0, "maximum": 999_999_999 }
        }
    })
}

fn pose() -> Value {
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

fn point_cloud() -> Value {
    let numeric_types: Vec<Value> = [
        "UNKNOWN", "UINT8", "INT8", "UINT16", "INT16", "UINT32", "INT32", "FLOAT32", "FLOAT64",
    ]
    .iter()
    .enumerate()
    .map(|(i, name)| json!({ "title": name, "const": i }))
    .collect();
    json!({
        "title": POINT_CLOUD,
        "description": "Points with packed per-point fields",
        "type": "object",
        "properties": {
            "timestamp": time(),
            "frame_id": { "type": "string" },
            "pose": pose(),
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

fn poses_in_frame() -> Value {
    json!({
        "title": POSES_IN_FRAME,
        "description": "Timestamped poses in one reference frame",
        "type": "object",
        "properties": {
            "timestamp": time(),
            "frame_id": { "type": "string" },
            "poses": { "type": "array", "items": pose() }
        }
    })
}

fn pose_in_frame() -> Value {
    json!({
        "title": POSE_IN_FRAME,
        "description": "A timestamped pose in a reference frame",
        "type": "object",
        "properties": {
            "timestamp": time(),
            "frame_id": { "type": "string" },
            "pose": pose()
        }
    })
}

fn raw_image() -> Value {
    json!({
        "title": RAW_IMAGE,
        "description": "A raw image",
        "type": "object",
        "properties": {
            "timestamp": time(),
            "frame_id": { "type": "string" },
            "width": { "type": "integer", "minimum": 0 },
            "height": { "type": "integer", "minimum": 0 },
            "encoding": { "type": "string" },
            "step": { "type": "integer", "minimum": 0 },
            "data": { "type": "string", "contentEncoding": "base64" }
        }
    })
}
