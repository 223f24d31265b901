//! The C API from C and C++: the checked-in header is the one cbindgen
//! makes of the code, the C example compiles with `-Wall -Werror` against
//! it and maps a generated log (misuse answered with status codes, a freed
//! handle refused), also under AddressSanitizer and UBSan, the C++
//! example does the same through the RAII wrapper, and each kind of error
//! (a setting, a damaged file, an argument) has its own status.

use std::path::{Path, PathBuf};
use std::process::Command;

fn crate_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Where `cargo test` put `liblatentam_c.so`: the `deps` folder holding
/// this test (the crate also builds as an rlib so that cargo builds the
/// shared library for its integration tests; `cargo build` alone would copy
/// it one folder up, which `cargo test` does not do).
fn library_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().unwrap().to_path_buf();
    assert!(
        dir.join("liblatentam_c.so").exists(),
        "{} has no liblatentam_c.so",
        dir.display()
    );
    dir
}

fn compile(compiler: &str, source: &Path, out: &Path, extra: &[&str]) {
    let lib = library_dir();
    let status = Command::new(compiler)
        .args(["-Wall", "-Wextra", "-Werror"])
        .args(extra)
        .arg("-I")
        .arg(crate_dir().join("include"))
        .arg(source)
        .arg("-L")
        .arg(&lib)
        .arg("-llatentam_c")
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .arg("-o")
        .arg(out)
        .status()
        .unwrap_or_else(|e| panic!("running {compiler}: {e} (tools/run test installs gcc)"));
    assert!(
        status.success(),
        "{compiler} failed on {}",
        source.display()
    );
}

#[test]
fn header_is_current() {
    let generated = std::fs::read_to_string(Path::new(env!("OUT_DIR")).join("latentam.h")).unwrap();
    let checked_in = std::fs::read_to_string(crate_dir().join("include/latentam.h")).unwrap();
    assert!(
        generated == checked_in,
        "include/latentam.h is stale: run `LATENTAM_WRITE_HEADER=1 cargo build -p latentam-capi`"
    );
}

#[test]
fn the_c_and_cpp_examples_map_a_log() {
    let dir = std::env::temp_dir().join(format!("latentam-capi-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("scene.mcap");
    let scene = latentam_scene::SceneConfig {
        frames: 24,
        dim: 32,
        ..Default::default()
    };
    latentam_scene::generate(&scene, &log, |_| {}).unwrap();

    let c = dir.join("map_log");
    compile(
        "cc",
        &crate_dir().join("examples/map_log.c"),
        &c,
        &["-std=gnu11"],
    );
    let out = Command::new(&c)
        .arg(&log)
        .arg(dir.join("run-c"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("frames 24 keyframes 6 gaussians") && stdout.contains("dropped 0"),
        "{stdout}"
    );
    assert!(dir.join("run-c/state.latentam").exists());

    // The C side under AddressSanitizer and UBSan: the example's use of
    // the API reads and writes only what it owns (leak checking is off:
    // the Vulkan driver keeps allocations until exit on purpose).
    let asan = dir.join("map_log_asan");
    compile(
        "cc",
        &crate_dir().join("examples/map_log.c"),
        &asan,
        &[
            "-std=gnu11",
            "-fsanitize=address,undefined",
            "-fno-omit-frame-pointer",
        ],
    );
    let out = Command::new(&asan)
        .arg(&log)
        .arg(dir.join("run-asan"))
        .env("ASAN_OPTIONS", "detect_leaks=0")
        .env("UBSAN_OPTIONS", "halt_on_error=1")
        .output()
        .unwrap();
    assert!(
        out.status.success() && String::from_utf8_lossy(&out.stdout).contains("keyframes 6"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let cpp = dir.join("map_log_cpp");
    compile(
        "c++",
        &crate_dir().join("examples/map_log.cpp"),
        &cpp,
        &["-std=c++17"],
    );
    let out = Command::new(&cpp)
        .arg(&log)
        .arg(dir.join("run-cpp"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("frames 24"));
    assert!(dir.join("run-cpp/state.latentam").exists());

    // A byte of the saved map's tensors changed: its checksum no longer
    // matches, and loading it says so with its own status.
    let state = dir.join("run-c/state.latentam");
    let mut bytes = std::fs::read(&state).unwrap();
    let last = bytes.len() - 5;
    bytes[last] ^= 0x40;
    std::fs::write(&state, bytes).unwrap();
    let kinds = dir.join("error_kinds");
    compile(
        "cc",
        &crate_dir().join("tests/error_kinds.c"),
        &kinds,
        &["-std=gnu11"],
    );
    let out = Command::new(&kinds)
        .arg(dir.join("run-c"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("every kind has its status"));
    std::fs::remove_dir_all(&dir).unwrap();
}
