#![no_main]
//! libFuzzer target: the `gcps_csv` reader (see `timesift_fuzz::Target::GcpsCsv`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::GcpsCsv, data);
});
