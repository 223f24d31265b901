//! Implausible input counted as bad input, and frames whose stamps go
//! back in time paired all the same.

use super::*;

/// What one log entry writes: at log time `log_ms`, the parts of frame
/// `id` stamped `stamp_ms` (all relative to a base time). Depth values
/// encode the frame (1000 + id mm), colour bytes too.
struct Entry {
    log_ms: i64,
    stamp_ms: i64,
    id: u8,
    color: bool,
    depth: bool,
}

fn entry(log_ms: i64, stamp_ms: i64, id: u8) -> Entry {
    Entry {
        log_ms,
        stamp_ms,
        id,
        color: true,
        depth: true,
    }
}

fn write_entries(path: &Path, entries: &[Entry]) {
    let mut log = LogWriter::create(path, Compression::None).unwrap();
    let t0 = 1_000_000_000_000i64;
    for e in entries {
        let lt = (t0 + e.log_ms * MS) as u64;
        let t = t0 + e.stamp_ms * MS;
        let pose = PoseStamped {
            header: Header::at(t, "map"),
            pose: pose_at(t),
        };
        log.write("/camera/pose", lt, &pose).unwrap();
        let info = CameraInfo::pinhole(Header::at(t, "cam"), W, H, [5.0, 5.0, 3.5, 2.5]);
        log.write("/camera/color/camera_info", lt, &info).unwrap();
        let data = color_bytes(e.id);
        let img = Image::packed(Header::at(t, "cam"), W, H, "rgb8", &data);
        if e.color {
            log.write("/camera/color/image_raw", lt, &img).unwrap();
        }
        let data = depth_bytes(1000 + e.id as u16);
        let depth = Image {
            encoding: "16UC1",
            step: W * 2,
            data: &data,
            ..img
        };
        if e.depth {
            log.write("/camera/depth/image_raw", lt, &depth).unwrap();
        }
    }
    log.finish().unwrap();
}

/// One frame every 100 ms of log time, frame `i` stamped `stamps[i]` ms.
fn write_restamped(path: &Path, stamps: &[i64]) {
    let entries: Vec<Entry> = stamps
        .iter()
        .enumerate()
        .map(|(i, &ms)| entry(i as i64 * 100, ms, i as u8))
        .collect();
    write_entries(path, &entries);
}

/// Each frame's depth is its own (1000 + id mm, id in its colour bytes).
fn own_depth(frames: &[Frame]) {
    for f in frames {
        let i = f.color.data[0] as u16;
        assert_eq!(f.depth.metres(0), Some((1000 + i) as f32 * 0.001));
    }
}

#[test]
fn frames_stamped_back_in_time_keep_their_partners() {
    let dir = TempDir::new("restamped");
    let path = dir.path().join("log.mcap");
    // The fourth frame is stamped 150 ms, after the third at 200 ms (log
    // time and file order unchanged): its depth has the same stamp.
    write_restamped(&path, &[0, 100, 200, 150, 400, 500]);
    let (frames, report) = read_all(&path, AssemblyConfig::default());
    assert_eq!(report.total_skipped(), 0, "{report}");
    assert_eq!(frames.len(), 6, "{report}");
    own_depth(&frames);
    let stamps: Vec<i64> = frames.iter().map(|f| f.stamp_ns / MS % 1000).collect();
    assert_eq!(stamps, [0, 100, 150, 200, 400, 500]);
}

#[test]
fn a_late_frame_is_paired_or_counted_as_out_of_order() {
    let dir = TempDir::new("late");
    let path = dir.path().join("log.mcap");
    // Stamped 50 ms, arriving whole after frames up to 300 ms were
    // resolved: paired with its own depth all the same.
    write_restamped(&path, &[0, 100, 200, 300, 400, 50, 600, 700]);
    let (frames, report) = read_all(&path, AssemblyConfig::default());
    assert_eq!(report.total_skipped(), 0, "{report}");
    assert_eq!(frames.len(), 8, "{report}");
    own_depth(&frames);
    // Its depth came in time but its colour image only after frames past
    // 50 ms + the tolerance released it: counted for what happened.
    let mut entries: Vec<Entry> = (0..6).map(|i| entry(i * 100, i * 100, i as u8)).collect();
    entries.insert(
        1,
        Entry {
            color: false,
            ..entry(50, 50, 9)
        },
    );
    entries.push(Entry {
        depth: false,
        ..entry(550, 50, 9)
    });
    let path = dir.path().join("late.mcap");
    write_entries(&path, &entries);
    let (frames, report) = read_all(&path, AssemblyConfig::default());
    assert_eq!(report.skipped_for("frame: out of order"), 1, "{report}");
    assert_eq!(report.skipped_for("depth: unpaired"), 1, "{report}");
    assert_eq!(frames.len(), 6, "{report}");
}

#[test]
fn implausible_positions_and_depths_are_counted() {
    let dir = TempDir::new("extent");
    let path = dir.path().join("log.mcap");
    write_log(&path, &Spec::default(), &|_, _, _| {});
    // The test poses sit 1000 to 2000 m from the origin.
    let (frames, report) = read_all(
        &path,
        AssemblyConfig {
            max_extent_m: 1500.0,
            ..AssemblyConfig::default()
        },
    );
    assert!(frames.is_empty());
    let n = report.skipped_for("frame: position beyond the world extent");
    assert_eq!(n, 6, "{report}");
    // Depth of about 1 m against a limit of 0.5 m: nothing valid is left.
    let (frames, report) = read_all(
        &path,
        AssemblyConfig {
            max_depth_m: 0.5,
            ..AssemblyConfig::default()
        },
    );
    assert!(frames.is_empty());
    assert_eq!(report.skipped_for("frame: no valid depth"), 6, "{report}");
    // Samples beyond the limit are invalidated one by one.
    let mut d = DepthImage {
        width: 3,
        height: 1,
        data: DepthData::Metres(vec![1.0, 1e30, f32::NAN]),
    };
    d.invalidate_beyond(100.0);
    assert_eq!(
        (d.metres(0), d.metres(1), d.metres(2)),
        (Some(1.0), None, None)
    );
    let mut d = DepthImage {
        width: 2,
        height: 1,
        data: DepthData::Units {
            values: vec![1000, 60000],
            metres_per_unit: 0.01,
        },
    };
    d.invalidate_beyond(100.0);
    assert_eq!((d.metres(0), d.metres(1)), (Some(10.0), None));
}

#[test]
fn implausible_intrinsics_are_refused() {
    let k = |fx: f64, cx: f64, cy: f64| Intrinsics {
        width: 640,
        height: 480,
        fx,
        fy: fx,
        cx,
        cy,
    };
    assert!(super::parts::check_intrinsics(&k(525.0, 319.5, 239.5)).is_ok());
    // Wide and narrow lenses are fine.
    assert!(super::parts::check_intrinsics(&k(40.0, 320.0, 240.0)).is_ok());
    assert!(super::parts::check_intrinsics(&k(30000.0, 320.0, 240.0)).is_ok());
    for (bad, why) in [
        (k(525.0, 1e30, 240.0), "principal point"),
        (k(525.0, 320.0, -3.0), "principal point"),
        (k(1e-30, 320.0, 240.0), "focal length"),
        (k(1e9, 320.0, 240.0), "focal length"),
    ] {
        let r = super::parts::check_intrinsics(&bad).unwrap_err();
        assert_eq!(r.kind, "frame: implausible intrinsics");
        assert!(r.detail.contains(why), "{r}");
    }
}

#[test]
fn unusable_region_embeddings_are_refused_one_by_one() {
    // Frame 2 carries region 0 with a NaN and region 2 all zero; frame 4 has
    // nothing usable.
    let dir = TempDir::new("regions");
    let path = dir.path().join("log.mcap");
    write_log(&path, &Spec::default(), &|log, i, t| {
        let rows: [[f32; 4]; 3] = match i {
            2 => [[f32::NAN, 1.0, 0.0, 0.0], [1.0, 2.0, 3.0, 4.0], [0.0; 4]],
            4 => [[f32::INFINITY, 0.0, 0.0, 0.0], [0.0; 4], [0.0; 4]],
            _ => return,
        };
        let labels: Vec<u8> = (0..W * H)
            .flat_map(|p| ((p % 3) as u16).to_le_bytes())
            .collect();
        let data = encode_floats(rows.as_flattened(), Dtype::F32);
        let m = MaskFeatures {
            header: Header::at(t, "cam"),
            height: H,
            width: W,
            labels: cdr::Seq::new(&labels, cdr::Endian::Little),
            count: 3,
            dim: 4,
            dtype: "f32",
            data: &data,
            model: "test-model",
        };
        log.write("/camera/embeddings", t as u64, &m).unwrap();
    });
    let (frames, report) = read_all(&path, AssemblyConfig::default());
    assert_eq!(frames.len(), 6, "{report}");
    assert_eq!(
        report.skipped_for("embeddings: region with non-finite values"),
        2,
        "{report}"
    );
    assert_eq!(
        report.skipped_for("embeddings: region with zero norm"),
        3,
        "{report}"
    );
    let e = frames[2].embeddings.as_ref().unwrap();
    let EmbeddingLayout::Regions(l) = &e.layout else {
        panic!("regions expected")
    };
    // Regions 0 and 2 lost their pixels and their vectors; region 1 kept.
    assert!(l.labels.iter().all(|&x| x == 1 || x == u16::MAX));
    assert_eq!(l.labels.iter().filter(|&&x| x == 1).count(), 16);
    let v = e.to_f32();
    assert!(v.iter().all(|x| x.is_finite()));
    assert_eq!(&v[4..8], &[1.0, 2.0, 3.0, 4.0]);
    // With nothing usable in the message at its stamp, frame 4 takes the
    // next nearest (the log's own, 1 ms later).
    let e = frames[4].embeddings.as_ref().unwrap();
    assert_eq!(e.to_f32()[5], 5.0 + 4.0);
    // Under the stop policy the first refusal ends the read.
    let config = AssemblyConfig {
        on_bad_input: BadInputPolicy::Stop,
        ..AssemblyConfig::default()
    };
    let result: Result<Vec<Frame>, InputError> = McapFrames::open(&path, config).unwrap().collect();
    let err = result.unwrap_err().to_string();
    assert!(err.contains("region with non-finite values"), "{err}");
}

#[test]
fn vocabularies_with_duplicates_or_unusable_vectors_are_refused() {
    let dir = TempDir::new("vocab");
    for (names, values, why) in [
        (
            vec!["wall", "door", "wall"],
            vec![1.0f32, 0.0, 0.0, 1.0, 1.0, 1.0],
            "duplicate name",
        ),
        (
            vec!["wall", "door"],
            vec![1.0, f32::NAN, 0.0, 1.0],
            "unusable vector",
        ),
        (
            vec!["wall", "door"],
            vec![1.0, 1.0, 0.0, 0.0],
            "unusable vector",
        ),
    ] {
        let path = dir.path().join("v.mcap");
        let mut log = LogWriter::create(&path, Compression::None).unwrap();
        let ids: Vec<u8> = (0..names.len() as u16)
            .flat_map(|i| i.to_le_bytes())
            .collect();
        let data = encode_floats(&values, Dtype::F32);
        let v = TextEmbeddings {
            header: Header::at(0, ""),
            names: names.clone(),
            ids: cdr::Seq::new(&ids, cdr::Endian::Little),
            dim: 2,
            dtype: "f32",
            data: &data,
            model: "m",
        };
        log.write("/vocabulary", 0, &v).unwrap();
        log.finish().unwrap();
        let e = read_vocabulary(&path, "/vocabulary")
            .unwrap_err()
            .to_string();
        assert!(e.contains(why), "{e}");
    }
}

#[test]
fn a_frame_seen_twice_is_counted_as_a_duplicate_not_mapped_twice() {
    let dir = TempDir::new("dup");
    let bag = dir.path().join("bag");
    std::fs::create_dir(&bag).unwrap();
    // The same recording twice in one bag folder.
    write_restamped(&bag.join("bag_0.mcap"), &[0, 100, 200, 300]);
    std::fs::copy(bag.join("bag_0.mcap"), bag.join("bag_1.mcap")).unwrap();
    let (frames, report) = read_all(&bag, AssemblyConfig::default());
    assert_eq!(frames.len(), 4, "{report}");
    assert_eq!(report.skipped_for("frame: duplicate stamp"), 4, "{report}");
    own_depth(&frames);
}
