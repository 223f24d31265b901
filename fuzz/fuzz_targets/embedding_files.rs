//! See `latentam_fuzz_targets::embedding_files`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| latentam_fuzz_targets::embedding_files::run(data));
