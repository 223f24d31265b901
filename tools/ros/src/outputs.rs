//! What the node publishes: the map as `sensor_msgs/PointCloud2`, the
//! keyframe trajectory as `nav_msgs/Path`, and its status as
//! `diagnostic_msgs/DiagnosticArray`.

use latentam::messages::cdr::{CdrWriter, Endian};
use latentam::messages::{
    DiagnosticArray, DiagnosticStatus, Header, Path, PointCloud2, PointField, Pose, RosMessage,
};
use latentam::{LiveStatus, MapSnapshot};
use latentam_view::MapPoints;

/// Bytes of one published point before its extra fields: `x y z` and
/// `rgb` (packed as RViz reads it), `opacity`.
const BASE_STEP: u32 = 20;

/// A cloud of `points` of the map, with one extra `f32` field per entry
/// of `extra` (`relevance_<word>`, one value per point), encoded.
pub fn map_cloud(
    frame_id: &str,
    stamp_ns: i64,
    points: &MapPoints,
    extra: &[(String, Vec<f32>)],
) -> Vec<u8> {
    let mut w = CdrWriter::new(Endian::Little);
    map_cloud_fields(&mut w, frame_id, stamp_ns, points, extra);
    w.finish()
}

/// [`map_cloud`]'s fields, written into `w` (a field of a larger
/// message: a service's reply).
pub fn map_cloud_fields(
    w: &mut CdrWriter,
    frame_id: &str,
    stamp_ns: i64,
    points: &MapPoints,
    extra: &[(String, Vec<f32>)],
) {
    let mut fields = vec![
        PointField {
            name: "x",
            offset: 0,
            datatype: PointField::FLOAT32,
            count: 1,
        },
        PointField {
            name: "y",
            offset: 4,
            datatype: PointField::FLOAT32,
            count: 1,
        },
        PointField {
            name: "z",
            offset: 8,
            datatype: PointField::FLOAT32,
            count: 1,
        },
        // RViz's convention: 0x00RRGGBB in a field named `rgb`.
        PointField {
            name: "rgb",
            offset: 12,
            datatype: PointField::UINT32,
            count: 1,
        },
        PointField {
            name: "opacity",
            offset: 16,
            datatype: PointField::FLOAT32,
            count: 1,
        },
    ];
    for (i, (name, _)) in extra.iter().enumerate() {
        fields.push(PointField {
            name,
            offset: BASE_STEP + 4 * i as u32,
            datatype: PointField::FLOAT32,
            count: 1,
        });
    }
    let step = BASE_STEP + 4 * extra.len() as u32;
    let mut data = Vec::with_capacity(points.positions.len() * step as usize);
    for (i, (p, c)) in points.positions.iter().zip(&points.colours).enumerate() {
        for x in p {
            data.extend_from_slice(&x.to_le_bytes());
        }
        let rgb = (c[0] as u32) << 16 | (c[1] as u32) << 8 | c[2] as u32;
        data.extend_from_slice(&rgb.to_le_bytes());
        data.extend_from_slice(&points.opacity[i].to_le_bytes());
        for (_, values) in extra {
            data.extend_from_slice(&values[i].to_le_bytes());
        }
    }
    PointCloud2::unordered(Header::at(stamp_ns, frame_id), &fields, step, &data).encode_fields(w)
}

/// The keyframe trajectory of `snapshot`, encoded.
pub fn trajectory(frame_id: &str, snapshot: &MapSnapshot) -> Vec<u8> {
    let stamp = snapshot.trajectory.last().map_or(0, |&(s, _)| s);
    let path = Path {
        header: Header::at(stamp, frame_id),
        poses: snapshot
            .trajectory
            .iter()
            .map(|&(s, p)| (Header::at(s, frame_id), Pose::from(p)))
            .collect(),
    };
    path.encode()
}

/// What the node reports on its status topic, as key/value pairs.
pub struct Report<'a> {
    pub status: &'a LiveStatus,
    pub gaussians: usize,
    pub gpu_bytes: u64,
    pub messages: u64,
    pub frames: u64,
    pub refused: u64,
    pub queue_latency_p99_us: Option<u32>,
    pub pairing_wait_p99_us: Option<u32>,
    pub stamp_ns: i64,
}

/// The status as a `DiagnosticArray`, encoded.
pub fn status(r: &Report<'_>) -> Vec<u8> {
    let s = r.status;
    let values: Vec<(&str, String)> = vec![
        ("keyframes", s.keyframes.to_string()),
        ("frames_submitted", s.submitted.to_string()),
        ("frames_integrated", s.integrated.to_string()),
        ("queued_frames", s.queued_frames.to_string()),
        ("mapping_now", (s.mapping as u8).to_string()),
        ("dropped", s.dropped.total().to_string()),
        ("dropped_not_keyframe", s.dropped.not_keyframe.to_string()),
        ("dropped_superseded", s.dropped.superseded.to_string()),
        ("dropped_rejected", s.dropped.rejected.to_string()),
        ("gaussians", r.gaussians.to_string()),
        ("gpu_bytes", r.gpu_bytes.to_string()),
        ("messages_received", r.messages.to_string()),
        ("frames_assembled", r.frames.to_string()),
        ("messages_skipped", r.refused.to_string()),
        (
            "queue_latency_p99_us",
            r.queue_latency_p99_us
                .map_or(String::new(), |v| v.to_string()),
        ),
        (
            "pairing_wait_p99_us",
            r.pairing_wait_p99_us
                .map_or(String::new(), |v| v.to_string()),
        ),
        (
            "last_keyframe_ms",
            s.last_keyframe_ms
                .map_or(String::new(), |v| format!("{v:.1}")),
        ),
        (
            "keyframes_per_s",
            s.keyframes_per_s
                .map_or(String::new(), |v| format!("{v:.3}")),
        ),
    ];
    let (level, message) = match (&s.stopped, &s.last_error) {
        (Some(e), _) => (2, format!("stopped: {e}")),
        (None, Some(e)) => (1, format!("mapping; last error: {e}")),
        (None, None) => (0, "mapping".to_string()),
    };
    let status = DiagnosticStatus {
        level,
        name: "latentam",
        message: &message,
        hardware_id: "",
        values: values.iter().map(|(k, v)| (*k, v.as_str())).collect(),
    };
    DiagnosticArray {
        header: Header::at(r.stamp_ns, ""),
        status: vec![status],
    }
    .encode()
}
