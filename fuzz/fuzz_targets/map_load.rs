//! See `latentam_fuzz_targets::map_load`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| latentam_fuzz_targets::map_load::run(data));
