//! The multi-epoch input of a strategy ([`Block`]), and what every strategy does with its
//! partition: take one epoch out of it, orient the reference epoch alone, merge epochs oriented
//! apart back into one result.

use timesift_core::Track;

use crate::AlignError;
use crate::georef::{
    Datum, Diagnostics, EstimatedOffset, GeoreferenceInput, Georeferenced, GroundPoint, Marker,
    georeference,
};
use crate::incremental::reconstruct;
use crate::model::{Reconstruction, SfmInput};
use crate::options::SfmOptions;
use crate::stable_ground::StableGround;

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

/// A natural point on stable ground, measured by hand in images of several epochs; no surveyed
/// coordinates (`stable_points.csv` and `markers.csv` of docs/design.md).
#[derive(Debug, Clone, PartialEq)]
pub struct NaturalPoint {
    /// Name, as in the CSV files.
    pub name: String,
    /// How far the point may have moved between epochs, horizontal and vertical standard
    /// deviations in metres, when the user states it (`sxy`, `sz`); added to the precision of
    /// its intersection in the reference epoch.
    pub stability: Option<(f64, f64)>,
    /// Its markers, in images of any epoch.
    pub markers: Vec<Marker>,
}

impl Block {
    /// Whether image `i` belongs to epoch `e`.
    pub(crate) fn in_epoch_images(&self, e: usize) -> impl Fn(usize) -> bool + '_ {
        move |i| self.epoch_of[i] == e
    }

    /// The caller's stable ground, where `placed` has a datum it can be looked up in (a
    /// block in its own local frame has no world coordinates to compare).
    pub(crate) fn stable_ground_for(
        &self,
        placed: &crate::georef::Georeferenced,
    ) -> Option<&StableGround> {
        self.stable_ground
            .as_ref()
            .filter(|_| placed.datum != crate::georef::Datum::Local)
    }

    /// The tracks of epoch `e` alone (elements in its images; tracks left with fewer than two
    /// dropped), over every image of the block.
    pub(crate) fn epoch_input(&self, e: usize) -> SfmInput {
        restrict(&self.sfm, &self.in_epoch_images(e))
    }

    /// The priors and markers of epoch `e`'s images.
    pub(crate) fn epoch_ground(&self, e: usize) -> GeoreferenceInput {
        restrict_ground(&self.ground, &self.in_epoch_images(e))
    }

    /// `source`, said of epoch `e`.
    pub(crate) fn in_epoch(&self, e: usize, source: AlignError) -> AlignError {
        AlignError::Epoch {
            epoch: self.epoch_names[e].clone(),
            source: Box::new(source),
        }
    }

    /// Epoch `e` reconstructed and georeferenced alone, with its own priors and markers.
    pub(crate) fn orient_epoch(
        &self,
        e: usize,
        options: &SfmOptions,
    ) -> Result<Georeferenced, AlignError> {
        let sub = self.epoch_input(e);
        reconstruct(&sub, options)
            .and_then(|c| georeference(&sub, c, &self.epoch_ground(e), options))
            .map_err(|source| self.in_epoch(e, source))
    }

    /// Epochs oriented apart, as one result (their images are disjoint; points keep their
    /// observations, which name keypoints of the whole input).
    pub(crate) fn merge(&self, parts: Vec<Georeferenced>) -> Georeferenced {
        let input = &self.sfm;
        let mut merged = Reconstruction {
            cameras: input.cameras.clone(),
            poses: vec![None; input.images.len()],
            points: Vec::new(),
        };
        let mut datum = Datum::Local;
        let mut diagnostics = Diagnostics::default();
        let mut focal_held = vec![false; input.cameras.len()];
        let mut bound: Option<f64> = None;
        let mut group_bound_px: Vec<Option<f64>> = vec![None; input.cameras.len()];
        let mut group_sigma_px: Vec<Option<f64>> = vec![None; input.cameras.len()];
        let mut gnss_offsets: Vec<EstimatedOffset> = Vec::new();
        let mut rejected_control: Vec<String> = Vec::new();
        for part in parts {
            for name in &part.rejected_control {
                if !rejected_control.contains(name) {
                    rejected_control.push(name.clone());
                }
            }
            keep_carried_offsets(&mut gnss_offsets, &part.gnss_offsets);
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
            diagnostics.dropped_components += part.diagnostics.dropped_components;
            diagnostics.rejected_priors += part.diagnostics.rejected_priors;
        }
        let rms_px = merged.rms_px(input);
        Georeferenced {
            reconstruction: merged,
            datum,
            residuals: Vec::new(),
            rms_px,
            focal_held,
            observation_bound_px: bound,
            // A group no part bounded keeps the pooled bound, as in a part.
            group_bound_px: match bound {
                Some(b) => group_bound_px.iter().map(|g| g.unwrap_or(b)).collect(),
                None => Vec::new(),
            },
            group_sigma_px,
            gnss_offsets,
            diagnostics,
            // Parts adjusted apart: no covariance joins them.
            set_motion_covariance: None,
            surface_fits: Vec::new(),
            fits_against_dem: false,
            dem_heights: Vec::new(),
            surface_held: Vec::new(),
            rejected_control,
        }
    }
}

/// Each offset from the part whose priors carried it.
fn keep_carried_offsets(kept: &mut Vec<EstimatedOffset>, part: &[EstimatedOffset]) {
    for (o, offset) in part.iter().enumerate() {
        match kept.get_mut(o) {
            Some(k) if k.priors == 0 && offset.priors > 0 => *k = offset.clone(),
            Some(_) => {}
            None => kept.push(offset.clone()),
        }
    }
}

/// The input with only the track elements in images that `keep` accepts.
fn restrict(input: &SfmInput, keep: &dyn Fn(usize) -> bool) -> SfmInput {
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
fn restrict_ground(geo: &GeoreferenceInput, keep: &dyn Fn(usize) -> bool) -> GeoreferenceInput {
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
        // A part is adjusted apart: no covariance of epochs across parts.
        rigid_sets: Vec::new(),
        // Tracks of the whole block; a part's heights are its strategy's own.
        surface_heights: Vec::new(),
        reference_dem: None,
    }
}

/// Takes the poses of `other`'s oriented images and the intrinsics of their camera groups;
/// returns those groups (with repeats).
pub(crate) fn adopt_oriented(
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
