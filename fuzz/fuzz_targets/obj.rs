#![no_main]

// The OBJ loader catches a panic of the tobj parser and reports it as an error; only
// panics that escape are crashes (they abort at the fuzzer's boundary), so the handled
// ones must not abort through libFuzzer's panic hook.
libfuzzer_sys::fuzz_target!(init: { std::panic::set_hook(Box::new(|_| {})) }, |data: &[u8]| tilefarm_fuzz::obj(data));
