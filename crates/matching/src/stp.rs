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
use rayon::prelude::*;
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
            total += distance(da, db);
            count += 1;
        }
    }
    if count == 0 {
        f32::INFINITY
    } else {
        total / count as f32
    }
}

/// The mean of a tie point's descriptors (zeros for a point without any).
fn mean_descriptor(t: &TiePoint, dim: usize) -> Vec<f32> {
    let mut mean = vec![0.0f32; dim];
    let mut count = 0usize;
    for d in t.descriptors.chunks_exact(dim) {
        for (m, v) in mean.iter_mut().zip(d) {
            *m += v;
        }
        count += 1;
    }
    if count > 0 {
        mean.iter_mut().for_each(|m| *m /= count as f32);
    }
    mean
}

/// Slack of the lower bound against rounding: it only prunes a candidate whose bound is above
/// what it is compared with by more than float error.
const BOUND_SLACK: f32 = 1.0 - 1e-4;

/// Euclidean distance of two descriptors, summed in eight lanes so that the compiler can use
/// vector instructions (a single running sum of floats must keep its order and cannot).
fn distance(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            let d = x[k] - y[k];
            lanes[k] += d * d;
        }
    }
    let tail: f32 = ra.iter().zip(rb).map(|(x, y)| (x - y) * (x - y)).sum();
    (lanes.iter().sum::<f32>() + tail).sqrt()
}

/// A point's best match so far: the other side's index and the score.
type BestMatch = Option<(usize, f32)>;

/// Reference points per parallel task; the tasks' results are merged in order, so the pairs do
/// not depend on the thread count.
const REFERENCE_CHUNK: usize = 256;

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
    // The distance of two points' mean descriptors is a lower bound of their score (the norm
    // of a mean of differences is at most the mean of their norms): a candidate whose bound is
    // above both its reference point's second best and its own best so far cannot change
    // either, and is not scored. With priors of a few metres the radius takes in thousands of
    // candidates per point, nearly all of them pruned so; the result is the same.
    let search = CandidateSearch {
        reference,
        other,
        dim,
        origin,
        tree: &tree,
        reference_means: mean_descriptors(reference, dim),
        other_means: mean_descriptors(other, dim),
        r2: options.radius * options.radius,
        options,
    };
    let (best_of_reference, best_of_other) = search.best_matches();
    let candidates = mutual_pairs(&best_of_reference, &best_of_other);
    if candidates.len() < options.min_pairs.max(3) {
        return Err(MatchingError::InvalidOption {
            name: "stable tie points",
            value: candidates.len() as f64,
            expected: "enough candidate pairs for a similarity (fewer found: widen the radius or check the epochs overlap)",
        });
    }
    split_by_similarity(reference, other, candidates, origin, options)
}

/// The mean descriptors of `points`, `dim` values each, one after the other.
fn mean_descriptors(points: &[TiePoint], dim: usize) -> Vec<f32> {
    points
        .par_iter()
        .flat_map_iter(|t| mean_descriptor(t, dim))
        .collect()
}

/// What the search for every reference point's best candidates reads.
struct CandidateSearch<'a> {
    reference: &'a [TiePoint],
    other: &'a [TiePoint],
    dim: usize,
    /// Local origin of the tree's horizontal positions.
    origin: Vector3<f64>,
    /// Horizontal positions of `other` relative to `origin`.
    tree: &'a ImmutableKdTree<f64, 2>,
    /// Mean descriptors of `reference` and of `other`, for the pruning bound.
    reference_means: Vec<f32>,
    other_means: Vec<f32>,
    /// Squared search radius.
    r2: f64,
    options: &'a StpOptions,
}

impl CandidateSearch<'_> {
    /// Best and second-best candidate of every reference point (kept when it passes the score
    /// and ratio tests), and each other point's best among the reference points (for the mutual
    /// check), computed in chunks of reference points and merged in chunk order.
    fn best_matches(&self) -> (Vec<BestMatch>, Vec<BestMatch>) {
        let chunks: Vec<(Vec<BestMatch>, Vec<BestMatch>)> = self
            .reference
            .par_chunks(REFERENCE_CHUNK)
            .enumerate()
            .map(|(c, chunk)| self.search_chunk(c, chunk))
            .collect();
        let mut best_of_reference = Vec::with_capacity(self.reference.len());
        let mut best_of_other: Vec<BestMatch> = vec![None; self.other.len()];
        for (of_reference, of_other) in chunks {
            best_of_reference.extend(of_reference);
            // In chunk order with a strict comparison: the earliest reference point wins a tie,
            // as in one sequential pass.
            for (merged, found) in best_of_other.iter_mut().zip(of_other) {
                if let Some((i, s)) = found
                    && merged.is_none_or(|(_, b)| s < b)
                {
                    *merged = Some((i, s));
                }
            }
        }
        (best_of_reference, best_of_other)
    }

    /// The accepted best match of each point of chunk `c`, and each other point's best among
    /// the chunk's points.
    fn search_chunk(&self, c: usize, chunk: &[TiePoint]) -> (Vec<BestMatch>, Vec<BestMatch>) {
        let mut best_of_reference = vec![None; chunk.len()];
        let mut best_of_other: Vec<BestMatch> = vec![None; self.other.len()];
        for (k, t) in chunk.iter().enumerate() {
            let i = c * REFERENCE_CHUNK + k;
            let (best, second) = self.search_point(i, t, &mut best_of_other);
            if best.0 != usize::MAX
                && best.1 <= self.options.max_score
                && best.1 < self.options.ratio * second
            {
                best_of_reference[k] = Some(best);
            }
        }
        (best_of_reference, best_of_other)
    }

    /// The best candidate of reference point `i` (`t`) within the radius, as (index, score),
    /// and the second-best score; updates the other points' best matches it scores.
    fn search_point(
        &self,
        i: usize,
        t: &TiePoint,
        best_of_other: &mut [BestMatch],
    ) -> ((usize, f32), f32) {
        let dim = self.dim;
        let mean = &self.reference_means[i * dim..(i + 1) * dim];
        let q = [t.position.x - self.origin.x, t.position.y - self.origin.y];
        let (mut best, mut second) = ((usize::MAX, f32::INFINITY), f32::INFINITY);
        self.tree
            .query(&q)
            .within::<SquaredEuclidean<f64>>(self.r2)
            .unsorted()
            .visit(|n| {
                let j = n.item as usize;
                if let Some((_, b)) = best_of_other[j] {
                    let bound =
                        BOUND_SLACK * distance(mean, &self.other_means[j * dim..(j + 1) * dim]);
                    if bound >= second && bound >= b {
                        return;
                    }
                }
                let s = score(t, &self.other[j], dim);
                if s < best.1 {
                    second = best.1;
                    best = (j, s);
                } else if s < second {
                    second = s;
                }
                if best_of_other[j].is_none_or(|(_, b)| s < b) {
                    best_of_other[j] = Some((i, s));
                }
            });
        (best, second)
    }
}

/// The pairs whose reference point's best match is an other point whose own best is that
/// reference point, in reference order.
fn mutual_pairs(best_of_reference: &[BestMatch], best_of_other: &[BestMatch]) -> Vec<StablePair> {
    best_of_reference
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
        .collect()
}

/// The RANSAC similarity of the candidate pairs (fitted about `origin`) and the pairs it keeps
/// and rejects; the similarity comes back in absolute coordinates.
fn split_by_similarity(
    reference: &[TiePoint],
    other: &[TiePoint],
    candidates: Vec<StablePair>,
    origin: Vector3<f64>,
    options: &StpOptions,
) -> Result<StpResult, MatchingError> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use timesift_core::SeededRng;

    /// A random unit descriptor of `dim` values.
    fn unit(rng: &mut SeededRng, dim: usize) -> Vec<f32> {
        let v: Vec<f32> = (0..dim).map(|_| rng.normal() as f32).collect();
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.into_iter().map(|x| x / n).collect()
    }

    #[test]
    fn the_lane_distance_is_the_euclidean_distance() {
        let mut rng = SeededRng::new(3);
        for dim in [1, 7, 8, 61, 128] {
            let (a, b) = (unit(&mut rng, dim), unit(&mut rng, dim));
            let plain = a
                .iter()
                .zip(&b)
                .map(|(x, y)| f64::from(x - y).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!((f64::from(distance(&a, &b)) - plain).abs() < 1e-6, "{dim}");
        }
    }

    /// The pruning bound: the distance of the mean descriptors never exceeds the score, for
    /// points of one to five observations, alike or not.
    #[test]
    fn the_mean_descriptor_distance_bounds_the_score() {
        let mut rng = SeededRng::new(5);
        let dim = 16;
        for trial in 0..500 {
            let point = |rng: &mut SeededRng, n: usize| {
                let base = unit(rng, dim);
                TiePoint {
                    position: Vector3::zeros(),
                    descriptors: (0..n)
                        .flat_map(|_| {
                            base.iter()
                                .map(|v| v + 0.3 * rng.normal() as f32)
                                .collect::<Vec<_>>()
                        })
                        .collect(),
                }
            };
            let (na, nb) = (1 + trial % 5, 1 + (trial / 5) % 5);
            let (a, b) = (point(&mut rng, na), point(&mut rng, nb));
            let bound = distance(&mean_descriptor(&a, dim), &mean_descriptor(&b, dim));
            let s = score(&a, &b, dim);
            assert!(
                bound * BOUND_SLACK <= s,
                "{trial}: bound {bound} > score {s}"
            );
            // Identical points: bound and score both come from the same descriptors.
            assert!(distance(&mean_descriptor(&a, dim), &mean_descriptor(&a, dim)) == 0.0);
        }
    }

    /// 1,500 reference points and a copy of them moved by a similarity, with noisy
    /// descriptors and a few points of the copy moved on the ground: the same pairs whatever the
    /// number of threads, the moved points among the rejected.
    #[test]
    fn pairs_do_not_depend_on_the_thread_count_and_moved_points_are_rejected() {
        let mut rng = SeededRng::new(11);
        let dim = 32;
        let reference: Vec<TiePoint> = (0..1500)
            .map(|_| TiePoint {
                position: Vector3::new(
                    rng.uniform_range(0.0, 200.0),
                    rng.uniform_range(0.0, 200.0),
                    rng.uniform_range(0.0, 5.0),
                ),
                // Two observations of one point: alike, not identical.
                descriptors: {
                    let base = unit(&mut rng, dim);
                    let second: Vec<f32> = base
                        .iter()
                        .map(|v| v + 0.05 * rng.normal() as f32)
                        .collect();
                    [base, second].concat()
                },
            })
            .collect();
        let shift = Vector3::new(1.0, -0.5, 0.2);
        let other: Vec<TiePoint> = reference
            .iter()
            .enumerate()
            .map(|(k, t)| TiePoint {
                position: t.position
                    + shift
                    + if k % 100 == 0 {
                        Vector3::new(0.0, 0.0, 2.0)
                    } else {
                        Vector3::zeros()
                    },
                descriptors: t
                    .descriptors
                    .iter()
                    .map(|v| v + 0.01 * rng.normal() as f32)
                    .collect(),
            })
            .collect();
        let options = StpOptions {
            radius: 20.0,
            ..StpOptions::default()
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| stable_tie_points(&reference, &other, dim, &options).unwrap())
        };
        let (one, four) = (run(1), run(4));
        assert_eq!(one.pairs, four.pairs);
        assert_eq!(one.moved, four.moved);
        assert!(one.pairs.len() >= 1450, "{}", one.pairs.len());
        assert!(
            one.pairs
                .iter()
                .all(|p| p.reference == p.other && p.other % 100 != 0)
        );
        assert_eq!(one.moved.len(), 15);
    }
}
