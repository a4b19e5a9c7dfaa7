//! What an adjusted block is worth: residual statistics per kind, camera group and image; the
//! posterior variance factor; flagged outlier observations; and the covariances (standard
//! deviations) of camera centres and intrinsics from the inverse of the reduced camera system.
//!
//! The covariance of the camera-side parameters is the inverse of `S = U − E V⁻¹ Eᵀ` (the points
//! eliminated), computed from one Cholesky factorisation and solves against the identity columns of
//! the blocks asked for, so only diagonal blocks are ever formed. The datum must be fixed (control
//! points, camera-centre priors or fixed cameras): a free network's `S` is singular and is reported
//! as such rather than given an arbitrary gauge.

use nalgebra::{Matrix3, Matrix6, SMatrix};
use timesift_core::project_world;

use crate::BundleError;
use crate::layout::Layout;
use crate::problem::BundleProblem;
use crate::solver::{center_jacobian, reduced_system};

/// Root mean square and count.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Rms {
    /// Root mean square of the per-item error norms.
    pub rms: f64,
    /// Items.
    pub count: usize,
}

impl Rms {
    fn from_sum(sum_sq: f64, count: usize) -> Rms {
        Rms {
            rms: if count == 0 {
                0.0
            } else {
                (sum_sq / count as f64).sqrt()
            },
            count,
        }
    }
}

/// Residual statistics of an adjusted problem.
#[derive(Debug, Clone, PartialEq)]
pub struct ResidualStatistics {
    /// Reprojection error (pixels, norm per observation) over every observation that projects.
    pub reprojection: Rms,
    /// The same per camera group.
    pub per_group: Vec<Rms>,
    /// The same per image.
    pub per_image: Vec<Rms>,
    /// Camera centre minus GNSS prior (less its offset, when it has one): RMS east, north, up
    /// (m), and count.
    pub center_priors: Option<([f64; 3], usize)>,
    /// Adjusted minus surveyed control-point coordinates: RMS east, north, up (m), and count.
    pub point_priors: Option<([f64; 3], usize)>,
    /// Measured minus adjusted scale-bar lengths: RMS (m) and count.
    pub scale_bars: Option<(f64, usize)>,
    /// Observations minus unknowns (residual components counted singly).
    pub redundancy: i64,
    /// Posterior variance factor σ0² = Σ ‖r/σ‖² / redundancy over every residual (no robust loss):
    /// 1 when the given sigmas are right.
    pub variance_factor: f64,
    /// Observations whose normalised residual ‖r‖/σ exceeds `threshold · σ0`.
    pub outliers: Vec<usize>,
}

/// Residual statistics; observations beyond `outlier_threshold · σ0` (normalised) are flagged.
pub fn residual_statistics(p: &BundleProblem, outlier_threshold: f64) -> ResidualStatistics {
    let layout = Layout::new(p);
    let mut chi2 = Chi2 {
        normalised_sq: 0.0,
        components: 0,
    };
    let reprojection = ReprojectionSums::new(p, &mut chi2);
    let center_priors = chi2.prior_stats(
        p.center_priors
            .iter()
            .map(|c| {
                let offset = c
                    .offset
                    .map_or_else(nalgebra::Vector3::zeros, |o| p.prior_offsets[o].value);
                let d = p.images[c.image].pose.center() - c.position + offset;
                (
                    d,
                    nalgebra::Vector3::new(1.0 / c.sigma_xy, 1.0 / c.sigma_xy, 1.0 / c.sigma_z),
                )
            })
            .collect(),
    );
    let point_priors = chi2.prior_stats(
        p.point_priors
            .iter()
            .map(|c| {
                (
                    c.miss(&p.points[c.point].position),
                    nalgebra::Vector3::new(1.0 / c.sigma_xy, 1.0 / c.sigma_xy, 1.0 / c.sigma_z),
                )
            })
            .collect(),
    );
    // The free offsets' zero-mean priors are residuals too (not in `center_priors`' RMS).
    for o in p.prior_offsets.iter().filter(|o| !o.fixed) {
        let scale = crate::solver::offset_prior_scale(o);
        chi2.normalised_sq += o.value.component_mul(&scale).norm_squared();
        chi2.components += 3;
    }
    let scale_bars = chi2.scale_bar_stats(p);
    let unknowns = (layout.num_camera_params + 3 * layout.num_free_points) as i64;
    let redundancy = chi2.components - unknowns;
    let variance_factor = if redundancy > 0 {
        chi2.normalised_sq / redundancy as f64
    } else {
        f64::NAN
    };
    let sigma0 = variance_factor.sqrt();
    let outliers = reprojection
        .normalised
        .iter()
        .filter(|(_, r)| *r > outlier_threshold * sigma0)
        .map(|(k, _)| *k)
        .collect();
    ResidualStatistics {
        reprojection: Rms::from_sum(reprojection.sum, reprojection.count),
        per_group: reprojection
            .per_group
            .into_iter()
            .map(|(s, n)| Rms::from_sum(s, n))
            .collect(),
        per_image: reprojection
            .per_image
            .into_iter()
            .map(|(s, n)| Rms::from_sum(s, n))
            .collect(),
        center_priors,
        point_priors,
        scale_bars,
        redundancy,
        variance_factor,
        outliers,
    }
}

/// The running sums of the posterior variance factor, every residual kind added in turn:
/// `Σ ‖r/σ‖²` and the number of residual components.
struct Chi2 {
    normalised_sq: f64,
    components: i64,
}

impl Chi2 {
    /// RMS east, north, up and count of 3-D prior residuals `(d, 1/σ)`, `None` when there are
    /// none; adds their normalised squares and components.
    fn prior_stats(
        &mut self,
        residuals: Vec<(SMatrix<f64, 3, 1>, SMatrix<f64, 3, 1>)>,
    ) -> Option<([f64; 3], usize)> {
        if residuals.is_empty() {
            return None;
        }
        let mut sq = [0.0; 3];
        for (d, inv_sigma) in &residuals {
            for c in 0..3 {
                sq[c] += d[c] * d[c];
                // A component of infinite σ (a height alone) is no observation.
                if inv_sigma[c] > 0.0 {
                    self.normalised_sq += (d[c] * inv_sigma[c]).powi(2);
                    self.components += 1;
                }
            }
        }
        let n = residuals.len() as f64;
        Some((sq.map(|s| (s / n).sqrt()), residuals.len()))
    }

    /// RMS (m) and count of the scale bars' length residuals, `None` when there are none; adds
    /// their normalised squares and components.
    fn scale_bar_stats(&mut self, p: &BundleProblem) -> Option<(f64, usize)> {
        (!p.scale_bars.is_empty()).then(|| {
            let mut sq = 0.0;
            for bar in &p.scale_bars {
                let (r, _) = crate::solver::scale_bar_residual(p, bar);
                self.normalised_sq += r * r;
                self.components += 1;
                sq += (r * bar.sigma).powi(2);
            }
            ((sq / p.scale_bars.len() as f64).sqrt(), p.scale_bars.len())
        })
    }
}

/// Sums of the squared reprojection errors (pixels) over every observation that projects, in
/// all, per camera group and per image, with each observation's normalised error `‖r‖/σ`.
struct ReprojectionSums {
    sum: f64,
    count: usize,
    per_group: Vec<(f64, usize)>,
    per_image: Vec<(f64, usize)>,
    /// (observation, ‖r‖/σ).
    normalised: Vec<(usize, f64)>,
}

impl ReprojectionSums {
    /// Sums the reprojection errors of `p`, adding their normalised squares and components
    /// (two per observation) to `chi2`.
    fn new(p: &BundleProblem, chi2: &mut Chi2) -> Self {
        let mut per_group = vec![(0.0, 0usize); p.groups.len()];
        let mut per_image = vec![(0.0, 0usize); p.images.len()];
        let (mut sum, mut count) = (0.0, 0usize);
        let mut normalised: Vec<(usize, f64)> = Vec::with_capacity(p.observations.len());
        for (k, o) in p.observations.iter().enumerate() {
            let im = &p.images[o.image];
            let Ok(px) = project_world(
                &p.groups[im.group].camera,
                &im.pose,
                &p.points[o.point].position,
            ) else {
                continue;
            };
            let e2 = (px - o.pixel).norm_squared();
            sum += e2;
            count += 1;
            per_group[im.group].0 += e2;
            per_group[im.group].1 += 1;
            per_image[o.image].0 += e2;
            per_image[o.image].1 += 1;
            let n2 = e2 / (o.sigma_px * o.sigma_px);
            chi2.normalised_sq += n2;
            chi2.components += 2;
            normalised.push((k, n2.sqrt()));
        }
        ReprojectionSums {
            sum,
            count,
            per_group,
            per_image,
            normalised,
        }
    }
}

/// Covariances of the adjusted camera-side parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Precision {
    /// The factor the covariances were scaled by (σ0², or 1 for a-priori covariances).
    pub scale: f64,
    /// Covariance of each free image's camera centre (m²), world axes.
    pub centers: Vec<Option<Matrix3<f64>>>,
    /// Covariance of each free image's pose update (rotation δω then translation δt).
    pub poses: Vec<Option<Matrix6<f64>>>,
    /// Per camera group: (parameter index in the camera model, standard deviation) of each free
    /// intrinsic.
    pub intrinsics: Vec<Vec<(usize, f64)>>,
    /// Covariance of each free prior offset (m²), world axes.
    pub offsets: Vec<Option<Matrix3<f64>>>,
    /// Per prior offset: its correlations with every free intrinsic. A vertical offset and the
    /// focal length of a nadir block over flat ground correlate near 1: the data cannot
    /// separate a shifted flying height from a changed focal length, only the priors can.
    pub offset_intrinsic_correlations: Vec<Vec<OffsetCorrelation>>,
}

/// The correlation of a prior offset with one free intrinsic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffsetCorrelation {
    /// Camera group.
    pub group: usize,
    /// Parameter index in the camera model.
    pub param: usize,
    /// Correlation of the offset's east, north and up components with the parameter.
    pub rho: [f64; 3],
}

impl Precision {
    /// The same covariances scaled by `scale` instead of [`Precision::scale`]: the a-priori and
    /// the a-posteriori precision of one adjustment differ by the variance factor alone, so one
    /// factorisation gives both.
    pub fn rescaled(&self, scale: f64) -> Precision {
        let ratio = scale / self.scale;
        let sd = ratio.sqrt();
        Precision {
            scale,
            centers: self.centers.iter().map(|c| c.map(|c| c * ratio)).collect(),
            poses: self.poses.iter().map(|c| c.map(|c| c * ratio)).collect(),
            intrinsics: self
                .intrinsics
                .iter()
                .map(|g| g.iter().map(|&(k, s)| (k, s * sd)).collect())
                .collect(),
            offsets: self.offsets.iter().map(|c| c.map(|c| c * ratio)).collect(),
            offset_intrinsic_correlations: self.offset_intrinsic_correlations.clone(),
        }
    }

    /// Standard deviations (east, north, up) of an image's camera centre.
    pub fn center_std(&self, image: usize) -> Option<[f64; 3]> {
        self.centers[image].map(|c| [c[(0, 0)].sqrt(), c[(1, 1)].sqrt(), c[(2, 2)].sqrt()])
    }

    /// Standard deviations (east, north, up) of a prior offset, when free.
    pub fn offset_std(&self, offset: usize) -> Option<[f64; 3]> {
        self.offsets[offset].map(|c| [c[(0, 0)].sqrt(), c[(1, 1)].sqrt(), c[(2, 2)].sqrt()])
    }

    /// Standard deviation of intrinsic `param` (camera-model index) of `group`, when free.
    pub fn intrinsic_std(&self, group: usize, param: usize) -> Option<f64> {
        self.intrinsics[group]
            .iter()
            .find(|(k, _)| *k == param)
            .map(|(_, s)| *s)
    }
}

/// Whether covariances are scaled by the posterior variance factor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CovarianceScale {
    /// A-posteriori: scaled by σ0² (what adjustment reports usually give).
    Posterior,
    /// A-priori: from the given sigmas alone.
    Prior,
}

impl CovarianceScale {
    /// What covariances are multiplied by: σ0² of `p` (1 where it is not finite), or 1.
    pub fn factor(self, p: &BundleProblem) -> f64 {
        match self {
            CovarianceScale::Prior => 1.0,
            CovarianceScale::Posterior => {
                let v = residual_statistics(p, f64::INFINITY).variance_factor;
                if v.is_finite() { v } else { 1.0 }
            }
        }
    }
}

/// Covariances of camera centres, poses and free intrinsics at the current (adjusted) parameters.
pub fn precision(p: &BundleProblem, scale: CovarianceScale) -> Result<Precision, BundleError> {
    precision_of(p, scale, true)
}

/// [`precision`] without the poses' and centres' covariances (every entry `None`): the
/// intrinsics', the offsets' and their correlations only. A pose block of `S⁻¹` is six solves
/// against the factorisation, so on a block of hundreds of images the poses are most of the
/// cost of [`precision`].
pub fn intrinsic_and_offset_precision(
    p: &BundleProblem,
    scale: CovarianceScale,
) -> Result<Precision, BundleError> {
    precision_of(p, scale, false)
}

fn precision_of(
    p: &BundleProblem,
    scale: CovarianceScale,
    with_poses: bool,
) -> Result<Precision, BundleError> {
    p.validate()?;
    let layout = Layout::new(p);
    if layout.num_camera_params == 0 {
        return Err(BundleError::NothingToAdjust);
    }
    let singular = || {
        BundleError::Singular(
            "the reduced camera system is not positive definite: the datum is not fixed (no \
             control points, camera-centre priors or fixed cameras) or a parameter is not \
             observable"
                .to_string(),
        )
    };
    let s = reduced_system(p, &layout)?.ok_or_else(singular)?;
    let s = s.factor().ok_or_else(singular)?;
    let mut blocks = Vec::new();
    if with_poses {
        for off in layout.pose_offset.iter().flatten() {
            blocks.push((*off, 6));
        }
    }
    for (g, off) in layout.group_offset.iter().enumerate() {
        if let Some(off) = off {
            blocks.push((*off, layout.group_free[g].len()));
        }
    }
    for off in layout.bias_offset.iter().flatten() {
        blocks.push((*off, 3));
    }
    let inverse = s.inverse_diagonal_blocks(&blocks).ok_or_else(singular)?;
    let factor = scale.factor(p);
    let mut k = 0;
    let mut poses = vec![None; p.images.len()];
    let mut centers = vec![None; p.images.len()];
    for (i, off) in layout.pose_offset.iter().enumerate() {
        if off.is_none() || !with_poses {
            continue;
        }
        let cov = Matrix6::from_fn(|r, c| inverse[k][(r, c)] * factor);
        k += 1;
        let j = center_jacobian(&p.images[i].pose);
        centers[i] = Some(j * cov * j.transpose());
        poses[i] = Some(cov);
    }
    let mut intrinsics = vec![Vec::new(); p.groups.len()];
    for (g, off) in layout.group_offset.iter().enumerate() {
        if off.is_none() {
            continue;
        }
        let block = &inverse[k];
        k += 1;
        intrinsics[g] = layout.group_free[g]
            .iter()
            .enumerate()
            .map(|(q, &param)| (param, (block[(q, q)] * factor).sqrt()))
            .collect();
    }
    let mut offsets = vec![None; p.prior_offsets.len()];
    for (o, off) in layout.bias_offset.iter().enumerate() {
        if off.is_some() {
            offsets[o] = Some(Matrix3::from_fn(|r, c| inverse[k][(r, c)] * factor));
            k += 1;
        }
    }
    let offset_intrinsic_correlations = offset_correlations(&s, &layout)?;
    Ok(Precision {
        scale: factor,
        centers,
        poses,
        intrinsics,
        offsets,
        offset_intrinsic_correlations,
    })
}

/// The correlations of every free offset's components with every free intrinsic (the scale
/// of the covariance cancels): three columns of the inverse per offset, read at the rows of
/// the intrinsics.
fn offset_correlations(
    s: &crate::reduced::Factor,
    layout: &Layout,
) -> Result<Vec<Vec<OffsetCorrelation>>, BundleError> {
    let mut out = vec![Vec::new(); layout.bias_offset.len()];
    let intrinsics: Vec<(usize, usize, usize)> = layout
        .group_offset
        .iter()
        .enumerate()
        .filter_map(|(g, off)| off.map(|off| (g, off)))
        .flat_map(|(g, off)| {
            layout.group_free[g]
                .iter()
                .enumerate()
                .map(move |(q, &param)| (g, param, off + q))
        })
        .collect();
    if intrinsics.is_empty() {
        return Ok(out);
    }
    let variances = s
        .inverse_columns(
            &intrinsics
                .iter()
                .map(|&(_, _, row)| row)
                .collect::<Vec<_>>(),
        )
        .ok_or_else(|| BundleError::Singular("intrinsic variances".into()))?;
    for (o, off) in layout.bias_offset.iter().enumerate() {
        let Some(off) = *off else { continue };
        let columns = s
            .inverse_columns(&[off, off + 1, off + 2])
            .ok_or_else(|| BundleError::Singular("offset covariances".into()))?;
        for (k, &(g, param, row)) in intrinsics.iter().enumerate() {
            let var_param = variances[(row, k)];
            let rho = [0, 1, 2].map(|c| {
                let var_offset = columns[(off + c, c)];
                let denominator = (var_param * var_offset).sqrt();
                if denominator > 0.0 {
                    (columns[(row, c)] / denominator).clamp(-1.0, 1.0)
                } else {
                    0.0
                }
            });
            out[o].push(OffsetCorrelation {
                group: g,
                param,
                rho,
            });
        }
    }
    Ok(out)
}
