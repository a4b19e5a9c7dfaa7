#![no_main]
//! libFuzzer target: the `project_toml` reader (see `timesift_fuzz::Target::ProjectToml`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::ProjectToml, data);
});
