//! See `latentam_fuzz_targets::frame_assembler`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| latentam_fuzz_targets::frame_assembler::run(data));
