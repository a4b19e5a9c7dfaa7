//! `timesift`'s second look for inter-epoch ties: the feature matching pairs images, and
//! across epochs (decades of film, a season of vegetation) most image pairs fall short of
//! verification, so few tie points join the epochs although much of the ground looks the same.
//! Once the first block is oriented, a stable ground point seen in two epochs is there twice,
//! as one epoch's tie point and the other's, a few ground pixels apart. Every two epochs' tie
//! points of their own are offered to the caller's descriptor matcher (the one `stp` uses)
//! within a radius of two ground pixels; the pairs it accepts — mutual, clearly the best by
//! descriptor, and agreeing on one 3-D similarity within a ground pixel, which ground that
//! moved does not — become inter-epoch ties (their tracks joined), and the
//! block is oriented again with them. The second block still splits what the first did: ties
//! off the stable ground, and ties that miss by more than the noise.
//!
//! What is offered: points whose track lies in one epoch (a track the first block split, for
//! moving or for lying off the stable ground, spans epochs and is never offered again), with
//! two observations at least; with stable ground given and a datum, only points on it.
//!
//! Opt-in (`SfmOptions::join_epoch_ties`), for twice the orientation's time. Measured with
//! `cargo xtask bench-methods --ties default,joined` on the synthetic scenes, it joined 0
//! (glacier, shore) to 462 (archival-mixed) ties. Where it joined few (campus 4, landslide 13)
//! nothing moved; on `orchard` (126: vegetation between the stable tracks) the stable-ground
//! tie points' tilt went from 1.34–1.41 to 1.16–1.25 mm/m; on `archival` (36, film decades
//! apart) the later epochs' check dH RMSE from 1.90 / 3.40 / 1.94 to 1.19 / 2.99 / 1.69 m; on
//! the `corridor` (189) the tilt from 0.24–0.36 to 0.33–0.44 mm/m. Two epochs' keypoints at one
//! ground point are seldom one point to a fraction of a pixel: with a 3-D tolerance of 3 ground
//! pixels instead of 1, the corridor's 827 joins raised the second block's moved-point splits
//! by 664.

use timesift_core::{Track, TrackElement};

use crate::AlignError;
use crate::georef::{Datum, Georeferenced};
use crate::incremental::reconstruct;
use crate::options::SfmOptions;

use super::block::Block;
use super::one_block::adjust_as_one_block;
use super::similarity::median_ground_pixel;
use super::stp::{OfferedTiePoint, StableMatcher, StableSearch};

/// Horizontal search radius, ground pixels: how far apart one block puts a ground point's two
/// epochs' tie points (each triangulated from its own epoch's images).
const JOIN_RADIUS_PX: f64 = 2.0;
/// 3-D tolerance of the similarity the pairs must agree on, ground pixels. Looser joins what the
/// second block's moved-point test splits again (see the module's measurements).
const JOIN_TOLERANCE_PX: f64 = 1.0;
/// Fewest tie points of its own an epoch offers before a pair of epochs is searched.
const MIN_OFFERED: usize = 20;

/// The block oriented again with the inter-epoch ties that `matcher` finds between the epochs'
/// own tie points of the `first` block; `first` itself when none is joined or the second
/// block does not orient.
///
/// After a join, a point names the lowest-indexed of the caller's tracks it joined, and its
/// observations may include keypoints of the others: unlike the other strategies', they are
/// not all in `block.sfm.tracks[point.track]`.
pub(crate) fn second_look(
    block: &Block,
    first: Georeferenced,
    matcher: &dyn StableMatcher,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    let joined = join_ties(block, &first, matcher);
    if joined.joined == 0 {
        return Ok(first);
    }
    let mut second_block = block.clone();
    second_block.sfm.tracks = joined.tracks;
    let second = reconstruct(&second_block.sfm, options)
        .and_then(|components| adjust_as_one_block(&second_block, components, options));
    match second {
        Ok(mut second) => {
            second.diagnostics.joined_ties = joined.joined;
            Ok(second)
        }
        Err(e) => {
            tracing::warn!(
                "the block with {} joined inter-epoch ties did not orient ({e}); keeping the \
                 first block",
                joined.joined
            );
            Ok(first)
        }
    }
}

/// The block's tracks with the joined ones, and how many joins were made.
struct Joined {
    /// Index for index with the block's tracks: a joined track at the lowest index of the
    /// tracks it joins (so a point of it names a track whose elements include its own), the
    /// others of the join emptied.
    tracks: Vec<Track>,
    /// Pairs of tie points joined.
    joined: usize,
}

/// Searches every two epochs for tie points of their own that are one ground point, and joins
/// their tracks. A matcher that finds too few pairs for its similarity joins nothing there.
fn join_ties(block: &Block, placed: &Georeferenced, matcher: &dyn StableMatcher) -> Joined {
    let rec = &placed.reconstruction;
    let tracks = &block.sfm.tracks;
    let epoch_of_image = |e: &TrackElement| block.epoch_of.get(e.image.index()).copied();
    let stable = block
        .stable_ground
        .as_ref()
        .filter(|_| placed.datum != Datum::Local);
    // Per epoch, the points it may offer.
    let mut offered: Vec<Vec<usize>> = vec![Vec::new(); block.epoch_names.len()];
    for (k, p) in rec.points.iter().enumerate() {
        let Some(track) = tracks.get(p.track) else {
            continue;
        };
        let Some(epoch) = track.elements.first().and_then(epoch_of_image) else {
            continue;
        };
        let own = track
            .elements
            .iter()
            .all(|e| epoch_of_image(e) == Some(epoch));
        if own
            && p.observations.len() >= 2
            && stable.is_none_or(|s| s.contains(&p.position))
            && let Some(list) = offered.get_mut(epoch)
        {
            list.push(k);
        }
    }
    let ground_px = median_ground_pixel(rec);
    let search = StableSearch {
        radius: JOIN_RADIUS_PX * ground_px,
        tolerance: JOIN_TOLERANCE_PX * ground_px,
    };
    // Each epoch's offer, made once for every pair it is in.
    let offers: Vec<Vec<OfferedTiePoint<'_>>> = offered
        .iter()
        .map(|points| {
            points
                .iter()
                .map(|&k| OfferedTiePoint {
                    position: rec.points[k].position,
                    observations: &rec.points[k].observations,
                })
                .collect()
        })
        .collect();
    let mut sets = TrackSets::new(tracks, &block.epoch_of);
    let mut joined = 0;
    for a in 0..offers.len() {
        for b in a + 1..offers.len() {
            if offers[a].len() < MIN_OFFERED || offers[b].len() < MIN_OFFERED {
                continue;
            }
            let epochs = format!("{} and {}", block.epoch_names[a], block.epoch_names[b]);
            let pairs = match matcher.stable_pairs(&offers[a], &offers[b], &search) {
                Ok(pairs) => pairs,
                Err(message) => {
                    tracing::info!(%epochs, %message, "no inter-epoch ties joined");
                    continue;
                }
            };
            let mut here = 0;
            for m in pairs {
                let (Some(&ka), Some(&kb)) = (offered[a].get(m.reference), offered[b].get(m.other))
                else {
                    continue;
                };
                if sets.join(rec.points[ka].track, rec.points[kb].track) {
                    here += 1;
                }
            }
            tracing::info!(%epochs, joined = here, "inter-epoch ties joined by descriptor");
            joined += here;
        }
    }
    Joined {
        tracks: sets.into_tracks(),
        joined,
    }
}

/// Disjoint sets of tracks (union–find), each joined set's elements kept sorted by image at
/// its root; two sets are joined only when no epoch is in both: a join ties epochs, and two
/// tracks of one epoch that the first block kept apart are two points (joins are transitive
/// over pairs of epochs, so a set can meet one epoch twice).
struct TrackSets<'a> {
    tracks: &'a [Track],
    epoch_of: &'a [usize],
    parent: Vec<usize>,
    /// Elements of a joined set, at its root; `None` for a track never joined.
    joined: Vec<Option<Vec<TrackElement>>>,
}

impl<'a> TrackSets<'a> {
    fn new(tracks: &'a [Track], epoch_of: &'a [usize]) -> TrackSets<'a> {
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
    fn join(&mut self, a: usize, b: usize) -> bool {
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

    /// The tracks after the joins, index for index with the input.
    fn into_tracks(mut self) -> Vec<Track> {
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
