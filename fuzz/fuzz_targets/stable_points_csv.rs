#![no_main]
//! libFuzzer target: the `stable_points_csv` reader (see `timesift_fuzz::Target::StablePointsCsv`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::StablePointsCsv, data);
});
