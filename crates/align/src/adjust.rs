//! Bundle adjustment of a reconstruction in progress through `timesift-bundle`: which images,
//! points and intrinsics are free, the datum, and writing the result back.

use std::collections::BTreeMap;

use nalgebra::Vector3;
use timesift_bundle::problem::{BundleImage, BundlePoint};
use timesift_bundle::{
    BundleOptions, BundleProblem, BundleReport, CameraGroup, CenterPrior, Loss, Observation,
    PointPrior, PriorOffset,
};
use timesift_core::CameraModel;

use crate::AlignError;
use crate::state::State;

/// A camera-centre prior (GNSS) on an image, in the reconstruction's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CentrePrior {
    /// Image index.
    pub image: usize,
    /// Measured centre.
    pub position: Vector3<f64>,
    /// Horizontal standard deviation, metres.
    pub sigma_xy: f64,
    /// Vertical standard deviation, metres.
    pub sigma_z: f64,
    /// The GNSS offset this prior carries (index into
    /// [`crate::GeoreferenceInput::prior_offsets`]), estimated in the adjustment; `None`: the
    /// prior is taken as unbiased.
    pub offset: Option<usize>,
}

/// An unknown GNSS offset shared by the centre priors of one flight (an epoch or a camera
/// group): consumer receivers carry a bias of metres per flight and centimetres of noise within
/// it. Estimated with a zero-mean prior of these σ.
#[derive(Debug, Clone, PartialEq)]
pub struct OffsetPrior {
    /// What it belongs to (an epoch's name), for reports.
    pub name: String,
    /// Horizontal standard deviation of the prior, metres.
    pub sigma_xy: f64,
    /// Vertical standard deviation of the prior, metres.
    pub sigma_z: f64,
}

/// A point measured by markers in images (a ground control point in an adjustment): its start
/// position, its image measurements, and its surveyed coordinates when it constrains the datum.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct MarkedPoint {
    pub position: Vector3<f64>,
    /// (image, pixel, sigma in pixels).
    pub markers: Vec<(usize, nalgebra::Vector2<f64>, f64)>,
    /// Surveyed position with horizontal and vertical standard deviations.
    pub prior: Option<(Vector3<f64>, f64, f64)>,
}

/// Which intrinsics an adjustment estimates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Intrinsics {
    /// All fixed (local adjustments, early global ones).
    Fixed,
    /// `SelfCalibration::parameters` for groups with enough images.
    Running,
    /// `SelfCalibration::final_parameters` where a group has enough images for them.
    Final,
}

/// One adjustment: the free images and the points; every other oriented image that sees one of
/// the points enters fixed.
pub(crate) struct Adjustment<'p> {
    pub free_images: Vec<usize>,
    pub points: Vec<usize>,
    pub intrinsics: Intrinsics,
    pub priors: &'p [CentrePrior],
    /// The offsets the priors refer to; their current values are in [`State::offsets`].
    pub offsets: &'p [OffsetPrior],
    pub marked: &'p [MarkedPoint],
    /// Loss on every reprojection residual (markers included).
    pub loss: Loss,
    pub iterations: usize,
    /// Per camera group: hold the focal length fixed whatever the phase says.
    pub focal_fixed: &'p [bool],
    /// Also compute the standard deviations of the free intrinsics (needs a fixed datum).
    pub precision: bool,
    /// With `precision`: sets of images (input indices) whose rigid motion's covariance is
    /// computed too ([`Adjusted::rigid_covariance`]).
    pub rigid_sets: &'p [Vec<usize>],
    /// Height observations of points, by track (sorted by track).
    pub heights: &'p [crate::SurfaceHeight],
}

/// What an adjustment gives back besides the updated state.
pub(crate) struct Adjusted {
    pub report: BundleReport,
    /// Per group: (parameter index, standard deviation) of each free intrinsic, when asked for
    /// and the datum allowed it.
    pub intrinsic_std: Option<Vec<Vec<(usize, f64)>>>,
    /// Per offset: standard deviations (east, north, up), when asked for and the datum allowed
    /// it.
    pub offset_std: Option<Vec<Option<[f64; 3]>>>,
    /// Per offset: the largest |correlation| of its up component with a free focal length,
    /// when asked for and some focal length was free.
    pub offset_focal_correlation: Option<Vec<Option<f64>>>,
    /// The covariance of the rigid motions of [`Adjustment::rigid_sets`], 6 rows per set, when
    /// asked for, every set had two free images and the datum was fixed.
    pub rigid_covariance: Option<nalgebra::DMatrix<f64>>,
}

/// Robust loss of tie-point residuals (in sigmas) while the block grows: soft L1 beyond about
/// 2 σ, so a few wrong matches do not pull the block before filtering removes them. Adjustments
/// with markers use the trivial loss: a marker far from its prediction is the datum speaking,
/// not an outlier.
pub(crate) const TIE_POINT_LOSS: Loss = Loss::SoftL1(2.0);

impl State<'_> {
    /// Runs an adjustment and writes poses, points and intrinsics back.
    pub fn adjust(&mut self, a: &Adjustment<'_>) -> Result<Adjusted, AlignError> {
        let mut problem = BundleProblem {
            groups: self.camera_groups(a)?,
            ..BundleProblem::default()
        };
        let slot = self.add_images_and_points(a, &mut problem);
        add_marked_points(a.marked, &slot, &mut problem);
        self.add_priors(a, &slot, &mut problem);
        // Datum: without fixed images or priors, the gauge image holds it (scale stays free;
        // the damped solver copes with that one-dimensional null space).
        let datum = problem.center_priors.len() + problem.point_priors.len();
        if datum < 3 && problem.images.iter().all(|im| !im.fixed) {
            let gauge = slot.get(&self.gauge).copied().unwrap_or(0);
            if let Some(im) = problem.images.get_mut(gauge) {
                im.fixed = true;
            }
        }
        let options = BundleOptions {
            loss: a.loss,
            max_iterations: a.iterations,
            ..BundleOptions::default()
        };
        let report = timesift_bundle::solve(&mut problem, &options)?;
        let (intrinsic_std, offset_std, offset_focal_correlation) =
            adjusted_precision(&problem, a.precision);
        let rigid_covariance = match a.precision && !a.rigid_sets.is_empty() {
            true => rigid_covariance(&problem, &slot, a.rigid_sets),
            false => None,
        };
        for (value, offset) in self.offsets.iter_mut().zip(&problem.prior_offsets) {
            *value = offset.value;
        }
        for (&i, &s) in &slot {
            self.rec.poses[i] = Some(problem.images[s].pose);
        }
        for (k, &p) in a.points.iter().enumerate() {
            self.rec.points[p].position = problem.points[k].position;
        }
        for (g, group) in problem.groups.into_iter().enumerate() {
            self.rec.cameras[g] = group.camera;
        }
        Ok(Adjusted {
            report,
            intrinsic_std,
            offset_std,
            offset_focal_correlation,
            rigid_covariance,
        })
    }

    /// One bundle group per camera group, with the intrinsics this adjustment frees: none when
    /// fixed, or for a group without free images or with too few oriented ones.
    fn camera_groups(&self, a: &Adjustment<'_>) -> Result<Vec<CameraGroup>, AlignError> {
        let input = self.input;
        let mut groups = Vec::with_capacity(input.cameras.len());
        let oriented_per_group = {
            let mut n = vec![0usize; input.cameras.len()];
            for i in self.oriented() {
                n[input.images[i].group] += 1;
            }
            n
        };
        let calibration = &self.options.self_calibration;
        let mut free_group = vec![false; input.cameras.len()];
        for &i in &a.free_images {
            free_group[input.images[i].group] = true;
        }
        for (g, camera) in self.rec.cameras.iter().enumerate() {
            let names: &[String] = match a.intrinsics {
                Intrinsics::Fixed => &[],
                _ if !free_group[g] || oriented_per_group[g] < calibration.min_images => &[],
                Intrinsics::Final if oriented_per_group[g] >= calibration.final_min_images => {
                    &calibration.final_parameters
                }
                _ => &calibration.parameters,
            };
            let model_names = camera.param_names();
            let focal_fixed = a.focal_fixed.get(g).copied().unwrap_or(false);
            let held = calibration.held.get(g).map_or(&[][..], Vec::as_slice);
            let names: Vec<&str> = names
                .iter()
                .map(String::as_str)
                .filter(|n| model_names.contains(n) && !(focal_fixed && *n == "f"))
                .filter(|n| !held.iter().any(|h| h == n))
                .collect();
            groups.push(CameraGroup::with_free(camera.clone(), &names)?);
        }
        Ok(groups)
    }

    /// The free images, the points with their observations, and the fixed images that see
    /// them, into `problem`; each image's slot in it.
    fn add_images_and_points(
        &self,
        a: &Adjustment<'_>,
        problem: &mut BundleProblem,
    ) -> BTreeMap<usize, usize> {
        let input = self.input;
        // Images: the free ones, then fixed ones seeing the points.
        let mut slot: BTreeMap<usize, usize> = BTreeMap::new();
        for &i in &a.free_images {
            if let Some(pose) = self.rec.poses[i] {
                slot.entry(i).or_insert_with(|| {
                    problem.images.push(BundleImage {
                        pose,
                        group: input.images[i].group,
                        fixed: false,
                    });
                    problem.images.len() - 1
                });
            }
        }
        for (k, &p) in a.points.iter().enumerate() {
            let point = &self.rec.points[p];
            problem.points.push(BundlePoint {
                position: point.position,
                fixed: false,
            });
            for e in &point.observations {
                let i = e.image.index();
                let Some(pose) = self.rec.poses[i] else {
                    continue;
                };
                let image = *slot.entry(i).or_insert_with(|| {
                    problem.images.push(BundleImage {
                        pose,
                        group: input.images[i].group,
                        fixed: true,
                    });
                    problem.images.len() - 1
                });
                problem.observations.push(Observation {
                    image,
                    point: k,
                    pixel: input.pixel(e),
                    sigma_px: self.options.tie_point_sigma_px,
                });
            }
            if let Ok(h) = a.heights.binary_search_by_key(&point.track, |h| h.track) {
                let h = a.heights[h];
                // A height alone: no horizontal weight; on a sloped reference, the height of its
                // tangent plane where the point was sampled.
                problem.point_priors.push(PointPrior {
                    point: k,
                    position: Vector3::new(h.at[0], h.at[1], h.height),
                    sigma_xy: f64::INFINITY,
                    sigma_z: h.sigma,
                    slope: h.slope,
                });
            }
        }
        slot
    }

    /// The GNSS offsets (at their current values) and the centre priors of the images in the
    /// problem.
    fn add_priors(
        &mut self,
        a: &Adjustment<'_>,
        slot: &BTreeMap<usize, usize>,
        problem: &mut BundleProblem,
    ) {
        if self.offsets.len() != a.offsets.len() {
            self.offsets = vec![Vector3::zeros(); a.offsets.len()];
        }
        for (o, value) in a.offsets.iter().zip(&self.offsets) {
            problem.prior_offsets.push(PriorOffset {
                value: *value,
                sigma_xy: o.sigma_xy,
                sigma_z: o.sigma_z,
                fixed: false,
            });
        }
        for prior in a.priors {
            if let Some(&image) = slot.get(&prior.image) {
                problem.center_priors.push(CenterPrior {
                    image,
                    position: prior.position,
                    sigma_xy: prior.sigma_xy,
                    sigma_z: prior.sigma_z,
                    offset: prior.offset.filter(|&o| o < a.offsets.len()),
                });
            }
        }
    }
}

/// The marked points (control), their markers in the images of the problem and their surveyed
/// positions as priors.
fn add_marked_points(
    marked: &[MarkedPoint],
    slot: &BTreeMap<usize, usize>,
    problem: &mut BundleProblem,
) {
    for m in marked {
        let k = problem.points.len();
        problem.points.push(BundlePoint {
            position: m.position,
            fixed: false,
        });
        for &(i, pixel, sigma_px) in &m.markers {
            let Some(&image) = slot.get(&i) else {
                continue;
            };
            problem.observations.push(Observation {
                image,
                point: k,
                pixel,
                sigma_px,
            });
        }
        if let Some((position, sigma_xy, sigma_z)) = m.prior {
            problem.point_priors.push(PointPrior {
                point: k,
                position,
                sigma_xy,
                sigma_z,
                slope: [0.0; 2],
            });
        }
    }
}

/// The a-posteriori covariance of the rigid motions of `sets` (input image indices, mapped to
/// the problem's by `slot`), rotations weighed by the median distance from camera to point;
/// `None` where it cannot be had (a set with fewer than two free images, a free datum).
fn rigid_covariance(
    problem: &BundleProblem,
    slot: &BTreeMap<usize, usize>,
    sets: &[Vec<usize>],
) -> Option<nalgebra::DMatrix<f64>> {
    let sets: Vec<Vec<usize>> = sets
        .iter()
        .map(|set| set.iter().filter_map(|i| slot.get(i).copied()).collect())
        .collect();
    let mut distances: Vec<f64> = problem
        .observations
        .iter()
        .step_by(7)
        .map(|o| (problem.points[o.point].position - problem.images[o.image].pose.center()).norm())
        .collect();
    if distances.is_empty() {
        return None;
    }
    let middle = distances.len() / 2;
    let lever = *distances.select_nth_unstable_by(middle, f64::total_cmp).1;
    timesift_bundle::rigid::rigid_motion_covariance(
        problem,
        &sets,
        lever,
        timesift_bundle::precision::CovarianceScale::Posterior,
    )
    .map_err(|e| tracing::info!("no covariance of the epochs' rigid motions: {e}"))
    .ok()
}

/// The intrinsics' standard deviations, the offsets' (the larger of the a-priori and the
/// a-posteriori), and each offset's largest correlation with a focal length, when asked for.
#[allow(clippy::type_complexity)]
fn adjusted_precision(
    problem: &BundleProblem,
    asked: bool,
) -> (
    Option<Vec<Vec<(usize, f64)>>>,
    Option<Vec<Option<[f64; 3]>>>,
    Option<Vec<Option<f64>>>,
) {
    use timesift_bundle::precision::{CovarianceScale, intrinsic_and_offset_precision};
    // One factorisation for both: the a-priori covariances are the a-posteriori ones without
    // the variance factor.
    let prior_precision = asked
        .then(|| intrinsic_and_offset_precision(problem, CovarianceScale::Prior).ok())
        .flatten();
    let precision = prior_precision
        .as_ref()
        .map(|p| p.rescaled(CovarianceScale::Posterior.factor(problem)));
    // An offset's σ is the larger of the a-priori and a-posteriori ones: priors that state
    // the bias in their σ make the block's variance factor small, and the posterior σ alone
    // would then claim the mean of the flight's noise is known better than it is.
    let offset_std = precision.as_ref().map(|p| {
        (0..problem.prior_offsets.len())
            .map(|o| {
                let posterior = p.offset_std(o)?;
                let prior = prior_precision.as_ref().and_then(|q| q.offset_std(o));
                Some(match prior {
                    Some(q) => [0, 1, 2].map(|k| posterior[k].max(q[k])),
                    None => posterior,
                })
            })
            .collect()
    });
    let offset_focal_correlation = precision.as_ref().map(|p| {
        p.offset_intrinsic_correlations
            .iter()
            .map(|list| {
                list.iter()
                    .filter(|c| {
                        problem.groups[c.group].camera.param_names().get(c.param) == Some(&"f")
                    })
                    .map(|c| c.rho[2].abs())
                    .reduce(f64::max)
            })
            .collect()
    });
    let intrinsic_std = precision.map(|p| p.intrinsics);
    (intrinsic_std, offset_std, offset_focal_correlation)
}
