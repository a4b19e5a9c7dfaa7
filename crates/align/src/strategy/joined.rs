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

use timesift_core::TrackElement;

use crate::AlignError;
use crate::georef::Georeferenced;
use crate::incremental::reconstruct;
use crate::options::SfmOptions;

use super::block::Block;
use super::guided::guided_ties;
use super::one_block::adjust_as_one_block;
use super::similarity::median_ground_pixel;
use super::stp::{OfferedTiePoint, StableMatcher, StableSearch};
use super::track_sets::TrackSets;

/// Horizontal search radius, ground pixels: how far apart one block puts a ground point's two
/// epochs' tie points (each triangulated from its own epoch's images).
const JOIN_RADIUS_PX: f64 = 2.0;
/// 3-D tolerance of the similarity the pairs must agree on, ground pixels. Looser joins what the
/// second block's moved-point test splits again (see the module's measurements).
const JOIN_TOLERANCE_PX: f64 = 1.0;
/// Fewest tie points of its own an epoch offers before a pair of epochs is searched.
const MIN_OFFERED: usize = 20;

/// The block oriented again with the inter-epoch ties that the second look finds: `matcher`
/// pairing the epochs' own tie points of the `first` block ([`SfmOptions::join_epoch_ties`]),
/// and keypoints found near where the first block projects each point into the other epochs'
/// images ([`SfmOptions::guided_epoch_ties`], module `guided`); `first` itself when none is
/// found or the second block does not orient.
///
/// After a join, a point names the lowest-indexed of the caller's tracks it joined, and its
/// observations may include keypoints of the others (or in no track): unlike the other
/// strategies', they are not all in `block.sfm.tracks[point.track]`.
pub(crate) fn second_look(
    block: &Block,
    first: Georeferenced,
    matcher: &dyn StableMatcher,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    let mut sets = TrackSets::new(&block.sfm.tracks, &block.epoch_of);
    let joined = match options.join_epoch_ties {
        true => join_ties(block, &first, matcher, &mut sets),
        false => 0,
    };
    let guided = match options.guided_epoch_ties {
        true => guided_ties(block, &first, matcher, &mut sets),
        false => 0,
    };
    if joined + guided == 0 {
        return Ok(first);
    }
    let mut second_block = block.clone();
    second_block.sfm.tracks = sets.into_tracks();
    let second = reconstruct(&second_block.sfm, options)
        .and_then(|components| adjust_as_one_block(&second_block, components, options));
    match second {
        Ok(mut second) => {
            second.diagnostics.joined_ties = joined;
            second.diagnostics.guided_ties = guided;
            Ok(second)
        }
        Err(e) => {
            tracing::warn!(
                "the block with {joined} joined and {guided} guided inter-epoch ties did not \
                 orient ({e}); keeping the first block"
            );
            Ok(first)
        }
    }
}

/// Searches every two epochs for tie points of their own that are one ground point, and joins
/// their tracks in `sets`; the number of joins. A matcher that finds too few pairs for its
/// similarity joins nothing there.
fn join_ties(
    block: &Block,
    placed: &Georeferenced,
    matcher: &dyn StableMatcher,
    sets: &mut TrackSets<'_>,
) -> usize {
    let rec = &placed.reconstruction;
    let tracks = &block.sfm.tracks;
    let epoch_of_image = |e: &TrackElement| block.epoch_of.get(e.image.index()).copied();
    let stable = block.stable_ground_for(placed);
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
    joined
}
