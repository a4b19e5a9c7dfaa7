//! Georeferencing: each component is brought into the world frame by a robust similarity from
//! its camera centres to their GNSS priors and from intersected control points to their surveyed
//! coordinates; the components that could be placed are merged and adjusted together with the
//! priors as weighted observations; control and check points are then intersected from their
//! markers alone and compared with their surveyed coordinates.

use nalgebra::{Vector2, Vector3};
use timesift_geometry::ransac::{RansacOptions, ransac};
use timesift_geometry::similarity::{Similarity, SimilarityEstimator, TransformKind, umeyama};
use timesift_geometry::triangulation::{IntersectedPoint, PixelObservation, intersect_weighted};

use timesift_bundle::Loss;

use crate::AlignError;
use crate::adjust::{Adjustment, CentrePrior, Intrinsics, MarkedPoint, OffsetPrior};
use crate::model::{FocalSource, Reconstruction, SfmInput};
use crate::options::{ScatterWeighing, SfmOptions};
use crate::robust::median_abs_deviation;
use crate::state::{State, track_table};

/// A marker: the measured pixel of a ground point in an image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Marker {
    /// Image index.
    pub image: usize,
    /// Pixel (docs/design.md convention).
    pub pixel: Vector2<f64>,
}

/// A surveyed ground point: a control point (constrains the datum) or a check point (only
/// compared afterwards).
#[derive(Debug, Clone, PartialEq)]
pub struct GroundPoint {
    /// Name, as in the CSV files.
    pub name: String,
    /// Surveyed coordinates in the frame of the priors.
    pub position: Vector3<f64>,
    /// Horizontal standard deviation, metres.
    pub sigma_xy: f64,
    /// Vertical standard deviation, metres.
    pub sigma_z: f64,
    /// A check point (not used in the adjustment).
    pub check: bool,
    /// Its markers.
    pub markers: Vec<Marker>,
    /// σ of its markers, pixels; `None`: the input's `marker_sigma_px`. Points made of tie
    /// points (`stp`'s stable control) carry the tie points' measured noise, not the accuracy
    /// of a hand-placed marker.
    pub marker_sigma_px: Option<f64>,
}

impl GroundPoint {
    /// σ of this point's markers, pixels.
    pub fn marker_sigma(&self, geo: &GeoreferenceInput) -> f64 {
        self.marker_sigma_px.unwrap_or(geo.marker_sigma_px)
    }
}

/// Everything that can place the block in the world.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GeoreferenceInput {
    /// GNSS camera-centre priors.
    pub centre_priors: Vec<CentrePrior>,
    /// The GNSS offsets the priors may carry (one per flight), estimated in the adjustment.
    pub prior_offsets: Vec<OffsetPrior>,
    /// Control and check points.
    pub points: Vec<GroundPoint>,
    /// Standard deviation of marker measurements, pixels.
    pub marker_sigma_px: f64,
    /// Sets of images (each epoch's) whose rigid motion's covariance the final adjustment
    /// reports ([`Georeferenced::set_motion_covariance`]); empty: none asked for.
    pub rigid_sets: Vec<Vec<usize>>,
    /// Height observations of tie points (by track) from a reference surface; empty: none.
    /// The single-block strategies add those of the reference epoch's own surface
    /// ([`crate::SfmOptions::surface_ties`]).
    pub surface_heights: Vec<crate::SurfaceHeight>,
    /// A reference DEM in the block's frame: the single-block strategies hold every epoch's
    /// tie points on stable ground to it instead of the later epochs' to the reference
    /// epoch's surface. It needs a datum to start from (control points or centre priors).
    pub reference_dem: Option<std::sync::Arc<crate::ReferenceDem>>,
}

/// What fixed the datum.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Datum {
    /// Camera-centre priors only.
    Gnss,
    /// Control points only.
    ControlPoints,
    /// Both.
    GnssAndControlPoints,
    /// Nothing: the arbitrary frame of the largest component (first image at the origin).
    Local,
}

/// A control or check point after adjustment.
#[derive(Debug, Clone, PartialEq)]
pub struct PointResidual {
    /// Name.
    pub name: String,
    /// Check point (true) or control point.
    pub check: bool,
    /// Oriented images measuring it.
    pub images: usize,
    /// Intersected minus surveyed (dE, dN, dH), metres; `None` with fewer than two oriented
    /// images.
    pub residual: Option<Vector3<f64>>,
    /// Standard deviations (E, N, H) of the intersected position that the markers' own accuracy
    /// alone gives, through the adjusted cameras, metres. A point clicked in two images with a
    /// short baseline can be off by more in height than the whole orientation: this is the
    /// scatter of `residual` that the orientation cannot be blamed for.
    pub markers_sigma: Option<Vector3<f64>>,
}

/// A GNSS offset as estimated: what the receiver's positions of one flight were off by.
#[derive(Debug, Clone, PartialEq)]
pub struct EstimatedOffset {
    /// Its name (the epoch's).
    pub name: String,
    /// Measured minus true camera centre, common to the flight (E, N, H), metres.
    pub value: Vector3<f64>,
    /// Standard deviations (E, N, H), metres, when the adjustment's covariance was available.
    pub std: Option<[f64; 3]>,
    /// Priors that carried it in the final adjustment (0: not estimated).
    pub priors: usize,
    /// Largest |correlation| of the up component with a free focal length: near 1, a nadir
    /// block over flat ground cannot tell a flying-height bias from a focal length, and the
    /// offset's prior decides.
    pub focal_correlation: Option<f64>,
    /// The noise of the flight's positions about its offset (horizontal per axis, vertical),
    /// metres, estimated from its priors' residuals.
    pub within_flight_sigma: Option<[f64; 2]>,
    /// Whether the final adjustment weighed the flight's priors by that noise (where below the
    /// stated σ) rather than by the stated σ: see [`crate::ScatterWeighing`].
    pub scatter_weighs_priors: bool,
}

impl EstimatedOffset {
    /// The σ (horizontal, vertical) the final adjustment gave a prior of this flight stated
    /// with `sigma_xy`, `sigma_z`: by the flight's own noise where that weighed its priors and
    /// was estimated below the stated σ.
    pub fn prior_sigma(&self, sigma_xy: f64, sigma_z: f64) -> (f64, f64) {
        match self.within_flight_sigma {
            Some(noise) if self.scatter_weighs_priors => {
                flight_prior_sigma(noise, sigma_xy, sigma_z)
            }
            _ => (sigma_xy, sigma_z),
        }
    }
}

/// The georeferenced block.
#[derive(Debug, Clone, PartialEq)]
pub struct Georeferenced {
    /// The merged block in the world frame.
    pub reconstruction: Reconstruction,
    /// What fixed the datum.
    pub datum: Datum,
    /// Control and check points.
    pub residuals: Vec<PointResidual>,
    /// Final RMS reprojection error of the tie points, pixels.
    pub rms_px: f64,
    /// Per camera group: whether its focal length was held at its known value because the
    /// block did not determine it (relative standard deviation above 5 %).
    pub focal_held: Vec<bool>,
    /// Largest reprojection error of a kept observation in the final adjustment, pixels: 4 σ of
    /// the block's own noise, at most the options' threshold; the largest over the parts of a
    /// strategy that georeferences epochs apart. `None` when nothing was georeferenced.
    pub observation_bound_px: Option<f64>,
    /// Per camera group: its own outlier bound, pixels (empty without a datum).
    pub group_bound_px: Vec<f64>,
    /// Per camera group: σ of its own reprojection errors (robust, from their median), pixels.
    pub group_sigma_px: Vec<Option<f64>>,
    /// The GNSS offsets, index for index with [`GeoreferenceInput::prior_offsets`] (empty when
    /// none was asked for or nothing was georeferenced).
    pub gnss_offsets: Vec<EstimatedOffset>,
    /// What was left out, rejected, split or joined on the way.
    pub diagnostics: Diagnostics,
    /// The covariance of the rigid motions (rotation, radians; translation, metres) of
    /// [`GeoreferenceInput::rigid_sets`] in the final adjustment, 6 rows per set
    /// (`timesift_bundle::rigid::rigid_motion_covariance`, a-posteriori): how firmly the
    /// block holds each epoch, and each against the others. `None` when none was asked for,
    /// a set had fewer than two oriented images, or the datum was not fixed.
    pub set_motion_covariance: Option<nalgebra::DMatrix<f64>>,
    /// Each later epoch's own tie points against the reference epoch's surface in the final
    /// block ([`crate::SurfaceFit`]: offset, tilt, dome, height scale, with σ); empty where
    /// the strategy does not compare them or too few points could be compared.
    pub surface_fits: Vec<crate::SurfaceFit>,
    /// Whether [`Self::surface_fits`] are every epoch's against the reference DEM
    /// ([`GeoreferenceInput::reference_dem`]) rather than the later epochs' against the
    /// reference epoch's surface.
    pub fits_against_dem: bool,
    /// The height observations from the reference DEM in the final adjustment (by track): with
    /// the control and priors, what fixes the datum's tilt.
    pub dem_heights: Vec<crate::SurfaceHeight>,
    /// The height observations from the reference epoch's surface in the final adjustment (by
    /// track; surface ties): where the later epochs are held to the reference epoch, which
    /// ties them across more of the block than their shared tie points may.
    pub surface_held: Vec<crate::SurfaceHeight>,
    /// The control points left out of the adjustment, by name: where the block is placed by
    /// the other priors and control points, their markers intersect far from their surveyed
    /// coordinates (a typing error, a point in another CRS, a wrong marker). Their residuals
    /// still show by how much.
    pub rejected_control: Vec<String>,
}

/// What a georeferencing and the strategy around it left out, rejected, split or joined: for
/// reports, never for the result's use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Diagnostics {
    /// Components left out because nothing placed them relative to the others.
    pub dropped_components: usize,
    /// Camera-centre priors rejected as outliers by the similarity RANSAC.
    pub rejected_priors: usize,
    /// Inter-epoch tie points split by epoch because a surface moved between the epochs
    /// (strategies that orient epochs together; 0 otherwise).
    pub moved_ties_split: usize,
    /// Epoch groups of inter-epoch tie points split off for lying off the stable ground
    /// ([`crate::Block::stable_ground`]).
    pub unstable_ties_split: usize,
    /// Inter-epoch ties joined by descriptor after a first block (`timesift` with
    /// [`crate::SfmOptions::join_epoch_ties`]; 0 otherwise).
    pub joined_ties: usize,
    /// Inter-epoch ties found by keypoint near where a first block projects a point into
    /// another epoch's images (`timesift` with [`crate::SfmOptions::guided_epoch_ties`]; 0
    /// otherwise): keypoints added to a point, or tracks joined to it.
    pub guided_ties: usize,
    /// Regions of the block found changed from its own inter-epoch ties
    /// ([`crate::ChangeDetection::Regional`]), over every round; 0 without the detection.
    pub changed_regions: usize,
    /// Height observations from the reference epoch's surface on the later epochs' tie points
    /// ([`crate::SfmOptions::surface_ties`]); 0 without them.
    pub surface_heights: usize,
    /// The mapper that oriented the images (never [`crate::Mapper::Auto`]):
    /// [`crate::Mapper::Global`] only where it was chosen and did not fall back to the
    /// incremental one.
    pub mapper: crate::Mapper,
}

impl Georeferenced {
    /// A reconstruction as it is, in the frame `datum` says, with nothing adjusted: no
    /// residuals, bounds or offsets.
    pub(crate) fn unadjusted(
        input: &SfmInput,
        reconstruction: Reconstruction,
        datum: Datum,
    ) -> Georeferenced {
        Georeferenced {
            rms_px: reconstruction.rms_px(input),
            reconstruction,
            datum,
            residuals: Vec::new(),
            focal_held: input.focal_held_during_sfm(),
            observation_bound_px: None,
            group_bound_px: Vec::new(),
            group_sigma_px: Vec::new(),
            gnss_offsets: Vec::new(),
            diagnostics: Diagnostics::default(),
            set_motion_covariance: None,
            surface_fits: Vec::new(),
            fits_against_dem: false,
            dem_heights: Vec::new(),
            surface_held: Vec::new(),
            rejected_control: Vec::new(),
        }
    }
}

/// Pairs (block position, world position, threshold) of one component.
struct Correspondences {
    src: Vec<Vector3<f64>>,
    dst: Vec<Vector3<f64>>,
    sigma: Vec<f64>,
    from_control: usize,
    prior_index: Vec<Option<usize>>,
    /// Per correspondence: the control point's index into `geo.points`.
    control_index: Vec<Option<usize>>,
}

fn intersect(
    input: &SfmInput,
    rec: &Reconstruction,
    markers: &[Marker],
    sigma_px: f64,
) -> (usize, Option<IntersectedPoint>) {
    let observations: Vec<PixelObservation<'_>> = markers
        .iter()
        .filter_map(|m| {
            let pose = rec.poses.get(m.image).copied().flatten()?;
            Some(PixelObservation {
                camera: rec.camera_of(input, m.image),
                pose,
                pixel: m.pixel,
                sigma_px,
            })
        })
        .collect();
    let n = observations.len();
    (n, intersect_weighted(&observations).ok())
}

fn correspondences(
    input: &SfmInput,
    rec: &Reconstruction,
    geo: &GeoreferenceInput,
) -> Correspondences {
    let mut c = Correspondences {
        src: Vec::new(),
        dst: Vec::new(),
        sigma: Vec::new(),
        from_control: 0,
        prior_index: Vec::new(),
        control_index: Vec::new(),
    };
    for (k, prior) in geo.centre_priors.iter().enumerate() {
        if let Some(Some(pose)) = rec.poses.get(prior.image) {
            c.src.push(pose.center());
            c.dst.push(prior.position);
            c.sigma.push(prior.sigma_xy.max(prior.sigma_z));
            c.prior_index.push(Some(k));
            c.control_index.push(None);
        }
    }
    for (k, point) in geo.points.iter().enumerate().filter(|(_, p)| !p.check) {
        if let (_, Some(point_at)) = intersect(input, rec, &point.markers, point.marker_sigma(geo))
        {
            c.src.push(point_at.position);
            c.dst.push(point.position);
            c.sigma.push(point.sigma_xy.max(point.sigma_z));
            c.from_control += 1;
            c.prior_index.push(None);
            c.control_index.push(Some(k));
        }
    }
    c
}

/// What placing one component accepted and rejected.
struct Placed {
    /// Indices into `geo.centre_priors` of the priors accepted.
    accepted_priors: Vec<usize>,
    /// Whether control points took part.
    control: bool,
    /// Priors rejected as outliers.
    rejected_priors: usize,
    /// Indices into `geo.points` of the control points rejected as outliers.
    rejected_control: Vec<usize>,
}

/// A control point whose miss after placement is this many times the control points' median
/// miss (and beyond the placement's threshold) is a gross error: left out of the adjustment.
const GROSS_CONTROL_FACTOR: f64 = 20.0;

/// The control points left out of the adjustment: outliers of the placement that miss by far more
/// than the others do. The placement's threshold follows the points' survey σ, but a control
/// point's position in the block is its markers' intersection, which on scanned film is metres
/// off (2.7 m pixels): there every control point misses the threshold, and the placement's
/// outliers are only the ones that agree least. Such points stay in the adjustment, which weighs
/// their markers as what they are; a point typed 100 km off, or in another CRS, does not.
fn gross_control_errors(
    c: &Correspondences,
    world_from_block: &Similarity,
    inliers: &[bool],
    threshold: f64,
) -> Vec<usize> {
    // Each control point's miss (its correspondence, the distance).
    let misses: Vec<(usize, f64)> = (0..c.src.len())
        .filter(|&k| c.control_index[k].is_some())
        .map(|k| (k, (world_from_block.apply(&c.src[k]) - c.dst[k]).norm()))
        .collect();
    let mut sorted: Vec<f64> = misses.iter().map(|&(_, miss)| miss).collect();
    sorted.sort_by(f64::total_cmp);
    let Some(&median) = sorted.get(sorted.len() / 2) else {
        return Vec::new();
    };
    let bound = threshold.max(GROSS_CONTROL_FACTOR * median);
    misses
        .into_iter()
        .filter(|&(k, miss)| !inliers[k] && miss > bound)
        .filter_map(|(k, _)| c.control_index[k])
        .collect()
}

/// Places a component in the world frame by a robust similarity, or `None` when it cannot be
/// placed.
fn place(
    input: &SfmInput,
    rec: &mut Reconstruction,
    geo: &GeoreferenceInput,
    seed: u64,
) -> Option<Placed> {
    let c = correspondences(input, rec, geo);
    if c.src.len() < 3 {
        return None;
    }
    // Four standard deviations of the least accurate prior (the 3-D distance of an inlier stays
    // below 3.8 σ with 99.7 % probability), at least a centimetre.
    let threshold = 4.0 * c.sigma.iter().copied().fold(0.01, f64::max);
    let result = ransac(
        &SimilarityEstimator {
            src: &c.src,
            dst: &c.dst,
            kind: TransformKind::Similarity,
        },
        &RansacOptions {
            max_error: threshold,
            seed,
            ..RansacOptions::default()
        },
    )
    .ok()?;
    let inliers: Vec<usize> = (0..c.src.len()).filter(|&k| result.inliers[k]).collect();
    if inliers.len() < 3 {
        return None;
    }
    let src: Vec<_> = inliers.iter().map(|&k| c.src[k]).collect();
    let dst: Vec<_> = inliers.iter().map(|&k| c.dst[k]).collect();
    // Weighted by the priors' accuracies: a few surveyed control points outweigh many GNSS
    // centres, as they do in the adjustment that follows.
    let weights: Vec<f64> = inliers
        .iter()
        .map(|&k| 1.0 / (c.sigma[k] * c.sigma[k]))
        .collect();
    let world_from_block = umeyama(&src, &dst, Some(&weights), TransformKind::Similarity).ok()?;
    rec.transform(&world_from_block);
    let accepted: Vec<usize> = inliers.iter().filter_map(|&k| c.prior_index[k]).collect();
    let rejected_priors = c.prior_index.iter().flatten().count() - accepted.len();
    let rejected_control = gross_control_errors(&c, &world_from_block, &result.inliers, threshold);
    Some(Placed {
        control: inliers.iter().any(|&k| c.control_index[k].is_some()),
        accepted_priors: accepted,
        rejected_priors,
        rejected_control,
    })
}

/// Georeferences the components of [`crate::reconstruct`] (largest first) and adjusts the
/// merged block with the priors and control points. Without anything to place the largest
/// component, it is returned in its own frame (`Datum::Local`) and the others are dropped.
pub fn georeference(
    input: &SfmInput,
    components: Vec<Reconstruction>,
    geo: &GeoreferenceInput,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    georeference_settled(input, components, geo, options, None)
}

/// [`georeference`], with the focal lengths held where `focal_held` (per camera group) says,
/// as an earlier georeferencing of the same images and observations settled them: the round
/// that settles them (an adjustment with the intrinsics' precision, a third of the cost on a
/// block of hundreds of images) is not run again. `None`: settled here.
pub(crate) fn georeference_settled(
    input: &SfmInput,
    components: Vec<Reconstruction>,
    geo: &GeoreferenceInput,
    options: &SfmOptions,
    focal_held: Option<&[bool]>,
) -> Result<Georeferenced, AlignError> {
    if components.is_empty() {
        return Err(AlignError::Georeferencing("no oriented component".into()));
    }
    if !(geo.marker_sigma_px > 0.0) && geo.points.iter().any(|p| !p.markers.is_empty()) {
        return Err(AlignError::InvalidOption {
            name: "marker_sigma_px",
            value: geo.marker_sigma_px,
            expected: "a positive standard deviation in pixels",
        });
    }
    let placement = place_components(input, components, geo, options.seed)?;
    let diagnostics = Diagnostics {
        dropped_components: placement.dropped_components,
        rejected_priors: placement.rejected_priors,
        ..Diagnostics::default()
    };
    if placement.datum == Datum::Local {
        let mut local = Georeferenced::unadjusted(input, placement.merged, Datum::Local);
        local.diagnostics = diagnostics;
        return Ok(local);
    }
    let datum = placement.datum;
    // Control points the placement rejected are left out of the adjustment: one point typed
    // 100 km off would otherwise pull the whole block (and its priors out) towards it.
    let kept_control;
    let adjusted_geo = match placement.rejected_control.is_empty() {
        true => geo,
        false => {
            let mut kept = geo.clone();
            kept.points = geo
                .points
                .iter()
                .enumerate()
                .filter(|(k, _)| !placement.rejected_control.contains(k))
                .map(|(_, p)| p.clone())
                .collect();
            kept_control = kept;
            &kept_control
        }
    };
    let rejected_control: Vec<String> = placement
        .rejected_control
        .iter()
        .map(|&k| geo.points[k].name.clone())
        .collect();
    for name in &rejected_control {
        tracing::warn!(point = %name, "control point rejected: its markers disagree with the block");
    }
    let priors = placement
        .accepted_priors
        .iter()
        .map(|&k| geo.centre_priors[k])
        .collect();
    let track_of = track_table(input);
    let mut state = State::with_reconstruction(input, options, &track_of, placement.merged);
    let mut rounds = PriorAdjustment::new(input, adjusted_geo, options, priors);
    match focal_held {
        Some(held) if held.len() == rounds.focal_fixed.len() => {
            rounds.focal_fixed.copy_from_slice(held);
        }
        _ => rounds.settle_focal_lengths(&mut state)?,
    }
    rounds.measure_noise(&mut state)?;
    let (gnss_offsets, set_motion_covariance) = rounds.final_adjustment(&mut state)?;
    let group_sigma_px = state
        .group_noise()
        .into_iter()
        .map(|n| n.map(|(median, _)| median / RAYLEIGH_MEDIAN))
        .collect();
    let (bound, group_bound_px) = (state.max_error_px, state.group_bound_px.clone());
    let merged = state.rec;
    let residuals = ground_point_residuals(input, &merged, geo, &|_| true);
    let rms_px = merged.rms_px(input);
    Ok(Georeferenced {
        reconstruction: merged,
        datum,
        residuals,
        rms_px,
        focal_held: rounds.focal_fixed,
        observation_bound_px: Some(bound),
        group_bound_px,
        group_sigma_px,
        gnss_offsets,
        diagnostics,
        set_motion_covariance,
        surface_fits: Vec::new(),
        fits_against_dem: false,
        dem_heights: Vec::new(),
        surface_held: Vec::new(),
        rejected_control,
    })
}

/// The components placed in the world frame, merged.
struct Placement {
    merged: Reconstruction,
    datum: Datum,
    /// Indices into the input's centre priors of those the placements accepted.
    accepted_priors: Vec<usize>,
    rejected_priors: usize,
    /// Indices into `geo.points` of the control points a placement rejected, ascending.
    rejected_control: Vec<usize>,
    dropped_components: usize,
}

/// Places every component ([`place`]) and merges those placed; with none placed, the largest
/// in its own frame.
fn place_components(
    input: &SfmInput,
    components: Vec<Reconstruction>,
    geo: &GeoreferenceInput,
    seed: u64,
) -> Result<Placement, AlignError> {
    let total = components.len();
    let mut placed: Vec<Reconstruction> = Vec::new();
    let mut accepted_priors: Vec<usize> = Vec::new();
    let mut used_control = false;
    let mut rejected_priors = 0;
    let mut rejected_control = Vec::new();
    let mut largest_unplaced = None;
    for (k, mut rec) in components.into_iter().enumerate() {
        match place(input, &mut rec, geo, seed ^ k as u64) {
            Some(p) => {
                accepted_priors.extend(p.accepted_priors);
                used_control |= p.control;
                rejected_priors += p.rejected_priors;
                rejected_control.extend(p.rejected_control);
                placed.push(rec);
            }
            None if k == 0 => largest_unplaced = Some(rec),
            None => {}
        }
    }
    let dropped_components = total - placed.len().max(1);
    let mut iter = placed.into_iter();
    let Some(mut merged) = iter.next() else {
        let merged = largest_unplaced
            .ok_or_else(|| AlignError::Georeferencing("no component could be kept".into()))?;
        return Ok(Placement {
            merged,
            datum: Datum::Local,
            accepted_priors,
            rejected_priors,
            rejected_control: Vec::new(),
            dropped_components,
        });
    };
    for other in iter {
        for (i, pose) in other.poses.into_iter().enumerate() {
            if pose.is_some() {
                merged.poses[i] = pose;
            }
        }
        merged.points.extend(other.points);
    }
    let datum = match (accepted_priors.is_empty(), used_control) {
        (false, true) => Datum::GnssAndControlPoints,
        (true, true) => Datum::ControlPoints,
        _ => Datum::Gnss,
    };
    rejected_control.sort_unstable();
    rejected_control.dedup();
    Ok(Placement {
        merged,
        datum,
        accepted_priors,
        rejected_priors,
        rejected_control,
        dropped_components,
    })
}

/// The adjustment of a placed block with its priors and control, in three rounds: the first
/// settles the focal lengths, the second (a consistent block again) measures the block's noise
/// and drops the outliers beyond it, the last adjusts without them.
struct PriorAdjustment<'a> {
    input: &'a SfmInput,
    geo: &'a GeoreferenceInput,
    options: &'a SfmOptions,
    /// The accepted priors, reweighed by their flight's scatter after the second round.
    priors: Vec<CentrePrior>,
    /// Per camera group: its focal length held.
    focal_fixed: Vec<bool>,
    /// Per flight, the noise of its positions about its offset (after the second round).
    within_flight: Vec<Option<[f64; 2]>>,
    /// Per flight, the scatter that weighs its priors (`None`: they keep the stated σ).
    weighing: Vec<Option<[f64; 2]>>,
}

impl<'a> PriorAdjustment<'a> {
    fn new(
        input: &'a SfmInput,
        geo: &'a GeoreferenceInput,
        options: &'a SfmOptions,
        priors: Vec<CentrePrior>,
    ) -> Self {
        // Every focal length but the calibrated ones free.
        let focal_fixed = (0..input.cameras.len())
            .map(|g| input.focal_source(g) == FocalSource::Calibrated)
            .collect();
        PriorAdjustment {
            input,
            geo,
            options,
            priors,
            focal_fixed,
            within_flight: vec![None; geo.prior_offsets.len()],
            weighing: vec![None; geo.prior_offsets.len()],
        }
    }

    /// One adjustment of every oriented image and live point, then the points filtered, the
    /// tracks completed and the state compacted.
    fn round(
        &self,
        state: &mut State<'_>,
        precision: bool,
        between: impl FnOnce(&mut State<'_>, &crate::adjust::Adjusted),
    ) -> Result<crate::adjust::Adjusted, AlignError> {
        self.round_with_sets(state, precision, &[], between)
    }

    /// [`Self::round`], with the covariance of the rigid motions of `rigid_sets` when
    /// `precision` is asked for.
    fn round_with_sets(
        &self,
        state: &mut State<'_>,
        precision: bool,
        rigid_sets: &[Vec<usize>],
        between: impl FnOnce(&mut State<'_>, &crate::adjust::Adjusted),
    ) -> Result<crate::adjust::Adjusted, AlignError> {
        let marked = marked_points(self.input, &state.rec, self.geo);
        let points = state.live_points();
        let adjusted = state.adjust(&Adjustment {
            free_images: state.oriented(),
            points: points.clone(),
            intrinsics: Intrinsics::Final,
            priors: &self.priors,
            offsets: &self.geo.prior_offsets,
            marked: &marked,
            loss: Loss::Trivial,
            iterations: self.options.global_iterations,
            focal_fixed: &self.focal_fixed,
            precision,
            rigid_sets,
            heights: &self.geo.surface_heights,
        })?;
        tracing::debug!(report = ?adjusted.report, "georeferenced adjustment");
        between(state, &adjusted);
        state.filter_points(&points);
        state.complete_all_tracks();
        state.compact();
        Ok(adjusted)
    }

    /// Round 1, with the precision of every free intrinsic: a nominal focal length that the
    /// block does not determine well goes back to its nominal value and stays.
    fn settle_focal_lengths(&mut self, state: &mut State<'_>) -> Result<(), AlignError> {
        let before = state.rec.cameras.clone();
        let input = self.input;
        let mut held = Vec::new();
        self.round(state, true, |state, adjusted| {
            for g in
                (0..input.cameras.len()).filter(|&g| input.focal_source(g) == FocalSource::Nominal)
            {
                let relative = focal_relative_std(
                    &state.rec.cameras[g],
                    adjusted.intrinsic_std.as_ref().and_then(|s| s.get(g)),
                );
                tracing::info!(group = g, relative_std = ?relative, "focal length precision");
                // Without a precision (the covariance failed), the data decide as usual.
                if relative.is_some_and(|r| r > FOCAL_DETERMINED) {
                    held.push(g);
                    restore_focal(&mut state.rec.cameras[g], &before[g]);
                }
            }
        })?;
        for g in held {
            self.focal_fixed[g] = true;
        }
        Ok(())
    }

    /// Round 2: the outlier bound from the block's noise, the noise of each flight's positions,
    /// and the priors of the flights [`scatter_weighed_flights`] names weighed by it.
    fn measure_noise(&mut self, state: &mut State<'_>) -> Result<(), AlignError> {
        let mut within_flight = Vec::new();
        let priors = &self.priors;
        self.round(state, false, |state, _| {
            let bound = state.tighten_to_noise();
            tracing::info!(
                bound_px = bound,
                "observation outlier bound from the block's noise"
            );
            within_flight = within_flight_noise(priors, &state.rec, &state.offsets);
        })?;
        let scatter_weighed = scatter_weighed_flights(self.geo, self.options.scatter_weighing);
        self.weighing = within_flight
            .iter()
            .zip(&scatter_weighed)
            .map(|(noise, &weighs)| noise.filter(|_| weighs))
            .collect();
        reweigh_priors(&mut self.priors, &self.weighing);
        tracing::info!(
            ?within_flight,
            ?scatter_weighed,
            "GNSS noise within each flight, and the flights it weighs"
        );
        self.within_flight = within_flight;
        Ok(())
    }

    /// Round 3: the final adjustment, with the offsets' precision when there are offsets; the
    /// offsets as estimated.
    #[allow(clippy::type_complexity)]
    fn final_adjustment(
        &self,
        state: &mut State<'_>,
    ) -> Result<(Vec<EstimatedOffset>, Option<nalgebra::DMatrix<f64>>), AlignError> {
        let mut offsets = Vec::new();
        let precision = !self.geo.prior_offsets.is_empty() || !self.geo.rigid_sets.is_empty();
        let adjusted =
            self.round_with_sets(state, precision, &self.geo.rigid_sets, |state, adjusted| {
                offsets = estimated_offsets(
                    self.geo,
                    &self.priors,
                    &state.offsets,
                    adjusted,
                    FlightNoise {
                        sigma: &self.within_flight,
                        weighing: &self.weighing,
                    },
                );
            })?;
        Ok((offsets, adjusted.rigid_covariance))
    }
}

/// Per flight, its scatter about its offset, and the scatter that weighed its priors (the same
/// where it did, `None` where the priors kept their stated σ).
struct FlightNoise<'a> {
    sigma: &'a [Option<[f64; 2]>],
    weighing: &'a [Option<[f64; 2]>],
}

/// The offsets of the final adjustment with their precision and the priors that carried them.
fn estimated_offsets(
    geo: &GeoreferenceInput,
    priors: &[CentrePrior],
    values: &[Vector3<f64>],
    adjusted: &crate::adjust::Adjusted,
    noise: FlightNoise<'_>,
) -> Vec<EstimatedOffset> {
    geo.prior_offsets
        .iter()
        .enumerate()
        .map(|(o, spec)| {
            let carried = priors.iter().filter(|p| p.offset == Some(o)).count();
            EstimatedOffset {
                name: spec.name.clone(),
                value: values.get(o).copied().unwrap_or_else(Vector3::zeros),
                std: adjusted
                    .offset_std
                    .as_ref()
                    .and_then(|s| s.get(o).copied().flatten())
                    .filter(|_| carried > 0),
                priors: carried,
                focal_correlation: adjusted
                    .offset_focal_correlation
                    .as_ref()
                    .and_then(|c| c.get(o).copied().flatten())
                    .filter(|_| carried > 0),
                within_flight_sigma: noise.sigma.get(o).copied().flatten(),
                scatter_weighs_priors: noise.weighing.get(o).is_some_and(Option::is_some),
            }
        })
        .collect()
}

/// Priors a flight needs before its noise is estimated from them.
const MIN_PRIORS_FOR_NOISE: usize = 10;
/// Smallest within-flight σ taken from the data, metres (RTK grade): a flight whose centres
/// happen to agree closely must not outweigh the photogrammetry.
const MIN_WITHIN_FLIGHT_SIGMA: f64 = 0.02;

/// Per estimated offset: the robust σ (horizontal per axis, vertical) of its priors' residuals
/// (adjusted centre − position + offset), each axis about its median, scaled up for the
/// offset's three parameters. Why: a receiver's stated accuracy covers its bias, which the
/// offset now carries; the scatter within a flight is often several times smaller, and
/// weighing the priors by the stated σ throws away what they say about the block's tilt (two
/// strips of a corridor: their heights fix the roll about its axis).
fn within_flight_noise(
    priors: &[CentrePrior],
    rec: &Reconstruction,
    offsets: &[Vector3<f64>],
) -> Vec<Option<[f64; 2]>> {
    (0..offsets.len())
        .map(|o| {
            let residuals: Vec<Vector3<f64>> = priors
                .iter()
                .filter(|p| p.offset == Some(o))
                .filter_map(|p| {
                    let centre = rec.poses.get(p.image)?.as_ref()?.center();
                    Some(centre - p.position + offsets[o])
                })
                .collect();
            let n = residuals.len();
            if n < MIN_PRIORS_FOR_NOISE {
                return None;
            }
            let spread = |axis: usize| {
                let mut v: Vec<f64> = residuals.iter().map(|r| r[axis]).collect();
                1.4826 * median_abs_deviation(&mut v)
            };
            let redundancy = (n as f64 / (n - 3) as f64).sqrt();
            let horizontal = ((spread(0).powi(2) + spread(1).powi(2)) / 2.0).sqrt();
            let sigma = [horizontal * redundancy, spread(2) * redundancy];
            sigma.iter().all(|s| s.is_finite()).then_some(sigma)
        })
        .collect()
}

/// Per estimated offset: whether its priors are weighed by the flight's own scatter
/// ([`within_flight_noise`]) in the final adjustment. [`ScatterWeighing::Controlled`]: with
/// control points marked (in two images or more), the flights of the images they are marked
/// in, and no other (control marked only in images without GNSS, a film epoch's, leaves every
/// flight with its stated σ); without control, every flight.
///
/// Why: with control, the datum is the control's, and the flights that share images with it
/// are where their scatter-weighed heights add what the control leaves loose (a corridor's
/// control along its axis leaves the roll about it to the GNSS heights across it). The other
/// flights are placed through the tie points. Measured (`cargo xtask bench-methods --seed
/// 1,2,3 --ties default,scatter-all`; control in the first epoch, biased GNSS in all; the
/// first epoch's orientation-alone check-point height RMSE over the seeds, `all` → this rule,
/// against `independent`'s; the later epochs' likewise):
/// - orchard (15 priors per flight): 0.046 → 0.038 m (0.042); later 0.066 / 0.071 / 0.075 →
///   0.057 / 0.053 / 0.065 m;
/// - glacier (20): 0.223 → 0.184 m (0.212); later 0.228 / 0.223 → 0.190 / 0.184 m;
/// - shore (12) within 0.003 m; campus (6 per flight, no scatter estimated) identical;
/// - the other way on landslide (25): 0.064 → 0.080 m (0.085), later 0.066 / 0.064 → 0.081 /
///   0.080 m; and corridor (39): 0.067 → 0.081 m (0.082), later 0.070 / 0.072 → 0.086 / 0.087
///   m, though its worst stable-tie tilt over the seeds fell from 2.94 to 1.87 mm/m.
///
/// So every scene's first epoch is within 1.1 × `independent`'s with this rule, and orchard's
/// is not with every flight weighed (1.11 ×); flights of many priors may be worth weighing
/// too, which these six scenes do not settle.
fn scatter_weighed_flights(geo: &GeoreferenceInput, weighing: ScatterWeighing) -> Vec<bool> {
    let flights = geo.prior_offsets.len();
    match weighing {
        ScatterWeighing::All => return vec![true; flights],
        ScatterWeighing::NoFlight => return vec![false; flights],
        ScatterWeighing::Controlled => {}
    }
    // Control the adjustment can use: a control point marked in two images or more.
    let control: Vec<&GroundPoint> = geo
        .points
        .iter()
        .filter(|p| !p.check && p.markers.len() >= 2)
        .collect();
    if control.is_empty() {
        return vec![true; flights];
    }
    // Every prior's flight, rejected ones too: a flight is the receiver's, whatever the
    // placement kept of it.
    let flight_of: std::collections::HashMap<usize, usize> = geo
        .centre_priors
        .iter()
        .filter_map(|p| Some((p.image, p.offset?)))
        .collect();
    let mut controlled = vec![false; flights];
    for marker in control.iter().flat_map(|p| &p.markers) {
        let flight = flight_of.get(&marker.image);
        if let Some(flag) = flight.and_then(|&o| controlled.get_mut(o)) {
            *flag = true;
        }
    }
    controlled
}

/// Weighs each prior that carries an offset as [`EstimatedOffset::prior_sigma`] says.
fn reweigh_priors(priors: &mut [CentrePrior], noise: &[Option<[f64; 2]>]) {
    for prior in priors.iter_mut() {
        if let Some(noise) = prior.offset.and_then(|o| noise.get(o).copied().flatten()) {
            (prior.sigma_xy, prior.sigma_z) =
                flight_prior_sigma(noise, prior.sigma_xy, prior.sigma_z);
        }
    }
}

/// A prior's σ (horizontal, vertical) weighed by its flight's noise `[xy, z]`: that noise where
/// below the stated σ (never above: the stated σ is what the receiver promises), and not below
/// [`MIN_WITHIN_FLIGHT_SIGMA`].
fn flight_prior_sigma([xy, z]: [f64; 2], sigma_xy: f64, sigma_z: f64) -> (f64, f64) {
    let weigh = |noise: f64, stated: f64| {
        noise.clamp(MIN_WITHIN_FLIGHT_SIGMA, stated.max(MIN_WITHIN_FLIGHT_SIGMA))
    };
    (weigh(xy, sigma_xy), weigh(z, sigma_z))
}

/// Median of the norm of a 2-D Gaussian error in units of its per-axis σ (Rayleigh).
const RAYLEIGH_MEDIAN: f64 = 1.1774;

/// A known focal length is held at its known value when the block determines it worse than this
/// relative standard deviation: the block cannot tell the focal length (a nadir block over flat
/// ground trades it against flying height). A tighter gate (0.2 %) was tried: it held the EXIF
/// focal length of `lund`, which is 20 % off (RMS 1.07 px instead of 0.71), and did not help
/// where biased GNSS, not a weak geometry, drags the focal length (glacier).
const FOCAL_DETERMINED: f64 = 0.05;

/// σ_f / f of a group from the adjustment's intrinsic standard deviations.
fn focal_relative_std(
    camera: &timesift_core::Camera,
    stds: Option<&Vec<(usize, f64)>>,
) -> Option<f64> {
    use timesift_core::CameraModel;
    let k = camera.param_names().iter().position(|n| *n == "f")?;
    let sigma = stds?.iter().find(|(i, _)| *i == k)?.1;
    let mut p = vec![0.0; camera.num_params()];
    camera.params(&mut p);
    Some(sigma / p[k].abs().max(1e-12))
}

/// Puts back the focal length of `before`, keeping the other adjusted intrinsics.
fn restore_focal(camera: &mut timesift_core::Camera, before: &timesift_core::Camera) {
    use timesift_core::CameraModel;
    let Some(k) = camera.param_names().iter().position(|n| *n == "f") else {
        return;
    };
    let mut p = vec![0.0; camera.num_params()];
    camera.params(&mut p);
    let mut q = vec![0.0; before.num_params()];
    before.params(&mut q);
    p[k] = q[k];
    let _ = camera.set_params(&p);
}

/// The control points (not check points) with at least two oriented markers, as marked points
/// of an adjustment, started at their intersection.
fn marked_points(
    input: &SfmInput,
    rec: &Reconstruction,
    geo: &GeoreferenceInput,
) -> Vec<MarkedPoint> {
    geo.points
        .iter()
        .filter(|p| !p.check)
        .filter_map(|p| {
            let sigma = p.marker_sigma(geo);
            let (_, point) = intersect(input, rec, &p.markers, sigma);
            Some(MarkedPoint {
                position: point?.position,
                markers: p
                    .markers
                    .iter()
                    .map(|m| (m.image, m.pixel, sigma))
                    .collect(),
                prior: Some((p.position, p.sigma_xy, p.sigma_z)),
            })
        })
        .collect()
}

/// Intersects every ground point from its markers in the oriented images that `keep` accepts and
/// compares it with its surveyed coordinates (e.g. per epoch: the images of one epoch).
pub fn ground_point_residuals(
    input: &SfmInput,
    rec: &Reconstruction,
    geo: &GeoreferenceInput,
    keep: &dyn Fn(usize) -> bool,
) -> Vec<PointResidual> {
    geo.points
        .iter()
        .map(|p| {
            let markers: Vec<Marker> = p
                .markers
                .iter()
                .filter(|m| keep(m.image))
                .copied()
                .collect();
            let (images, point) = intersect(input, rec, &markers, p.marker_sigma(geo));
            PointResidual {
                name: p.name.clone(),
                check: p.check,
                images,
                residual: point.map(|x| x.position - p.position),
                markers_sigma: point.map(|x| x.covariance.diagonal().map(|v| v.max(0.0).sqrt())),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use timesift_core::{Pose, SeededRng};

    /// Control points whose block positions are their markers' intersections on film scans
    /// (metres off, every one beyond a survey-σ threshold) all stay in the adjustment; one typed
    /// 100 km off among them is left out, and so is a point off by far more than the others on
    /// a drone block.
    #[test]
    fn only_gross_control_errors_are_left_out_of_the_adjustment() {
        let identity = Similarity {
            scale: 1.0,
            rotation: nalgebra::UnitQuaternion::identity(),
            translation: Vector3::zeros(),
        };
        let correspondences = |misses: &[f64]| Correspondences {
            src: misses.iter().map(|&m| Vector3::new(m, 0.0, 0.0)).collect(),
            dst: vec![Vector3::zeros(); misses.len()],
            sigma: vec![0.08; misses.len()],
            from_control: misses.len(),
            prior_index: vec![None; misses.len()],
            control_index: (0..misses.len()).map(Some).collect(),
        };
        let threshold = 4.0 * 0.08;
        let outside =
            |misses: &[f64]| -> Vec<bool> { misses.iter().map(|m| *m <= threshold).collect() };
        let film = [1.4, 0.6, 1.8, 1.3, 0.7, 6.8, 4.7, 0.3];
        let c = correspondences(&film);
        assert_eq!(
            gross_control_errors(&c, &identity, &outside(&film), threshold),
            Vec::<usize>::new()
        );
        let mut typo = film.to_vec();
        typo[2] = 100_000.0;
        let c = correspondences(&typo);
        assert_eq!(
            gross_control_errors(&c, &identity, &outside(&typo), threshold),
            vec![2]
        );
        let drone = [0.02, 0.03, 0.01, 1.5, 0.04, 0.02];
        let c = correspondences(&drone);
        assert_eq!(
            gross_control_errors(&c, &identity, &outside(&drone), threshold),
            vec![3]
        );
    }

    /// Two flights of 300 priors scattered by σ = (0.5, 1.0) m about their own offsets: the
    /// estimate recovers each flight's σ, and the priors are weighed by it within the stated σ.
    #[test]
    fn the_scatter_within_each_flight_is_recovered_and_weighs_its_priors() {
        let mut rng = SeededRng::new(7);
        let offsets = [Vector3::new(1.2, -0.8, 2.5), Vector3::new(-2.0, 0.4, -3.0)];
        let truth = [[0.5, 1.0], [0.2, 0.3]];
        let mut poses = Vec::new();
        let mut priors = Vec::new();
        for k in 0..600 {
            let flight = k % 2;
            let centre = Vector3::new(3.0 * k as f64, 40.0 * flight as f64, 60.0);
            poses.push(Some(
                Pose::look_at(&centre, &Vector3::new(centre.x + 5.0, centre.y, 0.0)).expect("pose"),
            ));
            let [xy, z] = truth[flight];
            let noise = Vector3::new(xy * rng.normal(), xy * rng.normal(), z * rng.normal());
            priors.push(CentrePrior {
                image: k,
                position: centre + offsets[flight] + noise,
                sigma_xy: 1.58,
                sigma_z: 3.16,
                offset: Some(flight),
            });
        }
        let rec = Reconstruction {
            cameras: Vec::new(),
            poses,
            points: Vec::new(),
        };
        let noise = within_flight_noise(&priors, &rec, &offsets);
        for (estimate, truth) in noise.iter().zip(truth) {
            let estimate = estimate.expect("estimated");
            for k in 0..2 {
                assert!(
                    (estimate[k] / truth[k] - 1.0).abs() < 0.12,
                    "{estimate:?} against {truth:?}"
                );
            }
        }
        reweigh_priors(&mut priors, &noise);
        assert!((priors[0].sigma_z - noise[0].unwrap()[1]).abs() < 1e-12);
        // Never looser than stated, never tighter than RTK.
        let mut loose = vec![CentrePrior {
            sigma_xy: 0.1,
            sigma_z: 0.1,
            ..priors[0]
        }];
        reweigh_priors(&mut loose, &[Some([0.5, 1.0]), None]);
        assert_eq!((loose[0].sigma_xy, loose[0].sigma_z), (0.1, 0.1));
        reweigh_priors(&mut loose, &[Some([0.001, 0.001]), None]);
        assert_eq!(
            (loose[0].sigma_xy, loose[0].sigma_z),
            (MIN_WITHIN_FLIGHT_SIGMA, MIN_WITHIN_FLIGHT_SIGMA)
        );
        // Too few priors: nothing estimated.
        assert_eq!(
            within_flight_noise(&priors[..8], &rec, &offsets),
            vec![None, None]
        );
    }

    /// Control marked in images of the first of three flights: only that flight's priors are
    /// weighed by their scatter. Check points do not count; without control, every flight is.
    #[test]
    fn only_the_flights_that_share_images_with_control_are_weighed_by_their_scatter() {
        let prior = |image: usize, offset: Option<usize>| CentrePrior {
            image,
            position: Vector3::zeros(),
            sigma_xy: 1.58,
            sigma_z: 3.16,
            offset,
        };
        // Images 0-1: flight 0; 2-3: flight 1; 4-5: flight 2; 6: a prior without an offset.
        let priors: Vec<CentrePrior> = (0..6)
            .map(|k| prior(k, Some(k / 2)))
            .chain([prior(6, None)])
            .collect();
        let offset = |name: &str| OffsetPrior {
            name: name.into(),
            sigma_xy: 1.58,
            sigma_z: 3.16,
        };
        let point = |name: &str, check: bool, images: &[usize]| GroundPoint {
            name: name.into(),
            position: Vector3::zeros(),
            sigma_xy: 0.02,
            sigma_z: 0.03,
            check,
            markers: images
                .iter()
                .map(|&image| Marker {
                    image,
                    pixel: Vector2::zeros(),
                })
                .collect(),
            marker_sigma_px: None,
        };
        let mut geo = GeoreferenceInput {
            centre_priors: priors.clone(),
            prior_offsets: vec![offset("a"), offset("b"), offset("c")],
            points: vec![
                point("GCP1", false, &[0, 1, 6]),
                point("CHK1", true, &[2, 3, 4]),
            ],
            marker_sigma_px: 0.5,
            rigid_sets: Vec::new(),
            surface_heights: Vec::new(),
            reference_dem: None,
        };
        assert_eq!(
            scatter_weighed_flights(&geo, ScatterWeighing::Controlled),
            [true, false, false]
        );
        geo.points[0].markers.push(Marker {
            image: 5,
            pixel: Vector2::zeros(),
        });
        assert_eq!(
            scatter_weighed_flights(&geo, ScatterWeighing::Controlled),
            [true, false, true]
        );
        for (weighing, expected) in [
            (ScatterWeighing::All, [true; 3]),
            (ScatterWeighing::NoFlight, [false; 3]),
        ] {
            assert_eq!(scatter_weighed_flights(&geo, weighing), expected);
        }
        // Control marked only in images without GNSS (a film epoch's): no flight is weighed.
        let mut film = geo.clone();
        film.points[0].markers = vec![7, 8]
            .into_iter()
            .map(|image| Marker {
                image,
                pixel: Vector2::zeros(),
            })
            .collect();
        assert_eq!(
            scatter_weighed_flights(&film, ScatterWeighing::Controlled),
            [false; 3]
        );
        // A control point in one image only fixes nothing: as without control.
        film.points[0].markers.truncate(1);
        assert_eq!(
            scatter_weighed_flights(&film, ScatterWeighing::Controlled),
            [true; 3]
        );
        geo.points.remove(0);
        assert_eq!(
            scatter_weighed_flights(&geo, ScatterWeighing::Controlled),
            [true; 3]
        );
    }
}
