#![no_main]
//! libFuzzer target: the `stable_areas_wkt` reader (see `timesift_fuzz::Target::StableAreasWkt`).

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    timesift_fuzz::fuzz(timesift_fuzz::Target::StableAreasWkt, data);
});
