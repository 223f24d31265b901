//! Replays every input of `fuzz/corpus/<target>/` through its target: the
//! inputs the fuzzers kept for the coverage they reach, and those that once
//! found a bug (named `crash-*`), so a change that breaks what they cover
//! fails here on the stable toolchain without a fuzzing run.

use std::path::PathBuf;

use latentam_fuzz_targets::TARGETS;

fn corpus_dir(target: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../corpus")
        .join(target)
}

#[test]
fn every_corpus_input_runs_through_its_target() {
    for (name, run) in TARGETS {
        let dir = corpus_dir(name);
        let mut inputs: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .collect();
        inputs.sort();
        assert!(
            inputs.len() >= 10,
            "{}: {} inputs; a fuzzing run leaves its corpus here (docs/fuzzing.md)",
            dir.display(),
            inputs.len()
        );
        for input in &inputs {
            let bytes = std::fs::read(input).unwrap();
            let outcome = std::panic::catch_unwind(|| run(&bytes));
            assert!(outcome.is_ok(), "{name}: {} panicked", input.display());
        }
        eprintln!("{name}: {} inputs replayed", inputs.len());
    }
}
