#![no_main]
//! libFuzzer target: the `libmv` reader (see `timesift_fuzz::Target::Libmv`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::Libmv, data);
});
