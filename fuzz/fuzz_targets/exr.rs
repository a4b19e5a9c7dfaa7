#![no_main]
//! libFuzzer target: the `exr` reader (see `timesift_fuzz::Target::Exr`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::Exr, data);
});
