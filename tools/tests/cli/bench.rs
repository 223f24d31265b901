//! `selfcheck` and the `bench` subcommands: their JSON, and their refusals.

use super::*;

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
    // Stage I's measure and Stage II's end: Stage I's step is not waited
    // for (Stage II's wait covers it).
    assert_eq!(calls["stage_one_and_two_max"], 2, "{calls}");
    assert!(calls["dispatches_mean"].as_f64().unwrap() > 50.0, "{calls}");
    let atoms: Vec<u64> = curve.iter().map(|p| p["atoms"].as_u64().unwrap()).collect();
    assert!(
        atoms[0] > 0 && atoms.windows(2).all(|w| w[1] >= w[0]),
        "{atoms:?}"
    );
    assert!(curve.iter().all(|p| p["stage_one_and_two_waits"] == 2));
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

#[test]
fn bench_query_scores_a_spilled_map_and_writes_json() {
    let dir = common::scratch("bench-query");
    let log = common::gen_scene(&dir, 12);
    let run = dir.join("run");
    run_ok(&[
        "map".as_ref(),
        log.as_os_str(),
        "--out".as_ref(),
        run.as_os_str(),
        "--no-trace".as_ref(),
    ]);
    let spill = dir.join("spill").display().to_string();
    let v = bench_json(
        "query",
        &[
            "query",
            run.to_str().unwrap(),
            "--runs",
            "5",
            "--host-budget",
            "1",
            "--spill-dir",
            &spill,
        ],
    );
    let gaussians = v["gaussians"].as_u64().unwrap();
    assert!(gaussians > 0);
    assert_eq!(v["gaussians"], common::report(&run)["gaussians"]);
    // A one-byte budget: everything but nothing is spilled once loaded.
    assert!(v["spilled_gaussians"].as_u64().unwrap() > 0, "{v}");
    assert_eq!(v["runs"], 5);
    assert_eq!(v["query_ms"].as_array().unwrap().len(), 5);
    let (p50, p99, max) = (
        v["p50_ms"].as_f64().unwrap(),
        v["p99_ms"].as_f64().unwrap(),
        v["max_ms"].as_f64().unwrap(),
    );
    assert!(0.0 < p50 && p50 <= p99 && p99 <= max, "{v}");
    assert!(v["first_query_ms"].as_f64().unwrap() > 0.0);
    assert!(v["peak_rss_bytes"].as_u64().unwrap() > 0);
    std::fs::remove_dir_all(&dir).ok();
}
