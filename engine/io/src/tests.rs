//! Round trips through the writer and the reader, pairing, and bad input.

use std::collections::BTreeMap;
use std::path::Path;

use glam::{DQuat, DVec3};

use super::*;

#[path = "input_check_tests.rs"]
mod input_checks;
#[path = "topic_plan_tests.rs"]
mod topic_plans;

pub(crate) use latentam_base::files::testing::TempDir;

const W: u32 = 8;
const H: u32 = 6;
const MS: i64 = 1_000_000;

fn depth_bytes(fill: u16) -> Vec<u8> {
    (0..W * H)
        .flat_map(|i| (fill + i as u16).to_le_bytes())
        .collect()
}

fn color_bytes(seed: u8) -> Vec<u8> {
    (0..W * H * 3)
        .map(|i| (i as u8).wrapping_mul(7).wrapping_add(seed))
        .collect()
}

fn pose_at(t: i64) -> Pose {
    let s = t as f64 * 1e-9;
    Pose {
        translation: DVec3::new(s, 2.0 * s, -s),
        rotation: DQuat::from_rotation_y(0.3 * s),
    }
}

/// What a synthetic log holds; each field can be broken by a test.
struct Spec {
    frames: usize,
    color_period: i64,
    depth_period: i64,
    depth_offset: i64,
    pose_period: i64,
    embeddings: bool,
    compression: Compression,
    depth_frame: &'static str,
}

impl Default for Spec {
    fn default() -> Self {
        Spec {
            frames: 6,
            color_period: 100 * MS,
            depth_period: 50 * MS,
            depth_offset: 3 * MS,
            pose_period: 20 * MS,
            embeddings: true,
            compression: Compression::Zstd,
            depth_frame: "cam",
        }
    }
}

type Tweak<'a> = &'a dyn Fn(&mut LogWriter<std::io::BufWriter<std::fs::File>>, usize, i64);

fn write_log(path: &Path, spec: &Spec, tweak: Tweak<'_>) {
    let mut log = LogWriter::create(path, spec.compression).unwrap();
    let t0 = 1_000_000_000_000i64;
    let end = t0 + spec.color_period * spec.frames as i64;
    let mut events: Vec<(i64, u8)> = Vec::new();
    for i in 0..spec.frames as i64 {
        events.push((t0 + i * spec.color_period, 0));
    }
    let mut t = t0 + spec.depth_offset;
    while t < end {
        events.push((t, 1));
        t += spec.depth_period;
    }
    let mut t = t0 - spec.pose_period;
    while t <= end + spec.pose_period {
        events.push((t, 2));
        t += spec.pose_period;
    }
    events.sort();
    let mut frame = 0;
    for (t, kind) in events {
        let lt = t as u64;
        match kind {
            0 => {
                let info = CameraInfo::pinhole(Header::at(t, "cam"), W, H, [5.0, 5.0, 3.5, 2.5]);
                log.write("/camera/color/camera_info", lt, &info).unwrap();
                let data = color_bytes(frame as u8);
                let img = Image::packed(Header::at(t, "cam"), W, H, "rgb8", &data);
                log.write("/camera/color/image_raw", lt, &img).unwrap();
                if spec.embeddings {
                    let labels: Vec<u16> = (0..W * H)
                        .map(|i| if i % 5 == 0 { u16::MAX } else { (i % 3) as u16 })
                        .collect();
                    let values: Vec<f32> = (0..3 * 4).map(|i| i as f32 + frame as f32).collect();
                    let data = encode_floats(&values, Dtype::F16);
                    let lbytes: Vec<u8> = labels.iter().flat_map(|l| l.to_le_bytes()).collect();
                    let m = MaskFeatures {
                        header: Header::at(t + MS, "cam"),
                        height: H,
                        width: W,
                        labels: cdr::Seq::new(&lbytes, cdr::Endian::Little),
                        count: 3,
                        dim: 4,
                        dtype: "f16",
                        data: &data,
                        model: "test-model",
                    };
                    log.write("/camera/embeddings", lt + MS as u64, &m).unwrap();
                }
                tweak(&mut log, frame, t);
                frame += 1;
            }
            1 => {
                let data = depth_bytes(1000 + (t / MS % 100) as u16);
                let img = Image {
                    header: Header::at(t, spec.depth_frame),
                    height: H,
                    width: W,
                    encoding: "16UC1",
                    is_bigendian: false,
                    step: W * 2,
                    data: &data,
                };
                log.write("/camera/depth/image_raw", lt, &img).unwrap();
            }
            _ => {
                let p = PoseStamped {
                    header: Header::at(t, "map"),
                    pose: pose_at(t),
                };
                log.write("/camera/pose", lt, &p).unwrap();
            }
        }
    }
    log.metadata(
        "latentam",
        BTreeMap::from([
            ("source".to_string(), "test".to_string()),
            (
                "semantic_classes".to_string(),
                r#"{"0": "undefined", "10": "wall", "93": "door"}"#.to_string(),
            ),
        ]),
    )
    .unwrap();
    log.finish().unwrap();
}

fn read_all(path: &Path, config: AssemblyConfig) -> (Vec<Frame>, IngestReport) {
    let mut frames = McapFrames::open(path, config).unwrap();
    let v: Vec<Frame> = (&mut frames).map(|f| f.unwrap()).collect();
    (v, frames.report().clone())
}

#[test]
fn frames_are_paired_by_stamp_with_interpolated_poses() {
    for compression in [Compression::Zstd, Compression::Lz4, Compression::None] {
        let dir = TempDir::new("pairing");
        let path = dir.path().join("log.mcap");
        let spec = Spec {
            compression,
            ..Spec::default()
        };
        write_log(&path, &spec, &|_, _, _| {});
        let (frames, report) = read_all(&path, AssemblyConfig::default());
        assert_eq!(frames.len(), 6, "{report}");
        assert_eq!(report.frames_with_embeddings, 6);
        // 12 depth images, 6 used: the rest are counted, not lost.
        assert_eq!(report.skipped_for("depth: unpaired"), 6, "{report}");
        assert_eq!(report.total_skipped(), 6, "{report}");
        for (i, f) in frames.iter().enumerate() {
            assert_eq!(f.color.data, color_bytes(i as u8));
            // The depth 3 ms after the colour image, not the one 47 ms later.
            let dt = f.stamp_ns + 3 * MS;
            assert_eq!(
                f.depth.metres(0),
                Some((1000 + (dt / MS % 100) as u16) as f32 * 0.001)
            );
            assert_eq!(f.intrinsics.fx, 5.0);
            assert_eq!((f.intrinsics.width, f.intrinsics.height), (W, H));
            let want = pose_at(f.stamp_ns);
            assert!((f.pose.translation - want.translation).length() < 1e-9);
            assert!(f.pose.rotation.angle_between(want.rotation) < 1e-9);
            let e = f.embeddings.as_ref().unwrap();
            assert_eq!((e.count, e.dim, e.dtype), (3, 4, Dtype::F16));
            assert_eq!(e.to_f32()[5], 5.0 + i as f32);
            assert!(
                matches!(&e.layout, EmbeddingLayout::Regions(l) if l.labels[0] == u16::MAX && l.labels[1] == 1)
            );
        }
        let log = McapLog::open(&path).unwrap();
        assert_eq!(log.message_count("/camera/pose"), Some(33));
        assert_eq!(log.metadata().unwrap()[0].1["source"], "test");
        let names = super::read_class_names(&path).unwrap();
        assert_eq!((names[&10].as_str(), names[&93].as_str()), ("wall", "door"));
    }
}

#[test]
fn a_rosbag2_directory_of_split_files_reads_as_one_log() {
    let dir = TempDir::new("split");
    let one = dir.path().join("one.mcap");
    write_log(&one, &Spec::default(), &|_, _, _| {});
    let (want, _) = read_all(&one, AssemblyConfig::default());
    // Split the same messages by time into three files named so that name
    // order (2 < 10) differs from lexical order.
    let bag = dir.path().join("bag");
    std::fs::create_dir(&bag).unwrap();
    let log = McapLog::open(&one).unwrap();
    let mut reader = log.reader(ReadFilter::default());
    let mut all = Vec::new();
    while let Some(m) = reader.next_with(|m| {
        (
            m.channel.topic.clone(),
            m.channel.schema_name.clone(),
            m.log_time,
            m.data.to_vec(),
        )
    }) {
        all.push(m.unwrap());
    }
    let third = all.len() / 3;
    for (k, part) in all.chunks(third + 1).enumerate() {
        let name = ["bag_0.mcap", "bag_2.mcap", "bag_10.mcap"][k];
        let mut w = LogWriter::create(&bag.join(name), Compression::Lz4).unwrap();
        for (topic, ty, t, data) in part {
            match ty.as_str() {
                "sensor_msgs/msg/Image" => w.write_raw::<Image>(topic, *t, data),
                "sensor_msgs/msg/CameraInfo" => w.write_raw::<CameraInfo>(topic, *t, data),
                "geometry_msgs/msg/PoseStamped" => w.write_raw::<PoseStamped>(topic, *t, data),
                "latentam_msgs/msg/MaskFeatures" => w.write_raw::<MaskFeatures>(topic, *t, data),
                other => panic!("{other}"),
            }
            .unwrap();
        }
        w.finish().unwrap();
    }
    let (got, _) = read_all(&bag, AssemblyConfig::default());
    assert_eq!(got, want);
}

#[test]
fn tf_poses_are_chained_to_the_camera_frame() {
    let dir = TempDir::new("tf");
    let path = dir.path().join("log.mcap");
    let optical = Pose {
        translation: DVec3::new(0.0, 0.1, 0.2),
        rotation: DQuat::from_rotation_x(-1.0),
    };
    let spec = Spec {
        embeddings: false,
        ..Spec::default()
    };
    write_log(&path, &spec, &|log, i, t| {
        if i == 0 {
            let s = TfMessage {
                transforms: vec![TransformStamped {
                    header: Header::at(0, "base_link"),
                    child_frame_id: "cam",
                    transform: optical,
                }],
            };
            log.write("/tf_static", t as u64, &s).unwrap();
        }
        for dt in [-60 * MS, 60 * MS] {
            let d = TfMessage {
                transforms: vec![TransformStamped {
                    header: Header::at(t + dt, "odom"),
                    child_frame_id: "base_link",
                    transform: pose_at(t + dt),
                }],
            };
            log.write("/tf", (t + dt).max(0) as u64, &d).unwrap();
        }
    });
    let config = AssemblyConfig {
        topics: Topics {
            pose: PoseSource::Tf {
                world_frame: "odom".into(),
                camera_frame: None,
            },
            ..Topics::default()
        },
        ..AssemblyConfig::default()
    };
    let (frames, report) = read_all(&path, config);
    assert_eq!(frames.len(), 6, "{report}");
    for f in &frames {
        let base = pose_at(f.stamp_ns - 60 * MS).interpolate(&pose_at(f.stamp_ns + 60 * MS), 0.5);
        let want = base.compose(&optical);
        assert!((f.pose.translation - want.translation).length() < 1e-9);
        assert!(f.pose.rotation.angle_between(want.rotation) < 1e-9);
    }
}

/// Writes a log with `tweak`, checks `kind` is counted once and `frames`
/// frames come out, then that the stop policy turns it into an error.
fn bad_input(kind: &str, frames_expected: usize, tweak: Tweak<'_>) {
    let dir = TempDir::new("bad");
    let path = dir.path().join("log.mcap");
    write_log(&path, &Spec::default(), tweak);
    let (frames, report) = read_all(&path, AssemblyConfig::default());
    assert_eq!(report.skipped_for(kind), 1, "{kind}: {report}");
    assert_eq!(frames.len(), frames_expected, "{kind}: {report}");
    // The same log under the stop policy ends with an error naming it.
    let config = AssemblyConfig {
        on_bad_input: BadInputPolicy::Stop,
        ..AssemblyConfig::default()
    };
    let result: Result<Vec<Frame>, InputError> = McapFrames::open(&path, config).unwrap().collect();
    let err = result.unwrap_err().to_string();
    assert!(err.contains(kind), "{kind}: {err}");
}

#[test]
fn bad_messages_are_counted_or_stop_the_run() {
    // A pose with NaN, and one with a non-unit quaternion, right at the
    // third frame's stamp replace the good one.
    for (kind, q) in [
        (
            "pose: not finite",
            DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0),
        ),
        (
            "pose: non-unit quaternion",
            DQuat::from_xyzw(0.0, 0.0, 0.0, 0.5),
        ),
    ] {
        // The message is rejected; the frame's pose comes from the others.
        bad_input(kind, 6, &move |log, i, t| {
            if i == 2 {
                let p = PoseStamped {
                    header: Header::at(t, "map"),
                    pose: Pose {
                        translation: DVec3::ZERO,
                        rotation: q,
                    },
                };
                log.write("/camera/pose", t as u64, &p).unwrap();
            }
        });
    }
    // Embeddings whose data length disagrees with count × dim, whose labels
    // reach past the region count, with an unknown dtype, or whose
    // dimension changes mid-log: the embeddings are rejected (the frame
    // keeps its geometry).
    let cases: [(&str, u32, u16, &str); 4] = [
        ("embeddings: size mismatch", 4, 0, "f32"),
        ("embeddings: label out of range", 4, 7, "f16"),
        ("embeddings: unknown dtype", 4, 0, "bf16"),
        ("embeddings: dimension changed", 2, 0, "f16"),
    ];
    for (kind, dim, label, dtype) in cases {
        let dir = TempDir::new("emb");
        let path = dir.path().join("log.mcap");
        write_log(&path, &Spec::default(), &move |log, i, t| {
            if i == 3 {
                let labels: Vec<u8> = [label; (W * H) as usize]
                    .iter()
                    .flat_map(|l| l.to_le_bytes())
                    .collect();
                let data = encode_floats(&vec![1.0; 3 * dim as usize], Dtype::F16);
                let m = MaskFeatures {
                    header: Header::at(t, "cam"),
                    height: H,
                    width: W,
                    labels: cdr::Seq::new(&labels, cdr::Endian::Little),
                    count: 3,
                    dim,
                    dtype,
                    data: &data,
                    model: "test-model",
                };
                log.write("/camera/embeddings", t as u64, &m).unwrap();
            }
        });
        let (frames, report) = read_all(&path, AssemblyConfig::default());
        assert_eq!(report.skipped_for(kind), 1, "{kind}: {report}");
        assert_eq!(frames.len(), 6, "{kind}: {report}");
    }
}

#[test]
fn an_embedding_dimension_beyond_the_limit_is_rejected() {
    // With no regions (count 0) the empty data matches any dim; the dim
    // must still be bounded, since the mapper sizes buffers by it.
    bad_input("embeddings: size mismatch", 6, &|log, i, t| {
        if i == 3 {
            let labels: Vec<u8> = [u16::MAX; (W * H) as usize]
                .iter()
                .flat_map(|l| l.to_le_bytes())
                .collect();
            let m = MaskFeatures {
                header: Header::at(t, "cam"),
                height: H,
                width: W,
                labels: cdr::Seq::new(&labels, cdr::Endian::Little),
                count: 0,
                dim: u32::MAX,
                dtype: "f16",
                data: &[],
                model: "test-model",
            };
            log.write("/camera/embeddings", t as u64, &m).unwrap();
        }
    });
}

#[test]
fn a_model_change_mid_log_is_counted_or_stops_the_run() {
    bad_input("embeddings: model changed", 6, &|log, i, t| {
        if i == 3 {
            let labels: Vec<u8> = [0u16; (W * H) as usize]
                .iter()
                .flat_map(|l| l.to_le_bytes())
                .collect();
            let data = encode_floats(&[1.0; 3 * 4], Dtype::F16);
            let m = MaskFeatures {
                header: Header::at(t, "cam"),
                height: H,
                width: W,
                labels: cdr::Seq::new(&labels, cdr::Endian::Little),
                count: 3,
                dim: 4,
                dtype: "f16",
                data: &data,
                model: "another-model",
            };
            log.write("/camera/embeddings", t as u64, &m).unwrap();
        }
    });
}

#[test]
fn extreme_tolerances_do_not_overflow() {
    // `--tolerance-ms 1e300` becomes i64::MAX nanoseconds.
    let dir = TempDir::new("tolerance");
    let path = dir.path().join("log.mcap");
    write_log(&path, &Spec::default(), &|_, _, _| {});
    for (tolerance_ns, max_pose_gap_ns) in [(i64::MAX, i64::MAX), (i64::MAX, 200 * MS)] {
        let config = AssemblyConfig {
            tolerance_ns,
            max_pose_gap_ns,
            ..AssemblyConfig::default()
        };
        let (frames, report) = read_all(&path, config);
        assert_eq!(frames.len(), 6, "{report}");
    }
}

#[test]
fn corrupt_summary_counts_do_not_overflow() {
    let dir = TempDir::new("stats");
    let path = dir.path().join("log.mcap");
    write_log(&path, &Spec::default(), &|_, _, _| {});
    let log = McapLog::open(&path).unwrap();
    let (total, poses) = (log.total_messages().unwrap(), 33u64);
    assert_eq!(log.message_count("/camera/pose"), Some(poses));
    let mut bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let pose_channel = summary
        .channels
        .iter()
        .find(|(_, c)| c.topic == "/camera/pose")
        .map(|(id, _)| *id)
        .unwrap();
    // The Statistics record (opcode 0x0b, u64 length) starts with the
    // message count; its per-channel counts follow as (u16 id, u64 count).
    let at = (0..bytes.len() - 17)
        .rev()
        .find(|&i| bytes[i] == 0x0b && bytes[i + 9..i + 17] == total.to_le_bytes())
        .expect("a statistics record");
    let huge = (u64::MAX / 2 + 1).to_le_bytes();
    bytes[at + 9..at + 17].copy_from_slice(&huge);
    let mut entry = pose_channel.to_le_bytes().to_vec();
    entry.extend_from_slice(&poses.to_le_bytes());
    let e = at + bytes[at..].windows(10).position(|w| w == entry).unwrap();
    bytes[e + 2..e + 10].copy_from_slice(&huge);
    // Two such files in one rosbag2 folder: the sums overflow.
    let bag = dir.path().join("bag");
    std::fs::create_dir(&bag).unwrap();
    for name in ["a.mcap", "b.mcap"] {
        std::fs::write(bag.join(name), &bytes).unwrap();
    }
    let log = McapLog::open(&bag).unwrap();
    assert_eq!(log.total_messages(), None);
    assert_eq!(log.message_count("/camera/pose"), None);
    // One file alone still reports its (corrupt) counts.
    let one = McapLog::open(&bag.join("a.mcap")).unwrap();
    assert_eq!(one.total_messages(), Some(u64::MAX / 2 + 1));
}

#[test]
fn bad_images_are_rejected_with_their_reason() {
    let depth_image = |encoding: &'static str, fill: u8, len: usize| {
        move |log: &mut LogWriter<std::io::BufWriter<std::fs::File>>, i: usize, t: i64| {
            if i == 1 {
                let data = vec![fill; len];
                let img = Image {
                    header: Header::at(t, "cam"),
                    height: H,
                    width: W,
                    encoding,
                    is_bigendian: false,
                    step: W * 2,
                    data: &data,
                };
                log.write("/camera/depth/image_raw", t as u64, &img)
                    .unwrap();
            }
        }
    };
    bad_input(
        "frame: no valid depth",
        5,
        &depth_image("16UC1", 0, (W * H * 2) as usize),
    );
    bad_input(
        "depth: size mismatch",
        5,
        &depth_image("16UC1", 1, (W * H * 2 - 3) as usize),
    );
    bad_input(
        "depth: unsupported encoding",
        5,
        &depth_image("8UC3", 1, (W * H * 2) as usize),
    );
    // A message whose bytes are not a valid Image at all.
    bad_input("colour: undecodable message", 6, &|log, i, t| {
        if i == 4 {
            log.write_raw::<Image>("/camera/color/image_raw", t as u64 + 1, &[0, 1, 0, 0, 9])
                .unwrap();
        }
    });
}

#[test]
fn damaged_files_give_clear_errors() {
    let dir = TempDir::new("damaged");
    let path = dir.path().join("log.mcap");
    write_log(&path, &Spec::default(), &|_, _, _| {});
    let bytes = std::fs::read(&path).unwrap();

    // Truncated: the summary is gone, the file is read linearly up to the
    // damage, then the error says where.
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let log = McapLog::open(&cut).unwrap();
    assert_eq!(log.unindexed_files().len(), 1);
    let mut frames = McapFrames::from_log(log, AssemblyConfig::default()).unwrap();
    let mut ok = 0;
    let mut err = None;
    for f in &mut frames {
        match f {
            Ok(_) => ok += 1,
            Err(e) => {
                err = Some(e.to_string());
                break;
            }
        }
    }
    let err = err.expect("a truncated log must end in an error");
    assert!(err.contains("truncated"), "{err}");
    assert!(ok >= 1, "frames before the damage are still delivered");

    // A corrupt chunk: flip bytes inside the first chunk's compressed data.
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let chunk = &summary.chunk_indexes[0];
    let start = chunk.compressed_data_offset().unwrap() as usize;
    let mut corrupt = bytes.clone();
    for b in &mut corrupt[start + 10..start + 40] {
        *b ^= 0x5a;
    }
    let bad = dir.path().join("corrupt.mcap");
    std::fs::write(&bad, &corrupt).unwrap();
    let result: Result<Vec<Frame>, InputError> = McapFrames::open(&bad, AssemblyConfig::default())
        .unwrap()
        .collect();
    let err = result.unwrap_err().to_string();
    assert!(err.contains("corrupt"), "{err}");

    // Not an MCAP file at all, and an empty directory.
    std::fs::write(dir.path().join("text.mcap"), b"hello").unwrap();
    let err = McapLog::open(&dir.path().join("text.mcap"))
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("not an MCAP file"), "{err}");
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    assert!(McapLog::open(&empty).is_err());
    assert!(McapLog::open(&dir.path().join("missing.mcap")).is_err());
}

#[test]
fn missing_topics_and_wrong_schemas_are_named() {
    let dir = TempDir::new("schema");
    let path = dir.path().join("log.mcap");
    let mut log = LogWriter::create(&path, Compression::Zstd).unwrap();
    let p = PoseStamped {
        header: Header::at(0, "map"),
        pose: Pose::IDENTITY,
    };
    // A pose where the colour images should be.
    log.write("/camera/color/image_raw", 0, &p).unwrap();
    log.finish().unwrap();
    let err = McapFrames::open(&path, AssemblyConfig::default())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("/camera/depth/image_raw") && err.contains("not in the log"),
        "{err}"
    );
    let config = AssemblyConfig {
        topics: Topics {
            depth: "/camera/color/image_raw".into(),
            camera_info: "/camera/color/image_raw".into(),
            pose: PoseSource::Topic("/camera/color/image_raw".into()),
            ..Topics::default()
        },
        ..AssemblyConfig::default()
    };
    let err = McapFrames::open(&path, config).err().unwrap().to_string();
    assert!(
        err.contains("carries `geometry_msgs/msg/PoseStamped`"),
        "{err}"
    );
}

#[test]
fn every_message_type_round_trips_in_both_byte_orders() {
    fn round<'a, M: RosMessage<'a>>(m: &M, bytes: &mut Vec<Vec<u8>>) {
        for endian in [cdr::Endian::Little, cdr::Endian::Big] {
            bytes.push(m.encode_with(endian));
        }
    }
    let labels: Vec<u8> = [1u16, 2, 3, 65535]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let data = [9u8; 16];
    let mask = MaskFeatures {
        header: Header::at(-5, "x"),
        height: 2,
        width: 2,
        labels: cdr::Seq::new(&labels, cdr::Endian::Little),
        count: 2,
        dim: 4,
        dtype: "f16",
        data: &data,
        model: "m",
    };
    let mut store = Vec::new();
    round(&mask, &mut store);
    for b in &store {
        let back = MaskFeatures::decode(b).unwrap();
        assert_eq!(back.header.stamp.as_nanos(), -5);
        assert_eq!(back.labels.to_vec(), vec![1, 2, 3, 65535]);
        assert_eq!(
            (back.count, back.dim, back.dtype, back.data, back.model),
            (2, 4, "f16", &data[..], "m")
        );
    }
    let vocab = TextEmbeddings {
        header: Header::at(7, ""),
        names: vec!["chair", "", "table lamp"],
        ids: cdr::Seq::new(&[1, 0, 2, 0, 3, 0], cdr::Endian::Little),
        dim: 1,
        dtype: "f32",
        data: &[0; 12],
        model: "clip",
    };
    for endian in [cdr::Endian::Little, cdr::Endian::Big] {
        let b = vocab.encode_with(endian);
        let back = TextEmbeddings::decode(&b).unwrap();
        assert_eq!(back.names, vocab.names);
        assert_eq!(back.ids.to_vec(), vec![1, 2, 3]);
        let odo = Odometry {
            header: Header::at(3, "odom"),
            child_frame_id: "base",
            pose: pose_at(1_500_000_000),
        };
        let b = odo.encode_with(endian);
        let back = Odometry::decode(&b).unwrap();
        assert_eq!((back.child_frame_id, back.pose), ("base", odo.pose));
        let info = CameraInfo::pinhole(Header::at(1, "c"), 640, 480, [500.0, 501.0, 320.0, 240.0]);
        let b = info.encode_with(endian);
        let back = CameraInfo::decode(&b).unwrap();
        assert_eq!(
            (back.k, back.p, back.d.to_vec()),
            (info.k, info.p, vec![0.0; 5])
        );
        let grid = FeatureGrid {
            header: Header::at(2, "c"),
            rows: 2,
            cols: 3,
            dim: 1,
            dtype: "f16",
            data: &[1; 12],
            model: "lseg",
        };
        let b = grid.encode_with(endian);
        let back = FeatureGrid::decode(&b).unwrap();
        assert_eq!((back.rows, back.cols, back.data.len()), (2, 3, 12));
        let c = CompressedImage {
            header: Header::at(2, "c"),
            format: "jpeg",
            data: &[1, 2, 3],
        };
        let b = c.encode_with(endian);
        let back = CompressedImage::decode(&b).unwrap();
        assert_eq!((back.format, back.data), ("jpeg", &[1u8, 2, 3][..]));
    }
}

#[test]
fn recycled_buffers_give_identical_frames() {
    let dir = TempDir::new("recycle");
    let path = dir.path().join("log.mcap");
    write_log(&path, &Spec::default(), &|_, _, _| {});
    let (want, _) = read_all(&path, AssemblyConfig::default());
    let mut frames = McapFrames::open(&path, AssemblyConfig::default()).unwrap();
    let mut got = Vec::new();
    while let Some(f) = frames.next() {
        let f = f.unwrap();
        got.push(f.clone());
        frames.recycle(f);
    }
    assert_eq!(got, want);
}

#[test]
fn reading_by_topic_and_time_range_uses_the_index() {
    let dir = TempDir::new("filter");
    let path = dir.path().join("log.mcap");
    write_log(&path, &Spec::default(), &|_, _, _| {});
    let log = McapLog::open(&path).unwrap();
    let t0 = 1_000_000_000_000u64;
    let filter = ReadFilter {
        topics: Some(vec!["/camera/pose".into()]),
        start_ns: Some(t0 + 100 * MS as u64),
        end_ns: Some(t0 + 300 * MS as u64),
    };
    let mut reader = log.reader(filter);
    let mut times = Vec::new();
    while let Some(m) = reader.next_with(|m| (m.channel.topic.clone(), m.log_time)) {
        let (topic, t) = m.unwrap();
        assert_eq!(topic, "/camera/pose");
        times.push(t);
    }
    // Poses every 20 ms from t0 - 20 ms: [t0 + 100, t0 + 300) holds 10.
    assert_eq!(times.len(), 10, "{times:?}");
    assert!(times.windows(2).all(|w| w[0] < w[1]));
    assert_eq!(times[0], t0 + 100 * MS as u64);

    // A topic the log does not have gives nothing (mcap's indexed reader
    // on its own would give every message), and so no vocabulary.
    let mut reader = log.reader(ReadFilter {
        topics: Some(vec!["/nope".into()]),
        ..Default::default()
    });
    assert!(reader.next_with(|m| m.channel.topic.clone()).is_none());
    assert_eq!(read_vocabulary(&path, "/nope").unwrap(), None);
}

#[test]
fn pose_stamped_matches_golden_bytes() {
    // Written out by hand from the CDR rules: header, sec at payload offset
    // 0, nanosec at 4, the string "odom" as length 5 (incl. NUL) at 8 and
    // bytes 12..17, padding to 24 (doubles align to 8 counted from the
    // payload start), then 7 doubles.
    let mut golden = vec![0u8, 1, 0, 0];
    golden.extend_from_slice(&7i32.to_le_bytes());
    golden.extend_from_slice(&9u32.to_le_bytes());
    golden.extend_from_slice(&5u32.to_le_bytes());
    golden.extend_from_slice(b"odom\0");
    golden.extend_from_slice(&[0; 7]);
    for v in [1.0f64, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0] {
        golden.extend_from_slice(&v.to_le_bytes());
    }
    let msg = PoseStamped {
        header: Header {
            stamp: Time { sec: 7, nanosec: 9 },
            frame_id: "odom",
        },
        pose: Pose {
            translation: DVec3::new(1.0, 2.0, 3.0),
            rotation: DQuat::IDENTITY,
        },
    };
    assert_eq!(msg.encode(), golden);
    let back = PoseStamped::decode(&golden).unwrap();
    assert_eq!((back.header, back.pose), (msg.header, msg.pose));
    // Big-endian: same layout, bytes of each value reversed.
    let be = msg.encode_with(cdr::Endian::Big);
    assert_eq!(&be[..2], &[0, 0]);
    assert_eq!(&be[4..8], &7i32.to_be_bytes());
    assert_eq!(PoseStamped::decode(&be).unwrap().pose, msg.pose);
}

/// A log of `n` messages of 400 KiB of noise on `/blob`, one per
/// millisecond: several chunks (a chunk closes past 1 MiB), whose
/// payloads no compressor shrinks, so a flipped byte stays one flipped
/// byte of a payload.
fn write_blobs(path: &Path, compression: Compression, n: u64) {
    use rand::{RngCore, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut log = LogWriter::create(path, compression).unwrap();
    let mut payload = vec![0u8; 400 << 10];
    for i in 0..n {
        rng.fill_bytes(&mut payload);
        log.write_raw::<Image>("/blob", i * MS as u64, &payload)
            .unwrap();
    }
    log.finish().unwrap();
}

/// Reads every message of `path` through the index (or linearly when it
/// has no summary): the log times delivered, then the error, if any.
fn read_until_error(path: &Path) -> (Vec<u64>, Option<InputError>) {
    let log = McapLog::open(path).unwrap();
    let mut reader = log.reader(ReadFilter::default());
    let mut times = Vec::new();
    while let Some(m) = reader.next_with(|m| m.log_time) {
        match m {
            Ok(t) => times.push(t),
            Err(e) => return (times, Some(e)),
        }
    }
    (times, None)
}

#[test]
fn chunk_crcs_are_checked_before_any_message_is_used() {
    let dir = TempDir::new("crc");
    // The payloads are noise, so compressed chunks store them nearly as
    // they are and the flipped byte still decompresses (to a wrong value).
    for (compression, name) in [
        (Compression::None, "none"),
        (Compression::Lz4, "lz4"),
        (Compression::Zstd, "zstd"),
    ] {
        let path = dir.path().join(format!("{name}.mcap"));
        write_blobs(&path, compression, 12);
        let bytes = std::fs::read(&path).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        assert!(summary.chunk_indexes.len() >= 3, "{name}: too few chunks");
        let (times, err) = read_until_error(&path);
        assert_eq!(times.len(), 12, "{name}: the intact log reads whole");
        assert!(err.is_none(), "{name}: {err:?}");

        // One byte flipped in the middle of the second chunk's data: inside
        // a payload (a chunk holds a few 400 KiB messages and their
        // headers are 31 bytes).
        let chunk = &summary.chunk_indexes[1];
        let data = chunk.compressed_data_offset().unwrap() as usize;
        let mut damaged = bytes.clone();
        damaged[data + chunk.compressed_size as usize / 2] ^= 0x01;
        let at = chunk.chunk_start_offset as usize;
        // The chunk header's CRC: after the opcode, record length, start
        // and end times and uncompressed size.
        let stored = u32::from_le_bytes(damaged[at + 33..at + 37].try_into().unwrap());
        assert_ne!(stored, 0, "the writer stores chunk CRCs");
        let indexed = dir.path().join(format!("{name}-flipped.mcap"));
        std::fs::write(&indexed, &damaged).unwrap();
        // Without the summary: cut where it starts, as a recording that
        // stopped before writing it.
        let footer = mcap::read::footer(&damaged).unwrap();
        let linear = dir.path().join(format!("{name}-flipped-cut.mcap"));
        std::fs::write(&linear, &damaged[..footer.summary_start as usize]).unwrap();
        assert_eq!(McapLog::open(&linear).unwrap().unindexed_files().len(), 1);

        for file in [&indexed, &linear] {
            let (times, err) = read_until_error(file);
            let err =
                err.unwrap_or_else(|| panic!("{}: the damage went unnoticed", file.display()));
            assert!(matches!(err, InputError::Log { .. }), "{err:?}");
            let msg = err.to_string();
            assert!(msg.contains(&file.display().to_string()), "{msg}");
            assert!(
                msg.contains(&format!("chunk at byte {at} is corrupt")),
                "{msg}"
            );
            assert!(
                msg.contains(&format!("CRC mismatch (the chunk says {stored:08x}")),
                "{msg}"
            );
            // Everything delivered came before the damaged chunk.
            assert!(!times.is_empty(), "{msg}: the first chunk is intact");
            assert!(
                times.iter().all(|&t| t < chunk.message_start_time),
                "{}: a message of the damaged chunk was used: {times:?}",
                file.display()
            );
        }
    }
}

#[test]
fn a_flipped_pixel_in_an_uncompressed_log_stops_the_frames() {
    let dir = TempDir::new("crc-frames");
    let path = dir.path().join("log.mcap");
    let spec = Spec {
        compression: Compression::None,
        ..Spec::default()
    };
    write_log(&path, &spec, &|_, _, _| {});
    let mut bytes = std::fs::read(&path).unwrap();
    // A pixel of the fourth colour image.
    let pixels = color_bytes(3);
    let pos = bytes
        .windows(pixels.len())
        .position(|w| w == pixels)
        .expect("uncompressed chunks hold the pixels as written");
    bytes[pos + 10] ^= 0x80;
    std::fs::write(&path, &bytes).unwrap();
    let mut frames = McapFrames::open(&path, AssemblyConfig::default()).unwrap();
    let err = frames
        .find_map(|f| f.err())
        .expect("a damaged chunk is an error");
    assert!(err.to_string().contains("CRC mismatch"), "{err}");
    // The log is one chunk, so nothing of it became a frame.
    assert_eq!(frames.report().frames, 0);
    // Without its summary, the damaged chunk hides every topic: the error
    // says why rather than only that they are missing.
    let footer = mcap::read::footer(&bytes).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..footer.summary_start as usize]).unwrap();
    let err = McapFrames::open(&cut, AssemblyConfig::default())
        .err()
        .expect("no topic can be found")
        .to_string();
    assert!(
        err.contains("became unreadable") && err.contains("CRC mismatch"),
        "{err}"
    );
}

/// Depth stamped in another optical frame than colour is a lens the
/// mapper would mistake for the colour one: the frames are still made, and
/// the report says why their depth may be off, once.
#[test]
fn depth_in_another_camera_frame_is_a_warning() {
    let dir = TempDir::new("depth-frame");
    let path = dir.path().join("log.mcap");
    write_log(
        &path,
        &Spec {
            depth_frame: "camera_depth_optical_frame",
            ..Spec::default()
        },
        &|_, _, _| {},
    );
    let (frames, report) = read_all(&path, AssemblyConfig::default());
    assert_eq!(frames.len(), 6, "{report}");
    assert_eq!(report.warnings.len(), 1, "{report}");
    let w = &report.warnings[0];
    assert!(
        w.contains("`camera_depth_optical_frame`") && w.contains("`cam`"),
        "{w}"
    );
    assert!(
        report.to_string().contains("warning: depth images"),
        "{report}"
    );
    // Registered depth (same frame) says nothing.
    let path = dir.path().join("registered.mcap");
    write_log(&path, &Spec::default(), &|_, _, _| {});
    let (_, report) = read_all(&path, AssemblyConfig::default());
    assert!(report.warnings.is_empty(), "{report}");
}

/// Raw depth from a second lens, with that lens's camera info and the
/// static transform between the lenses in the log, is registered to the
/// colour camera while reading: each frame's depth is what
/// `DepthRegistration` makes of the raw image, and the report says so.
#[test]
fn depth_from_another_lens_is_registered_from_the_log_itself() {
    let dir = TempDir::new("depth-registered");
    let path = dir.path().join("raw.mcap");
    let (depth_lens, offset) = ([6.5, 6.0, 3.0, 2.0], DVec3::new(-0.3, 0.05, 0.0));
    let mount = Pose {
        translation: offset,
        rotation: DQuat::from_rotation_y(0.05),
    };
    // A log whose depth lens has its camera info, and with `tf` the
    // static transform that places it.
    let raw_log = |path: &Path, tf: bool| {
        write_log(
            path,
            &Spec {
                depth_frame: "depth_optical",
                ..Spec::default()
            },
            &|log, i, t| {
                if i > 0 {
                    return;
                }
                let info = CameraInfo::pinhole(Header::at(t, "depth_optical"), W, H, depth_lens);
                log.write("/camera/depth/camera_info", t as u64, &info)
                    .unwrap();
                if tf {
                    let s = TfMessage {
                        transforms: vec![TransformStamped {
                            header: Header::at(0, "cam"),
                            child_frame_id: "depth_optical",
                            transform: mount,
                        }],
                    };
                    log.write("/tf_static", t as u64, &s).unwrap();
                }
            },
        )
    };
    raw_log(&path, true);
    let (registered, report) = read_all(&path, AssemblyConfig::default());
    assert_eq!(registered.len(), 6, "{report}");
    assert!(report.warnings.is_empty(), "{report}");
    assert_eq!(report.notes.len(), 1, "{report}");
    assert!(
        report
            .to_string()
            .contains("note: depth images in frame `depth_optical` registered"),
        "{report}"
    );
    // The same log read as recorded (no depth camera info: a warning).
    let unregistered = AssemblyConfig {
        topics: Topics {
            depth_camera_info: String::new(),
            ..Topics::default()
        },
        ..AssemblyConfig::default()
    };
    let (raw, report) = read_all(&path, unregistered);
    assert_eq!(report.warnings.len(), 1, "{report}");
    assert!(
        report.warnings[0].contains("cannot be registered"),
        "{report}"
    );
    let reg = DepthRegistration {
        depth: depth_lens,
        colour: [5.0, 5.0, 3.5, 2.5],
        rotation: mount.rotation,
        translation: offset,
    };
    let mut moved = 0;
    for (r, f) in raw.iter().zip(&registered) {
        let DepthData::Units { values, .. } = &r.depth.data else {
            panic!("16-bit depth")
        };
        let want = reg.register(
            W as usize, H as usize, values, 1000.0, W as usize, H as usize,
        );
        let DepthData::Units { values: got, .. } = &f.depth.data else {
            panic!("16-bit depth")
        };
        assert_eq!(got, &want, "frame at {} ns", f.stamp_ns);
        moved += got.iter().zip(values).filter(|(a, b)| a != b).count();
    }
    assert!(moved > 0, "registration moved no depth sample");
    // Without the transform, the warning names what is missing.
    let path = dir.path().join("no-tf.mcap");
    raw_log(&path, false);
    let (_, report) = read_all(&path, AssemblyConfig::default());
    assert!(report.notes.is_empty(), "{report}");
    assert!(
        report.warnings[0].contains("/tf_static does not place it"),
        "{report}"
    );
}
