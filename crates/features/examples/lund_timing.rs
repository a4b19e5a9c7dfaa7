//! Seconds per image of SIFT on the `lund` photos, decoding excluded: the loop to profile
//! (`perf record cargo run --release -p timesift-features --example lund_timing`).

use std::time::Instant;

use timesift_features::{FeatureExtractor, GreyImage, SiftExtractor};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/opensfm/lund/images");
    let mut paths: Vec<_> = std::fs::read_dir(&dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    paths.sort();
    let images: Vec<_> = paths
        .iter()
        .map(|p| timesift_io::image::read_grey(p))
        .collect::<Result<_, _>>()?;
    let extractor = SiftExtractor::default();
    let start = Instant::now();
    let mut keypoints = 0;
    for image in &images {
        let grey = GreyImage::from_io(image)?;
        keypoints += extractor.extract(&grey, None)?.keypoints.len();
    }
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "{} images, {:.3} s per image, {} keypoints per image",
        images.len(),
        seconds / images.len() as f64,
        keypoints / images.len()
    );
    Ok(())
}
