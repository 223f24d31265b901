//! See `latentam_fuzz_targets::cdr_messages`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| latentam_fuzz_targets::cdr_messages::run(data));
