#![no_main]
//! libFuzzer target: the `scalebars_csv` reader (see `timesift_fuzz::Target::ScalebarsCsv`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::ScalebarsCsv, data);
});
