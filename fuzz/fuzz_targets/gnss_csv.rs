#![no_main]
//! libFuzzer target: the `gnss_csv` reader (see `timesift_fuzz::Target::GnssCsv`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::GnssCsv, data);
});
