#![no_main]
//! libFuzzer target: the `exif` reader (see `timesift_fuzz::Target::Exif`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::Exif, data);
});
