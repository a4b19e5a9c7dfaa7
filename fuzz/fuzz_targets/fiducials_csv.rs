#![no_main]
//! libFuzzer target: the `fiducials_csv` reader (see `timesift_fuzz::Target::FiducialsCsv`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::FiducialsCsv, data);
});
