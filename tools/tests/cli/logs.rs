//! Logs written by `gen-scene` and `convert` and read by `inspect`,
//! library warnings on stderr, and bad input files.

use super::*;

#[test]
fn gen_scene_and_convert_write_logs_that_inspect_reads() {
    let dir = std::env::temp_dir().join(format!("latentam-cli-logs-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("scene.mcap");
    let args = [
        "gen-scene",
        "--frames",
        "5",
        "--width",
        "48",
        "--height",
        "32",
        "--dim",
        "16",
        "--compression",
        "lz4",
        "-o",
    ];
    let mut a: Vec<&std::ffi::OsStr> = args.iter().map(|s| s.as_ref()).collect();
    a.push(scene.as_os_str());
    assert!(run_ok(&a).contains("5 frames"));
    let report: serde_json::Value = serde_json::from_str(&run_ok(&[
        "inspect".as_ref(),
        scene.as_os_str(),
        "--json".as_ref(),
    ]))
    .unwrap();
    let ingest = &report["ingest"];
    assert_eq!(
        (
            ingest["frames"].as_u64(),
            ingest["frames_with_embeddings"].as_u64()
        ),
        (Some(5), Some(5))
    );
    assert_eq!(ingest["skipped"], serde_json::json!({}));
    // Topics with their types and counts, the streams read, the duration.
    let topics = report["topics"].as_array().unwrap();
    assert!(topics
        .iter()
        .any(|t| t["topic"] == "/camera/color/image_raw"
            && t["type"] == "sensor_msgs/msg/Image"
            && t["count"] == 5));
    assert_eq!(report["streams"]["pose"], "/camera/pose");
    assert_eq!(report["frame_size"], serde_json::json!([48, 32]));
    assert!(report["duration_s"].as_f64().unwrap() > 0.0);

    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/7scenes-redkitchen");
    let converted = dir.join("7s.mcap");
    let out = run_ok(&[
        "convert".as_ref(),
        "7scenes".as_ref(),
        data.as_os_str(),
        "--max-frames".as_ref(),
        "3".as_ref(),
        "-o".as_ref(),
        converted.as_os_str(),
    ]);
    assert!(out.contains("3 frames"), "{out}");
    let text = run_ok(&["inspect".as_ref(), converted.as_os_str()]);
    assert!(
        text.contains("3 frames assembled") && text.contains("640×480"),
        "{text}"
    );
    assert!(
        text.contains("latentam.converter: latentam convert 7scenes"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// What the library reports through `log` reaches the user: a log that
/// lost its summary is read linearly, with a warning, unless `RUST_LOG`
/// asks for errors only.
#[test]
fn library_warnings_reach_stderr() {
    let dir = std::env::temp_dir().join(format!("latentam-cli-warn-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("scene.mcap");
    let mut a: Vec<&std::ffi::OsStr> = [
        "gen-scene",
        "--frames",
        "4",
        "--width",
        "32",
        "--height",
        "24",
        "-o",
    ]
    .iter()
    .map(|s| s.as_ref())
    .collect();
    a.push(scene.as_os_str());
    run_ok(&a);
    let bytes = std::fs::read(&scene).unwrap();
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();

    let warned = latentam().arg("inspect").arg(&cut).output().unwrap();
    let stderr = String::from_utf8_lossy(&warned.stderr);
    assert!(
        stderr.contains("warning: ") && stderr.contains("reading it linearly"),
        "{stderr}"
    );
    let quiet = latentam()
        .arg("inspect")
        .arg(&cut)
        .env("RUST_LOG", "error")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&quiet.stderr);
    assert!(!stderr.contains("reading it linearly"), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_inputs_are_clear_errors() {
    let dir = std::env::temp_dir().join(format!("latentam-cli-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let junk = dir.join("junk.mcap");
    std::fs::write(&junk, b"not a log").unwrap();
    let missing = dir.join("missing.mcap");
    let out = dir.join("o.mcap");
    let scene = dir.join("s.mcap");
    let cases: Vec<(Vec<&std::ffi::OsStr>, &str)> = vec![
        (
            vec!["inspect".as_ref(), junk.as_os_str()],
            "not an MCAP file",
        ),
        (
            vec!["inspect".as_ref(), missing.as_os_str()],
            "No such file",
        ),
        (
            vec![
                "convert".as_ref(),
                "replica".as_ref(),
                dir.as_os_str(),
                "-o".as_ref(),
                out.as_os_str(),
            ],
            "results",
        ),
        (
            vec![
                "gen-scene".as_ref(),
                "--frames".as_ref(),
                "0".as_ref(),
                "-o".as_ref(),
                scene.as_os_str(),
            ],
            "--frames",
        ),
    ];
    for (args, want) in cases {
        let out = latentam().args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(
            err.contains(want) && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
    assert!(!scene.exists() && !out.exists());
    std::fs::remove_dir_all(&dir).ok();
}
