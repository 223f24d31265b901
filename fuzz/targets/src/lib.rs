//! # latentam-fuzz-targets
//!
//! The bodies of latentam's fuzz targets, one module each with a
//! `run(data: &[u8])` that may see any bytes: the readers it drives may
//! refuse the input but must not panic, and what they accept must hold
//! together (each module says what it checks).
//!
//! They live in a library of the main workspace, so that the stable
//! toolchain builds them and `tests/corpus.rs` replays the corpus the
//! fuzzers found (`fuzz/corpus/<target>/`) on every test run. The
//! `cargo fuzz` crate in `fuzz/` (nightly, sanitizers) wraps each in a
//! `fuzz_target!`; the Fuzzing section of `docs/bad-input.md` says how to
//! run them.

pub mod cdr_messages;
pub mod embedding_files;
pub mod frame_assembler;
pub mod map_load;
pub mod settings;

/// A target's body: one input, any bytes.
pub type Target = fn(&[u8]);

/// Every target by the name of its corpus folder, for the corpus replay.
pub const TARGETS: &[(&str, Target)] = &[
    ("cdr_messages", cdr_messages::run),
    ("embedding_files", embedding_files::run),
    ("frame_assembler", frame_assembler::run),
    ("map_load", map_load::run),
    ("settings", settings::run),
];
