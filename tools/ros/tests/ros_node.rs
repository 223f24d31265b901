//! `latentam-ros` against an independent DDS implementation: a Cyclone
//! DDS publisher (Python `cyclonedds`) plays a generated log as ROS 2
//! topics at its recorded rate; the node maps it, publishes the map, the
//! trajectory and its status, answers a relevance query, is found in the
//! ROS 2 graph (`ros_discovery_info`), and saves its run folder on SIGINT. What Cyclone received is checked against that
//! saved map. Everything runs in a network namespace of its own holding
//! only loopback (multicast routed on it for discovery), so no packet
//! leaves the test.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use latentam::{Context, ContextOptions, Mapper, Scored, TextQuery};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("latentam-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

const SCRIPT: &str = r#"
ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo || exit 90
export CYCLONEDDS_URI='<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo" multicast="true"/></Interfaces></General></Domain></CycloneDDS>'
RMW_IMPLEMENTATION=rmw_cyclonedds_cpp "$NODE" --out "$DIR/run" --map-points 1000000 > "$DIR/node.out" 2> "$DIR/node.err" &
node=$!
RMW_IMPLEMENTATION=rmw_cyclonedds_cpp timeout 600 "$PY" "$CHECK" "$LOG" --save-dir "$DIR/by-service" > "$DIR/summary.json" 2> "$DIR/client.err"
client=$?
kill -INT $node
wait $node
echo "$client $?"
"#;

#[test]
fn a_cyclone_dds_robot_is_mapped_and_answered() {
    let dir = scratch("ros-node");
    let log = dir.join("scene.mcap");
    let scene = latentam_scene::SceneConfig {
        frames: 24,
        width: 120,
        height: 90,
        dim: 64,
        ..latentam_scene::SceneConfig::default()
    };
    latentam_scene::generate(&scene, &log, |_| {}).unwrap();
    let python = std::env::var("LATENTAM_PYTHON").unwrap_or_else(|_| "python3".into());
    let check = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/python/ros_node_check.py");
    let out = Command::new("unshare")
        .args(["--net", "sh", "-c", SCRIPT])
        .env("NODE", env!("CARGO_BIN_EXE_latentam-ros"))
        .env("PY", &python)
        .env("CHECK", &check)
        .env("LOG", &log)
        .env("DIR", &dir)
        .output()
        .expect("unshare (the test runs as root, with util-linux and iproute2)");
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap_or_default();
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).trim(),
        "0 0",
        "client / node exit status; node:\n{}\nclient:\n{}\n{}",
        read("node.err"),
        read("client.err"),
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_str(&read("summary.json")).unwrap();
    let status = &summary["status"];
    let num = |k: &str| status[k].as_str().unwrap().parse::<u64>().unwrap();

    // The node is in the ROS 2 graph (`ros_discovery_info`) as
    // `/latentam`, and the GUIDs it lists are its endpoints as DDS
    // discovery reports them: what `ros2 node info` joins.
    let graph = &summary["graph"];
    let topics = |k: &str| -> Vec<String> {
        graph[k]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t.as_str().unwrap().to_string())
            .collect()
    };
    let (writers, readers) = (topics("writers"), topics("readers"));
    for t in ["map", "trajectory", "status", "query/relevance", "saved"] {
        assert!(writers.contains(&format!("rt/latentam/{t}")), "{graph}");
    }
    assert_eq!(graph["writer_gids"], writers.len(), "{graph}");
    for t in [
        "rt/latentam/query",
        "rt/latentam/save",
        "rt/camera/color/image_raw",
    ] {
        assert!(readers.contains(&t.to_string()), "{graph}");
    }
    assert_eq!(graph["reader_gids"], readers.len(), "{graph}");
    assert!(graph["seconds_after_client_start"].as_f64().unwrap() < 60.0);
    for t in ["rr/latentam/queryReply", "rr/latentam/saveReply"] {
        assert!(writers.contains(&t.to_string()), "{graph}");
    }
    for t in ["rq/latentam/queryRequest", "rq/latentam/saveRequest"] {
        assert!(readers.contains(&t.to_string()), "{graph}");
    }

    // The services, called as a Cyclone DDS client calls them: the query
    // answers as the topic does; a query of the wrong dimension fails with
    // a reason and no points; a save writes the map where it was asked.
    let services = &summary["services"];
    assert_eq!(services["query"]["success"], true, "{services}");
    assert_eq!(services["query"]["same_points_as_the_topic"], true);
    assert!(services["query"]["points"].as_u64().unwrap() > 100);
    assert_eq!(services["wrong_query"]["success"], false);
    assert_eq!(services["wrong_query"]["points"], 0);
    assert!(
        services["wrong_query"]["message"]
            .as_str()
            .unwrap()
            .contains("3-d"),
        "{services}"
    );
    assert_eq!(services["save"]["success"], true, "{services}");
    let saved = services["save"]["message"].as_str().unwrap();
    assert!(saved.starts_with(dir.join("by-service").to_str().unwrap()));
    assert!(Path::new(saved).is_file(), "{saved}");

    // The parameters, through the standard parameter services: the
    // mapper's configuration read-only, the publishing settings
    // settable; a wrong type or a read-only key refused with a reason.
    let params = &services["parameters"];
    let names: Vec<&str> = params["names"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_str().unwrap())
        .collect();
    for n in [
        "voxel_size",
        "map_every",
        "map_points",
        "frame_id",
        "words",
        "temperature",
    ] {
        assert!(names.contains(&n), "{params}");
    }
    assert!(
        names.iter().any(|n| n.contains('.')),
        "sections as dotted names: {params}"
    );
    assert!(!params["prefixes"].as_array().unwrap().is_empty());
    let got = &params["got"];
    assert_eq!(got["voxel_size"], serde_json::json!([3, 0.01]), "{params}");
    assert_eq!(got["map_points"], serde_json::json!([2, 1_000_000]));
    assert_eq!(got["map_every"], serde_json::json!([3, 1.0]));
    assert_eq!(got["no_such_parameter"], serde_json::json!([0, null]));
    assert_eq!(params["types"], serde_json::json!([3, 2, 3, 0]));
    let set = params["set"].as_array().unwrap();
    assert_eq!(set[0], serde_json::json!([true, ""]), "{params}");
    assert_eq!(set[1][0], false);
    assert!(
        set[1][1].as_str().unwrap().contains("read-only"),
        "{params}"
    );
    assert_eq!(set[2][0], false);
    assert!(set[2][1].as_str().unwrap().contains("integer"), "{params}");
    assert_eq!(params["after"], serde_json::json!([[3, 0.5], [3, 0.01]]));
    assert_eq!(params["read_only"], serde_json::json!([true, false]));

    // Every message arrived, every frame was taken or dropped by policy.
    assert_eq!(
        num("messages_received"),
        summary["published_messages"].as_u64().unwrap()
    );
    assert!(num("frames_assembled") + 2 >= summary["published_frames"].as_u64().unwrap());
    assert_eq!(
        num("frames_submitted"),
        num("frames_integrated") + num("dropped_not_keyframe") + num("dropped_superseded")
    );
    assert!(num("keyframes") >= 3, "{status}");
    assert_eq!(status["level"], 0, "{status}");

    // The saved map is the one published: the same Gaussians (the budget
    // exceeds the map), the same keyframe poses.
    let ctx = Context::new(ContextOptions::default()).unwrap();
    let mut mapper = Mapper::load(&ctx, dir.join("run")).unwrap();
    let snapshot = mapper.snapshot().unwrap();
    let gaussians = snapshot.to_gaussians();
    let key = |p: [f32; 3]| p.map(f32::to_bits);
    let by_position: HashMap<[u32; 3], usize> = gaussians
        .iter()
        .enumerate()
        .map(|(i, g)| (key(g.mean), i))
        .collect();
    let cloud = summary["map"]["points"].as_array().unwrap();
    assert_eq!(cloud.len(), gaussians.len());
    assert_eq!(summary["map"]["frame_id"], "map");
    let point = |p: &serde_json::Value| ["x", "y", "z"].map(|a| p[a].as_f64().unwrap() as f32);
    for p in cloud {
        let i = by_position[&key(point(p))];
        let opacity = 1.0 / (1.0 + (-gaussians[i].opacity_logit as f64).exp());
        assert!((p["opacity"].as_f64().unwrap() - opacity).abs() < 1e-6);
    }
    let trajectory = summary["trajectory"].as_array().unwrap();
    assert_eq!(trajectory.len(), snapshot.trajectory.len());
    for (p, (_, t)) in trajectory.iter().zip(&snapshot.trajectory) {
        assert!((p[0].as_f64().unwrap() - t.translation.x).abs() < 1e-9);
        assert!((p[6].as_f64().unwrap() - t.rotation.w).abs() < 1e-9);
    }

    // The query's cosines are the map's (the live index drops attention
    // below 1e-3 of a Gaussian's mass, so a small difference is allowed).
    let vocab = latentam::frames::read_vocabulary(&log, "/vocabulary")
        .unwrap()
        .unwrap();
    let word = summary["word"].as_str().unwrap();
    let k = vocab.names.iter().position(|n| n == word).unwrap();
    let d = vocab.dim as usize;
    let word_embedding = TextQuery::embedding(vocab.vectors[k * d..(k + 1) * d].to_vec());
    let cosines = mapper
        .relevance(&word_embedding, Scored::Gaussians)
        .unwrap();
    let field = format!(
        "relevance_{}",
        word.to_lowercase()
            .replace(|c: char| !c.is_ascii_alphanumeric(), "_")
    );
    assert!(summary["relevance"]["fields"]
        .as_array()
        .unwrap()
        .iter()
        .any(|f| f == field.as_str()));
    let relevance = summary["relevance"]["points"].as_array().unwrap();
    assert_eq!(relevance.len(), gaussians.len());
    let mut worst = 0f64;
    for p in relevance {
        let i = by_position[&key(point(p))];
        worst = worst.max((p[field.as_str()].as_f64().unwrap() - cosines[i] as f64).abs());
    }
    assert!(
        worst < 2e-2,
        "largest difference to the map's cosines {worst}"
    );
    assert!(read("node.err").contains("saved"), "{}", read("node.err"));
    // The folder holds what `latentam map` leaves beside the state.
    let ply = latentam::interchange::read_ply(&dir.join("run/map.ply")).unwrap();
    assert_eq!(ply.gaussians.len(), gaussians.len());
    let tum = latentam::interchange::read_tum(&dir.join("run/trajectory.txt")).unwrap();
    assert_eq!(tum.len(), trajectory.len());
    assert!(dir.join("run/config.toml").is_file());
    // Its report, as `latentam map` writes it: every keyframe of the
    // trajectory, the inputs counted, ended by Ctrl-C, and report.html.
    let report: serde_json::Value =
        serde_json::from_str(&read("run/report.json")).expect("run/report.json");
    assert_eq!(report["ending"], "interrupted", "{}", report["ending"]);
    assert_eq!(report["log"], "ros2:/latentam");
    assert_eq!(
        report["keyframe_reports"].as_array().unwrap().len(),
        trajectory.len()
    );
    assert_eq!(
        report["keyframes"].as_u64().unwrap() as usize,
        trajectory.len()
    );
    assert!(
        report["ingest"]["messages"].as_u64().unwrap()
            >= summary["published_messages"].as_u64().unwrap() - 2
    );
    assert!(report["frames"].as_u64().unwrap() >= num("frames_submitted"));
    let html = read("run/report.html");
    assert!(
        html.starts_with("<!DOCTYPE html>") && html.contains("<svg"),
        "{}",
        &html[..html.len().min(200)]
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_arguments_are_clear_errors_before_anything_starts() {
    let node = env!("CARGO_BIN_EXE_latentam-ros");
    let cases: [(&[&str], &str, Option<&str>); 5] = [
        (
            &["--map-points", "0"],
            "--map-points must be at least 1",
            None,
        ),
        (
            &["--temperature=-1"],
            "--temperature must be positive",
            None,
        ),
        (&["--map-every", "nan"], "--map-every must be", None),
        (
            &["--live", "--live-words", "chair"],
            "--live-words is for logs",
            None,
        ),
        (&[], "ROS_DOMAIN_ID=seven is not a domain id", Some("seven")),
    ];
    for (args, says, domain) in cases {
        let mut c = Command::new(node);
        c.args(args);
        if let Some(d) = domain {
            c.env("ROS_DOMAIN_ID", d);
        }
        let out = c.output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(stderr.contains(says), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}
