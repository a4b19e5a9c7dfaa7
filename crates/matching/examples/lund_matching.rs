//! Exhaustive matching of the 29 `lund` photos (RootSIFT, 8192 keypoints at most): seconds for
//! extraction, descriptor matching and verification, verified pairs and median inliers — the
//! loop to profile and to try settings on. Environment: `RAYON_NUM_THREADS` (threads),
//! `CONTRAST` (detector contrast threshold, default 0.02), `EUCLIDEAN` (ratio on distances
//! instead of angles), `UNCALIBRATED` (fundamental instead of essential with EXIF focal),
//! `ITERATIONS` (RANSAC cap), `BUDGET` (keypoints per image, default 8192), `NOMUTUAL` (no
//! mutual check), `PAIRS` (print every pair's matches and inliers), `UNGUIDED` (no guided
//! matching after verification), `PRESELECT` (preselection settings against the verified pairs).

use std::path::PathBuf;
use std::time::Instant;

use rayon::prelude::*;
use timesift_core::{CameraModel, PinholeCamera};
use timesift_features::{
    DetectorOptions, FeatureExtractor, KeypointLimit, SiftExtractor, SiftNormalization,
};
use timesift_matching::guided::{GuidedOptions, grow_verified};
use timesift_matching::pairs::{PairPolicy, select};
use timesift_matching::preselect::{PreselectOptions, coarse_matches, preselect};
use timesift_matching::verify::{VerifyOptions, verify_pair};
use timesift_matching::{FloatDistance, MatchOptions, match_descriptors};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/opensfm/lund/images");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    paths.sort();
    let extractor = SiftExtractor {
        detector: DetectorOptions {
            limit: Some(KeypointLimit::spread(
                std::env::var("BUDGET")
                    .ok()
                    .and_then(|v| v.parse().ok())
                    .unwrap_or(8192),
            )),
            contrast_threshold: std::env::var("CONTRAST")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(0.02),
            ..DetectorOptions::default()
        },
        normalization: SiftNormalization::Root,
    };
    let start = Instant::now();
    let features = paths
        .par_iter()
        .map(|p| timesift_features::files::extract_file(p, &extractor as &dyn FeatureExtractor))
        .collect::<Result<Vec<_>, _>>()?;
    let extraction = start.elapsed().as_secs_f64();
    let n = features.len();
    let pairs = select(
        &(0..n).collect::<Vec<_>>(),
        &vec![None; n],
        PairPolicy::Exhaustive,
    );
    let start = Instant::now();
    let matches = pairs
        .par_iter()
        .map(|&(a, b)| {
            match_descriptors(
                &features[a].descriptors,
                &features[b].descriptors,
                &MatchOptions {
                    ratio_on: if std::env::var("EUCLIDEAN").is_ok() {
                        FloatDistance::Euclidean
                    } else {
                        FloatDistance::Angle
                    },
                    mutual: std::env::var("NOMUTUAL").is_err(),
                    ..MatchOptions::default()
                },
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let matching = start.elapsed().as_secs_f64();
    // Calibrated verification (essential matrix) with the EXIF focal length, as COLMAP does.
    let cameras: Vec<Option<PinholeCamera>> = paths
        .iter()
        .map(|p| {
            let exif = timesift_io::exif::read_exif(p).ok()?;
            let f = exif.focal_length_px(1024, 768)?;
            PinholeCamera::new(1024, 768, f).ok()
        })
        .collect();
    let calibrated = std::env::var("UNCALIBRATED").is_err();
    let start = Instant::now();
    let verified = pairs
        .par_iter()
        .zip(&matches)
        .map(|(&(a, b), m)| {
            let pair_cameras = match (&cameras[a], &cameras[b]) {
                (Some(ca), Some(cb)) if calibrated => {
                    Some((ca as &dyn CameraModel, cb as &dyn CameraModel))
                }
                _ => None,
            };
            let (ka, da) = (&features[a].keypoints, &features[a].descriptors);
            let (kb, db) = (&features[b].keypoints, &features[b].descriptors);
            let verified = verify_pair(
                ka,
                kb,
                m,
                pair_cameras,
                &VerifyOptions {
                    max_iterations: std::env::var("ITERATIONS")
                        .ok()
                        .and_then(|v| v.parse().ok())
                        .unwrap_or(10_000),
                    ..VerifyOptions::default()
                },
            )?;
            match verified {
                Some(v) if std::env::var("UNGUIDED").is_err() => Ok(Some(grow_verified(
                    ka,
                    da,
                    kb,
                    db,
                    &v,
                    &GuidedOptions::default(),
                )?)),
                v => Ok(v.map(|v| v.inliers)),
            }
        })
        .collect::<Result<Vec<_>, timesift_matching::MatchingError>>()?;
    let verification = start.elapsed().as_secs_f64();
    if std::env::var("PAIRS").is_ok() {
        // One line per pair: image numbers (1-based, as COLMAP's image ids in name order),
        // descriptor matches, verified inliers (0 when not verified).
        for ((&(a, b), m), v) in pairs.iter().zip(&matches).zip(&verified) {
            println!(
                "pair {} {} {} {}",
                a + 1,
                b + 1,
                m.len(),
                v.as_ref().map_or(0, Vec::len)
            );
        }
    }
    if std::env::var("PRESELECT").is_ok() {
        // Preselection settings against the verified pairs of exhaustive matching.
        let feats: Vec<_> = features
            .iter()
            .map(|f| (f.keypoints.as_slice(), &f.descriptors))
            .collect();
        let total: usize = verified.iter().flatten().map(Vec::len).sum();
        let epochs = vec![timesift_core::EpochId::from(0); n];
        for keypoints in [512, 1024, 2048] {
            let base = PreselectOptions {
                keypoints,
                ..PreselectOptions::default()
            };
            let coarse = coarse_matches(&feats, &pairs, &base)?;
            for min_matches in [4, 6, 8, 12] {
                for keep_best in [3, 5] {
                    let options = PreselectOptions {
                        min_matches,
                        keep_best,
                        ..base
                    };
                    let selected = preselect(&coarse, &epochs, &options);
                    let (mut kept, mut kept_inliers, mut all) = (0, 0, 0);
                    for (p, v) in pairs.iter().zip(&verified) {
                        if let Some(v) = v {
                            all += 1;
                            if selected.binary_search(p).is_ok() {
                                kept += 1;
                                kept_inliers += v.len();
                            }
                        }
                    }
                    println!(
                        "preselect {keypoints} kp, >= {min_matches} or best {keep_best}: {} pairs, \
                         {kept} of {all} verified, {:.1} % of inliers",
                        selected.len(),
                        100.0 * kept_inliers as f64 / total as f64
                    );
                }
            }
        }
    }
    let mut inliers: Vec<usize> = verified.iter().flatten().map(Vec::len).collect();
    inliers.sort_unstable();
    println!(
        "calibrated: {} of {n} images have an EXIF focal length",
        cameras.iter().flatten().count()
    );
    println!(
        "{n} images, {} keypoints mean; extraction {extraction:.1} s, matching {matching:.1} s, \
         verification {verification:.1} s; {} of {} pairs verified, median {} inliers",
        features.iter().map(|f| f.keypoints.len()).sum::<usize>() / n,
        inliers.len(),
        pairs.len(),
        inliers.get(inliers.len() / 2).copied().unwrap_or(0)
    );
    Ok(())
}
