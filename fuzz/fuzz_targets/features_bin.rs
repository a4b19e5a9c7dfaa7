#![no_main]
//! libFuzzer target: the `features_bin` reader (see `timesift_fuzz::Target::FeaturesBin`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::FeaturesBin, data);
});
