//! The hand-written CDR code against an independent implementation: the
//! `mcap` + `mcap-ros2-support` Python packages, driven by
//! `tests/python/ros2_cross_check.py`. Logs written by Python are decoded
//! here, and logs written here are decoded (and re-encoded byte for byte)
//! there, with the schema texts compared field by field.
//!
//! Needs `python3` (or `$LATENTAM_PYTHON`) with `mcap==1.6.0` and
//! `mcap-ros2-support==0.6.0`; `tools/run test` installs them.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::{DQuat, DVec3};
use latentam_io::{
    cdr, CameraInfo, CompressedImage, Compression, FeatureGrid, Header, Image, LogWriter,
    MaskFeatures, McapLog, Odometry, Pose, PoseStamped, ReadFilter, RosMessage, TextEmbeddings,
    TfMessage, TransformStamped,
};
use serde_json::{json, Value};

fn python() -> String {
    std::env::var("LATENTAM_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("python/ros2_cross_check.py")
}

fn run_python(args: &[&str]) -> String {
    let out = Command::new(python())
        .arg(script())
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python()));
    assert!(
        out.status.success(),
        "{} {args:?} failed ({}): {}\n(the cross-check needs: pip install mcap==1.6.0 mcap-ros2-support==0.6.0; \
         tools/run test sets this up)",
        script().display(),
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn header(h: &Header<'_>) -> Value {
    json!({"stamp": {"sec": h.stamp.sec, "nanosec": h.stamp.nanosec}, "frame_id": h.frame_id})
}

fn pose(p: &Pose, a: &str, b: &str) -> Value {
    let (t, q) = (p.translation, p.rotation);
    json!({a: {"x": t.x, "y": t.y, "z": t.z}, b: {"x": q.x, "y": q.y, "z": q.z, "w": q.w}})
}

/// The fields the engine keeps, in the Python script's JSON layout.
fn to_json(schema: &str, data: &[u8]) -> Value {
    match schema {
        "sensor_msgs/msg/Image" => {
            let m = Image::decode(data).unwrap();
            json!({"header": header(&m.header), "height": m.height, "width": m.width, "encoding": m.encoding,
                   "is_bigendian": m.is_bigendian as u8, "step": m.step, "data": hex(m.data)})
        }
        "sensor_msgs/msg/CompressedImage" => {
            let m = CompressedImage::decode(data).unwrap();
            json!({"header": header(&m.header), "format": m.format, "data": hex(m.data)})
        }
        "sensor_msgs/msg/CameraInfo" => {
            let m = CameraInfo::decode(data).unwrap();
            let [x, y, h, w] = m.roi.0;
            json!({"header": header(&m.header), "height": m.height, "width": m.width,
                   "distortion_model": m.distortion_model, "d": m.d.to_vec(), "k": m.k, "r": m.r, "p": m.p,
                   "binning_x": m.binning_x, "binning_y": m.binning_y,
                   "roi": {"x_offset": x, "y_offset": y, "height": h, "width": w, "do_rectify": m.roi.1}})
        }
        "geometry_msgs/msg/PoseStamped" => {
            let m = PoseStamped::decode(data).unwrap();
            json!({"header": header(&m.header), "pose": pose(&m.pose, "position", "orientation")})
        }
        "nav_msgs/msg/Odometry" => {
            let m = Odometry::decode(data).unwrap();
            json!({"header": header(&m.header), "child_frame_id": m.child_frame_id,
                   "pose": {"pose": pose(&m.pose, "position", "orientation")}})
        }
        "tf2_msgs/msg/TFMessage" => {
            let m = TfMessage::decode(data).unwrap();
            let t: Vec<Value> = m
                .transforms
                .iter()
                .map(|t| {
                    json!({"header": header(&t.header), "child_frame_id": t.child_frame_id,
                                "transform": pose(&t.transform, "translation", "rotation")})
                })
                .collect();
            json!({ "transforms": t })
        }
        "latentam_msgs/msg/MaskFeatures" => {
            let m = MaskFeatures::decode(data).unwrap();
            json!({"header": header(&m.header), "height": m.height, "width": m.width, "labels": m.labels.to_vec(),
                   "count": m.count, "dim": m.dim, "dtype": m.dtype, "data": hex(m.data), "model": m.model})
        }
        "latentam_msgs/msg/FeatureGrid" => {
            let m = FeatureGrid::decode(data).unwrap();
            json!({"header": header(&m.header), "rows": m.rows, "cols": m.cols, "dim": m.dim, "dtype": m.dtype,
                   "data": hex(m.data), "model": m.model})
        }
        "latentam_msgs/msg/TextEmbeddings" => {
            let m = TextEmbeddings::decode(data).unwrap();
            json!({"header": header(&m.header), "names": m.names, "ids": m.ids.to_vec(), "dim": m.dim,
                   "dtype": m.dtype, "data": hex(m.data), "model": m.model})
        }
        other => panic!("unexpected schema {other}"),
    }
}

/// Every field in `ours` is in `theirs` with the same value (the engine
/// skips some fields, e.g. the odometry twist).
fn assert_subset(ours: &Value, theirs: &Value, at: &str) {
    match (ours, theirs) {
        (Value::Object(a), Value::Object(b)) => {
            for (k, v) in a {
                let other = b
                    .get(k)
                    .unwrap_or_else(|| panic!("{at}.{k} missing on the Python side"));
                assert_subset(v, other, &format!("{at}.{k}"));
            }
        }
        (Value::Array(a), Value::Array(b)) => {
            assert_eq!(a.len(), b.len(), "{at}: lengths");
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                assert_subset(x, y, &format!("{at}[{i}]"));
            }
        }
        (Value::Number(a), Value::Number(b)) => {
            assert_eq!(a.as_f64(), b.as_f64(), "{at}");
        }
        _ => assert_eq!(ours, theirs, "{at}"),
    }
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("latentam-cross-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn logs_written_by_the_python_packages_decode_identically() {
    let path = temp("python.mcap");
    run_python(&["write", path.to_str().unwrap()]);
    let expected: Value =
        serde_json::from_str(&std::fs::read_to_string(path.with_extension("json")).unwrap())
            .unwrap();
    let expected = expected["messages"].as_array().unwrap();
    let log = McapLog::open(&path).unwrap();
    let mut reader = log.reader(ReadFilter::default());
    let mut seen = 0;
    while let Some(m) = reader.next_with(|m| {
        (
            m.channel.topic.clone(),
            m.channel.schema_name.clone(),
            m.log_time,
            to_json(&m.channel.schema_name, m.data),
        )
    }) {
        let (topic, schema, log_time, ours) = m.unwrap();
        let want = expected
            .iter()
            .find(|e| e["topic"] == topic.as_str())
            .unwrap();
        assert_eq!(want["schema"], schema.as_str());
        assert_eq!(want["log_time"].as_u64(), Some(log_time));
        assert_subset(&ours, &want["fields"], &topic);
        seen += 1;
    }
    assert_eq!(seen, expected.len());
}

#[test]
fn logs_written_here_decode_identically_in_python() {
    let path = temp("rust.mcap");
    let mut log = LogWriter::create(&path, Compression::Lz4).unwrap();
    let rgb: Vec<u8> = (0..3 * 2 * 5).map(|i| i as u8 * 3).collect();
    let labels: Vec<u8> = [0u16, 1, 65535, 1, 0, 2]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let ids: Vec<u8> = [4u16, 9].iter().flat_map(|v| v.to_le_bytes()).collect();
    let q = DQuat::from_xyzw(0.5, -0.5, 0.5, 0.5);
    let p = Pose {
        translation: DVec3::new(1.25, -0.5, 3.0),
        rotation: q,
    };
    let mut messages: Vec<(&str, &str, Vec<u8>)> = Vec::new();
    let h = |n: i64, f| Header::at(1_700_000_000_000_000_000 + n * 1_000_123, f);
    messages.push((
        "/image",
        Image::TYPE_NAME,
        Image {
            header: h(1, "cam"),
            height: 2,
            width: 3,
            encoding: "rgb8",
            is_bigendian: false,
            step: 15,
            data: &rgb,
        }
        .encode(),
    ));
    messages.push((
        "/compressed",
        CompressedImage::TYPE_NAME,
        CompressedImage {
            header: h(2, "c"),
            format: "16UC1; compressedDepth png",
            data: &rgb[..7],
        }
        .encode(),
    ));
    let mut info = CameraInfo::pinhole(h(3, "optical"), 640, 480, [525.5, 526.25, 319.75, 239.5]);
    info.roi = ([1, 2, 3, 4], true);
    messages.push(("/camera_info", CameraInfo::TYPE_NAME, info.encode()));
    messages.push((
        "/pose",
        PoseStamped::TYPE_NAME,
        PoseStamped {
            header: h(4, "map"),
            pose: p,
        }
        .encode(),
    ));
    messages.push((
        "/odom",
        Odometry::TYPE_NAME,
        Odometry {
            header: h(5, "odom"),
            child_frame_id: "base",
            pose: p,
        }
        .encode(),
    ));
    messages.push((
        "/tf",
        TfMessage::TYPE_NAME,
        TfMessage {
            transforms: vec![
                TransformStamped {
                    header: h(6, "odom"),
                    child_frame_id: "base",
                    transform: p,
                },
                TransformStamped {
                    header: h(7, "base"),
                    child_frame_id: "cam_optical",
                    transform: Pose::IDENTITY,
                },
            ],
        }
        .encode(),
    ));
    messages.push((
        "/mask",
        MaskFeatures::TYPE_NAME,
        MaskFeatures {
            header: h(8, "cam"),
            height: 2,
            width: 3,
            labels: cdr::Seq::new(&labels, cdr::Endian::Little),
            count: 3,
            dim: 1,
            dtype: "f16",
            data: &rgb[..6],
            model: "clip-x",
        }
        .encode(),
    ));
    messages.push((
        "/grid",
        FeatureGrid::TYPE_NAME,
        FeatureGrid {
            header: h(9, "cam"),
            rows: 1,
            cols: 1,
            dim: 3,
            dtype: "f16",
            data: &rgb[..6],
            model: "lseg",
        }
        .encode(),
    ));
    messages.push((
        "/vocab",
        TextEmbeddings::TYPE_NAME,
        TextEmbeddings {
            header: h(10, ""),
            names: vec!["mug", "coffee table"],
            ids: cdr::Seq::new(&ids, cdr::Endian::Little),
            dim: 1,
            dtype: "f32",
            data: &rgb[..8],
            model: "clip-x",
        }
        .encode(),
    ));
    for (i, (topic, ty, data)) in messages.iter().enumerate() {
        let t = 1_000 + i as u64;
        match *ty {
            "sensor_msgs/msg/Image" => log.write_raw::<Image>(topic, t, data),
            "sensor_msgs/msg/CompressedImage" => log.write_raw::<CompressedImage>(topic, t, data),
            "sensor_msgs/msg/CameraInfo" => log.write_raw::<CameraInfo>(topic, t, data),
            "geometry_msgs/msg/PoseStamped" => log.write_raw::<PoseStamped>(topic, t, data),
            "nav_msgs/msg/Odometry" => log.write_raw::<Odometry>(topic, t, data),
            "tf2_msgs/msg/TFMessage" => log.write_raw::<TfMessage>(topic, t, data),
            "latentam_msgs/msg/MaskFeatures" => log.write_raw::<MaskFeatures>(topic, t, data),
            "latentam_msgs/msg/FeatureGrid" => log.write_raw::<FeatureGrid>(topic, t, data),
            _ => log.write_raw::<TextEmbeddings>(topic, t, data),
        }
        .unwrap();
    }
    log.finish().unwrap();
    // The script checks our schema texts against its own definitions and
    // that its re-encoding equals our bytes.
    let out: Value = serde_json::from_str(&run_python(&["read", path.to_str().unwrap()])).unwrap();
    let theirs = out["messages"].as_array().unwrap();
    assert_eq!(theirs.len(), messages.len());
    for ((topic, ty, data), t) in messages.iter().zip(theirs) {
        assert_eq!(t["topic"], *topic);
        assert_eq!(t["schema"], *ty);
        assert_subset(&to_json(ty, data), &t["fields"], topic);
    }
}
