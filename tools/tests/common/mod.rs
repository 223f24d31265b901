//! Helpers shared by the integration tests of the `latentam` binary.

// Each test file uses a different subset.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Embedding dimension of the logs [`gen_scene`] writes.
pub const SCENE_DIM: usize = 64;

/// The binary under test, with the Vulkan validation layer required.
pub fn latentam() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_latentam"));
    c.env("LATENTAM_VALIDATION", "1");
    c
}

/// The binary without the validation layer, for tests that map a lot and
/// check files rather than API use.
pub fn latentam_fast() -> Command {
    Command::new(env!("CARGO_BIN_EXE_latentam"))
}

/// Asserts that a command failed and its stderr holds every one of
/// `words`; returns the stderr.
pub fn failed_with(out: &Output, words: &[&str]) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "should have failed:\n{stderr}");
    for w in words {
        assert!(stderr.contains(w), "no `{w}` in:\n{stderr}");
    }
    stderr
}

/// A run folder's `report.json`.
pub fn report(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap()
}

/// An empty folder of this test process's own.
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("latentam-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A generated log of `frames` frames of 120×90 with [`SCENE_DIM`]-d
/// embeddings, written to `dir/scene.mcap`.
pub fn gen_scene(dir: &Path, frames: usize) -> PathBuf {
    let log = dir.join("scene.mcap");
    let out = latentam()
        .args(["gen-scene", "--width", "120", "--height", "90"])
        .args([
            "--frames",
            &frames.to_string(),
            "--dim",
            &SCENE_DIM.to_string(),
        ])
        .arg("--out")
        .arg(&log)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "gen-scene failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    log
}

/// A `.npy` file holding one f32 vector.
pub fn write_npy(path: &Path, v: &[f32]) {
    let mut header = format!(
        "{{'descr': '<f4', 'fortran_order': False, 'shape': ({},), }}",
        v.len()
    );
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    bytes.extend(v.iter().flat_map(|x| x.to_le_bytes()));
    std::fs::write(path, bytes).unwrap();
}

/// Runs `tests/python/SCRIPT` with `args` under `$LATENTAM_PYTHON` (else
/// `python3`) and returns its stdout; `tools/run test` sets up the
/// packages the scripts need.
pub fn run_python(script: &str, args: &[&std::ffi::OsStr]) -> String {
    let python = std::env::var("LATENTAM_PYTHON").unwrap_or_else(|_| "python3".into());
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/python")
        .join(script);
    let out = Command::new(&python)
        .arg(&path)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    assert!(
        out.status.success(),
        "{} failed ({}): {}\n(tools/run test installs the Python packages it needs)",
        path.display(),
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}
