//! Topics chosen by message type: a bag laid out as a RealSense driver
//! records it, with poses only in TF, maps with no topic named.

use super::*;

const COLOR: &str = "/camera/camera/color/image_raw";
const DEPTH: &str = "/camera/camera/aligned_depth_to_color/image_raw";

/// A RealSense-like bag of 4 frames; `extra_depth` adds a second
/// depth-named topic that preferences cannot tell apart.
fn write_realsense_bag(path: &Path, extra_depth: bool) {
    let mut log = LogWriter::create(path, Compression::None).unwrap();
    let t0 = 1_000_000_000_000i64;
    let optical = Pose {
        translation: DVec3::new(0.0, 0.05, 0.0),
        rotation: DQuat::from_rotation_x(-1.5),
    };
    let s = TfMessage {
        transforms: vec![TransformStamped {
            header: Header::at(t0, "camera_link"),
            child_frame_id: "camera_color_optical_frame",
            transform: optical,
        }],
    };
    log.write("/tf_static", t0 as u64, &s).unwrap();
    for i in -1..6i64 {
        let t = t0 + i * 50 * MS;
        let d = TfMessage {
            transforms: vec![TransformStamped {
                header: Header::at(t, "map"),
                child_frame_id: "camera_link",
                transform: pose_at(t),
            }],
        };
        log.write("/tf", t.max(0) as u64, &d).unwrap();
    }
    for i in 0..4i64 {
        let t = t0 + i * 50 * MS;
        let lt = t as u64;
        for info in [
            "/camera/camera/color/camera_info",
            "/camera/camera/depth/camera_info",
        ] {
            let k = CameraInfo::pinhole(
                Header::at(t, "camera_color_optical_frame"),
                W,
                H,
                [5.0, 5.0, 3.5, 2.5],
            );
            log.write(info, lt, &k).unwrap();
        }
        let data = color_bytes(i as u8);
        let img = Image::packed(
            Header::at(t, "camera_color_optical_frame"),
            W,
            H,
            "rgb8",
            &data,
        );
        log.write(COLOR, lt, &img).unwrap();
        // The driver's compressed twin and an infrared stream: not colour.
        let twin = CompressedImage {
            header: Header::at(t, "camera_color_optical_frame"),
            format: "jpeg",
            data: &[0xff, 0xd8],
        };
        log.write(&format!("{COLOR}/compressed"), lt, &twin)
            .unwrap();
        let ir = Image {
            encoding: "mono8",
            step: W,
            data: &data[..(W * H) as usize],
            ..img
        };
        log.write("/camera/camera/infra1/image_rect_raw", lt, &ir)
            .unwrap();
        let data = depth_bytes(1000 + i as u16);
        let depth = Image {
            encoding: "16UC1",
            step: W * 2,
            data: &data,
            ..img
        };
        log.write(DEPTH, lt, &depth).unwrap();
        log.write("/camera/camera/depth/image_rect_raw", lt, &depth)
            .unwrap();
        if extra_depth {
            log.write("/camera/camera/depth_registered/image_raw", lt, &depth)
                .unwrap();
            log.write("/camera/camera/depth/image_raw", lt, &depth)
                .unwrap();
        }
    }
    log.finish().unwrap();
}

fn choosing() -> AssemblyConfig {
    AssemblyConfig {
        choose: TopicChoice::all(),
        ..AssemblyConfig::default()
    }
}

#[test]
fn a_realsense_bag_with_tf_poses_maps_with_no_topic_named() {
    let dir = TempDir::new("plan");
    let path = dir.path().join("rs.mcap");
    write_realsense_bag(&path, false);
    // Without choosing, the default topics are missing.
    assert!(McapFrames::open(&path, AssemblyConfig::default()).is_err());
    let mut frames = McapFrames::open(&path, choosing()).unwrap();
    let t = frames.topics().clone();
    assert_eq!((t.color.as_str(), t.depth.as_str()), (COLOR, DEPTH));
    assert_eq!(t.camera_info, "/camera/camera/color/camera_info");
    assert!(matches!(&t.pose, PoseSource::Tf { world_frame, .. } if world_frame.is_empty()));
    let plan = frames.topic_plan().join("\n");
    assert!(
        plan.contains("colour: /camera/camera/color/image_raw"),
        "{plan}"
    );
    assert!(plan.contains("/tf + /tf_static"), "{plan}");
    let all: Vec<Frame> = (&mut frames).map(|f| f.unwrap()).collect();
    assert_eq!(all.len(), 4, "{}", frames.report());
    for (i, f) in all.iter().enumerate() {
        assert_eq!(f.depth.metres(0), Some((1000 + i as u16) as f32 * 0.001));
        // Pose: the map → camera_link track composed with the optical mount.
        let optical = Pose {
            translation: DVec3::new(0.0, 0.05, 0.0),
            rotation: DQuat::from_rotation_x(-1.5),
        };
        let want = pose_at(f.stamp_ns).compose(&optical);
        assert!((f.pose.translation - want.translation).length() < 1e-9);
    }
}

#[test]
fn an_ambiguous_choice_names_the_candidates_and_the_flag() {
    let dir = TempDir::new("plan-ambiguous");
    let path = dir.path().join("rs.mcap");
    write_realsense_bag(&path, true);
    // Four depth-named topics: `aligned_depth_to_color` is preferred,
    // then `depth_registered` (both registered to colour).
    let frames = McapFrames::open(&path, choosing()).unwrap();
    assert_eq!(frames.topics().depth, DEPTH);
    let all = McapLog::open(&path).unwrap().channels();
    let without = |gone: &[&str]| -> Vec<_> {
        all.iter()
            .filter(|c| !gone.contains(&c.topic.as_str()))
            .cloned()
            .collect()
    };
    let registered = "/camera/camera/depth_registered/image_raw";
    let (topics, _) = plan_topics(&without(&[DEPTH]), &choosing()).unwrap();
    assert_eq!(topics.depth, registered);
    // Without them, two equally good candidates: an error naming both and
    // the flag that settles it.
    let e = plan_topics(&without(&[DEPTH, registered]), &choosing())
        .unwrap_err()
        .to_string();
    for want in [
        "/camera/camera/depth/image_raw",
        "/camera/camera/depth/image_rect_raw",
        "--depth-topic",
    ] {
        assert!(e.contains(want), "{e}");
    }
    // A topic named but absent is an error as before, not a choice.
    let mut config = choosing();
    config.topics.depth = "/nope".into();
    config.choose.depth = false;
    let e = McapFrames::open(&path, config).err().unwrap().to_string();
    assert!(e.contains("/nope") && e.contains("not in the log"), "{e}");
}

/// A bag with the default depth topic and the driver's registered depth
/// beside it reads the registered one (the default would be a second
/// lens); a depth topic the user names is read as named.
#[test]
fn registered_depth_is_preferred_over_the_raw_default() {
    let ty = Image::TYPE_NAME;
    let channels = [
        Channel::ros2("/camera/color/image_raw", ty),
        Channel::ros2("/camera/color/camera_info", CameraInfo::TYPE_NAME),
        Channel::ros2("/camera/pose", PoseStamped::TYPE_NAME),
        Channel::ros2("/camera/depth/image_raw", ty),
        Channel::ros2("/camera/depth_registered/image_raw", ty),
    ];
    let (topics, plan) = plan_topics(&channels, &choosing()).unwrap();
    assert_eq!(topics.depth, "/camera/depth_registered/image_raw");
    assert!(
        plan.iter()
            .any(|l| l.contains("preferred over /camera/depth/image_raw")),
        "{plan:?}"
    );
    let mut named = choosing();
    named.choose.depth = false;
    let (topics, _) = plan_topics(&channels, &named).unwrap();
    assert_eq!(topics.depth, "/camera/depth/image_raw");
    // Only the raw one: it is read (and the frame ids tell if it is
    // unregistered, see `depth_in_another_camera_frame_is_a_warning`).
    let (topics, plan) = plan_topics(&channels[..4], &choosing()).unwrap();
    assert_eq!(topics.depth, "/camera/depth/image_raw");
    assert!(plan.iter().all(|l| !l.starts_with("depth")), "{plan:?}");
}

/// Raw depth read by name: the camera info beside it is the depth
/// camera's, chosen to register it; registered depth needs none.
#[test]
fn raw_depth_gets_the_camera_info_beside_it() {
    let info = CameraInfo::TYPE_NAME;
    let channels = [
        Channel::ros2(COLOR, Image::TYPE_NAME),
        Channel::ros2("/camera/camera/color/camera_info", info),
        Channel::ros2("/camera/camera/depth/image_rect_raw", Image::TYPE_NAME),
        Channel::ros2("/camera/camera/depth/camera_info", info),
        Channel::ros2(DEPTH, Image::TYPE_NAME),
        Channel::ros2("/camera/camera/aligned_depth_to_color/camera_info", info),
        Channel::ros2("/camera/pose", PoseStamped::TYPE_NAME),
    ];
    let mut raw = choosing();
    raw.topics.depth = "/camera/camera/depth/image_rect_raw".into();
    raw.choose.depth = false;
    let (topics, plan) = plan_topics(&channels, &raw).unwrap();
    assert_eq!(topics.depth_camera_info, "/camera/camera/depth/camera_info");
    assert!(
        plan.iter()
            .any(|l| l.starts_with("depth camera info: /camera/camera/depth/camera_info")),
        "{plan:?}"
    );
    let (topics, plan) = plan_topics(&channels, &choosing()).unwrap();
    assert_eq!(topics.depth, DEPTH);
    assert_eq!(
        topics.depth_camera_info,
        Topics::default().depth_camera_info
    );
    assert!(
        !plan.iter().any(|l| l.contains("depth camera info")),
        "{plan:?}"
    );
}
