#![no_main]
//! libFuzzer target: the `laz_positions` reader (see `timesift_fuzz::Target::LazPositions`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::LazPositions, data);
});
