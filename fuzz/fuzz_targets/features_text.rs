#![no_main]
//! libFuzzer target: the `features_text` reader (see `timesift_fuzz::Target::FeaturesText`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::FeaturesText, data);
});
