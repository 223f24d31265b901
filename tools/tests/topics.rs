//! A log whose topics are not the defaults maps with no topic flag: the
//! streams are chosen by message type, the choice printed; an ambiguous
//! choice names the candidates and the flag.

use std::path::{Path, PathBuf};
use std::process::Output;

mod common;
use common::{gen_scene, latentam_fast as latentam, scratch};
use latentam::logs::{Compression, LogWriter, McapLog, ReadFilter};
use latentam::messages::{CameraInfo, Image, MaskFeatures, PoseStamped, TextEmbeddings};

/// `src` rewritten with each topic renamed by `rename` (`None` drops it)
/// and, when `extra` is given, the depth images written a second time on
/// that topic.
fn rewrite(src: &Path, dst: &Path, rename: &dyn Fn(&str) -> Option<String>, extra: Option<&str>) {
    let log = McapLog::open(src).unwrap();
    let mut reader = log.reader(ReadFilter::default());
    let mut out = LogWriter::create(dst, Compression::Lz4).unwrap();
    while let Some(m) = reader.next_with(|m| {
        (
            m.channel.topic.clone(),
            m.channel.schema_name.clone(),
            m.log_time,
            m.data.to_vec(),
        )
    }) {
        let (topic, ty, t, data) = m.unwrap();
        let mut targets: Vec<String> = rename(&topic).into_iter().collect();
        if topic == "/camera/depth/image_raw" {
            targets.extend(extra.map(str::to_string));
        }
        for to in targets {
            match ty.as_str() {
                "sensor_msgs/msg/Image" => out.write_raw::<Image>(&to, t, &data),
                "sensor_msgs/msg/CameraInfo" => out.write_raw::<CameraInfo>(&to, t, &data),
                "geometry_msgs/msg/PoseStamped" => out.write_raw::<PoseStamped>(&to, t, &data),
                "latentam_msgs/msg/MaskFeatures" => out.write_raw::<MaskFeatures>(&to, t, &data),
                "latentam_msgs/msg/TextEmbeddings" => {
                    out.write_raw::<TextEmbeddings>(&to, t, &data)
                }
                other => panic!("{other}"),
            }
            .unwrap();
        }
    }
    out.finish().unwrap();
}

/// The demo log's topics as a robot's driver might name them.
fn robot_name(topic: &str) -> Option<String> {
    Some(
        match topic {
            "/camera/color/image_raw" => "/robot/front/color/image_raw",
            "/camera/depth/image_raw" => "/robot/front/aligned_depth_to_color/image_raw",
            "/camera/color/camera_info" => "/robot/front/color/camera_info",
            "/camera/pose" => "/robot/front/optical_pose",
            "/camera/embeddings" => "/perception/regions",
            "/vocabulary" => "/perception/vocabulary",
            _ => return None,
        }
        .to_string(),
    )
}

fn map(log: &Path, out: &Path) -> Output {
    latentam()
        .arg("map")
        .arg(log)
        .arg("--out")
        .arg(out)
        .arg("--no-trace")
        .output()
        .unwrap()
}

#[test]
fn a_log_with_its_own_topic_names_maps_without_flags() {
    let dir = scratch("topics");
    let log = gen_scene(&dir, 8);
    let robot: PathBuf = dir.join("robot.mcap");
    rewrite(&log, &robot, &robot_name, None);
    let out = map(&robot, &dir.join("run"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    for line in [
        "input: colour: /robot/front/color/image_raw",
        "input: depth: /robot/front/aligned_depth_to_color/image_raw",
        "input: camera info: /robot/front/color/camera_info",
        "input: poses: /robot/front/optical_pose",
        "input: embeddings: /perception/regions",
    ] {
        assert!(stderr.contains(line), "no `{line}` in:\n{stderr}");
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("run/report.json")).unwrap())
            .unwrap();
    assert_eq!(report["keyframes"], 2);
    assert!(dir.join("run/decoder.safetensors").exists());

    // Two depth topics neither name settles: an error naming both and the
    // flag, and --depth-topic settles it.
    let two = dir.join("two-depths.mcap");
    let plain_names = |t: &str| robot_name(t).map(|n| n.replace("aligned_depth_to_color", "depth"));
    rewrite(
        &log,
        &two,
        &plain_names,
        Some("/robot/rear/depth/image_raw"),
    );
    let out = map(&two, &dir.join("run2"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    for want in [
        "/robot/front/depth/image_raw",
        "/robot/rear/depth/image_raw",
        "--depth-topic",
    ] {
        assert!(stderr.contains(want), "no `{want}` in:\n{stderr}");
    }
    let out = latentam()
        .arg("map")
        .arg(&two)
        .arg("--out")
        .arg(dir.join("run2"))
        .args([
            "--no-trace",
            "--depth-topic",
            "/robot/front/depth/image_raw",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::remove_dir_all(&dir).ok();
}
