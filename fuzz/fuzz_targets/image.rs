#![no_main]
//! libFuzzer target: the `image` reader (see `timesift_fuzz::Target::Image`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::Image, data);
});
