//! `manual` (Garieri et al.'s Method 1, the gold standard their automatic methods are judged
//! against): natural points on stable ground — a boulder's corner, a fence post, a crack in a
//! rock — that the user measured by hand in images of several epochs, without surveyed
//! coordinates. The reference epoch is oriented and georeferenced alone; each natural point is
//! intersected there from its markers (at least [`MIN_REFERENCE_IMAGES`] images, with the
//! covariance of the intersection); every later epoch is then oriented alone and adjusted with
//! those points as control points, weighted by that covariance (and by the stability the user
//! states for the point, when given).
//!
//! Unlike `stp`, nothing here compares descriptors: the user's eye decided which ground did not
//! move. Unlike `chunk`, each later epoch's own geometry (focal length, distortion, block
//! deformation) is corrected by the control points, not only moved by one similarity.

use nalgebra::Vector3;
use timesift_geometry::triangulation::{PixelObservation, intersect_weighted};

use crate::AlignError;
use crate::georef::{GeoreferenceInput, Georeferenced, GroundPoint, Marker, georeference};
use crate::incremental::reconstruct;
use crate::model::{Reconstruction, SfmInput};
use crate::options::SfmOptions;

use super::block::{Block, NaturalPoint};
use super::method::{DatumControl, Method, Strategy};

/// The `manual` strategy.
pub struct ManualStablePoints;

/// Fewest oriented reference images a natural point must be measured in to control the later
/// epochs: two rays intersect, but a blunder among them goes unseen; four show it.
pub const MIN_REFERENCE_IMAGES: usize = 4;

/// Fewest natural points an epoch needs: a similarity has seven parameters, three points fix it
/// and leave redundancy.
const MIN_CONTROL_POINTS: usize = 3;

/// A natural point intersected in the reference epoch: its position and the standard deviations
/// it controls later epochs with.
#[derive(Debug, Clone, PartialEq)]
struct Intersected<'a> {
    point: &'a NaturalPoint,
    position: Vector3<f64>,
    sigma_xy: f64,
    sigma_z: f64,
}

impl Strategy for ManualStablePoints {
    fn method(&self) -> Method {
        Method::Manual
    }

    fn datum_control(&self) -> DatumControl {
        DatumControl::ThroughReference
    }

    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        if block.natural_points.is_empty() {
            return Err(AlignError::InvalidInput(
                "method \"manual\" needs natural stable points: their names in \
                 stable_points.csv and their markers in images of several epochs"
                    .into(),
            ));
        }
        let r = block.reference;
        let reference = block.orient_epoch(r, options)?;
        let sigma_px = block.ground.marker_sigma_px;
        let intersected = intersect_in_reference(
            &block.sfm,
            &reference.reconstruction,
            &block.natural_points,
            sigma_px,
        );
        if intersected.len() < MIN_CONTROL_POINTS {
            return Err(block.in_epoch(
                r,
                AlignError::Georeferencing(format!(
                    "{} of {} natural stable points are measured in {MIN_REFERENCE_IMAGES} or \
                     more oriented images of the reference epoch; {MIN_CONTROL_POINTS} are needed",
                    intersected.len(),
                    block.natural_points.len()
                )),
            ));
        }
        tracing::info!(
            points = intersected.len(),
            given = block.natural_points.len(),
            "natural stable points intersected in the reference epoch"
        );
        let mut parts = vec![reference];
        for e in (0..block.epoch_names.len()).filter(|&e| e != r) {
            let sub = block.epoch_input(e);
            let ground = block.epoch_ground(e);
            let keep = block.in_epoch_images(e);
            let placed = control_epoch(&sub, &ground, &intersected, &keep, options)
                .map_err(|source| block.in_epoch(e, source))?;
            parts.push(placed);
        }
        Ok(block.merge(parts))
    }
}

/// The natural points measured in at least [`MIN_REFERENCE_IMAGES`] oriented images of the
/// reference, intersected with their covariance; those with fewer (or whose intersection
/// fails) are left out with a warning.
fn intersect_in_reference<'a>(
    input: &SfmInput,
    reference: &Reconstruction,
    points: &'a [NaturalPoint],
    sigma_px: f64,
) -> Vec<Intersected<'a>> {
    let mut out = Vec::new();
    for point in points {
        let observations: Vec<PixelObservation<'_>> = point
            .markers
            .iter()
            .filter_map(|m| {
                let pose = reference.poses.get(m.image).copied().flatten()?;
                Some(PixelObservation {
                    camera: reference.camera_of(input, m.image),
                    pose,
                    pixel: m.pixel,
                    sigma_px,
                })
            })
            .collect();
        if observations.len() < MIN_REFERENCE_IMAGES {
            tracing::warn!(
                point = point.name.as_str(),
                images = observations.len(),
                "natural stable point left out: measured in fewer than {MIN_REFERENCE_IMAGES} \
                 oriented images of the reference epoch"
            );
            continue;
        }
        match intersect_weighted(&observations) {
            Ok(x) => {
                // The a-posteriori precision when the markers disagree more than their stated
                // σ says, never better than the a-priori one.
                let factor = x.variance_factor.max(1.0);
                let c = x.covariance * factor;
                let (sxy, sz) = point.stability.unwrap_or((0.0, 0.0));
                out.push(Intersected {
                    point,
                    position: x.position,
                    sigma_xy: (0.5 * (c[(0, 0)] + c[(1, 1)]) + sxy * sxy).sqrt(),
                    sigma_z: (c[(2, 2)] + sz * sz).sqrt(),
                });
            }
            Err(e) => tracing::warn!(
                point = point.name.as_str(),
                error = %e,
                "natural stable point left out: its intersection in the reference epoch failed"
            ),
        }
    }
    out
}

/// Orients one later epoch alone and adjusts it on the natural points (its markers in this
/// epoch) as control points. Its GNSS priors stay when they carry an estimated offset (the
/// flight's bias is then a parameter, and the priors still hold the block's shape); priors
/// taken as unbiased would pull against the control and are dropped.
fn control_epoch(
    sub: &SfmInput,
    ground: &GeoreferenceInput,
    intersected: &[Intersected<'_>],
    keep: &dyn Fn(usize) -> bool,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    let components = reconstruct(sub, options)?;
    let mut controlled = GeoreferenceInput {
        centre_priors: ground
            .centre_priors
            .iter()
            .filter(|p| p.offset.is_some())
            .copied()
            .collect(),
        prior_offsets: ground.prior_offsets.clone(),
        points: ground.points.clone(),
        marker_sigma_px: ground.marker_sigma_px,
        rigid_sets: Vec::new(),
        surface_heights: Vec::new(),
        reference_dem: None,
    };
    let mut used = 0;
    for point in intersected {
        let markers: Vec<Marker> = point
            .point
            .markers
            .iter()
            .filter(|m| keep(m.image))
            .copied()
            .collect();
        if markers.len() < 2 {
            continue;
        }
        used += 1;
        controlled.points.push(GroundPoint {
            name: point.point.name.clone(),
            position: point.position,
            sigma_xy: point.sigma_xy,
            sigma_z: point.sigma_z,
            check: false,
            markers,
            marker_sigma_px: None,
        });
    }
    if used < MIN_CONTROL_POINTS {
        return Err(AlignError::Georeferencing(format!(
            "{used} natural stable points measured in two or more of its images; \
             {MIN_CONTROL_POINTS} are needed"
        )));
    }
    tracing::info!(points = used, "epoch controlled by natural stable points");
    let mut placed = georeference(sub, components, &controlled, options)?;
    // The report is about the user's control and check points.
    let user: std::collections::HashSet<&str> =
        ground.points.iter().map(|p| p.name.as_str()).collect();
    placed.residuals.retain(|p| user.contains(p.name.as_str()));
    Ok(placed)
}
