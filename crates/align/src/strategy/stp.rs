//! `stp` (stable tie points): the reference epoch oriented and georeferenced; every other epoch
//! oriented alone and roughly placed (its GNSS priors, or the similarity of the tie points it
//! shares with the reference when it has none); its tie points matched by descriptor to the
//! reference's within a horizontal radius, the pairs a RANSAC similarity keeps (ground that did
//! not move) becoming control points of a final adjustment of the epoch. Unlike `chunk`, the
//! epoch's own geometry (focal length, distortion, block deformation) is corrected by hundreds
//! of control points, not only moved by one similarity.
//!
//! Descriptors are not this crate's business: the matching is a [`StableMatcher`] given by the
//! caller (the orchestrator reads the feature files and uses `timesift-matching::stp`).

use nalgebra::Vector3;
use timesift_core::{FeatureIndex, ImageId, TrackElement};

use crate::AlignError;
use crate::georef::{Datum, GeoreferenceInput, Georeferenced, GroundPoint, Marker, georeference};
use crate::incremental::reconstruct;
use crate::model::{Reconstruction, SfmInput};
use crate::options::SfmOptions;

use super::block::Block;
use super::method::{DatumControl, Method, Strategy};
use super::similarity::{fit_similarity, median_ground_pixel, point_index, shared_points};

/// A tie point offered for matching: its position (the reference epoch's world frame, or the
/// other epoch's rough placement in it) and its observations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OfferedTiePoint<'a> {
    /// Position, metres.
    pub position: Vector3<f64>,
    /// Its observations (image and keypoint), whose descriptors the matcher compares.
    pub observations: &'a [TrackElement],
}

/// Where a [`StableMatcher`] searches and how far a stable pair may disagree.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StableSearch {
    /// Horizontal search radius, metres: how far the rough placement may be off.
    pub radius: f64,
    /// RANSAC tolerance of the similarity between the two sets, metres.
    pub tolerance: f64,
}

/// A stable pair: indices into the reference's and the other epoch's offered points, and the
/// descriptor distance (lower is more certain).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StableMatch {
    /// Index into the reference's points.
    pub reference: usize,
    /// Index into the other epoch's points.
    pub other: usize,
    /// Mean descriptor distance of the pair.
    pub score: f64,
}

/// Matches two epochs' tie points by descriptor and keeps those on ground that did not move.
pub trait StableMatcher {
    /// The stable pairs between `reference` and `other`.
    fn stable_pairs(
        &self,
        reference: &[OfferedTiePoint<'_>],
        other: &[OfferedTiePoint<'_>],
        search: &StableSearch,
    ) -> Result<Vec<StableMatch>, String>;

    /// For each query, the keypoint among its candidates whose descriptor is clearly the
    /// nearest to the point's, or `None` (`timesift`'s guided look for inter-epoch ties,
    /// [`crate::SfmOptions::guided_epoch_ties`]). A matcher that cannot compare single
    /// keypoints says so.
    fn guided_matches(
        &self,
        queries: &[GuidedQuery<'_>],
    ) -> Result<Vec<Option<GuidedMatch>>, String> {
        let _ = queries;
        Err("this matcher does not match single keypoints (guided inter-epoch ties)".into())
    }
}

/// A tie point of one epoch sought among the keypoints of an image of another epoch, near
/// where the oriented block projects it.
#[derive(Debug, Clone, PartialEq)]
pub struct GuidedQuery<'a> {
    /// The point's observations, whose descriptors describe it.
    pub observations: &'a [TrackElement],
    /// The image it is sought in.
    pub image: ImageId,
    /// Keypoints of that image within the search radius of the projection, nearest first.
    pub candidates: Vec<FeatureIndex>,
}

/// The keypoint a [`GuidedQuery`] found and its descriptor distance (lower is more certain).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidedMatch {
    /// The keypoint, in the query's image.
    pub feature: FeatureIndex,
    /// Descriptor distance to the nearest of the point's descriptors.
    pub distance: f64,
}

/// The `stp` strategy, with the matcher that compares descriptors.
pub struct StableTiePoints<'m> {
    /// Descriptor matching of tie points.
    pub matcher: &'m dyn StableMatcher,
}

/// Fewest stable pairs that may control an epoch.
const MIN_STABLE_PAIRS: usize = 6;

/// Search radius without priors (placement by shared tie points), in ground pixels.
const RADIUS_WITHOUT_PRIORS_PX: f64 = 20.0;

impl Strategy for StableTiePoints<'_> {
    fn method(&self) -> Method {
        Method::Stp
    }

    fn datum_control(&self) -> DatumControl {
        DatumControl::ThroughReference
    }

    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        let r = block.reference;
        let reference = block.orient_epoch(r, options)?;
        let ground_px = median_ground_pixel(&reference.reconstruction);
        let offered_reference = offer(&reference.reconstruction);
        let mut parts = vec![reference.clone()];
        for e in (0..block.epoch_names.len()).filter(|&e| e != r) {
            let sub = block.epoch_input(e);
            let ground = block.epoch_ground(e);
            let placed = self
                .control_epoch(
                    block,
                    &sub,
                    &ground,
                    &reference,
                    &offered_reference,
                    ground_px,
                    options,
                )
                .map_err(|source| block.in_epoch(e, source))?;
            parts.push(placed);
        }
        Ok(block.merge(parts))
    }
}

impl StableTiePoints<'_> {
    /// Orients one later epoch, places it roughly, finds its stable tie points and adjusts it
    /// on them.
    #[allow(clippy::too_many_arguments)]
    fn control_epoch(
        &self,
        block: &Block,
        sub: &SfmInput,
        ground: &GeoreferenceInput,
        reference: &Georeferenced,
        offered_reference: &[OfferedTiePoint<'_>],
        ground_px: f64,
        options: &SfmOptions,
    ) -> Result<Georeferenced, AlignError> {
        let components = reconstruct(sub, options)?;
        let (rough, radius, dropped) = place_roughly(
            block, sub, ground, reference, components, ground_px, options,
        )?;
        let offered = offer(&rough);
        let search = StableSearch {
            radius,
            tolerance: 3.0 * ground_px,
        };
        let pairs = self
            .matcher
            .stable_pairs(offered_reference, &offered, &search)
            .map_err(AlignError::StableMatching)?;
        tracing::info!(
            pairs = pairs.len(),
            radius,
            tolerance = search.tolerance,
            "stable tie points"
        );
        if pairs.len() < MIN_STABLE_PAIRS {
            return Err(AlignError::Georeferencing(format!(
                "{} stable tie points with the reference epoch (search radius {radius:.2} m); \
                 {MIN_STABLE_PAIRS} are needed",
                pairs.len()
            )));
        }
        let mut controlled = GeoreferenceInput {
            centre_priors: Vec::new(),
            prior_offsets: Vec::new(),
            points: ground.points.clone(),
            marker_sigma_px: ground.marker_sigma_px,
            rigid_sets: Vec::new(),
            surface_heights: Vec::new(),
            reference_dem: None,
        };
        // The stable points' observations are tie points of this epoch: weighted by the
        // epoch's own measured reprojection noise (σ per axis from the RMS), not as hand-placed
        // markers.
        let rms = rough.rms_px(sub);
        let tie_sigma_px = if rms.is_finite() && rms > 0.0 {
            (rms / std::f64::consts::SQRT_2).max(MIN_TIE_SIGMA_PX)
        } else {
            options.tie_point_sigma_px
        };
        tracing::debug!(
            tie_sigma_px,
            "stable tie points weighted by the epoch's noise"
        );
        controlled.points.extend(stable_control(
            &pairs,
            offered_reference,
            &offered,
            sub,
            ground_px,
            tie_sigma_px,
        ));
        let mut placed = georeference(sub, vec![rough], &controlled, options)?;
        // The report is about the user's control and check points.
        let user: std::collections::HashSet<&str> =
            ground.points.iter().map(|p| p.name.as_str()).collect();
        placed.residuals.retain(|p| user.contains(p.name.as_str()));
        placed.diagnostics.dropped_components += dropped;
        Ok(placed)
    }
}

/// A later epoch placed roughly in the reference's frame: by its GNSS priors when they place
/// it (three or more, not all rejected), else its largest component by the tracks it shares
/// with the reference. With the search radius that placement allows, and the components it
/// dropped.
fn place_roughly(
    block: &Block,
    sub: &SfmInput,
    ground: &GeoreferenceInput,
    reference: &Georeferenced,
    components: Vec<Reconstruction>,
    ground_px: f64,
    options: &SfmOptions,
) -> Result<(Reconstruction, f64, usize), AlignError> {
    let priors_only = GeoreferenceInput {
        centre_priors: ground.centre_priors.clone(),
        prior_offsets: ground.prior_offsets.clone(),
        points: Vec::new(),
        marker_sigma_px: ground.marker_sigma_px,
        rigid_sets: Vec::new(),
        surface_heights: Vec::new(),
        reference_dem: None,
    };
    // Placed by the priors when they place it (three or more, not all rejected).
    let by_priors = if ground.centre_priors.len() >= 3 {
        let placed = georeference(sub, components.clone(), &priors_only, options)?;
        (placed.datum != Datum::Local).then_some(placed)
    } else {
        None
    };
    let dropped;
    let (rough, radius) = if let Some(placed) = by_priors {
        dropped = placed.diagnostics.dropped_components;
        // Priors claim their accuracy; the placement of a whole block is off by about
        // their common bias, which the stated σ covers.
        let sigma = ground
            .centre_priors
            .iter()
            .map(|p| p.sigma_xy)
            .fold(0.0, f64::max);
        (placed.reconstruction, 3.0 * sigma + 5.0 * ground_px)
    } else {
        // Without placing priors only the largest component can be placed, by the tracks
        // it shares with the reference epoch.
        dropped = components.len().saturating_sub(1);
        let mut rec = components
            .into_iter()
            .next()
            .ok_or_else(|| AlignError::Georeferencing("nothing oriented".into()))?;
        let index = point_index(&reference.reconstruction);
        let (src, dst) = shared_points(&block.sfm.tracks, &rec, &reference.reconstruction, &index);
        let reference_from_epoch =
            fit_similarity(&src, &dst, &reference.reconstruction, options.seed)?;
        rec.transform(&reference_from_epoch);
        (rec, RADIUS_WITHOUT_PRIORS_PX * ground_px)
    };
    Ok((rough, radius, dropped))
}

/// The stable pairs as control points of the later epoch: at the reference's position, with
/// the later epoch's observations as markers of the epoch's own noise.
fn stable_control(
    pairs: &[StableMatch],
    offered_reference: &[OfferedTiePoint<'_>],
    offered: &[OfferedTiePoint<'_>],
    sub: &SfmInput,
    ground_px: f64,
    tie_sigma_px: f64,
) -> Vec<GroundPoint> {
    let mut points = Vec::new();
    for (k, pair) in pairs.iter().enumerate() {
        let Some(point) = offered.get(pair.other) else {
            continue;
        };
        let Some(anchor) = offered_reference.get(pair.reference) else {
            continue;
        };
        // A tie point is about a ground pixel precise across and two in height; a worse
        // descriptor match weighs less.
        let sigma = ground_px * (1.0 + 2.0 * pair.score);
        points.push(GroundPoint {
            name: format!("stable tie point {k}"),
            position: anchor.position,
            sigma_xy: sigma,
            sigma_z: 2.0 * sigma,
            check: false,
            markers: point
                .observations
                .iter()
                .map(|e| Marker {
                    image: e.image.index(),
                    pixel: sub.pixel(e),
                })
                .collect(),
            marker_sigma_px: Some(tie_sigma_px),
        });
    }
    points
}

/// Least σ of a stable tie point's observations, pixels: a noise-free synthetic epoch must not
/// give its stable points infinite weight.
const MIN_TIE_SIGMA_PX: f64 = 0.1;

/// The points of a reconstruction as offered tie points.
fn offer(rec: &Reconstruction) -> Vec<OfferedTiePoint<'_>> {
    rec.points
        .iter()
        .map(|p| OfferedTiePoint {
            position: p.position,
            observations: &p.observations,
        })
        .collect()
}
