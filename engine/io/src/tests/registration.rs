//! Depth from another camera frame or another lens.

use super::*;

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
