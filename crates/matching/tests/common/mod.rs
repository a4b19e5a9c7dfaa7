//! Shared set-up of the matching tests: the rendered `landslide` scene with its true cameras,
//! and the extractor the tests match with.

#![allow(dead_code)]

use timesift_features::{DetectorOptions, KeypointLimit, SiftExtractor, SiftNormalization};
use timesift_io::cameras_json::{Reconstruction, read_cameras_json};
use timesift_synth::scenes::{Scale, build};
use timesift_synth::writer::{WriteOptions, write_scene};

/// A rendered scene: its directory (removed on drop), true cameras and epoch names in order.
pub struct Rendered {
    pub dir: tempfile::TempDir,
    pub truth: Reconstruction,
    pub epochs: Vec<String>,
}

/// `landslide` at the small scale, seed 1, written with its images.
pub fn landslide() -> Rendered {
    let dir = tempfile::tempdir().unwrap();
    let spec = build("landslide", Scale::Small, 1).unwrap();
    write_scene(&spec, dir.path(), &WriteOptions::default()).unwrap();
    let truth = read_cameras_json(&dir.path().join("truth/cameras.json")).unwrap();
    let mut epochs: Vec<String> = truth.images.iter().map(|i| i.epoch.clone()).collect();
    epochs.sort();
    epochs.dedup();
    Rendered { dir, truth, epochs }
}

/// RootSIFT with at most `budget` keypoints, spread by the default rule.
pub fn rootsift(budget: usize) -> SiftExtractor {
    SiftExtractor {
        detector: DetectorOptions {
            limit: Some(KeypointLimit::spread(budget)),
            ..DetectorOptions::default()
        },
        normalization: SiftNormalization::Root,
    }
}
