//! Pair preselection by coarse matching (the idea of Metashape's "generic preselection"): before
//! matching candidate pairs with every keypoint, match them with the largest-scale keypoints
//! only, and keep the pairs that share enough of them.
//!
//! The largest-scale keypoints of an image are the ones a downscaled copy of it would yield
//! (a blob of σ = 16 px at full size is one of σ = 4 px at a quarter), so no image is read
//! again: the preselection works on the feature files the `features` stage already wrote.
//! With a thousand keypoints per image instead of several thousand, a pair costs a few per cent
//! of its full matching; unrelated pairs of a large block without position priors (scanned
//! archival photos) are then never matched in full.

use std::collections::{BTreeMap, BTreeSet};

use timesift_core::{Descriptors, EpochId, Keypoint};

use crate::{FloatDistance, MatchOptions, MatchingError, match_descriptors};

/// Options of [`preselect`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreselectOptions {
    /// Keypoints per image taken for the coarse matching: the largest-scale ones.
    pub keypoints: usize,
    /// A pair is selected when its coarse keypoints give at least this many matches. On `lund`
    /// (`PRESELECT=1` in the `lund_matching` example), 1024 keypoints and 6 matches keep 251 of
    /// the 406 pairs, among them 208 of the 241 pairs that verify when every pair is matched,
    /// with 96.5 % of their inliers; 12 matches would keep 143 pairs, with 88 % of the inliers.
    pub min_matches: usize,
    /// Besides, each image keeps its `keep_best` candidates with the most coarse matches (at
    /// least one) in every epoch, its own included, so that no image and no epoch is cut off by
    /// the threshold.
    pub keep_best: usize,
    /// Descriptor matching of the coarse keypoints.
    pub matching: MatchOptions,
}

impl Default for PreselectOptions {
    fn default() -> Self {
        Self {
            keypoints: 1024,
            min_matches: 6,
            keep_best: 3,
            matching: MatchOptions {
                ratio_on: FloatDistance::Angle,
                ..MatchOptions::default()
            },
        }
    }
}

/// A candidate pair and its number of coarse matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CoarsePair {
    /// Index of the first image.
    pub a: usize,
    /// Index of the second image.
    pub b: usize,
    /// Coarse matches between them.
    pub matches: usize,
}

/// The coarse-match counts of every candidate pair (`features[i]`: keypoints and descriptors of
/// image i, borrowed from wherever the caller holds them; pairs index into it).
pub fn coarse_matches(
    features: &[(&[Keypoint], &Descriptors)],
    candidates: &[(usize, usize)],
    options: &PreselectOptions,
) -> Result<Vec<CoarsePair>, MatchingError> {
    use rayon::prelude::*;
    let coarse: Vec<Descriptors> = features
        .par_iter()
        .map(|&(keypoints, descriptors)| largest_scales(keypoints, descriptors, options.keypoints))
        .collect::<Result<_, _>>()?;
    candidates
        .par_iter()
        .map(|&(a, b)| {
            let (da, db) = match (coarse.get(a), coarse.get(b)) {
                (Some(da), Some(db)) => (da, db),
                _ => {
                    return Err(MatchingError::KeypointIndex {
                        index: a.max(b),
                        count: coarse.len(),
                    });
                }
            };
            let matches = match_descriptors(da, db, &options.matching)?.len();
            Ok(CoarsePair { a, b, matches })
        })
        .collect()
}

/// The candidate pairs worth matching in full (sorted): those with at least `min_matches`
/// coarse matches, and each image's `keep_best` strongest candidates in every epoch.
pub fn preselect(
    coarse: &[CoarsePair],
    epoch_of: &[EpochId],
    options: &PreselectOptions,
) -> Vec<(usize, usize)> {
    let mut keep: BTreeSet<(usize, usize)> = coarse
        .iter()
        .filter(|p| p.matches >= options.min_matches)
        .map(|p| (p.a.min(p.b), p.a.max(p.b)))
        .collect();
    // Each image's candidates per epoch of the other image, strongest first.
    let mut by_image: BTreeMap<(usize, EpochId), Vec<&CoarsePair>> = BTreeMap::new();
    for p in coarse.iter().filter(|p| p.matches > 0) {
        let (Some(&ea), Some(&eb)) = (epoch_of.get(p.a), epoch_of.get(p.b)) else {
            continue;
        };
        by_image.entry((p.a, eb)).or_default().push(p);
        by_image.entry((p.b, ea)).or_default().push(p);
    }
    for list in by_image.values_mut() {
        list.sort_by(|x, y| y.matches.cmp(&x.matches).then((x.a, x.b).cmp(&(y.a, y.b))));
        for p in list.iter().take(options.keep_best) {
            keep.insert((p.a.min(p.b), p.a.max(p.b)));
        }
    }
    keep.into_iter().collect()
}

/// The descriptors of the `count` largest-scale keypoints (ties: the stronger response first).
fn largest_scales(
    keypoints: &[Keypoint],
    descriptors: &Descriptors,
    count: usize,
) -> Result<Descriptors, MatchingError> {
    if keypoints.len() != descriptors.len() {
        return Err(MatchingError::InvalidOption {
            name: "descriptors",
            value: descriptors.len() as f64,
            expected: "one descriptor per keypoint",
        });
    }
    Ok(descriptor_rows(
        descriptors,
        &largest_scale_indices(keypoints, count),
    ))
}

/// The indices (ascending) of the `count` largest-scale keypoints, ties to the stronger
/// response, then the lower index.
pub(crate) fn largest_scale_indices(keypoints: &[Keypoint], count: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..keypoints.len()).collect();
    order.sort_by(|&i, &j| {
        let (p, q) = (&keypoints[i], &keypoints[j]);
        q.scale
            .total_cmp(&p.scale)
            .then(q.response.total_cmp(&p.response))
            .then(i.cmp(&j))
    });
    order.truncate(count);
    order.sort_unstable();
    order
}

/// The descriptors of rows `order` (each below `descriptors.len()`).
pub(crate) fn descriptor_rows(descriptors: &Descriptors, order: &[usize]) -> Descriptors {
    fn rows<T: Copy>(data: &[T], width: usize, order: &[usize]) -> Vec<T> {
        order
            .iter()
            .flat_map(|&i| data[i * width..(i + 1) * width].iter().copied())
            .collect()
    }
    match descriptors {
        Descriptors::Float { dim, data } => Descriptors::Float {
            dim: *dim,
            data: rows(data, *dim, order),
        },
        Descriptors::Binary { bytes, data } => Descriptors::Binary {
            bytes: *bytes,
            data: rows(data, *bytes, order),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair(a: usize, b: usize, matches: usize) -> CoarsePair {
        CoarsePair { a, b, matches }
    }

    #[test]
    fn threshold_and_best_per_epoch() {
        // Images 0–2 in epoch 0, 3–4 in epoch 1.
        let epochs: Vec<EpochId> = [0, 0, 0, 1, 1].into_iter().map(EpochId::from).collect();
        let coarse = [
            pair(0, 1, 40),
            pair(0, 2, 2),
            pair(1, 2, 0),
            pair(0, 3, 3),
            pair(0, 4, 1),
            pair(1, 3, 0),
            pair(1, 4, 0),
            pair(2, 3, 0),
            pair(2, 4, 0),
            pair(3, 4, 30),
        ];
        let options = PreselectOptions {
            min_matches: 12,
            keep_best: 1,
            ..PreselectOptions::default()
        };
        let kept = preselect(&coarse, &epochs, &options);
        // (0,1) and (3,4) pass the threshold; 0's best in epoch 1 is 3, and 3's best in epoch 0
        // is 0; 2's best in epoch 0 is 0 (2 matches); 4's best in epoch 0 is 0 (1 match).
        // Pairs without a single coarse match are never kept.
        assert_eq!(kept, vec![(0, 1), (0, 2), (0, 3), (0, 4), (3, 4)]);
        let options = PreselectOptions {
            keep_best: 0,
            ..options
        };
        assert_eq!(preselect(&coarse, &epochs, &options), vec![(0, 1), (3, 4)]);
    }

    #[test]
    fn coarse_keypoints_are_the_largest() {
        let keypoint = |scale: f64| Keypoint {
            x: 0.0,
            y: 0.0,
            scale,
            orientation: 0.0,
            response: 1.0,
            octave: 0,
        };
        let keypoints: Vec<Keypoint> = [1.0, 8.0, 2.0, 16.0].into_iter().map(keypoint).collect();
        let descriptors = Descriptors::Binary {
            bytes: 1,
            data: vec![10, 11, 12, 13],
        };
        let coarse = largest_scales(&keypoints, &descriptors, 2).unwrap();
        assert_eq!(
            coarse,
            Descriptors::Binary {
                bytes: 1,
                data: vec![11, 13]
            }
        );
        let short = Descriptors::Binary {
            bytes: 1,
            data: vec![10],
        };
        assert!(largest_scales(&keypoints, &short, 2).is_err());
    }
}
