//! Every message type through the writer and the reader, recycled
//! buffers, indexed reading and golden bytes.

use super::*;

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
