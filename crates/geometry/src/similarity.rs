//! Similarity (7-parameter Helmert) and rigid (6-parameter) transforms between point sets:
//! weighted Umeyama, a Helmert report in surveyors' units, and the RANSAC estimator.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::GeometryError;
use crate::error::{check_finite, check_pairs};
use crate::p3p::nearest_rotation;
use crate::ransac::Estimator;

/// `dst = scale · R · src + t`, named `dst_from_src` where used.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    /// Scale factor (1 for a rigid transform).
    pub scale: f64,
    /// Rotation.
    pub rotation: UnitQuaternion<f64>,
    /// Translation.
    pub translation: Vector3<f64>,
}

impl Similarity {
    /// Applies the transform to a point.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p * self.scale + self.translation
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Similarity {
        let r = self.rotation.inverse();
        Similarity {
            scale: 1.0 / self.scale,
            rotation: r,
            translation: -(r * self.translation) / self.scale,
        }
    }

    /// The transform in surveyors' terms.
    pub fn helmert_report(&self) -> HelmertReport {
        let (rx, ry, rz) = self.rotation.euler_angles();
        HelmertReport {
            translation: self.translation,
            rotation_deg: [rx.to_degrees(), ry.to_degrees(), rz.to_degrees()],
            scale_ppm: (self.scale - 1.0) * 1e6,
        }
    }
}

/// A Helmert transform as reported to users.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HelmertReport {
    /// Translation (m).
    pub translation: Vector3<f64>,
    /// Rotations about X, Y, Z in degrees, with `R = Rz · Ry · Rx`.
    pub rotation_deg: [f64; 3],
    /// Scale difference in parts per million.
    pub scale_ppm: f64,
}

/// Whether the transform includes a scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransformKind {
    /// 7 parameters: rotation, translation, scale.
    Similarity,
    /// 6 parameters: rotation and translation.
    Rigid,
}

/// Weighted least-squares transform `dst ≈ s R src + t` (Umeyama 1991). Needs three or more
/// points not all on one line.
pub fn umeyama(
    src: &[Vector3<f64>],
    dst: &[Vector3<f64>],
    weights: Option<&[f64]>,
    kind: TransformKind,
) -> Result<Similarity, GeometryError> {
    let solver = "Umeyama";
    check_pairs(solver, src.len(), dst.len(), 3)?;
    check_finite(solver, src.iter().chain(dst).flat_map(|v| v.iter()))?;
    if let Some(w) = weights {
        check_pairs(solver, src.len(), w.len(), 3)?;
        if w.iter().any(|v| !(*v >= 0.0) || !v.is_finite()) {
            return Err(GeometryError::Degenerate {
                solver,
                reason: "weights must be finite and non-negative",
            });
        }
    }
    let weight = |i: usize| weights.map_or(1.0, |w| w[i]);
    let total: f64 = (0..src.len()).map(weight).sum();
    if !(total > 0.0) {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "all weights are zero",
        });
    }
    let mu_s = (0..src.len()).fold(Vector3::zeros(), |a, i| a + src[i] * weight(i)) / total;
    let mu_d = (0..src.len()).fold(Vector3::zeros(), |a, i| a + dst[i] * weight(i)) / total;
    let mut cov = Matrix3::zeros();
    let mut var_s = 0.0;
    for i in 0..src.len() {
        let (a, b) = (src[i] - mu_s, dst[i] - mu_d);
        cov += b * a.transpose() * weight(i);
        var_s += a.norm_squared() * weight(i);
    }
    cov /= total;
    var_s /= total;
    let svd = cov.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "SVD failed",
        });
    };
    let sv = svd.singular_values;
    let mut sorted = [sv[0], sv[1], sv[2]];
    sorted.sort_by(|a, b| b.total_cmp(a));
    if !(sorted[1] > 1e-12 * sorted[0]) || !(var_s > 0.0) {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "points are collinear or coincide",
        });
    }
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = nearest_rotation(&(u * d * vt));
    let scale = match kind {
        TransformKind::Similarity => (Matrix3::from_diagonal(&sv) * d).trace() / var_s,
        TransformKind::Rigid => 1.0,
    };
    let rotation = UnitQuaternion::from_rotation_matrix(&r);
    Ok(Similarity {
        scale,
        rotation,
        translation: mu_d - rotation * mu_s * scale,
    })
}

/// RANSAC estimator of a similarity or rigid transform; residual |s R src + t − dst|² (m²).
pub struct SimilarityEstimator<'a> {
    /// Source points.
    pub src: &'a [Vector3<f64>],
    /// Destination points.
    pub dst: &'a [Vector3<f64>],
    /// With or without scale.
    pub kind: TransformKind,
}

impl Estimator for SimilarityEstimator<'_> {
    type Model = Similarity;
    const NAME: &'static str = "similarity RANSAC";
    fn min_samples(&self) -> usize {
        3
    }
    fn num_data(&self) -> usize {
        self.src.len().min(self.dst.len())
    }
    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Similarity>) {
        let a: Vec<_> = sample.iter().map(|&i| self.src[i]).collect();
        let b: Vec<_> = sample.iter().map(|&i| self.dst[i]).collect();
        if let Ok(s) = umeyama(&a, &b, None, self.kind) {
            models.push(s);
        }
    }
    fn fit_nonminimal(
        &self,
        idx: &[usize],
        w: Option<&[f64]>,
        _: &Similarity,
    ) -> Option<Similarity> {
        let a: Vec<_> = idx.iter().map(|&i| self.src[i]).collect();
        let b: Vec<_> = idx.iter().map(|&i| self.dst[i]).collect();
        umeyama(&a, &b, w, self.kind).ok()
    }
    fn residual_sq(&self, s: &Similarity, i: usize) -> f64 {
        (s.apply(&self.src[i]) - self.dst[i]).norm_squared()
    }
}
