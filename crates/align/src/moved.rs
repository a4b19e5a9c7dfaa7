//! Tie points across a change. Time-SIFT relies on matches between epochs landing on what did
//! not change; a feature on a surface that moved a little (ice thinning by decimetres, a creeping
//! slope, a growing crop) still passes two-view verification at a few pixels and links the
//! epochs through a point that fits none of them, straining the whole block (on the synthetic
//! glacier the single block's median reprojection error doubles). Such a point is split by
//! epoch: the epoch with the most observations keeps it; every other epoch whose observations
//! miss it by more than the block's noise allows gets a track and a point of its own, which
//! still serve its epoch's orientation but no longer tie the epochs together.

use std::collections::BTreeMap;

use nalgebra::Vector3;
use timesift_core::{Pose, Track, TrackElement};

use crate::AlignError;
use crate::adjust::Intrinsics;
use crate::incremental::global;
use crate::model::{Reconstruction, SfmInput, SparsePoint};
use crate::options::SfmOptions;
use crate::stable_ground::StableGround;
use crate::state::{State, track_table};

/// Smallest miss threshold, pixels: on noise-free data the median error is ~0 and nothing may
/// be called moved for rounding.
const MIN_MISS_PX: f64 = 0.25;

/// What [`separate_moved_points`] returns: the input with the split tracks, and the components
/// whose points refer to them.
pub(crate) struct Separated {
    pub input: SfmInput,
    pub components: Vec<Reconstruction>,
    /// Epoch groups split off their points, over both passes.
    pub split: usize,
    /// For each track appended to `input.tracks` (index `first_new + k`), the caller's track it
    /// was split from.
    origin: Vec<usize>,
    /// Number of the caller's tracks.
    first_new: usize,
    /// Epoch groups split off their points for lying off the stable ground
    /// ([`Separated::split_unstable`]).
    pub split_unstable: usize,
}

impl Separated {
    /// Points back onto the caller's tracks: a point of a split-off track names the track it
    /// came from (whose elements include its observations), so the reconstruction is consistent
    /// with the caller's input. Two points may then name one track.
    pub fn restore_track_ids(&self, rec: &mut Reconstruction) {
        for p in &mut rec.points {
            if p.track >= self.first_new {
                p.track = self.origin[p.track - self.first_new];
            }
        }
    }
}

impl Separated {
    /// Splits every inter-epoch tie point of `rec` (a georeferenced block of this input) whose
    /// position is not on `stable` ground: the reference epoch keeps it (or, without reference
    /// observations, the epoch with the most); every other epoch gets a track and a point of its
    /// own, started at the same position. Unlike the moved-point test this needs no measurable
    /// miss: ground that changed by less than the noise shows (sand, ice, a creeping slope)
    /// still must not bend the block. Returns the epoch groups split off.
    pub fn split_unstable(
        &mut self,
        rec: &mut Reconstruction,
        epoch_of: &[usize],
        reference: usize,
        stable: &StableGround,
    ) -> usize {
        let first_new = self.first_new;
        let original = |origin: &[usize], t: usize| {
            if t >= first_new {
                origin[t - first_new]
            } else {
                t
            }
        };
        let mut uses = vec![0u8; self.input.tracks.len()];
        for p in &rec.points {
            uses[p.track] = uses[p.track].saturating_add(1);
        }
        let mut new_points = Vec::new();
        let mut split = 0;
        for point in &mut rec.points {
            // A track shared by two points (from an earlier split) is left alone.
            if uses[point.track] != 1 || stable.contains(&point.position) {
                continue;
            }
            let groups = by_epoch(&point.observations, epoch_of);
            if groups.len() < 2 {
                continue;
            }
            let Some(&keeper) = groups
                .iter()
                .max_by_key(|(e, obs)| (**e == reference, obs.len()))
                .map(|(e, _)| e)
            else {
                continue;
            };
            for (&epoch, observations) in groups.iter().filter(|(e, _)| **e != keeper) {
                split += 1;
                point
                    .observations
                    .retain(|e| epoch_of[e.image.index()] != epoch);
                let elements: Vec<TrackElement> = self.input.tracks[point.track]
                    .elements
                    .iter()
                    .filter(|e| epoch_of[e.image.index()] == epoch)
                    .copied()
                    .collect();
                self.input.tracks[point.track]
                    .elements
                    .retain(|e| epoch_of[e.image.index()] != epoch);
                if elements.len() < 2 {
                    continue;
                }
                let track = self.input.tracks.len();
                self.input.tracks.push(Track { elements });
                let from = original(&self.origin, point.track);
                self.origin.push(from);
                if observations.len() >= 2 {
                    new_points.push(SparsePoint {
                        position: point.position,
                        track,
                        observations: observations.clone(),
                    });
                }
            }
            if point.observations.len() < 2 {
                point.observations.clear();
            }
        }
        rec.points.retain(|p| !p.observations.is_empty());
        rec.points.extend(new_points);
        self.split_unstable += split;
        split
    }
}

/// Splits the tie points whose epochs disagree, in two passes with a global adjustment of
/// each component in between (the first pass sees a strained block, the second a relaxed one).
/// `epoch_of` gives each image's epoch; `reference` keeps a point on ties.
pub(crate) fn separate_moved_points(
    input: &SfmInput,
    mut components: Vec<Reconstruction>,
    epoch_of: &[usize],
    reference: usize,
    options: &SfmOptions,
) -> Result<Separated, AlignError> {
    let first_new = input.tracks.len();
    let mut input = input.clone();
    let mut origin = Vec::new();
    let mut split = 0;
    let passes = if options.moved_point_factor.is_finite() {
        2
    } else {
        0
    };
    for pass in 0..passes {
        let n = split_pass(
            &mut input,
            &mut components,
            epoch_of,
            reference,
            options,
            &mut origin,
        );
        split += n;
        tracing::info!(
            pass,
            split = n,
            "inter-epoch tie points split where a surface moved"
        );
        if n == 0 {
            break;
        }
        let track_of = track_table(&input);
        components = components
            .into_iter()
            .map(|rec| {
                let mut state = State::with_reconstruction(&input, options, &track_of, rec);
                global(&mut state, Intrinsics::Final)?;
                Ok(state.rec)
            })
            .collect::<Result<_, AlignError>>()?;
    }
    Ok(Separated {
        input,
        components,
        split,
        origin,
        first_new,
        split_unstable: 0,
    })
}

/// One pass over every component; returns the number of epoch groups split off. `origin`
/// receives, for each track appended, the track of the caller's input it comes from.
fn split_pass(
    input: &mut SfmInput,
    components: &mut [Reconstruction],
    epoch_of: &[usize],
    reference: usize,
    options: &SfmOptions,
    origin: &mut Vec<usize>,
) -> usize {
    let first_new = input.tracks.len() - origin.len();
    let original = |t: usize| {
        if t >= first_new {
            origin[t - first_new]
        } else {
            t
        }
    };
    // A track with points in two components is left alone: its elements are shared.
    let mut uses = vec![0u8; input.tracks.len()];
    for rec in components.iter() {
        for p in &rec.points {
            uses[p.track] = uses[p.track].saturating_add(1);
        }
    }
    let track_of = track_table(input);
    let mut new_tracks: Vec<Track> = Vec::new();
    let mut new_origin: Vec<usize> = Vec::new();
    let mut removed: Vec<(usize, usize)> = Vec::new(); // (track, epoch) moved to a new track
    let mut split = 0;
    for rec in components.iter_mut() {
        let state = State::with_reconstruction(input, options, &track_of, rec.clone());
        let threshold = miss_threshold(&state, options);
        let mut views: Vec<(Pose, Vector3<f64>)> = Vec::new();
        let mut new_points: Vec<SparsePoint> = Vec::new();
        for point in &mut rec.points {
            if uses[point.track] != 1 {
                continue;
            }
            let groups = by_epoch(&point.observations, epoch_of);
            if groups.len() < 2 {
                continue;
            }
            let Some((&keeper, kept)) = groups
                .iter()
                .max_by_key(|(e, obs)| (obs.len(), **e == reference))
            else {
                continue;
            };
            let anchor = keeper_anchor(&state, kept, threshold, options, &mut views)
                .unwrap_or(point.position);
            for (&epoch, observations) in groups.iter().filter(|(e, _)| **e != keeper) {
                let missing = observations
                    .iter()
                    .filter(|e| state.error(&anchor, e) > threshold)
                    .count();
                if 2 * missing <= observations.len() {
                    continue;
                }
                split += 1;
                point
                    .observations
                    .retain(|e| epoch_of[e.image.index()] != epoch);
                removed.push((point.track, epoch));
                let elements: Vec<TrackElement> = input.tracks[point.track]
                    .elements
                    .iter()
                    .filter(|e| epoch_of[e.image.index()] == epoch)
                    .copied()
                    .collect();
                if elements.len() < 2 {
                    continue;
                }
                let track = input.tracks.len() + new_tracks.len();
                new_tracks.push(Track { elements });
                new_origin.push(original(point.track));
                if let Some(position) = epoch_point(&state, observations, options, &mut views) {
                    new_points.push(SparsePoint {
                        position,
                        track,
                        observations: observations.clone(),
                    });
                }
            }
            // A point left with one observation is no point (`compact` drops it).
            if point.observations.len() < 2 {
                point.observations.clear();
            }
        }
        rec.points.extend(new_points);
    }
    for (track, epoch) in removed {
        input.tracks[track]
            .elements
            .retain(|e| epoch_of[e.image.index()] != epoch);
    }
    input.tracks.extend(new_tracks);
    origin.extend(new_origin);
    split
}

/// Where the keeping epoch's own observations put a point: triangulated from two or more, at a
/// wide enough angle, and seen by each within `threshold`; `None` otherwise.
fn keeper_anchor(
    state: &State<'_>,
    kept: &[TrackElement],
    threshold: f64,
    options: &SfmOptions,
    views: &mut Vec<(Pose, Vector3<f64>)>,
) -> Option<Vector3<f64>> {
    (kept.len() >= 2)
        .then(|| state.triangulate_elements(kept, views))
        .flatten()
        .filter(|x| {
            state.max_angle_deg(x, kept) >= options.min_triangulation_angle_deg
                && kept.iter().all(|e| state.error(x, e) <= threshold)
        })
}

/// The point an epoch split off a track triangulates from its own observations (two or more,
/// at a wide enough angle).
fn epoch_point(
    state: &State<'_>,
    observations: &[TrackElement],
    options: &SfmOptions,
    views: &mut Vec<(Pose, Vector3<f64>)>,
) -> Option<Vector3<f64>> {
    (observations.len() >= 2)
        .then(|| state.triangulate_elements(observations, views))
        .flatten()
        .filter(|x| state.max_angle_deg(x, observations) >= options.min_triangulation_angle_deg)
}

/// Observations grouped by epoch.
fn by_epoch(
    observations: &[TrackElement],
    epoch_of: &[usize],
) -> BTreeMap<usize, Vec<TrackElement>> {
    let mut groups: BTreeMap<usize, Vec<TrackElement>> = BTreeMap::new();
    for e in observations {
        groups
            .entry(epoch_of[e.image.index()])
            .or_default()
            .push(*e);
    }
    groups
}

/// The miss that marks a moved point: `moved_point_factor` times the component's median
/// reprojection error, at least [`MIN_MISS_PX`], at most the observation threshold.
fn miss_threshold(state: &State<'_>, options: &SfmOptions) -> f64 {
    match state.median_error() {
        None => options.max_reprojection_px,
        Some((median, _)) => (options.moved_point_factor * median)
            .max(MIN_MISS_PX)
            .min(options.max_reprojection_px),
    }
}
