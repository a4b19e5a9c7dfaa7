#![no_main]
//! libFuzzer target: the `matches_bin` reader (see `timesift_fuzz::Target::MatchesBin`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::MatchesBin, data);
});
