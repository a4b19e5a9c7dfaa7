#![no_main]
//! libFuzzer target: the `las` reader (see `timesift_fuzz::Target::Las`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::Las, data);
});
