#![no_main]
//! libFuzzer target: the `bal` reader (see `timesift_fuzz::Target::Bal`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::Bal, data);
});
