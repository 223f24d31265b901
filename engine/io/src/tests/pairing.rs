//! Frames paired by stamp with interpolated poses, split rosbag2 folders
//! read as one log, and TF chains to the camera frame.

use super::*;

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
