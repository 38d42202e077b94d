#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| tilefarm_fuzz::mtl(data));
