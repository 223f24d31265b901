//! See `latentam_fuzz_targets::settings`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| latentam_fuzz_targets::settings::run(data));
