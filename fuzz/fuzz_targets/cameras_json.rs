#![no_main]
//! libFuzzer target: the `cameras_json` reader (see `timesift_fuzz::Target::CamerasJson`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::CamerasJson, data);
});
