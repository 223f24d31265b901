//! End-to-end tests of the `latentam` binary.

mod common;
use common::{latentam, write_npy};

/// Runs `latentam bench <args> --json FILE`, checks it succeeded and
/// returns the parsed JSON.
fn bench_json(name: &str, args: &[&str]) -> serde_json::Value {
    let dir = std::env::temp_dir().join(format!("latentam-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join(format!("{name}.json"));
    let out = latentam()
        .arg("bench")
        .args(args)
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    v
}

/// Names of a JSON array's objects' `name` fields.
fn names(rows: &serde_json::Value) -> Vec<&str> {
    rows.as_array()
        .unwrap()
        .iter()
        .map(|r| r["name"].as_str().unwrap())
        .collect()
}

#[test]
fn selfcheck_passes_with_validation() {
    let out = latentam()
        .args(["selfcheck", "--validation"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("all 6 primitives match"), "{stdout}");
}

#[test]
fn bench_primitives_writes_json_with_every_primitive() {
    let v = bench_json("primitives", &["primitives", "--quick", "--runs", "5"]);
    assert!(v["device"].as_str().is_some_and(|d| !d.is_empty()));
    assert!(v["memory_bandwidth_gbps"].as_f64().unwrap() > 0.0);
    assert!(v["gemm_gflops"].as_f64().unwrap() > 0.0);
    let names = names(&v["primitives"]);
    for want in [
        "copy",
        "fma_peak",
        "scan_u32",
        "reduce_sum_f32",
        "radix_sort_kv",
        "gemm_nn",
        "gemm_tn",
        "gemm_nt",
        "softmax",
    ] {
        assert!(names.contains(&want), "{want} missing from {names:?}");
    }
    for r in v["primitives"].as_array().unwrap() {
        let ms = r["gpu_ms_median"].as_f64().unwrap();
        assert!(ms > 0.0 && ms.is_finite(), "{r}");
    }
}

#[test]
fn bench_raster_writes_json_with_times_and_kernels() {
    let v = bench_json(
        "raster",
        &[
            "raster",
            "--width",
            "40",
            "--height",
            "30",
            "--gaussians",
            "2000",
            "--views",
            "2",
            "--runs",
            "3",
        ],
    );
    assert!(v["device"].as_str().is_some_and(|d| !d.is_empty()));
    assert_eq!(v["width"], 40);
    assert_eq!(v["height"], 30);
    assert_eq!(v["gaussians"], 2000);
    assert_eq!(v["views"], 2);
    assert!(v["intersections"].as_u64().unwrap() > 0);
    assert!(v["forward_ms_median"].as_f64().unwrap() > 0.0);
    assert!(v["backward_ms_median"].as_f64().unwrap() > 0.0);
    // The work counts nest: every contributor is tested by both passes, and
    // backward stops at each pixel's last contributor.
    let w = &v["work"];
    let count = |k: &str| w[k].as_u64().unwrap();
    assert!(count("contributing") > 0, "{w}");
    assert!(count("contributing") <= count("tested_backward"), "{w}");
    assert!(count("tested_backward") <= count("tested_forward"), "{w}");
    assert_eq!(count("pixels"), 2 * 40 * 30);
    let r = &v["roofline"];
    let f = |k: &str| r[k].as_f64().unwrap();
    assert!(f("machine_gflops") > 0.0 && f("machine_gbps") > 0.0, "{r}");
    assert!(f("bound_ms") > 0.0, "{r}");
    assert!(
        (f("ratio") - f("measured_ms") / f("bound_ms")).abs() < 1e-9 * f("ratio"),
        "{r}"
    );
    let measured =
        v["forward_ms_median"].as_f64().unwrap() + v["backward_ms_median"].as_f64().unwrap();
    assert!((f("measured_ms") - measured).abs() < 1e-9 * measured, "{r}");
    let names = names(&v["kernels"]);
    for want in [
        "project_forward",
        "raster_forward",
        "raster_backward",
        "project_backward",
    ] {
        assert!(
            names.iter().any(|n| n.starts_with(want)),
            "{want} missing from {names:?}"
        );
    }
}

#[test]
fn bench_map_writes_json_with_stages_memory_and_curves() {
    let v = bench_json(
        "map",
        &[
            "map",
            "--frames",
            "12",
            "--width",
            "64",
            "--height",
            "48",
            "--dim",
            "32",
            "--eval-keyframes",
            "2",
        ],
    );
    assert_eq!(v["frames"], 12);
    assert_eq!(v["keyframes"], 3, "interval 4 over 12 frames");
    assert!(v["keyframes_per_s"].as_f64().unwrap() > 0.0);
    let m = &v["ms_per_keyframe"];
    for k in [
        "kmeans_ms",
        "insertion_ms",
        "stage_one_ms",
        "stage_two_ms",
        "total_ms",
    ] {
        assert!(m[k].as_f64().is_some_and(|x| x >= 0.0), "{k}: {m}");
    }
    assert!(m["stage_one_ms"].as_f64().unwrap() > 0.0);
    let peak = v["peak_gpu_bytes"].as_u64().unwrap();
    assert!(peak > 0 && peak <= v["gpu_budget"].as_u64().unwrap());
    assert!(v["peak_cpu_bytes"].as_u64().unwrap() > 0);
    let curve = v["curve"].as_array().unwrap();
    assert_eq!(curve.len(), 3);
    let g: Vec<u64> = curve
        .iter()
        .map(|p| p["gaussians"].as_u64().unwrap())
        .collect();
    assert!(g[0] > 0 && g.windows(2).all(|w| w[1] >= w[0]), "{g:?}");
    assert_eq!(curve[2]["gaussians"], v["gaussians"]);
    let psnr = v["psnr_keyframes"].as_f64().unwrap();
    assert!(psnr > 10.0 && psnr < 60.0, "{psnr}");
    assert_eq!(v["keyframes_evaluated"], 2);
    // The paper's per-pixel protocol on the same keyframes.
    let cos = v["cosine_loss_keyframes"].as_f64().unwrap();
    assert!((0.0..=2.0).contains(&cos), "{cos}");
    let miou = v["miou_keyframes"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&miou), "{miou}");
    // The memory split names its parts; mapping allocates no feature image.
    assert_eq!(v["peak_gpu_split"]["features"], 0);
    assert!(v["peak_gpu_split"]["images"].as_u64().unwrap() > 0);
    // Round trips per keyframe, and the dictionary filling (the first
    // keyframe is in neither phase).
    let calls = &v["gpu_calls_per_keyframe"];
    assert_eq!(calls["stage_one_and_two_max"], 3, "{calls}");
    assert!(calls["dispatches_mean"].as_f64().unwrap() > 50.0, "{calls}");
    let atoms: Vec<u64> = curve.iter().map(|p| p["atoms"].as_u64().unwrap()).collect();
    assert!(
        atoms[0] > 0 && atoms.windows(2).all(|w| w[1] >= w[0]),
        "{atoms:?}"
    );
    assert!(curve.iter().all(|p| p["stage_one_and_two_waits"] == 3));
    assert_eq!(v["atoms"], 2000);
    assert_eq!(v["while_filling"]["keyframes"], 2);
    assert!(v["once_full"].is_null());
}

#[test]
fn bench_latent_writes_json_with_every_measurement() {
    let v = bench_json(
        "latent",
        &[
            "latent",
            "--regions",
            "20",
            "--atoms",
            "64",
            "--dim",
            "96",
            "--ssim-width",
            "40",
            "--ssim-height",
            "30",
            "--runs",
            "3",
        ],
    );
    assert_eq!(
        (v["regions"].clone(), v["atoms"].clone(), v["dim"].clone()),
        (20.into(), 64.into(), 96.into())
    );
    for key in [
        "decode_forward_ms_median",
        "decode_backward_ms_median",
        "kmeans_ms_median",
        "ssim_forward_backward_ms_median",
        "stage2_iteration_ms_median",
        "decode_gflops",
    ] {
        assert!(
            v[key].as_f64().is_some_and(|t| t > 0.0),
            "{key}: {}",
            v[key]
        );
    }
    let names = names(&v["kernels"]);
    // The GEMM kernel is the device's: register blocks on CPU drivers.
    assert!(
        names.contains(&"gemm_nt") || names.contains(&"gemm_blocked_nt"),
        "no GEMM in {names:?}"
    );
    for want in [
        "softmax_backward",
        "kmeans_update",
        "ssim_map_v",
        "adam_step",
    ] {
        assert!(names.contains(&want), "{want} missing from {names:?}");
    }
}

#[test]
fn bench_rejects_fewer_than_five_runs() {
    let out = latentam()
        .args(["bench", "primitives", "--runs", "2"])
        .output()
        .unwrap();
    assert!(!out.status.success());
}

#[test]
fn unknown_device_is_a_clear_error() {
    let out = latentam()
        .arg("devices")
        .env("LATENTAM_DEVICE", "no-such-gpu")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("matches no device"), "{err}");
}

#[test]
fn bench_ingest_writes_json_with_every_measurement() {
    let v = bench_json(
        "ingest",
        &[
            "ingest",
            "--width",
            "64",
            "--height",
            "48",
            "--regions",
            "8",
            "--dim",
            "16",
            "--frames",
            "6",
        ],
    );
    assert_eq!(
        (v["width"].as_u64(), v["regions"].as_u64()),
        (Some(64), Some(8))
    );
    for key in [
        "decode_us_median",
        "assemble_ms_median",
        "assemble_ms_p90",
        "assemble_fresh_buffers_ms_median",
    ] {
        assert!(v[key].as_f64().unwrap() > 0.0, "{key}");
    }
    let rows = v["from_mcap"].as_array().unwrap();
    let kinds: Vec<&str> = rows
        .iter()
        .map(|r| r["compression"].as_str().unwrap())
        .collect();
    assert_eq!(kinds, ["none", "lz4", "zstd"]);
    assert!(rows
        .iter()
        .all(|r| r["cpu_ms_per_frame"].as_f64().unwrap() > 0.0));
}

fn run_ok(args: &[&std::ffi::OsStr]) -> String {
    let out = latentam().args(args).output().unwrap();
    assert!(
        out.status.success(),
        "latentam {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

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

/// Runs each `(args, exit status, words)` case: it must fail with that
/// status, print the expected words on stderr, and not panic.
fn fails_clearly(cases: &[(Vec<&std::ffi::OsStr>, i32, &str)]) {
    for (args, code, want) in cases {
        let out = latentam().args(args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(*code), "{args:?}: {err}");
        assert!(
            err.contains(want) && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
}

#[test]
fn command_line_misuse_is_a_clear_error() {
    let dir = std::env::temp_dir().join(format!("latentam-cli-misuse-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let run = dir.join("run");
    let log = dir.join("missing.mcap");
    let q = dir.join("q.npy");
    write_npy(&q, &[1.0; 4]);
    let png = dir.join("v.png");
    let os = |s: &'static str| -> &std::ffi::OsStr { s.as_ref() };
    let map = |extra: &[&'static str]| {
        let mut a = vec![os("map"), log.as_os_str(), os("--out"), run.as_os_str()];
        a.extend(extra.iter().map(|s| os(s)));
        a
    };
    let query_view = |view: &'static str| {
        vec![
            os("query"),
            run.as_os_str(),
            os("--embedding"),
            q.as_os_str(),
            os("--view"),
            os(view),
            os("--png"),
            png.as_os_str(),
        ]
    };
    let exit_error = 1;
    let usage_error = 2;
    fails_clearly(&[
        (map(&["--resume"]), exit_error, "holds no saved map"),
        (
            map(&["--tolerance-ms=-1"]),
            exit_error,
            "--tolerance-ms must be",
        ),
        (
            map(&["--depth-scale", "0"]),
            exit_error,
            "--depth-scale must be",
        ),
        (
            map(&["--max-extent", "1e300"]),
            exit_error,
            "--max-extent must be",
        ),
        (
            map(&["--max-depth", "NaN"]),
            exit_error,
            "--max-depth must be",
        ),
        (query_view("1,2,3"), exit_error, "expected 7 finite numbers"),
        (query_view("a,b,c,d,e,f,g"), exit_error, "not numbers"),
        (query_view("0,0,0,0,0,0,2"), exit_error, "has norm 2.0000"),
        (query_view("0,0,0,nan,0,0,1"), exit_error, "finite"),
        (
            vec![
                os("query"),
                run.as_os_str(),
                os("--view"),
                os("0,0,0,0,0,0,1"),
            ],
            usage_error,
            "--png",
        ),
        (
            vec![os("query"), run.as_os_str(), os("--name"), os("chair")],
            usage_error,
            "--vocabulary",
        ),
        (
            vec![os("query"), run.as_os_str()],
            usage_error,
            "--embedding",
        ),
        (
            vec![
                os("convert"),
                os("7scenes"),
                dir.as_os_str(),
                os("--fps"),
                os("0"),
                os("-o"),
                log.as_os_str(),
            ],
            exit_error,
            "--fps must be positive",
        ),
    ]);
    assert!(!run.exists() && !png.exists() && !log.exists());

    // --config files: unknown key, wrong type, out of range, not TOML,
    // missing.
    let mut cases = Vec::new();
    for (name, text, want) in [
        ("unknown.toml", "replya = 3\n", "unknown field `replya`"),
        ("type.toml", "replay = \"x\"\n", "expected u32"),
        (
            "range.toml",
            "voxel_size = 0\n",
            "voxel_size 0 must be from 0.0001 to 1 metres",
        ),
        ("syntax.toml", "replay = [\n", "TOML parse error"),
    ] {
        std::fs::write(dir.join(name), text).unwrap();
        cases.push((name, want));
    }
    cases.push(("missing.toml", "No such file"));
    let files: Vec<_> = cases.iter().map(|(name, _)| dir.join(name)).collect();
    fails_clearly(
        &cases
            .iter()
            .zip(&files)
            .map(|((_, want), file)| {
                (
                    vec![os("config"), os("--config"), file.as_os_str()],
                    exit_error,
                    *want,
                )
            })
            .collect::<Vec<_>>(),
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn query_render_and_export_misuse_are_clear_errors() {
    let dir = std::env::temp_dir().join(format!("latentam-cli-query-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let os = |s: &'static str| -> &std::ffi::OsStr { s.as_ref() };
    // Two small logs whose embeddings differ in dimension (11 classes each:
    // 11 × 16 values divide into 22-d rows, which used to be taken for 8
    // texts and crash the softmax).
    let scene = |dim: &str| {
        let log = dir.join(format!("s{dim}.mcap"));
        let mut a = vec![
            os("gen-scene"),
            os("--frames"),
            os("4"),
            os("--width"),
            os("48"),
            os("--height"),
            os("32"),
        ];
        a.extend([os("--dim"), dim.as_ref(), os("-o"), log.as_os_str()]);
        run_ok(&a);
        log
    };
    let (s22, s16) = (scene("22"), scene("16"));
    let run = dir.join("run");
    run_ok(&[os("map"), s22.as_os_str(), os("--out"), run.as_os_str()]);
    let plain = dir.join("plain");
    run_ok(&[
        os("map"),
        s22.as_os_str(),
        os("--out"),
        plain.as_os_str(),
        os("--embeddings-topic"),
        os("/none"),
    ]);
    // Mapped without embeddings: no latent properties, no decoder.
    let ply = std::fs::read(plain.join("map.ply")).unwrap();
    let end = ply.windows(10).position(|w| w == b"end_header").unwrap();
    assert!(!String::from_utf8_lossy(&ply[..end]).contains("latent_"));
    assert!(!plain.join("decoder.safetensors").exists());
    assert!(latentam_core::map::read_ply(&plain.join("map.ply")).is_ok());
    let short = dir.join("short.npy");
    write_npy(&short, &[1.0; 8]);
    let zeros = dir.join("zeros.npy");
    write_npy(&zeros, &[0.0; 22]);
    // `--name NAME --vocabulary LOG`, LOG the 22-d log or the 16-d one.
    let by_name = |name: &'static str, dim: u32, extra: &[&'static str]| {
        let vocabulary = if dim == 16 { &s16 } else { &s22 };
        let mut a = vec![
            os("query"),
            run.as_os_str(),
            os("--name"),
            os(name),
            os("--vocabulary"),
            vocabulary.as_os_str(),
        ];
        a.extend(extra.iter().map(|s| os(s)));
        a
    };
    let nowhere = dir.join("nowhere");
    fails_clearly(&[
        (
            vec![
                os("query"),
                run.as_os_str(),
                os("--embedding"),
                short.as_os_str(),
            ],
            1,
            "the query has 8 values; the map's embeddings are 22-d",
        ),
        (
            vec![
                os("query"),
                run.as_os_str(),
                os("--embedding"),
                zeros.as_os_str(),
            ],
            1,
            "all zeros",
        ),
        (
            by_name("sofa", 22, &[]),
            1,
            "`sofa` is not in the vocabulary",
        ),
        (
            by_name("ball", 16, &[]),
            1,
            "16-d embeddings (the vocabulary's",
        ),
        (
            by_name("ball", 22, &["--vocabulary-topic", "/nope"]),
            1,
            "has no vocabulary on /nope",
        ),
        (
            by_name("ball", 22, &["--temperature", "0"]),
            1,
            "--temperature must be positive",
        ),
        (
            // Past f32's range: infinite, and said so.
            by_name("ball", 22, &["--temperature", "1e308"]),
            1,
            "must be positive and finite, got inf",
        ),
        (
            vec![
                os("query"),
                plain.as_os_str(),
                os("--embedding"),
                zeros.as_os_str(),
            ],
            1,
            "mapped without embeddings",
        ),
        (
            vec![
                os("query"),
                nowhere.as_os_str(),
                os("--embedding"),
                short.as_os_str(),
            ],
            1,
            "loading the map",
        ),
    ]);
    let out = dir.join("views").join("v");
    let render = |extra: &[&'static str]| {
        let mut a = vec![os("render"), run.as_os_str(), os("--out"), out.as_os_str()];
        a.extend(extra.iter().map(|s| os(s)));
        a
    };
    let render_frame = |run: &std::path::Path, n: &'static str, extra: &[&'static str]| {
        let mut a = vec![
            os("render").to_owned(),
            run.as_os_str().to_owned(),
            s22.as_os_str().to_owned(),
            os("--frame").to_owned(),
            os(n).to_owned(),
            os("--out").to_owned(),
            out.as_os_str().to_owned(),
        ];
        a.extend(extra.iter().map(|s| os(s).to_owned()));
        a
    };
    let (f99, plain_named, sofa) = (
        render_frame(&run, "99", &[]),
        render_frame(&plain, "0", &["--name", "ball"]),
        render_frame(&run, "0", &["--name", "sofa"]),
    );
    let mut both = render_frame(&run, "0", &["--view"]);
    both.push("0,0,0,0,0,0,1".into());
    fn refs(v: &[std::ffi::OsString]) -> Vec<&std::ffi::OsStr> {
        v.iter().map(|s| s.as_os_str()).collect()
    }
    fails_clearly(&[
        (render(&[]), 2, "--frame"),
        (render(&["--frame", "3"]), 2, "<LOG>"),
        (
            render(&["--view", "0,0,0,0,0,0,1", "--name", "ball"]),
            1,
            "--name needs --vocabulary LOG",
        ),
        (refs(&f99), 1, "has 4 frames: there is no frame 99"),
        (refs(&plain_named), 1, "mapped without embeddings"),
        (refs(&sofa), 1, "`sofa` is not in the vocabulary"),
        (refs(&both), 2, "cannot be used with"),
    ]);
    assert!(
        !dir.join("views").exists(),
        "a failed render wrote pictures"
    );
    let fox = dir.join("fox.mcap");
    let export = |run: &std::path::Path, extra: &[&'static str]| {
        let mut a = vec![
            os("export").to_owned(),
            run.as_os_str().to_owned(),
            os("--foxglove").to_owned(),
            fox.as_os_str().to_owned(),
        ];
        a.extend(extra.iter().map(|s| os(s).to_owned()));
        a
    };
    let mut other_vocabulary = export(&run, &["--vocabulary"]);
    other_vocabulary.push(s16.clone().into());
    let mut unknown_word = export(&run, &["--words", "sofa", "--vocabulary"]);
    unknown_word.push(s22.clone().into());
    fails_clearly(&[
        (
            refs(&export(&plain, &["--words", "ball"])),
            1,
            "--words needs a vocabulary: the map was mapped without embeddings",
        ),
        (refs(&unknown_word), 1, "`sofa` is not in the vocabulary"),
        (
            refs(&other_vocabulary),
            1,
            "16-d embeddings (the vocabulary's",
        ),
        (
            refs(&export(&run, &["--temperature", "0"])),
            1,
            "--temperature must be positive",
        ),
        (
            refs(&export(&run, &["--frame-id", " "])),
            1,
            "--frame-id must name a frame",
        ),
    ]);
    assert!(!fox.exists(), "a failed export wrote a file");
    // A map without embeddings exports its cloud and trajectory only.
    let stdout = run_ok(&refs(&export(&plain, &[])));
    assert!(
        stdout.contains("/latentam/map") && !stdout.contains("/latentam/relevance"),
        "{stdout}"
    );
    assert!(fox.exists());
    std::fs::remove_dir_all(&dir).ok();
}

/// Makes a FIFO at `path`.
fn mkfifo(path: &std::path::Path) {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: `c` is a NUL-terminated path that outlives the call.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

#[test]
fn fifos_given_as_inputs_are_refused_without_blocking() {
    use std::ffi::OsStr;
    use std::process::Stdio;
    use std::time::{Duration, Instant};

    let dir = common::scratch("cli-fifo");
    let fifo = dir.join("x.mcap");
    mkfifo(&fifo);
    // A rosbag2 folder whose split file is a link to the FIFO.
    let bag = dir.join("bag");
    std::fs::create_dir(&bag).unwrap();
    std::os::unix::fs::symlink(&fifo, bag.join("bag_0.mcap")).unwrap();
    // TUM folders: one whose list is a FIFO, one whose images are.
    let tum_list = dir.join("tum-list");
    std::fs::create_dir(&tum_list).unwrap();
    mkfifo(&tum_list.join("rgb.txt"));
    let tum_images = dir.join("tum-images");
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(tum_images.join(sub)).unwrap();
        mkfifo(&tum_images.join(sub).join("1.png"));
    }
    for (name, text) in [
        ("rgb.txt", "1.0 rgb/1.png\n"),
        ("depth.txt", "1.0 depth/1.png\n"),
        ("groundtruth.txt", "1.0 0 0 0 0 0 0 1\n"),
    ] {
        std::fs::write(tum_images.join(name), text).unwrap();
    }
    let scene = common::gen_scene(&dir, 3);
    let run = dir.join("run");
    run_ok(&[
        OsStr::new("map"),
        scene.as_os_str(),
        OsStr::new("--out"),
        run.as_os_str(),
    ]);
    let out = dir.join("out");
    let converted = dir.join("converted.mcap");

    let os = |s: &'static str| -> &OsStr { s.as_ref() };
    let cases: Vec<Vec<&OsStr>> = vec![
        vec![os("inspect"), fifo.as_os_str()],
        vec![os("inspect"), bag.as_os_str()],
        vec![os("map"), fifo.as_os_str(), os("--out"), out.as_os_str()],
        vec![os("map"), bag.as_os_str(), os("--out"), out.as_os_str()],
        vec![
            os("map"),
            scene.as_os_str(),
            os("--config"),
            fifo.as_os_str(),
            os("--out"),
            out.as_os_str(),
        ],
        vec![os("config"), os("--config"), fifo.as_os_str()],
        vec![os("eval"), run.as_os_str(), fifo.as_os_str()],
        vec![
            os("query"),
            run.as_os_str(),
            os("--embedding"),
            fifo.as_os_str(),
        ],
        vec![
            os("query"),
            run.as_os_str(),
            os("--name"),
            os("chair"),
            os("--vocabulary"),
            fifo.as_os_str(),
        ],
        vec![
            os("convert"),
            os("tum"),
            tum_list.as_os_str(),
            os("-o"),
            converted.as_os_str(),
        ],
        vec![
            os("convert"),
            os("tum"),
            tum_images.as_os_str(),
            os("--intrinsics"),
            os("500"),
            os("500"),
            os("320"),
            os("240"),
            os("-o"),
            converted.as_os_str(),
        ],
    ];
    for args in cases {
        let mut child = latentam()
            .args(&args)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let started = Instant::now();
        while child.try_wait().unwrap().is_none() {
            if started.elapsed() > Duration::from_secs(20) {
                child.kill().unwrap();
                let _ = child.wait();
                panic!("latentam {args:?} blocked on the FIFO for 20 s");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let output = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains("a FIFO, not a regular file") && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
    assert!(!out.exists() && !converted.exists());
    std::fs::remove_dir_all(&dir).ok();
}

/// Text from the command line or a file is printed defused: an escape
/// sequence in a value is shown escaped, never sent to the terminal, and a
/// huge value is cut.
#[test]
fn errors_show_escape_sequences_escaped_and_huge_values_cut() {
    let dir = std::env::temp_dir().join(format!("latentam-hygiene-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let missing = dir.join("missing.mcap");
    for value in ["\u{1b}[2J\rerror: forged".to_string(), "9".repeat(100_000)] {
        let out = latentam()
            .arg("map")
            .arg(&missing)
            .arg("--out")
            .arg(dir.join("run"))
            .arg("--set")
            .arg(format!("seeding.stride={value}"))
            .output()
            .unwrap();
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !stderr.contains('\u{1b}') && !stderr.contains('\r'),
            "{stderr:?}"
        );
        assert!(stderr.len() < 10_000, "{} bytes of stderr", stderr.len());
        assert!(stderr.starts_with("error: "), "{stderr:?}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
