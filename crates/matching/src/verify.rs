//! Geometric verification of one pair's putative matches: fundamental-matrix RANSAC (or the
//! essential matrix when both cameras are calibrated) keeps the matches consistent with one
//! epipolar geometry; a homography RANSAC on the same matches tells planar scenes and pure
//! rotations apart (they verify, but are poor for initialisation and triangulation).

use nalgebra::{Vector2, Vector3};
use timesift_core::{CameraModel, Keypoint};
use timesift_geometry::essential::EssentialEstimator;
use timesift_geometry::fundamental::FundamentalEstimator;
use timesift_geometry::homography::{HomographyEstimator, TwoViewType, classify_two_view};
use timesift_geometry::ransac::{RansacOptions, ransac};

use crate::{Match, MatchingError};

/// Options of [`verify_pair`] (defaults: COLMAP's two-view geometry).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VerifyOptions {
    /// Inlier threshold, pixels (Sampson distance for the epipolar models, transfer error for
    /// the homography).
    pub max_error_px: f64,
    /// Fewest inliers for a pair to count as verified.
    pub min_inliers: usize,
    /// RANSAC confidence.
    pub confidence: f64,
    /// RANSAC iteration cap.
    pub max_iterations: usize,
    /// A pair is flagged planar or rotational when the homography keeps this share of the
    /// epipolar inliers.
    pub homography_ratio: f64,
    /// Seed of the samplers.
    pub seed: u64,
}

impl Default for VerifyOptions {
    fn default() -> Self {
        Self {
            max_error_px: 4.0,
            min_inliers: 15,
            confidence: 0.9999,
            max_iterations: 10_000,
            homography_ratio: 0.8,
            seed: 0x5eed,
        }
    }
}

/// Which model verified the pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EpipolarModel {
    /// Fundamental matrix (uncalibrated pixels).
    Fundamental,
    /// Essential matrix (calibrated rays).
    Essential,
    /// Only a homography: a planar scene or a rotation about the centre (COLMAP's "planar" or
    /// "panoramic" pairs). Useful for tracks, not for initialisation.
    Homography,
}

/// A verified pair.
#[derive(Debug, Clone, PartialEq)]
pub struct VerifiedPair {
    pub model: EpipolarModel,
    /// General epipolar geometry, or explained by a homography.
    pub kind: TwoViewType,
    /// The matches consistent with the epipolar model.
    pub inliers: Vec<Match>,
    /// Inliers of the homography fitted to the same matches.
    pub homography_inliers: usize,
}

/// Verifies the matches between images with keypoints `a` and `b`. With `cameras`, the essential
/// matrix is estimated on the cameras' rays (distortion removed); otherwise the fundamental matrix
/// on pixels. `Ok(None)`: fewer than `min_inliers` survive.
pub fn verify_pair(
    a: &[Keypoint],
    b: &[Keypoint],
    matches: &[Match],
    cameras: Option<(&dyn CameraModel, &dyn CameraModel)>,
    options: &VerifyOptions,
) -> Result<Option<VerifiedPair>, MatchingError> {
    if matches.len() < options.min_inliers.max(8) {
        return Ok(None);
    }
    let mut p1 = Vec::with_capacity(matches.len());
    let mut p2 = Vec::with_capacity(matches.len());
    let pixel = |keypoints: &[Keypoint], index: u32| {
        keypoints
            .get(index as usize)
            .map(|k| Vector2::new(k.x, k.y))
            .ok_or(MatchingError::KeypointIndex {
                index: index as usize,
                count: keypoints.len(),
            })
    };
    for m in matches {
        p1.push(pixel(a, m.query)?);
        p2.push(pixel(b, m.train)?);
    }
    let ransac_options = RansacOptions {
        max_error: options.max_error_px,
        confidence: options.confidence,
        max_iterations: options.max_iterations,
        seed: options.seed,
        ..RansacOptions::default()
    };
    let (model, inlier_flags) = match cameras {
        Some((ca, cb)) => {
            // Matches whose pixels cannot be unprojected are dropped before estimation.
            let mut keep = Vec::new();
            let mut x1: Vec<Vector3<f64>> = Vec::new();
            let mut x2: Vec<Vector3<f64>> = Vec::new();
            for (i, (u, v)) in p1.iter().zip(&p2).enumerate() {
                if let (Ok(r1), Ok(r2)) = (ca.unproject(u), cb.unproject(v)) {
                    keep.push(i);
                    x1.push(r1);
                    x2.push(r2);
                }
            }
            let focal_px = focal_length(ca).max(1.0);
            let estimator = EssentialEstimator {
                x1: &x1,
                x2: &x2,
                focal_px,
            };
            let mut flags = vec![false; matches.len()];
            if let Ok(result) = ransac(&estimator, &ransac_options) {
                for (k, &i) in keep.iter().enumerate() {
                    flags[i] = result.inliers[k];
                }
            }
            (EpipolarModel::Essential, flags)
        }
        None => {
            let estimator = FundamentalEstimator { p1: &p1, p2: &p2 };
            match ransac(&estimator, &ransac_options) {
                Ok(result) => (EpipolarModel::Fundamental, result.inliers),
                Err(_) => (EpipolarModel::Fundamental, vec![false; matches.len()]),
            }
        }
    };
    let keep = |flags: &[bool]| -> Vec<Match> {
        matches
            .iter()
            .zip(flags)
            .filter(|(_, ok)| **ok)
            .map(|(m, _)| *m)
            .collect()
    };
    let inliers = keep(&inlier_flags);
    let homography = ransac(&HomographyEstimator { p1: &p1, p2: &p2 }, &ransac_options).ok();
    let homography_inliers = homography.as_ref().map_or(0, |r| r.num_inliers);
    if inliers.len() >= options.min_inliers {
        return Ok(Some(VerifiedPair {
            model,
            kind: classify_two_view(inliers.len(), homography_inliers, options.homography_ratio),
            inliers,
            homography_inliers,
        }));
    }
    // No epipolar geometry, but a homography: planar or rotational.
    match homography {
        Some(h) if h.num_inliers >= options.min_inliers => Ok(Some(VerifiedPair {
            model: EpipolarModel::Homography,
            kind: TwoViewType::HomographyExplained,
            inliers: keep(&h.inliers),
            homography_inliers: h.num_inliers,
        })),
        _ => Ok(None),
    }
}

/// The focal length in pixels of a camera: the distance on the image plane covered by a unit
/// step of the ray near the principal point.
fn focal_length(camera: &dyn CameraModel) -> f64 {
    let centre = Vector3::new(0.0, 0.0, 1.0);
    let off = Vector3::new(0.001, 0.0, 1.0);
    match (camera.project(&centre), camera.project(&off)) {
        (Ok(p0), Ok(p1)) => (p1 - p0).norm() / 0.001,
        _ => 1.0,
    }
}
