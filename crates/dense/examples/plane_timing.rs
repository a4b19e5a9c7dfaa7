//! Seconds per view and pass of PatchMatch on the rendered plane of the tests: the loop to
//! profile (`cargo run --release -p timesift-dense --example plane_timing [level]`).

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::Instant;

use timesift_dense::{DenseOptions, reconstruct_epoch};

fn main() {
    let level: u32 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(1);
    let scene = common::plane(320, 240);
    let views = scene.views();
    let masks = vec![None; views.len()];
    let mut options = DenseOptions::default();
    options.plan.level = level;
    let start = Instant::now();
    let result = reconstruct_epoch(&scene.input, &views, &masks, &options).expect("dense");
    let seconds = start.elapsed().as_secs_f64();
    let pixels: usize = result
        .plan
        .views
        .iter()
        .map(|v| v.camera.width * v.camera.height)
        .sum();
    println!(
        "{} views, {:.2} s, {:.2} µs per working pixel, {} fused points",
        views.len(),
        seconds,
        seconds * 1e6 / pixels as f64,
        result.cloud.len()
    );
}
