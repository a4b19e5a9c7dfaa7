//! `timesift features`: the text format of docs/design.md on a real photo, the budget, the mask, and
//! clear errors.

use std::path::PathBuf;

use crate::common::timesift;
use timesift_core::Descriptors;
use timesift_features::text::{DescriptorKind, read};

fn lund(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/opensfm/lund/images")
        .join(name)
}

#[test]
fn features_command_writes_the_text_format() {
    let dir = tempfile::tempdir().unwrap();
    let image = lund("01.jpg");
    let sift = dir.path().join("sift.txt");
    let (ok, out, err) = timesift(&[
        "features",
        image.to_str().unwrap(),
        "--max",
        "500",
        "--out",
        sift.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("500 keypoints"), "{out}");
    let features = read(&sift, DescriptorKind::Float).unwrap();
    assert_eq!(features.keypoints.len(), 500);
    let Descriptors::Float { dim, data } = &features.descriptors else {
        panic!("float descriptors")
    };
    assert_eq!(*dim, 128);
    // Unit-norm SIFT vectors.
    for d in data.chunks(128) {
        let norm: f32 = d.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-3, "norm {norm}");
    }
    assert!(
        features
            .keypoints
            .iter()
            .all(|k| k.x > 0.0 && k.x < 1024.0 && k.y > 0.0 && k.y < 768.0)
    );

    let ldb = dir.path().join("ldb.txt");
    let (ok, _, err) = timesift(&[
        "features",
        image.to_str().unwrap(),
        "--method",
        "ldb",
        "--out",
        ldb.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let features = read(&ldb, DescriptorKind::Binary).unwrap();
    assert!(features.keypoints.len() > 1000);
    assert_eq!(features.descriptors.width(), 61);
    let header = std::fs::read_to_string(&ldb).unwrap();
    assert!(header.starts_with(&format!("{} 61\n", features.keypoints.len())));
}

#[test]
fn features_command_honours_a_mask_and_reports_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let image = lund("02.jpg");
    // Keypoints only in the right half.
    let mask = image::GrayImage::from_fn(1024, 768, |x, _| {
        image::Luma([if x >= 512 { 255 } else { 0 }])
    });
    let mask_path = dir.path().join("mask.png");
    mask.save(&mask_path).unwrap();
    let out_path = dir.path().join("masked.txt");
    let (ok, _, err) = timesift(&[
        "features",
        image.to_str().unwrap(),
        "--mask",
        mask_path.to_str().unwrap(),
        "--out",
        out_path.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let features = read(&out_path, DescriptorKind::Float).unwrap();
    assert!(!features.keypoints.is_empty());
    assert!(features.keypoints.iter().all(|k| k.x >= 512.0));

    let small = image::GrayImage::from_pixel(100, 100, image::Luma([255]));
    let small_path = dir.path().join("small.png");
    small.save(&small_path).unwrap();
    let (ok, _, err) = timesift(&[
        "features",
        image.to_str().unwrap(),
        "--mask",
        small_path.to_str().unwrap(),
        "--out",
        out_path.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(
        err.contains("small.png") && err.contains("100 × 100"),
        "{err}"
    );

    let missing = dir.path().join("nope.jpg");
    let (ok, _, err) = timesift(&[
        "features",
        missing.to_str().unwrap(),
        "--out",
        out_path.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(err.contains("nope.jpg"), "{err}");
}
