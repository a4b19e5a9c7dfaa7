//! Homographies: normalised DLT from four or more correspondences, the symmetric transfer error,
//! the RANSAC estimator, and the degeneracy check that flags a pair explained by a homography
//! (planar scene or pure rotation), where the epipolar geometry is unreliable.

use nalgebra::{Matrix3, SMatrix, Vector2};

use crate::GeometryError;
use crate::normalize::{normalized_pair, null_matrix};
use crate::ransac::Estimator;

/// Maps a pixel through a homography; `None` at infinity.
pub fn transfer(h: &Matrix3<f64>, p: &Vector2<f64>) -> Option<Vector2<f64>> {
    let q = h * p.push(1.0);
    (q.z.abs() > 1e-300).then(|| Vector2::new(q.x / q.z, q.y / q.z))
}

fn cross2(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Whether three points are (nearly) collinear relative to their spread.
fn collinear(a: &Vector2<f64>, b: &Vector2<f64>, c: &Vector2<f64>) -> bool {
    let (u, v) = (b - a, c - a);
    cross2(&u, &v).abs() <= 1e-9 * (u.norm_squared() + v.norm_squared())
}

/// Normalised DLT homography `p2 ~ H p1` from four or more correspondences, optionally weighted.
/// Fails when three of four points are collinear or the system is rank-deficient.
pub fn homography_dlt(
    p1: &[Vector2<f64>],
    p2: &[Vector2<f64>],
    weights: Option<&[f64]>,
) -> Result<Matrix3<f64>, GeometryError> {
    let solver = "homography DLT";
    let ((t1, n1), (t2, n2)) = normalized_pair(solver, p1, p2, weights, 4)?;
    if p1.len() == 4 {
        for pts in [p1, p2] {
            for skip in 0..4 {
                let t: Vec<_> = (0..4).filter(|&i| i != skip).map(|i| pts[i]).collect();
                if collinear(&t[0], &t[1], &t[2]) {
                    return Err(GeometryError::Degenerate {
                        solver,
                        reason: "three of the four points are collinear",
                    });
                }
            }
        }
    }
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for k in 0..n1.len() {
        let (a, b) = (n1[k], n2[k]);
        let w = weights.map_or(1.0, |w| w[k]);
        let r1 = SMatrix::<f64, 9, 1>::from_row_slice(&[
            -a.x,
            -a.y,
            -1.0,
            0.0,
            0.0,
            0.0,
            b.x * a.x,
            b.x * a.y,
            b.x,
        ]);
        let r2 = SMatrix::<f64, 9, 1>::from_row_slice(&[
            0.0,
            0.0,
            0.0,
            -a.x,
            -a.y,
            -1.0,
            b.y * a.x,
            b.y * a.y,
            b.y,
        ]);
        ata += (r1 * r1.transpose() + r2 * r2.transpose()) * w;
    }
    let hn = null_matrix(
        &ata,
        1e-16,
        solver,
        "correspondences do not determine a homography",
    )?;
    let inv_t2 = t2.try_inverse().ok_or(GeometryError::Degenerate {
        solver,
        reason: "normalisation not invertible",
    })?;
    let h = inv_t2 * hn * t1;
    let scale = if h[(2, 2)].abs() > 1e-12 * h.norm() {
        h[(2, 2)]
    } else {
        h.norm()
    };
    let h = h / scale;
    if h.iter().all(|x| x.is_finite()) {
        Ok(h)
    } else {
        Err(GeometryError::Degenerate {
            solver,
            reason: "non-finite homography",
        })
    }
}

/// Symmetric transfer error squared: |H p1 − p2|² + |H⁻¹ p2 − p1|².
pub fn symmetric_transfer_error_sq(
    h: &Matrix3<f64>,
    h_inv: &Matrix3<f64>,
    p1: &Vector2<f64>,
    p2: &Vector2<f64>,
) -> f64 {
    match (transfer(h, p1), transfer(h_inv, p2)) {
        (Some(a), Some(b)) => (a - p2).norm_squared() + (b - p1).norm_squared(),
        _ => f64::INFINITY,
    }
}

/// A homography with its inverse, so residuals need no inversion per point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HomographyModel {
    /// `p2 ~ H p1`.
    pub h: Matrix3<f64>,
    /// `H⁻¹`.
    pub h_inv: Matrix3<f64>,
}

impl HomographyModel {
    fn new(h: Matrix3<f64>) -> Option<Self> {
        h.try_inverse().map(|h_inv| HomographyModel { h, h_inv })
    }
}

/// RANSAC estimator of a homography; residual: one-way transfer error in pixels², which makes
/// the threshold comparable with the epipolar estimators'.
pub struct HomographyEstimator<'a> {
    /// Pixels in the first image.
    pub p1: &'a [Vector2<f64>],
    /// Pixels in the second image.
    pub p2: &'a [Vector2<f64>],
}

impl Estimator for HomographyEstimator<'_> {
    type Model = HomographyModel;
    const NAME: &'static str = "homography RANSAC";
    fn min_samples(&self) -> usize {
        4
    }
    fn num_data(&self) -> usize {
        self.p1.len().min(self.p2.len())
    }
    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<HomographyModel>) {
        let a: Vec<_> = sample.iter().map(|&i| self.p1[i]).collect();
        let b: Vec<_> = sample.iter().map(|&i| self.p2[i]).collect();
        if let Some(m) = homography_dlt(&a, &b, None)
            .ok()
            .and_then(HomographyModel::new)
        {
            models.push(m);
        }
    }
    fn fit_nonminimal(
        &self,
        idx: &[usize],
        w: Option<&[f64]>,
        _: &HomographyModel,
    ) -> Option<HomographyModel> {
        let a: Vec<_> = idx.iter().map(|&i| self.p1[i]).collect();
        let b: Vec<_> = idx.iter().map(|&i| self.p2[i]).collect();
        homography_dlt(&a, &b, w)
            .ok()
            .and_then(HomographyModel::new)
    }
    fn residual_sq(&self, m: &HomographyModel, i: usize) -> f64 {
        transfer(&m.h, &self.p1[i]).map_or(f64::INFINITY, |q| (q - self.p2[i]).norm_squared())
    }
}

/// Two-view geometry type, by which model explains the verified matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TwoViewType {
    /// Epipolar geometry with enough parallax: usable for initialisation and triangulation.
    General,
    /// A homography explains (nearly) as many matches as the epipolar model: planar scene or
    /// rotation without baseline; relative pose and triangulation are unreliable.
    HomographyExplained,
}

/// Classifies a pair from the inlier counts of the epipolar and homography models, flagging it
/// when the homography keeps at least `ratio` (e.g. 0.8) of the epipolar inliers.
pub fn classify_two_view(
    epipolar_inliers: usize,
    homography_inliers: usize,
    ratio: f64,
) -> TwoViewType {
    if epipolar_inliers == 0 || homography_inliers as f64 >= ratio * epipolar_inliers as f64 {
        TwoViewType::HomographyExplained
    } else {
        TwoViewType::General
    }
}
