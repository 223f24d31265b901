//! Bad messages, images and files: counted, or stopping the run with a
//! clear error.

use super::*;

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
