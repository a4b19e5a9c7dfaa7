//! The co-registration strategies of DESIGN.md behind one trait. A [`Block`] is the whole
//! multi-epoch input: epochs are only a partition of the images (which epoch each image belongs
//! to, which one carries the datum); what a strategy does with that partition is the strategy.
//!
//! - [`SingleBlock`] (`timesift`): all epochs in one reconstruction and one georeferencing;
//!   [`crate::JoinedSingleBlock`] (module `joined`), what `timesift` names, adds an optional
//!   second look for inter-epoch ties by descriptor.
//! - [`Independent`]: each epoch reconstructed and georeferenced with its own priors and markers.
//! - [`ChunkAlignment`] (`chunk`): each epoch reconstructed alone; the reference epoch
//!   georeferenced; every other epoch mapped onto it by one 7-parameter similarity from the
//!   tie points the two epochs share (tracks spanning both), RANSAC then least squares.
//! - [`ProgressiveMerge`] (`msfm`): epochs alone, merged into one block most-connected first.
//! - [`StableTiePoints`] (`stp`, module `stable`): stable tie points as control points.
//! - [`ManualStablePoints`] (`manual`, module `manual`): natural points measured by hand in
//!   several epochs, intersected in the reference, as control points of the others.
//!
//! The strategies that orient epochs together (`timesift`, `msfm`) split the tie points whose
//! epochs disagree (module `moved`).

use std::collections::HashMap;

use nalgebra::Vector3;
use timesift_core::{Track, TrackElement};
use timesift_geometry::ransac::{RansacOptions, ransac};
use timesift_geometry::similarity::{SimilarityEstimator, TransformKind, umeyama};

use crate::adjust::Intrinsics;
use crate::changed::detect_changed_ground;
use crate::georef::{Datum, GeoreferenceInput, Georeferenced, GroundPoint, georeference};
use crate::incremental::global;
use crate::manual::{ManualStablePoints, NaturalPoint};
use crate::model::{Reconstruction, SfmInput};
use crate::moved::{Separated, separate_moved_points};
use crate::options::{ChangeDetection, SfmOptions};
use crate::stable::{StableMatcher, StableTiePoints};
use crate::stable_ground::StableGround;
use crate::state::{State, track_table};
use crate::{AlignError, reconstruct};

/// The multi-epoch input of a strategy.
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    /// Cameras, images and tracks over all epochs.
    pub sfm: SfmInput,
    /// Priors, control and check points (markers of every epoch).
    pub ground: GeoreferenceInput,
    /// Epoch index of each image.
    pub epoch_of: Vec<usize>,
    /// Epoch names, for messages.
    pub epoch_names: Vec<String>,
    /// The epoch that carries the datum.
    pub reference: usize,
    /// Where the ground did not change, when the caller knows: the single-block strategies
    /// (`timesift`, `msfm`) then tie the epochs only through points on it.
    pub stable_ground: Option<StableGround>,
    /// Natural points on stable ground measured by hand in several epochs (the `manual`
    /// strategy's control; the others ignore them).
    pub natural_points: Vec<NaturalPoint>,
}

/// A co-registration strategy.
pub trait Strategy {
    /// The name of `align.method`.
    fn name(&self) -> &'static str;
    /// Orients and georeferences every epoch.
    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError>;
}

/// The strategy called `name`, or `None` for an unknown one. `stp`, and `timesift` with
/// [`SfmOptions::join_epoch_ties`], compare descriptors, which `matcher` does.
pub fn strategy<'m>(name: &str, matcher: &'m dyn StableMatcher) -> Option<Box<dyn Strategy + 'm>> {
    match name {
        "timesift" => Some(Box::new(crate::joined::JoinedSingleBlock { matcher })),
        "independent" => Some(Box::new(Independent)),
        "chunk" => Some(Box::new(ChunkAlignment)),
        "msfm" => Some(Box::new(ProgressiveMerge)),
        "stp" => Some(Box::new(StableTiePoints { matcher })),
        "manual" => Some(Box::new(ManualStablePoints)),
        _ => None,
    }
}

/// Names of the strategies.
pub const AVAILABLE: [&str; 6] = ["timesift", "independent", "chunk", "msfm", "stp", "manual"];

/// `timesift`: one block.
pub struct SingleBlock;

impl Strategy for SingleBlock {
    fn name(&self) -> &'static str {
        "timesift"
    }
    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        let components = reconstruct(&block.sfm, options)?;
        let mut separated = separate_moved_points(
            &block.sfm,
            components,
            &block.epoch_of,
            block.reference,
            options,
        )?;
        let components = std::mem::take(&mut separated.components);
        let placed = georeference(&separated.input, components, &block.ground, options)?;
        let mut placed = tie_on_stable_ground(block, &mut separated, placed, options)?;
        placed.moved_ties_split = separated.split;
        separated.restore_track_ids(&mut placed.reconstruction);
        Ok(placed)
    }
}

/// `independent`: every epoch alone.
pub struct Independent;

impl Strategy for Independent {
    fn name(&self) -> &'static str {
        "independent"
    }
    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        let mut parts = Vec::new();
        for e in 0..block.epoch_names.len() {
            let keep = |i: usize| block.epoch_of[i] == e;
            let sub = restrict(&block.sfm, &keep);
            let ground = restrict_ground(&block.ground, &keep);
            let placed = reconstruct(&sub, options)
                .and_then(|c| georeference(&sub, c, &ground, options))
                .map_err(|source| in_epoch(block, e, source))?;
            parts.push(placed);
        }
        Ok(merge(&block.sfm, parts))
    }
}

/// `chunk`: epochs alone, then a similarity onto the reference epoch.
pub struct ChunkAlignment;

impl Strategy for ChunkAlignment {
    fn name(&self) -> &'static str {
        "chunk"
    }
    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        let r = block.reference;
        let reference = orient_reference(block, options)?;
        let reference_points = point_index(&reference.reconstruction);
        let mut parts = vec![reference.clone()];
        let mut dropped_parts = 0;
        for e in (0..block.epoch_names.len()).filter(|&e| e != r) {
            let keep = |i: usize| block.epoch_of[i] == e;
            let sub = restrict(&block.sfm, &keep);
            let components =
                reconstruct(&sub, options).map_err(|source| in_epoch(block, e, source))?;
            if components.is_empty() {
                return Err(in_epoch(
                    block,
                    e,
                    AlignError::Georeferencing("empty".into()),
                ));
            }
            // Every component of the epoch goes onto the reference by the tie points it shares
            // with it; the largest must, the others are dropped (and counted) when they cannot.
            for (k, mut rec) in components.into_iter().enumerate() {
                let (src, dst) = shared_points(
                    &block.sfm.tracks,
                    &rec,
                    &reference.reconstruction,
                    &reference_points,
                );
                let fit = fit_similarity(&src, &dst, &reference.reconstruction, options.seed);
                let Some(ref_from_epoch) = placed_or_left_out(block, e, k == 0, &rec, fit)? else {
                    dropped_parts += 1;
                    continue;
                };
                rec.transform(&ref_from_epoch);
                parts.push(Georeferenced {
                    rms_px: rec.rms_px(&sub),
                    reconstruction: rec,
                    datum: reference.datum,
                    dropped_components: 0,
                    rejected_priors: 0,
                    residuals: Vec::new(),
                    focal_held: sub.focal_held_during_sfm(),
                    moved_ties_split: 0,
                    joined_ties: 0,
                    unstable_ties_split: 0,
                    changed_regions: 0,
                    observation_bound_px: None,
                    group_bound_px: Vec::new(),
                    group_sigma_px: Vec::new(),
                    gnss_offsets: Vec::new(),
                });
            }
        }
        let mut merged = merge(&block.sfm, parts);
        merged.dropped_components += dropped_parts;
        Ok(merged)
    }
}

/// `msfm`: epochs alone, merged progressively, adjusted and georeferenced together.
pub struct ProgressiveMerge;

impl Strategy for ProgressiveMerge {
    fn name(&self) -> &'static str {
        "msfm"
    }
    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        let input = &block.sfm;
        let track_of = track_table(input);
        let r = block.reference;
        // Every component of every epoch: (epoch, largest of its epoch, reconstruction).
        let mut epochs: Vec<(usize, bool, Reconstruction)> = Vec::new();
        for e in 0..block.epoch_names.len() {
            let keep = |i: usize| block.epoch_of[i] == e;
            let sub = restrict(input, &keep);
            let components =
                reconstruct(&sub, options).map_err(|source| in_epoch(block, e, source))?;
            if components.is_empty() {
                return Err(in_epoch(
                    block,
                    e,
                    AlignError::Georeferencing("empty".into()),
                ));
            }
            for (k, mut rec) in components.into_iter().enumerate() {
                // Points name tracks of the epoch's own input; renumber them to the whole
                // block's.
                for p in &mut rec.points {
                    if let Some(o) = p.observations.first() {
                        p.track = track_of[o.image.index()][o.feature.index()] as usize;
                    }
                }
                epochs.push((e, k == 0, rec));
            }
        }
        let at = epochs
            .iter()
            .position(|(e, largest, _)| *e == r && *largest)
            .unwrap_or(0);
        let (_, _, mut merged) = epochs.swap_remove(at);
        let mut dropped_parts = 0;
        while !epochs.is_empty() {
            // The part sharing the most tie points with the block so far goes next.
            let index = point_index(&merged);
            let (k, (src, dst)) = epochs
                .iter()
                .map(|(_, _, rec)| shared_points(&input.tracks, rec, &merged, &index))
                .enumerate()
                .max_by_key(|(_, (src, _))| src.len())
                .ok_or_else(|| AlignError::Georeferencing("no epoch left".into()))?;
            let (e, largest, mut rec) = epochs.swap_remove(k);
            let fit = fit_similarity(&src, &dst, &merged, options.seed);
            let Some(block_from_epoch) = placed_or_left_out(block, e, largest, &rec, fit)? else {
                dropped_parts += 1;
                continue;
            };
            rec.transform(&block_from_epoch);
            adopt_oriented(&mut merged, &rec, input);
            let mut state = State::with_reconstruction(input, options, &track_of, merged);
            state.complete_all_tracks();
            global(&mut state, Intrinsics::Running)?;
            tracing::debug!(epoch = e, points = state.rec.points.len(), "epoch merged");
            merged = state.rec;
        }
        let mut separated =
            separate_moved_points(input, vec![merged], &block.epoch_of, r, options)?;
        let components = std::mem::take(&mut separated.components);
        let placed = georeference(&separated.input, components, &block.ground, options)?;
        let mut placed = tie_on_stable_ground(block, &mut separated, placed, options)?;
        placed.moved_ties_split = separated.split;
        placed.dropped_components += dropped_parts;
        separated.restore_track_ids(&mut placed.reconstruction);
        Ok(placed)
    }
}

/// With stable ground given, the inter-epoch tie points of the georeferenced block that lie
/// off it are split by epoch ([`Separated::split_unstable`]) and the block is adjusted again:
/// only stable ground ties the epochs. Without it, and with [`ChangeDetection::Regional`], the
/// changed ground is found from the block's own ties ([`detect_changed_ground`]), the same way,
/// round after round until none is found. Otherwise `placed` as it is.
fn tie_on_stable_ground(
    block: &Block,
    separated: &mut Separated,
    mut placed: Georeferenced,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    let detect = options.change_detection == ChangeDetection::Regional;
    if block.stable_ground.is_none() && !detect {
        return Ok(placed);
    }
    if placed.datum == Datum::Local {
        // Without a datum the block's frame is not the stable ground's, and has no "up".
        tracing::warn!("stable ground cannot select inter-epoch ties in an ungeoreferenced block");
        return Ok(placed);
    }
    let rounds = if block.stable_ground.is_some() {
        1
    } else {
        CHANGE_DETECTION_ROUNDS
    };
    let (mut total, mut regions) = (0, 0);
    for _ in 0..rounds {
        let found;
        let stable = match &block.stable_ground {
            Some(stable) => stable,
            None => {
                // σ of one observation per axis, from the block's RMS (a 2-D norm).
                let noise_px = (placed.rms_px / std::f64::consts::SQRT_2).max(0.1);
                let Some(detected) = detect_changed_ground(
                    &separated.input,
                    &placed.reconstruction,
                    &block.epoch_of,
                    block.reference,
                    noise_px,
                ) else {
                    break;
                };
                regions += detected.regions_changed;
                found = detected;
                &found.stable
            }
        };
        let split = separated.split_unstable(
            &mut placed.reconstruction,
            &block.epoch_of,
            block.reference,
            stable,
        );
        tracing::info!(
            split,
            "inter-epoch tie points off the stable ground split by epoch"
        );
        if split == 0 {
            break;
        }
        total += split;
        let mut again = georeference(
            &separated.input,
            vec![placed.reconstruction],
            &block.ground,
            options,
        )?;
        again.dropped_components += placed.dropped_components;
        placed = again;
    }
    placed.unstable_ties_split = total;
    placed.changed_regions = regions;
    Ok(placed)
}

/// Most rounds of change detection: each takes the most significant regions left and adjusts
/// the block without their ties, which shows what is left more clearly.
const CHANGE_DETECTION_ROUNDS: usize = 6;

/// The reference epoch reconstructed and georeferenced alone, with its own priors and markers.
pub(crate) fn orient_reference(
    block: &Block,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    let r = block.reference;
    let keep = |i: usize| block.epoch_of[i] == r;
    let sub = restrict(&block.sfm, &keep);
    reconstruct(&sub, options)
        .and_then(|c| georeference(&sub, c, &restrict_ground(&block.ground, &keep), options))
        .map_err(|source| in_epoch(block, r, source))
}

pub(crate) fn in_epoch(block: &Block, e: usize, source: AlignError) -> AlignError {
    AlignError::Epoch {
        epoch: block.epoch_names[e].clone(),
        source: Box::new(source),
    }
}

/// Map from a track element to the point that it observes.
pub(crate) fn point_index(rec: &Reconstruction) -> HashMap<TrackElement, usize> {
    let mut map = HashMap::new();
    for (p, point) in rec.points.iter().enumerate() {
        for e in &point.observations {
            map.insert(*e, p);
        }
    }
    map
}

/// 3-D correspondences between an epoch's points and the reference epoch's: one per track of
/// the whole block that has a point in both.
pub(crate) fn shared_points(
    tracks: &[Track],
    rec: &Reconstruction,
    reference: &Reconstruction,
    reference_points: &HashMap<TrackElement, usize>,
) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let ours = point_index(rec);
    let mut src = Vec::new();
    let mut dst = Vec::new();
    for track in tracks {
        let a = track.elements.iter().find_map(|e| ours.get(e));
        let b = track.elements.iter().find_map(|e| reference_points.get(e));
        if let (Some(&a), Some(&b)) = (a, b) {
            src.push(rec.points[a].position);
            dst.push(reference.points[b].position);
        }
    }
    (src, dst)
}

/// A component's placement: the largest of its epoch must be placed (a failed fit is the
/// epoch's error); another that shares too few tie points is left out with a warning (`None`).
fn placed_or_left_out(
    block: &Block,
    epoch: usize,
    largest: bool,
    rec: &Reconstruction,
    fit: Result<timesift_geometry::similarity::Similarity, AlignError>,
) -> Result<Option<timesift_geometry::similarity::Similarity>, AlignError> {
    match fit {
        Ok(t) => Ok(Some(t)),
        Err(source) if largest => Err(in_epoch(block, epoch, source)),
        Err(source) => {
            tracing::warn!(
                epoch = block.epoch_names[epoch].as_str(),
                images = rec.num_oriented(),
                %source,
                "component left out: it shares too few tie points to be placed"
            );
            Ok(None)
        }
    }
}

/// RANSAC similarity from an epoch's points to the reference's, with a threshold of three
/// times the reference's median ground pixel (object-space size of a pixel at the points).
pub(crate) fn fit_similarity(
    src: &[Vector3<f64>],
    dst: &[Vector3<f64>],
    reference: &Reconstruction,
    seed: u64,
) -> Result<timesift_geometry::similarity::Similarity, AlignError> {
    if src.len() < 3 {
        return Err(AlignError::Georeferencing(format!(
            "{} tie points shared with the reference epoch; a similarity needs 3",
            src.len()
        )));
    }
    let threshold = 3.0 * median_ground_pixel(reference);
    let result = ransac(
        &SimilarityEstimator {
            src,
            dst,
            kind: TransformKind::Similarity,
        },
        &RansacOptions {
            max_error: threshold,
            seed,
            ..RansacOptions::default()
        },
    )?;
    let (a, b): (Vec<_>, Vec<_>) = (0..src.len())
        .filter(|&k| result.inliers[k])
        .map(|k| (src[k], dst[k]))
        .unzip();
    tracing::debug!(shared = src.len(), inliers = a.len(), "chunk similarity");
    Ok(umeyama(&a, &b, None, TransformKind::Similarity)?)
}

/// Median over points of (distance to the first observing camera / the longest focal length of
/// the block).
pub(crate) fn median_ground_pixel(rec: &Reconstruction) -> f64 {
    let f = rec
        .cameras
        .iter()
        .map(|c| {
            let mut v = vec![0.0; timesift_core::CameraModel::num_params(c)];
            timesift_core::CameraModel::params(c, &mut v);
            v[0]
        })
        .fold(0.0, f64::max)
        .max(1.0);
    let mut sizes: Vec<f64> = rec
        .points
        .iter()
        .filter_map(|p| {
            let e = p.observations.first()?;
            let pose = rec.poses[e.image.index()]?;
            Some((p.position - pose.center()).norm() / f)
        })
        .collect();
    if sizes.is_empty() {
        return 1.0;
    }
    sizes.sort_by(f64::total_cmp);
    sizes[sizes.len() / 2]
}

/// The input with only the track elements in images that `keep` accepts.
pub(crate) fn restrict(input: &SfmInput, keep: &dyn Fn(usize) -> bool) -> SfmInput {
    SfmInput {
        cameras: input.cameras.clone(),
        images: input.images.clone(),
        tracks: input
            .tracks
            .iter()
            .filter_map(|t| {
                let elements: Vec<_> = t
                    .elements
                    .iter()
                    .filter(|e| keep(e.image.index()))
                    .copied()
                    .collect();
                (elements.len() >= 2).then_some(Track { elements })
            })
            .collect(),
        focal: input.focal.clone(),
    }
}

/// Priors and markers of the images that `keep` accepts.
pub(crate) fn restrict_ground(
    geo: &GeoreferenceInput,
    keep: &dyn Fn(usize) -> bool,
) -> GeoreferenceInput {
    GeoreferenceInput {
        centre_priors: geo
            .centre_priors
            .iter()
            .filter(|p| keep(p.image))
            .copied()
            .collect(),
        prior_offsets: geo.prior_offsets.clone(),
        points: geo
            .points
            .iter()
            .map(|p| GroundPoint {
                markers: p
                    .markers
                    .iter()
                    .filter(|m| keep(m.image))
                    .copied()
                    .collect(),
                ..p.clone()
            })
            .collect(),
        marker_sigma_px: geo.marker_sigma_px,
    }
}

/// Takes the poses of `other`'s oriented images and the intrinsics of their camera groups;
/// returns those groups (with repeats).
fn adopt_oriented(
    merged: &mut Reconstruction,
    other: &Reconstruction,
    input: &SfmInput,
) -> Vec<usize> {
    let mut groups = Vec::new();
    for (i, pose) in other.poses.iter().enumerate() {
        if pose.is_some() {
            merged.poses[i] = *pose;
            let g = input.images[i].group;
            merged.cameras[g] = other.cameras[g].clone();
            groups.push(g);
        }
    }
    groups
}

/// Epochs oriented apart, as one block (their images are disjoint; points keep their
/// observations, which name keypoints of the whole input).
pub(crate) fn merge(input: &SfmInput, parts: Vec<Georeferenced>) -> Georeferenced {
    let mut merged = Reconstruction {
        cameras: input.cameras.clone(),
        poses: vec![None; input.images.len()],
        points: Vec::new(),
    };
    let mut datum = Datum::Local;
    let mut dropped = 0;
    let mut rejected = 0;
    let mut focal_held = vec![false; input.cameras.len()];
    let mut bound: Option<f64> = None;
    let mut group_bound_px: Vec<Option<f64>> = vec![None; input.cameras.len()];
    let mut group_sigma_px: Vec<Option<f64>> = vec![None; input.cameras.len()];
    let mut gnss_offsets: Vec<crate::georef::EstimatedOffset> = Vec::new();
    for part in parts {
        // Each offset from the part whose priors carried it.
        for (o, offset) in part.gnss_offsets.iter().enumerate() {
            match gnss_offsets.get_mut(o) {
                Some(kept) if kept.priors == 0 && offset.priors > 0 => *kept = offset.clone(),
                Some(_) => {}
                None => gnss_offsets.push(offset.clone()),
            }
        }
        bound = match (bound, part.observation_bound_px) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        let r = part.reconstruction;
        for g in adopt_oriented(&mut merged, &r, input) {
            focal_held[g] = part.focal_held.get(g).copied().unwrap_or(false);
            if let Some(&b) = part.group_bound_px.get(g) {
                group_bound_px[g] = Some(b);
            }
            if let Some(&s) = part.group_sigma_px.get(g) {
                group_sigma_px[g] = s;
            }
        }
        merged.points.extend(r.points);
        if datum == Datum::Local || part.datum == Datum::GnssAndControlPoints {
            datum = part.datum;
        }
        dropped += part.dropped_components;
        rejected += part.rejected_priors;
    }
    let rms_px = merged.rms_px(input);
    Georeferenced {
        reconstruction: merged,
        datum,
        dropped_components: dropped,
        rejected_priors: rejected,
        residuals: Vec::new(),
        rms_px,
        focal_held,
        moved_ties_split: 0,
        joined_ties: 0,
        unstable_ties_split: 0,
        changed_regions: 0,
        observation_bound_px: bound,
        // A group no part bounded keeps the pooled bound, as in a part.
        group_bound_px: match bound {
            Some(b) => group_bound_px.iter().map(|g| g.unwrap_or(b)).collect(),
            None => Vec::new(),
        },
        group_sigma_px,
        gnss_offsets,
    }
}
