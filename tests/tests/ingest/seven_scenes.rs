//! 7-Scenes converted: pixels, depth and poses kept, depth registered to
//! colour, and the raw depth bag read as the registered log.

use super::*;

#[test]
fn seven_scenes_frames_keep_their_pixels_depth_and_poses_unregistered() {
    let src = shared_data("7scenes-redkitchen");
    let dir = TempDir::new("7s");
    let out = dir.join("7s.mcap");
    let summary = convert(
        datasets::seven_scenes(&src, 30.0).unwrap(),
        &ConvertOptions {
            registration: Registration::Off,
            ..options("7scenes", EmbeddingSource::None, Some(8))
        },
        &out,
        |_, _| {},
    )
    .unwrap();
    assert_eq!(summary.frames, 8);
    let (frames, report) = frames_of(&out);
    assert_eq!(frames.len(), 8, "{report}");
    assert_eq!(report.total_skipped(), 0, "{report}");
    for (i, f) in frames.iter().enumerate() {
        let id = format!("frame-{i:06}");
        let jpeg = std::fs::read(src.join(format!("{id}.color.jpg"))).unwrap();
        assert_eq!(f.color, codec::decode_jpeg(&jpeg).unwrap(), "{id}: colour");
        let png = std::fs::read(src.join(format!("{id}.depth.png"))).unwrap();
        let (w, h, mm) = codec::decode_png_u16(&png).unwrap();
        assert_eq!((w, h), (640, 480));
        assert_eq!(
            depth_units(f),
            &mm[..],
            "{id}: depth must be unchanged millimetres"
        );
        assert_eq!(
            (f.intrinsics.fx, f.intrinsics.cx, f.intrinsics.cy),
            (585.0, 320.0, 240.0)
        );
        let text = std::fs::read_to_string(src.join(format!("{id}.pose.txt"))).unwrap();
        let m: Vec<f64> = text
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        let want_t = DVec3::new(m[3], m[7], m[11]);
        assert!((f.pose.translation - want_t).length() < 1e-9, "{id}");
        // The rotation maps camera axes to the matrix's columns (KinectFusion
        // rotations are orthonormal to ~2e-4 only).
        for c in 0..3 {
            let col = DVec3::new(m[c], m[4 + c], m[8 + c]);
            let mut axis = DVec3::ZERO;
            axis[c] = 1.0;
            assert!(
                (f.pose.rotation * axis - col).length() < 5e-4,
                "{id} column {c}"
            );
        }
    }
}

/// How well frame `i`'s colours agree with frame `j`'s on the surfaces
/// both see (every 2nd pixel of `i` with depth, moved into `j` through
/// depth, intrinsics and poses, kept where `j`'s depth agrees within 3 cm):
/// PSNR on the 0-255 scale.
fn cross_view_psnr(a: &Frame, b: &Frame) -> f64 {
    let (da, db) = (depth_units(a), depth_units(b));
    let (ka, kb) = (&a.intrinsics, &b.intrinsics);
    let (w, h) = (kb.width as i64, kb.height as i64);
    let (mut sse, mut n) = (0.0, 0u64);
    for y in (0..ka.height).step_by(2) {
        for x in (0..ka.width).step_by(2) {
            let d = da[(y * ka.width + x) as usize];
            if d == 0 {
                continue;
            }
            let z = d as f64 / 1000.0;
            let local = DVec3::new(
                (x as f64 - ka.cx) / ka.fx * z,
                (y as f64 - ka.cy) / ka.fy * z,
                z,
            );
            let world = a.pose.rotation * local + a.pose.translation;
            let p = b.pose.rotation.inverse() * (world - b.pose.translation);
            if p.z <= 0.1 {
                continue;
            }
            let u = (kb.fx * p.x / p.z + kb.cx).round() as i64;
            let v = (kb.fy * p.y / p.z + kb.cy).round() as i64;
            if u < 0 || v < 0 || u >= w || v >= h {
                continue;
            }
            let seen = db[(v * w + u) as usize] as f64 / 1000.0;
            if seen == 0.0 || (seen - p.z).abs() > 0.03 {
                continue;
            }
            let (ca, cb) = (a.color.rgb(x, y), b.color.rgb(u as u32, v as u32));
            for c in 0..3 {
                sse += (ca[c] as f64 - cb[c] as f64).powi(2);
            }
            n += 3;
        }
    }
    assert!(n > 10_000, "{n} samples");
    10.0 * (255.0f64.powi(2) / (sse / n as f64)).log10()
}

/// 7-Scenes colour is not registered to depth: the converter re-projects
/// depth into the measured colour lens and moves the poses to it. The
/// same surface must then look alike from two frames, as it does not
/// unregistered (measured: 2.5-4.5 dB better, docs/quality.md "Map fidelity").
#[test]
fn seven_scenes_depth_is_registered_to_colour() {
    let dir = TempDir::new("7s-registered");
    let frames = |registration, name: &str| {
        let out = dir.join(name);
        let summary = convert_seven_scenes(
            &out,
            ConvertOptions {
                registration,
                ..options("7scenes", EmbeddingSource::None, Some(41))
            },
        );
        assert!(
            summary.notes.iter().any(|n| n.contains("registered")),
            "{:?}",
            summary.notes
        );
        let (frames, report) = frames_of(&out);
        assert_eq!(frames.len(), 41, "{report}");
        frames
    };
    let raw = frames(Registration::Off, "raw.mcap");
    let registered = frames(Registration::Dataset, "registered.mcap");
    let k = &registered[0].intrinsics;
    assert_eq!((k.width, k.height), (640, 480));
    assert!(
        (k.fx - 0.905 * 585.0).abs() < 1e-9 && k.cy == 239.0,
        "{k:?}"
    );
    // The colour lens sits 2.27 cm along the depth camera's x axis.
    for (r, g) in raw.iter().zip(&registered) {
        let moved = r.pose.rotation.inverse() * (g.pose.translation - r.pose.translation);
        assert!(
            (moved - DVec3::new(12.0 / 529.425, 0.0, 0.0)).length() < 1e-6,
            "{moved}"
        );
    }
    let mut gains = Vec::new();
    for (i, j) in [(0, 4), (10, 14), (0, 20), (20, 40)] {
        let before = cross_view_psnr(&raw[i], &raw[j]);
        let after = cross_view_psnr(&registered[i], &registered[j]);
        eprintln!("frames {i} -> {j}: {before:.2} dB unregistered, {after:.2} dB registered");
        gains.push(after - before);
    }
    let mean = gains.iter().sum::<f64>() / gains.len() as f64;
    assert!(mean > 1.5, "registration gained {gains:?} dB");
}

/// 7-Scenes written as a Kinect bag recorded without registration (raw
/// depth in its own optical frame, the depth lens's camera info, the
/// 2.27 cm between the lenses on `/tf_static`) reads as the same frames as
/// the log `convert` registered: the reader registers it from the bag
/// itself, sample for sample, so the two map alike.
#[test]
fn seven_scenes_as_a_raw_depth_bag_reads_as_the_registered_log() {
    let dir = TempDir::new("7s-raw-bag");
    let write = |raw_depth, name: &str| {
        let out = dir.join(name);
        convert_seven_scenes(
            &out,
            ConvertOptions {
                raw_depth,
                ..options("7scenes", EmbeddingSource::None, Some(12))
            },
        );
        out
    };
    let (registered, _) = frames_of(&write(false, "registered.mcap"));
    let bag = write(true, "raw.mcap");
    let (read, report) = frames_of(&bag);
    assert_eq!(read.len(), 12, "{report}");
    assert!(report.warnings.is_empty(), "{report}");
    assert!(
        report
            .notes
            .iter()
            .any(|n| n.contains("registered to the colour camera") && n.contains("2.27 cm")),
        "{report}"
    );
    for (a, b) in read.iter().zip(&registered) {
        assert_eq!((a.stamp_ns, a.intrinsics), (b.stamp_ns, b.intrinsics));
        assert_eq!(a.pose, b.pose);
        let (da, db) = (a.depth.to_metres(), b.depth.to_metres());
        let differ = da.iter().zip(&db).filter(|(x, y)| x != y).count();
        assert_eq!(
            (differ, a.depth.width, a.depth.height),
            (0, b.depth.width, b.depth.height),
            "frame at {} ns: depth samples that differ",
            a.stamp_ns
        );
    }
    // The bag's depth itself is the raw 640×480 image in its own frame.
    let log = latentam_io::McapLog::open(&bag).unwrap();
    let topics: Vec<String> = log.channels().iter().map(|c| c.topic.clone()).collect();
    for t in ["/camera/depth/camera_info", "/tf_static"] {
        assert!(topics.iter().any(|x| x == t), "{topics:?}");
    }
}
