//! Tracks from verified matches: a union-find over (image, keypoint) that never joins two sets
//! holding the same image, so every track is consistent by construction.
//!
//! Matches are joined best first (smallest descriptor distance), so when two matches would put
//! two keypoints of one image into a track, the weaker one is the one left out: conflicting
//! components are split where they are weakest rather than dropped whole.

use std::collections::BTreeMap;

use timesift_core::{EpochId, FeatureIndex, ImageId, Track, TrackElement};

use crate::{Match, MatchingError};

/// The verified matches of one image pair.
#[derive(Debug, Clone, PartialEq)]
pub struct PairMatches {
    /// The first image (`Match::query` indexes its keypoints).
    pub a: ImageId,
    /// The second image (`Match::train` indexes its keypoints).
    pub b: ImageId,
    /// The verified matches.
    pub matches: Vec<Match>,
}

/// Tracks and what building them did.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackSet {
    /// Tracks of at least two images, ordered by their first element.
    pub tracks: Vec<Track>,
    /// Matches left out because they would have put two keypoints of one image in a track.
    pub conflicts: usize,
}

impl TrackSet {
    /// Number of tracks per track length.
    pub fn length_histogram(&self) -> BTreeMap<usize, usize> {
        let mut histogram = BTreeMap::new();
        for t in &self.tracks {
            *histogram.entry(t.len()).or_insert(0) += 1;
        }
        histogram
    }

    /// For every pair of epochs (a ≤ b), the number of tracks seen in both; (a, a) counts tracks
    /// with at least two images of epoch a.
    pub fn epoch_pairs(&self, epoch_of: &[EpochId]) -> BTreeMap<(EpochId, EpochId), usize> {
        let mut counts = BTreeMap::new();
        for t in &self.tracks {
            let mut per_epoch: BTreeMap<EpochId, usize> = BTreeMap::new();
            for e in &t.elements {
                *per_epoch.entry(epoch_of[e.image.index()]).or_insert(0) += 1;
            }
            let epochs: Vec<(EpochId, usize)> = per_epoch.into_iter().collect();
            for (i, &(a, na)) in epochs.iter().enumerate() {
                if na >= 2 {
                    *counts.entry((a, a)).or_insert(0) += 1;
                }
                for &(b, _) in &epochs[i + 1..] {
                    *counts.entry((a, b)).or_insert(0) += 1;
                }
            }
        }
        counts
    }
}

/// Union-find whose sets remember their images.
struct Sets {
    parent: Vec<u32>,
    images: Vec<Vec<u32>>,
}

impl Sets {
    fn find(&mut self, mut x: u32) -> u32 {
        while self.parent[x as usize] != x {
            let grand = self.parent[self.parent[x as usize] as usize];
            self.parent[x as usize] = grand;
            x = grand;
        }
        x
    }

    /// Joins the sets of x and y unless they share an image; false on conflict.
    fn union(&mut self, x: u32, y: u32) -> bool {
        let (rx, ry) = (self.find(x), self.find(y));
        if rx == ry {
            return true;
        }
        let (a, b) = (&self.images[rx as usize], &self.images[ry as usize]);
        // Both sorted: a linear merge tells whether they intersect.
        let (mut i, mut j) = (0, 0);
        while i < a.len() && j < b.len() {
            match a[i].cmp(&b[j]) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => return false,
            }
        }
        let (big, small) = if a.len() >= b.len() {
            (rx, ry)
        } else {
            (ry, rx)
        };
        let moved = std::mem::take(&mut self.images[small as usize]);
        let mut merged = Vec::with_capacity(self.images[big as usize].len() + moved.len());
        let kept = std::mem::take(&mut self.images[big as usize]);
        let (mut i, mut j) = (0, 0);
        while i < kept.len() || j < moved.len() {
            if j == moved.len() || (i < kept.len() && kept[i] < moved[j]) {
                merged.push(kept[i]);
                i += 1;
            } else {
                merged.push(moved[j]);
                j += 1;
            }
        }
        self.images[big as usize] = merged;
        self.parent[small as usize] = big;
        true
    }
}

/// Builds tracks from the verified matches of every pair; `keypoints[i]` is the number of
/// keypoints of image i.
pub fn build_tracks(keypoints: &[usize], pairs: &[PairMatches]) -> Result<TrackSet, MatchingError> {
    let mut offset = Vec::with_capacity(keypoints.len() + 1);
    offset.push(0usize);
    for &n in keypoints {
        offset.push(offset.last().copied().unwrap_or(0) + n);
    }
    let total = offset[keypoints.len()];
    let node = |image: ImageId, feature: u32| -> Result<u32, MatchingError> {
        let i = image.index();
        let count = keypoints.get(i).copied().unwrap_or(0);
        if feature as usize >= count {
            return Err(MatchingError::KeypointIndex {
                index: feature as usize,
                count,
            });
        }
        Ok((offset[i] + feature as usize) as u32)
    };
    let mut edges = Vec::new();
    for p in pairs {
        for m in &p.matches {
            edges.push((m.distance, node(p.a, m.query)?, node(p.b, m.train)?));
        }
    }
    edges.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let mut image_of = vec![0u32; total];
    for (i, w) in offset.windows(2).enumerate() {
        image_of[w[0]..w[1]].fill(i as u32);
    }
    let mut sets = Sets {
        parent: (0..total as u32).collect(),
        images: image_of.iter().map(|&i| vec![i]).collect(),
    };
    let mut conflicts = 0;
    for &(_, x, y) in &edges {
        if !sets.union(x, y) {
            conflicts += 1;
        }
    }
    // Collect components of two or more keypoints, only among nodes that were matched.
    let mut members: BTreeMap<u32, Vec<TrackElement>> = BTreeMap::new();
    let mut touched: Vec<u32> = edges.iter().flat_map(|e| [e.1, e.2]).collect();
    touched.sort_unstable();
    touched.dedup();
    for x in touched {
        let root = sets.find(x);
        let image = image_of[x as usize] as usize;
        members.entry(root).or_default().push(TrackElement {
            image: ImageId::from(image),
            feature: FeatureIndex::from(x as usize - offset[image]),
        });
    }
    let mut tracks: Vec<Track> = members
        .into_values()
        .filter(|m| m.len() >= 2)
        .filter_map(Track::new)
        .collect();
    tracks.sort_by(|a, b| a.elements.cmp(&b.elements));
    Ok(TrackSet { tracks, conflicts })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(query: u32, train: u32, distance: f32) -> Match {
        Match {
            query,
            train,
            distance,
        }
    }

    fn pair(a: u32, b: u32, matches: Vec<Match>) -> PairMatches {
        PairMatches {
            a: ImageId(a),
            b: ImageId(b),
            matches,
        }
    }

    #[test]
    fn chains_become_tracks_and_conflicts_are_split_at_the_weakest_match() {
        // Images 0, 1, 2. Keypoint 0 of image 0 ↔ 0 of image 1 ↔ 0 of image 2 (a 3-track).
        // A weak match 0:1 ↔ 2:0 closes a loop onto a second keypoint of image 0: conflict.
        let pairs = vec![
            pair(0, 1, vec![m(0, 0, 0.1), m(1, 1, 0.2)]),
            pair(1, 2, vec![m(0, 0, 0.1)]),
            pair(0, 2, vec![m(1, 0, 0.5)]),
        ];
        let set = build_tracks(&[2, 2, 1], &pairs).unwrap();
        assert_eq!(set.conflicts, 1);
        assert_eq!(set.tracks.len(), 2);
        let long = set.tracks.iter().find(|t| t.len() == 3).unwrap();
        assert!(long.elements.contains(&TrackElement {
            image: ImageId(0),
            feature: FeatureIndex(0)
        }));
        assert_eq!(set.length_histogram(), BTreeMap::from([(2, 1), (3, 1)]));
        // Every track has at most one keypoint per image.
        for t in &set.tracks {
            assert!(t.elements.windows(2).all(|w| w[0].image != w[1].image));
        }
        // Epochs: images 0, 1 in epoch 0, image 2 in epoch 1.
        let pairs = set.epoch_pairs(&[EpochId(0), EpochId(0), EpochId(1)]);
        assert_eq!(pairs[&(EpochId(0), EpochId(0))], 2);
        assert_eq!(pairs[&(EpochId(0), EpochId(1))], 1);
    }

    #[test]
    fn a_match_to_a_missing_keypoint_is_an_error() {
        let err = build_tracks(&[2, 2], &[pair(0, 1, vec![m(0, 5, 0.1)])]).unwrap_err();
        assert!(err.to_string().contains("keypoint 5"), "{err}");
    }
}
