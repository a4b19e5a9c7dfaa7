#![no_main]
//! libFuzzer target: the `colmap_text` reader (see `timesift_fuzz::Target::ColmapText`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::ColmapText, data);
});
