//! End-to-end tests of the `latentam` binary, one module per subject.

#[path = "../common/mod.rs"]
mod common;
use common::{latentam, write_npy};

mod bench;
mod hostile_input;
mod logs;
mod misuse;

/// Runs the binary with `args`, checks it succeeded and returns its stdout.
fn run_ok(args: &[&std::ffi::OsStr]) -> String {
    let out = latentam().args(args).output().unwrap();
    assert!(
        out.status.success(),
        "latentam {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}
