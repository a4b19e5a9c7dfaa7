#![no_main]
//! libFuzzer target: the `ply` reader (see `timesift_fuzz::Target::Ply`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::Ply, data);
});
