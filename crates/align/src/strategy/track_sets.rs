//! Tracks joined into sets (union–find): the inter-epoch ties a second look finds, whole
//! tracks of two epochs joined (`joined`) or single keypoints added to a point's track
//! (`guided`).

use timesift_core::{Track, TrackElement};

/// Disjoint sets of tracks (union–find), each joined set's elements kept sorted by image at
/// its root; two sets are joined only when no epoch is in both: a join ties epochs, and two
/// tracks of one epoch that the first block kept apart are two points (joins are transitive
/// over pairs of epochs, so a set can meet one epoch twice).
pub(super) struct TrackSets<'a> {
    tracks: &'a [Track],
    epoch_of: &'a [usize],
    parent: Vec<usize>,
    /// Elements of a joined set, at its root; `None` for a track never joined.
    joined: Vec<Option<Vec<TrackElement>>>,
}

impl<'a> TrackSets<'a> {
    pub(super) fn new(tracks: &'a [Track], epoch_of: &'a [usize]) -> TrackSets<'a> {
        TrackSets {
            tracks,
            epoch_of,
            parent: (0..tracks.len()).collect(),
            joined: vec![None; tracks.len()],
        }
    }

    fn root(&mut self, mut t: usize) -> usize {
        while self.parent[t] != t {
            self.parent[t] = self.parent[self.parent[t]];
            t = self.parent[t];
        }
        t
    }

    fn elements_of(&self, root: usize) -> &[TrackElement] {
        self.joined[root]
            .as_deref()
            .unwrap_or(&self.tracks[root].elements)
    }

    /// Epochs (bit per epoch, the first 64; a later epoch counts as the 64th) of a set.
    fn epochs_of(&self, root: usize) -> u64 {
        self.elements_of(root)
            .iter()
            .filter_map(|e| self.epoch_of.get(e.image.index()))
            .fold(0, |bits, &epoch| bits | 1 << epoch.min(63))
    }

    /// Joins the sets of tracks `a` and `b`; false when they are one set already, either is
    /// out of range, or they share an epoch.
    pub(super) fn join(&mut self, a: usize, b: usize) -> bool {
        if a >= self.parent.len() || b >= self.parent.len() {
            return false;
        }
        let (ra, rb) = (self.root(a), self.root(b));
        if ra == rb {
            return false;
        }
        let (low, high) = (ra.min(rb), ra.max(rb));
        if self.epochs_of(low) & self.epochs_of(high) != 0 {
            return false;
        }
        let Some(merged) = merge_by_image(self.elements_of(low), self.elements_of(high)) else {
            return false;
        };
        self.parent[high] = low;
        self.joined[low] = Some(merged);
        self.joined[high] = None;
        true
    }

    /// Adds keypoint `element`, which is in no track, to the set of track `t`; false when `t`
    /// is out of range or its set has an observation in that image already.
    pub(super) fn add_element(&mut self, t: usize, element: TrackElement) -> bool {
        if t >= self.parent.len() {
            return false;
        }
        let root = self.root(t);
        let Some(merged) = merge_by_image(self.elements_of(root), &[element]) else {
            return false;
        };
        self.joined[root] = Some(merged);
        true
    }

    /// The tracks after the joins, index for index with the input.
    pub(super) fn into_tracks(mut self) -> Vec<Track> {
        (0..self.tracks.len())
            .map(|t| {
                if self.root(t) != t {
                    Track {
                        elements: Vec::new(),
                    }
                } else {
                    match self.joined[t].take() {
                        Some(elements) => Track { elements },
                        None => self.tracks[t].clone(),
                    }
                }
            })
            .collect()
    }
}

/// Two element lists sorted by image, merged; `None` when an image is in both.
fn merge_by_image(x: &[TrackElement], y: &[TrackElement]) -> Option<Vec<TrackElement>> {
    let mut out = Vec::with_capacity(x.len() + y.len());
    let (mut i, mut j) = (0, 0);
    while i < x.len() && j < y.len() {
        match x[i].image.cmp(&y[j].image) {
            std::cmp::Ordering::Less => {
                out.push(x[i]);
                i += 1;
            }
            std::cmp::Ordering::Greater => {
                out.push(y[j]);
                j += 1;
            }
            std::cmp::Ordering::Equal => return None,
        }
    }
    out.extend_from_slice(&x[i..]);
    out.extend_from_slice(&y[j..]);
    Some(out)
}

#[cfg(test)]
mod tests {
    use timesift_core::{FeatureIndex, ImageId};

    use super::*;

    fn track(elements: &[(usize, usize)]) -> Track {
        Track {
            elements: elements
                .iter()
                .map(|&(image, feature)| TrackElement {
                    image: ImageId::from(image),
                    feature: FeatureIndex::from(feature),
                })
                .collect(),
        }
    }

    #[test]
    fn joined_tracks_sit_at_their_lowest_index_sorted_by_image() {
        // Images 0–7 in epochs 0, 1, 0, 1, 2, 2, 3, 3: one epoch per track.
        let epoch_of = [0, 1, 0, 1, 2, 2, 3, 3];
        let tracks = vec![
            track(&[(0, 1), (2, 1)]),
            track(&[(1, 4), (3, 4)]),
            track(&[(4, 0), (5, 0)]),
            track(&[(6, 2), (7, 2)]),
        ];
        let mut sets = TrackSets::new(&tracks, &epoch_of);
        assert!(sets.join(2, 0));
        // Through the set of 0 and 2, transitively.
        assert!(sets.join(1, 2));
        assert!(!sets.join(0, 1), "one set already");
        assert!(!sets.join(0, 9), "out of range");
        let joined = sets.into_tracks();
        assert_eq!(
            joined[0],
            track(&[(0, 1), (1, 4), (2, 1), (3, 4), (4, 0), (5, 0)])
        );
        assert!(joined[1].elements.is_empty() && joined[2].elements.is_empty());
        assert_eq!(joined[3], tracks[3]);
    }

    #[test]
    fn two_tracks_of_one_epoch_are_not_joined_even_through_another_epoch() {
        // Tracks 0 and 2 in epoch 0, track 1 in epoch 1.
        let epoch_of = [0, 0, 1, 1, 0, 0];
        let tracks = vec![
            track(&[(0, 1), (1, 1)]),
            track(&[(2, 5), (3, 5)]),
            track(&[(4, 6), (5, 6)]),
        ];
        let mut sets = TrackSets::new(&tracks, &epoch_of);
        assert!(!sets.join(0, 2), "one epoch");
        assert!(sets.join(0, 1));
        assert!(!sets.join(2, 1), "epoch 0 is in the set of 0 and 1 already");
        let joined = sets.into_tracks();
        assert_eq!(joined[0], track(&[(0, 1), (1, 1), (2, 5), (3, 5)]));
        assert!(joined[1].elements.is_empty());
        assert_eq!(joined[2], tracks[2]);
    }

    #[test]
    fn element_lists_with_an_image_in_both_do_not_merge() {
        let (x, y) = (track(&[(0, 1), (2, 1)]), track(&[(2, 5), (3, 5)]));
        assert_eq!(merge_by_image(&x.elements, &y.elements), None);
        let z = track(&[(1, 7), (4, 7)]);
        assert_eq!(
            merge_by_image(&x.elements, &z.elements),
            Some(track(&[(0, 1), (1, 7), (2, 1), (4, 7)]).elements)
        );
    }
}
