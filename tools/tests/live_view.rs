//! `latentam map --live`: a Foxglove WebSocket client (Python
//! `websockets`, decoding each message with the protobuf schema its
//! channel advertises and checking it against Foxglove's published types) connects while a generated log maps,
//! subscribes to every topic and receives the map, trajectory, camera
//! pose, keyframe image, render and a relevance cloud. Everything runs
//! in a network namespace of its own that holds only loopback, so no
//! packet leaves the test.

use std::path::Path;
use std::process::Command;

mod common;
use common::{gen_scene, scratch};
use latentam::frames::read_vocabulary;
use latentam::interchange::{read_ply, read_tum};

/// Runs `script` with `sh` in a new network namespace whose only
/// interface is loopback, brought up first.
fn in_private_network(script: &str, env: &[(&str, &Path)]) -> std::process::Output {
    let mut c = Command::new("unshare");
    c.args([
        "--net",
        "sh",
        "-c",
        &format!("ip link set lo up && {script}"),
    ]);
    for (k, v) in env {
        c.env(k, v);
    }
    c.output().unwrap_or_else(|e| {
        panic!("unshare: {e} (the test runs as root, with util-linux and iproute2)")
    })
}

#[test]
fn a_foxglove_client_watches_the_map_grow() {
    let dir = scratch("live-view");
    let log = gen_scene(&dir, 24);
    let vocab = read_vocabulary(&log, "/vocabulary").unwrap().unwrap();
    let word = vocab.names[0]
        .to_lowercase()
        .replace(|c: char| !c.is_ascii_alphanumeric(), "_");
    let run = dir.join("run");
    let python = std::env::var("LATENTAM_PYTHON").unwrap_or_else(|_| "python3".into());
    let check = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/python/live_view_check.py");
    let topics = [
        "/latentam/map".to_string(),
        "/latentam/trajectory".into(),
        "/latentam/camera".into(),
        "/latentam/image".into(),
        "/latentam/render".into(),
        format!("/latentam/relevance/{word}"),
    ];
    // The client starts first and retries until the server listens; the
    // map runs in the foreground; then the client's status.
    let script = format!(
        "\"$PY\" \"$CHECK\" ws://127.0.0.1:8765 {} > \"$DIR/summary.json\" 2> \"$DIR/client.err\" & \
         client=$!; \
         \"$BIN\" map \"$LOG\" --out \"$RUN\" --live --live-points 300 --live-every 0 --live-render-every 0 \
           --live-render-width 64 --live-words '{}' > \"$DIR/map.out\" 2> \"$DIR/map.err\"; \
         mapped=$?; wait $client; echo \"$mapped $?\"",
        topics.join(" "),
        vocab.names[0]
    );
    let bin = Path::new(env!("CARGO_BIN_EXE_latentam"));
    let out = in_private_network(
        &script,
        &[
            ("PY", Path::new(&python)),
            ("CHECK", &check),
            ("DIR", &dir),
            ("BIN", bin),
            ("LOG", &log),
            ("RUN", &run),
        ],
    );
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap_or_default();
    let status = String::from_utf8_lossy(&out.stdout).trim().to_string();
    assert_eq!(
        status,
        "0 0",
        "map / client exit status; map stderr:\n{}\nclient stderr:\n{}\n{}",
        read("map.err"),
        read("client.err"),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        read("map.err").contains("live view: ws://127.0.0.1:8765"),
        "{}",
        read("map.err")
    );
    let summary: serde_json::Value = serde_json::from_str(&read("summary.json")).unwrap();
    assert!(summary["server"].as_str().unwrap().starts_with("latentam"));
    let t = &summary["topics"];

    // The map: a subset within the budget, inside the saved map's bounds.
    let saved = read_ply(&run.join("map.ply")).unwrap();
    let means: Vec<[f32; 3]> = saved.gaussians.iter().map(|g| g.mean).collect();
    assert!(means.len() > 300, "the map should pass the point budget");
    let cloud = t["/latentam/map"]["points"].as_array().unwrap();
    assert!(
        !cloud.is_empty() && cloud.len() <= 300,
        "{} points",
        cloud.len()
    );
    assert_eq!(t["/latentam/map"]["frame_id"], "map");
    let lo: [f32; 3] = std::array::from_fn(|a| means.iter().map(|m| m[a]).fold(f32::MAX, f32::min));
    let hi: [f32; 3] = std::array::from_fn(|a| means.iter().map(|m| m[a]).fold(f32::MIN, f32::max));
    for p in cloud {
        for (a, axis) in ["x", "y", "z"].iter().enumerate() {
            let v = p[axis].as_f64().unwrap() as f32;
            assert!(
                v >= lo[a] - 0.5 && v <= hi[a] + 0.5,
                "{axis} = {v} outside {lo:?}..{hi:?}"
            );
        }
        // On the wire the opacity is a byte, as the alpha is.
        assert_eq!(p["opacity"], p["alpha"]);
    }
    // 17 bytes a point and a header of a few hundred.
    let map = &t["/latentam/map"];
    assert_eq!(map["point_stride"], 17);
    let bytes = map["bytes"].as_u64().unwrap() as usize;
    assert!(
        bytes <= 17 * cloud.len() + 400,
        "{bytes} bytes for {} points",
        cloud.len()
    );

    // The trajectory and the camera: keyframe poses of the saved run.
    let saved_poses = read_tum(&run.join("trajectory.txt")).unwrap();
    let poses = t["/latentam/trajectory"]["poses"].as_array().unwrap();
    assert!(!poses.is_empty() && poses.len() <= saved_poses.len());
    for (p, (_, s)) in poses.iter().zip(&saved_poses) {
        assert!((p[0].as_f64().unwrap() - s.translation.x).abs() < 1e-6);
        assert!((p[6].as_f64().unwrap() - s.rotation.w).abs() < 1e-6);
    }
    let camera = t["/latentam/camera"]["pose"].as_array().unwrap();
    assert!(
        saved_poses.iter().any(
            |(_, s)| (camera[0].as_f64().unwrap() - s.translation.x).abs() < 1e-6
                && (camera[2].as_f64().unwrap() - s.translation.z).abs() < 1e-6
        ),
        "the camera pose is a keyframe's"
    );

    // The keyframe's image at the log's size, the render at 64 wide.
    assert_eq!(t["/latentam/image"]["size"], serde_json::json!([120, 90]));
    assert_eq!(t["/latentam/image"]["encoding"], "rgb8");
    assert!(t["/latentam/image"]["mean"].as_f64().unwrap() > 5.0);
    assert_eq!(t["/latentam/render"]["size"], serde_json::json!([64, 48]));
    assert!(
        t["/latentam/render"]["mean"].as_f64().unwrap() > 1.0,
        "an empty render"
    );

    // The relevance of the word: probabilities, over the same budget.
    let rel = &t[format!("/latentam/relevance/{word}").as_str()];
    let points = rel["points"].as_array().unwrap();
    assert!(!points.is_empty() && points.len() <= 300);
    // Bytes: probability × 255, rounded.
    let relevance = |p: &serde_json::Value| p["relevance"].as_f64().unwrap() / 255.0;
    assert!(points.iter().all(|p| (0.0..=1.0).contains(&relevance(p))));
    assert!(
        points
            .iter()
            .any(|p| relevance(p) > 1.0 / vocab.names.len() as f64),
        "some points are more relevant than chance"
    );
    assert!(read("map.err").contains("live view (port 8765):"));
    std::fs::remove_dir_all(&dir).unwrap();
}
