//! `tools/gpu-check --quick` on lavapipe: the one command meant for a
//! machine with a GPU runs every step and writes what it promises, so it
//! works on the day a GPU is there.

use std::path::Path;
use std::process::Command;

mod common;
use common::scratch;

#[test]
fn the_gpu_check_runs_every_step_and_writes_its_files() {
    let dir = scratch("gpu-check");
    let out = dir.join("out");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("gpu-check");
    let run = Command::new(&script)
        .arg(&out)
        .arg("--quick")
        .env("LATENTAM_BIN", env!("CARGO_BIN_EXE_latentam"))
        .output()
        .unwrap();
    let steps = std::fs::read_to_string(out.join("steps.jsonl")).unwrap();
    assert!(
        run.status.success(),
        "{steps}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let steps: Vec<serde_json::Value> = steps
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let names: Vec<&str> = steps.iter().map(|s| s["step"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "devices",
            "selfcheck",
            "map-auto",
            "raster",
            "latent",
            "decode",
            "map-pixels",
            "map-columns",
            "live",
            "primitives"
        ]
    );
    assert!(steps.iter().all(|s| s["status"] == 0), "{steps:?}");
    let json = |name: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(out.join(name)).unwrap()).unwrap()
    };
    for f in ["primitives.json", "raster.json", "latent.json", "live.json"] {
        json(f);
    }
    // Every kernel's build time, each with its two parts.
    let kernels = json("kernels.json");
    let kernels = kernels["kernels"].as_array().unwrap();
    assert!(kernels.len() > 40, "{} kernels", kernels.len());
    for k in kernels {
        assert!(k["create_ms"].as_f64().unwrap() > 0.0, "{k}");
        assert!(k["first_dispatch_ms"].as_f64().unwrap() > 0.0, "{k}");
    }
    // The per-pixel evaluation on the device agrees with the CPU's.
    let decode = json("decode.json");
    assert!(decode["device_ms_median"].as_f64().unwrap() > 0.0);
    assert!(
        decode["cosine_loss_difference"].as_f64().unwrap() < 1e-4,
        "{decode}"
    );
    // Both blending layouts map the same keyframes of the same scene.
    let (pixels, columns) = (json("map-pixels.json"), json("map-columns.json"));
    assert_eq!(pixels["keyframes"], columns["keyframes"]);
    assert!(pixels["keyframes"].as_u64().unwrap() > 0);
    assert!(std::fs::read_to_string(out.join("selfcheck.log"))
        .unwrap()
        .contains("match their CPU references"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_gpu_check_says_how_to_use_it() {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("gpu-check");
    let run = Command::new(&script).output().unwrap();
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains("usage: tools/gpu-check OUT"));
    let run = Command::new(&script)
        .arg(std::env::temp_dir().join("latentam-gpu-check-unused"))
        .env("LATENTAM_BIN", "/nonexistent/latentam")
        .output()
        .unwrap();
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains("no binary at /nonexistent/latentam"));
}
