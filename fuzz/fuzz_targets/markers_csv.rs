#![no_main]
//! libFuzzer target: the `markers_csv` reader (see `timesift_fuzz::Target::MarkersCsv`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::MarkersCsv, data);
});
