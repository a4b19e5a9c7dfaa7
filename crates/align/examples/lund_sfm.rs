//! Incremental SfM on the 29 `lund` photos: RootSIFT (8192 keypoints at most), exhaustive
//! matching with verification, tracks, then `reconstruct`; prints components, oriented images,
//! points, RMS reprojection error and times. Features and matches are cached in `CACHE` (default
//! a folder under the system temp dir) so the orientation can be iterated on alone.

use std::path::PathBuf;
use std::time::Instant;

use rayon::prelude::*;
use timesift_align::{FocalSource, SfmImage, SfmInput, SfmOptions, reconstruct};
use timesift_core::{BrownCamera, Camera, ImageId};
use timesift_features::{
    DetectorOptions, FeatureExtractor, KeypointLimit, SiftExtractor, SiftNormalization,
};
use timesift_matching::pairs::{PairPolicy, select};
use timesift_matching::storage::{read_features, read_matches, write_features, write_matches};
use timesift_matching::tracks::{PairMatches, build_tracks};
use timesift_matching::verify::{VerifyOptions, verify_pair};
use timesift_matching::{FloatDistance, MatchOptions, match_descriptors};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    tracing_subscriber::fmt()
        .with_max_level(tracing::Level::INFO)
        .with_writer(std::io::stderr)
        .init();
    let dir =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/opensfm/lund/images");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    paths.sort();
    let cache = std::env::var("CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|_| std::env::temp_dir().join("timesift-lund-sfm"));
    std::fs::create_dir_all(&cache)?;
    let extractor = SiftExtractor {
        detector: DetectorOptions {
            limit: Some(KeypointLimit::spread(8192)),
            contrast_threshold: 0.02,
            ..DetectorOptions::default()
        },
        normalization: SiftNormalization::Root,
    };
    let start = Instant::now();
    let features = paths
        .par_iter()
        .enumerate()
        .map(
            |(i, p)| -> Result<_, Box<dyn std::error::Error + Send + Sync>> {
                let file = cache.join(format!("{i}.feat"));
                if let Ok(f) = read_features(&file) {
                    return Ok(f);
                }
                let f =
                    timesift_features::files::extract_file(p, &extractor as &dyn FeatureExtractor)?;
                write_features(&file, &f.keypoints, &f.descriptors)?;
                Ok((f.keypoints, f.descriptors))
            },
        )
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())?;
    let n = features.len();
    let pairs = select(
        &(0..n).collect::<Vec<_>>(),
        &vec![None; n],
        PairPolicy::Exhaustive,
    );
    let options = MatchOptions {
        ratio_on: FloatDistance::Angle,
        ..MatchOptions::default()
    };
    let verified = pairs
        .par_iter()
        .map(
            |&(a, b)| -> Result<_, Box<dyn std::error::Error + Send + Sync>> {
                let file = cache.join(format!("{a}_{b}.match"));
                let inliers = match read_matches(&file) {
                    Ok(m) => m,
                    Err(_) => {
                        let m = match_descriptors(&features[a].1, &features[b].1, &options)?;
                        let v = verify_pair(
                            &features[a].0,
                            &features[b].0,
                            &m,
                            None,
                            &VerifyOptions::default(),
                        )?;
                        let inliers = v.map(|v| v.inliers).unwrap_or_default();
                        write_matches(&file, &inliers)?;
                        inliers
                    }
                };
                Ok(PairMatches {
                    a: ImageId::from(a),
                    b: ImageId::from(b),
                    matches: inliers,
                })
            },
        )
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())?;
    let verified: Vec<PairMatches> = verified
        .into_iter()
        .filter(|p| !p.matches.is_empty())
        .collect();
    let counts: Vec<usize> = features.iter().map(|f| f.0.len()).collect();
    let tracks = build_tracks(&counts, &verified)?;
    println!(
        "{n} images, {} verified pairs, {} tracks; features and matches {:.1} s",
        verified.len(),
        tracks.tracks.len(),
        start.elapsed().as_secs_f64()
    );
    let exif = timesift_io::exif::read_exif(&paths[0])?;
    let f = exif.focal_length_px(1024, 768).unwrap_or(1.2 * 1024.0);
    let input = SfmInput {
        cameras: vec![Camera::Brown(BrownCamera::new(1024, 768, f)?)],
        images: features
            .iter()
            .map(|(k, _)| SfmImage {
                group: 0,
                keypoints: k.iter().map(|k| nalgebra::Vector2::new(k.x, k.y)).collect(),
            })
            .collect(),
        tracks: tracks.tracks,
        focal: vec![if exif.focal_length_px(1024, 768).is_some() {
            FocalSource::Nominal
        } else {
            FocalSource::Guessed
        }],
    };
    let start = Instant::now();
    let mut options = SfmOptions::default();
    if let Some(v) = std::env::var("INIT_MIN_INLIERS")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        options.init_min_inliers = v;
    }
    let components = reconstruct(&input, &options)?;
    let seconds = start.elapsed().as_secs_f64();
    for (k, c) in components.iter().enumerate() {
        let observations: usize = c.points.iter().map(|p| p.observations.len()).sum();
        println!(
            "component {k}: {} of {n} images oriented, {} points, {observations} observations, \
             RMS {:.3} px; camera {:?}",
            c.num_oriented(),
            c.points.len(),
            c.rms_px(&input),
            c.cameras[0]
        );
    }
    println!("orientation {seconds:.1} s");
    Ok(())
}
