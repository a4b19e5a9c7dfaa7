//! Stable tie points (strategy `stp`): between two epochs oriented separately, find the 3-D tie
//! points that did not move and serve as control points for one epoch in the frame of the other.
//!
//! For each tie point of the reference epoch, the tie points of the other epoch within a
//! horizontal radius (the two orientations disagree by at most that much) are candidates; a
//! candidate's score is the mean descriptor distance over every pair of their observations. A
//! pair is accepted when its score is low, clearly below the second best, and the choice is
//! mutual; a RANSAC 3-D similarity then removes the pairs whose ground moved, since moved
//! ground cannot follow the one transform between the two frames.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;
use timesift_geometry::ransac::{RansacOptions, ransac};
use timesift_geometry::similarity::{Similarity, SimilarityEstimator, TransformKind};

use crate::MatchingError;

/// A triangulated tie point of one epoch with the descriptors of its observations.
#[derive(Debug, Clone, PartialEq)]
pub struct TiePoint {
    /// Position in the epoch's frame.
    pub position: Vector3<f64>,
    /// Descriptors of its observations, `dim` values each.
    pub descriptors: Vec<f32>,
}

/// Options of [`stable_tie_points`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StpOptions {
    /// Horizontal search radius, metres: the largest disagreement between the two frames.
    pub radius: f64,
    /// Largest accepted score (mean Euclidean descriptor distance; RootSIFT/SIFT are unit-norm).
    pub max_score: f32,
    /// The best score must be below `ratio` × the second best.
    pub ratio: f32,
    /// RANSAC inlier threshold on the 3-D residual, metres.
    pub ransac_threshold: f64,
    /// Fewest surviving pairs.
    pub min_pairs: usize,
    /// Seed of the RANSAC sampler.
    pub seed: u64,
}

impl Default for StpOptions {
    fn default() -> Self {
        Self {
            radius: 5.0,
            max_score: 0.6,
            ratio: 0.8,
            ransac_threshold: 0.3,
            min_pairs: 6,
            seed: 0x57b,
        }
    }
}

/// An accepted pair: tie point `reference` of the reference epoch and `other` of the other.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StablePair {
    /// Index of the tie point of the reference epoch.
    pub reference: usize,
    /// Index of the tie point of the other epoch.
    pub other: usize,
    /// Mean descriptor distance; lower is more certain (weight the control point by it).
    pub score: f32,
}

/// The surviving pairs and the transform they agree on.
#[derive(Debug, Clone, PartialEq)]
pub struct StpResult {
    /// Pairs that passed the descriptor tests and the similarity.
    pub pairs: Vec<StablePair>,
    /// Pairs that passed the descriptor tests (before the similarity).
    pub candidates: usize,
    /// Candidate pairs the similarity rejected: ground that moved (or mismatches).
    pub moved: Vec<StablePair>,
    /// The reference frame from the other frame, fitted on the survivors.
    pub reference_from_other: Similarity,
}

/// Mean Euclidean distance over all pairs of observations of two tie points.
fn score(a: &TiePoint, b: &TiePoint, dim: usize) -> f32 {
    let mut total = 0.0f32;
    let mut count = 0usize;
    for da in a.descriptors.chunks(dim) {
        for db in b.descriptors.chunks(dim) {
            total += da
                .iter()
                .zip(db)
                .map(|(x, y)| (x - y) * (x - y))
                .sum::<f32>()
                .sqrt();
            count += 1;
        }
    }
    if count == 0 {
        f32::INFINITY
    } else {
        total / count as f32
    }
}

/// Finds the stable tie points between `reference` and `other` (descriptors of `dim` values).
pub fn stable_tie_points(
    reference: &[TiePoint],
    other: &[TiePoint],
    dim: usize,
    options: &StpOptions,
) -> Result<StpResult, MatchingError> {
    if dim == 0 || !(options.radius > 0.0) {
        return Err(MatchingError::InvalidOption {
            name: "radius",
            value: options.radius,
            expected: "a positive radius and non-empty descriptors",
        });
    }
    // Horizontal positions relative to a local origin, so the tree works in small numbers.
    let origin = reference
        .first()
        .or(other.first())
        .map_or(Vector3::zeros(), |t| t.position);
    let local: Vec<[f64; 2]> = other
        .iter()
        .map(|t| [t.position.x - origin.x, t.position.y - origin.y])
        .collect();
    if other.is_empty() || reference.is_empty() {
        return Err(MatchingError::InvalidOption {
            name: "stable tie points",
            value: 0.0,
            expected: "tie points in both epochs",
        });
    }
    let tree: ImmutableKdTree<f64, 2> =
        ImmutableKdTree::new_from_slice(&local).map_err(|_| MatchingError::InvalidOption {
            name: "stable tie points",
            value: local.len() as f64,
            expected: "finite positions a k-d tree accepts",
        })?;
    // Best and second-best candidate of every reference point.
    let r2 = options.radius * options.radius;
    let mut best_of_reference: Vec<Option<(usize, f32)>> = vec![None; reference.len()];
    let mut best_of_other: Vec<Option<(usize, f32)>> = vec![None; other.len()];
    for (i, t) in reference.iter().enumerate() {
        let q = [t.position.x - origin.x, t.position.y - origin.y];
        let (mut best, mut second) = ((usize::MAX, f32::INFINITY), f32::INFINITY);
        tree.query(&q)
            .within::<SquaredEuclidean<f64>>(r2)
            .unsorted()
            .visit(|n| {
                let j = n.item as usize;
                let s = score(t, &other[j], dim);
                if s < best.1 {
                    second = best.1;
                    best = (j, s);
                } else if s < second {
                    second = s;
                }
                // The other side's best among reference points, for the mutual check.
                if best_of_other[j].is_none_or(|(_, b)| s < b) {
                    best_of_other[j] = Some((i, s));
                }
            });
        if best.0 != usize::MAX && best.1 <= options.max_score && best.1 < options.ratio * second {
            best_of_reference[i] = Some(best);
        }
    }
    let candidates: Vec<StablePair> = best_of_reference
        .iter()
        .enumerate()
        .filter_map(|(i, b)| {
            let (j, s) = (*b)?;
            (best_of_other[j].map(|(r, _)| r) == Some(i)).then_some(StablePair {
                reference: i,
                other: j,
                score: s,
            })
        })
        .collect();
    if candidates.len() < options.min_pairs.max(3) {
        return Err(MatchingError::InvalidOption {
            name: "stable tie points",
            value: candidates.len() as f64,
            expected: "enough candidate pairs for a similarity (fewer found: widen the radius or check the epochs overlap)",
        });
    }
    let src: Vec<Vector3<f64>> = candidates
        .iter()
        .map(|p| other[p.other].position - origin)
        .collect();
    let dst: Vec<Vector3<f64>> = candidates
        .iter()
        .map(|p| reference[p.reference].position - origin)
        .collect();
    let estimator = SimilarityEstimator {
        src: &src,
        dst: &dst,
        kind: TransformKind::Similarity,
    };
    let result = ransac(
        &estimator,
        &RansacOptions {
            max_error: options.ransac_threshold,
            seed: options.seed,
            ..RansacOptions::default()
        },
    )
    .map_err(|e| MatchingError::InvalidOption {
        name: "stable tie points",
        value: candidates.len() as f64,
        expected: if matches!(e, timesift_geometry::GeometryError::NotEnoughData { .. }) {
            "enough pairs for a similarity"
        } else {
            "pairs that agree on one similarity"
        },
    })?;
    let mut pairs = Vec::new();
    let mut moved = Vec::new();
    for (p, &inlier) in candidates.iter().zip(&result.inliers) {
        if inlier {
            pairs.push(*p);
        } else {
            moved.push(*p);
        }
    }
    // Back to absolute coordinates: ref = s R (other − o) + t + o.
    let local_fit = result.model;
    let reference_from_other = Similarity {
        scale: local_fit.scale,
        rotation: local_fit.rotation,
        translation: local_fit.translation + origin - local_fit.rotation * origin * local_fit.scale,
    };
    Ok(StpResult {
        candidates: candidates.len(),
        moved,
        pairs,
        reference_from_other,
    })
}
