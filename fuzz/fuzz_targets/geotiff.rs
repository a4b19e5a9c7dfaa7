#![no_main]
//! libFuzzer target: the `geotiff` reader (see `timesift_fuzz::Target::Geotiff`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::Geotiff, data);
});
