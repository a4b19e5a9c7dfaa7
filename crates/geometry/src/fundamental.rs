//! The fundamental matrix: normalised eight-point (least squares, rank 2 enforced) and
//! seven-point (one or three solutions) solvers, and the RANSAC estimator. Pixels in, `x2ᵀ F x1 = 0`.

use nalgebra::{DMatrix, Matrix3, SMatrix, Vector2};

use crate::GeometryError;
use crate::error::{check_finite, check_pairs};
use crate::essential::sampson_distance_sq;
use crate::normalize::{normalize_points, normalized_pair, null_matrix};
use crate::poly::cubic_roots;
use crate::ransac::Estimator;

fn epipolar_row(a: &Vector2<f64>, b: &Vector2<f64>) -> [f64; 9] {
    [
        b.x * a.x,
        b.x * a.y,
        b.x,
        b.y * a.x,
        b.y * a.y,
        b.y,
        a.x,
        a.y,
        1.0,
    ]
}

fn to_matrix(v: &[f64]) -> Matrix3<f64> {
    Matrix3::new(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8])
}

/// Sets the smallest singular value to zero.
pub fn enforce_rank2(f: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = f.svd(true, true);
    match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => {
            let mut s = svd.singular_values;
            s[2] = 0.0;
            u * Matrix3::from_diagonal(&s) * vt
        }
        _ => *f,
    }
}

fn normalized_unit(f: Matrix3<f64>) -> Matrix3<f64> {
    let n = f.norm();
    let f = f / n;
    // Fix the sign so equal matrices compare equal.
    let (i, _) =
        f.iter().enumerate().fold(
            (0, 0.0),
            |acc, (i, v)| if v.abs() > acc.1 { (i, v.abs()) } else { acc },
        );
    if f[i] < 0.0 { -f } else { f }
}

/// Normalised eight-point algorithm (Hartley) for eight or more correspondences, optionally
/// weighted. Fails on configurations that do not determine F (e.g. all points on one plane).
pub fn eight_point(
    p1: &[Vector2<f64>],
    p2: &[Vector2<f64>],
    weights: Option<&[f64]>,
) -> Result<Matrix3<f64>, GeometryError> {
    let solver = "eight-point fundamental";
    let ((t1, n1), (t2, n2)) = normalized_pair(solver, p1, p2, weights, 8)?;
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for k in 0..n1.len() {
        let r = SMatrix::<f64, 9, 1>::from_row_slice(&epipolar_row(&n1[k], &n2[k]));
        let w = weights.map_or(1.0, |w| w[k]);
        ata += r * r.transpose() * w;
    }
    // A determined F needs a one-dimensional null space (planar scenes leave a three-dimensional
    // one).
    let f = enforce_rank2(&null_matrix(
        &ata,
        1e-16,
        solver,
        "correspondences do not determine F (points on a plane or too few distinct)",
    )?);
    Ok(normalized_unit(t2.transpose() * f * t1))
}

/// Seven-point algorithm: the one or three fundamental matrices through seven correspondences.
pub fn seven_point(
    p1: &[Vector2<f64>],
    p2: &[Vector2<f64>],
) -> Result<Vec<Matrix3<f64>>, GeometryError> {
    let solver = "seven-point fundamental";
    check_pairs(solver, p1.len(), p2.len(), 7)?;
    check_finite(solver, p1.iter().chain(p2).flat_map(|v| v.iter()))?;
    let (Some((t1, n1)), Some((t2, n2))) = (normalize_points(&p1[..7]), normalize_points(&p2[..7]))
    else {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "all points coincide",
        });
    };
    let mut a = DMatrix::<f64>::zeros(9, 9);
    for k in 0..7 {
        for (c, v) in epipolar_row(&n1[k], &n2[k]).iter().enumerate() {
            a[(k, c)] = *v;
        }
    }
    let Some(svd) = a.try_svd(false, true, f64::EPSILON, 1000) else {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "SVD did not converge",
        });
    };
    let Some(vt) = svd.v_t else {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "SVD failed",
        });
    };
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&x, &y| svd.singular_values[x].total_cmp(&svd.singular_values[y]));
    if !(svd.singular_values[order[2]] > 1e-10 * svd.singular_values[order[8]]) {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "seven correspondences do not give a two-dimensional solution space",
        });
    }
    let f1 = to_matrix(&vt.row(order[0]).iter().copied().collect::<Vec<_>>());
    let f2 = to_matrix(&vt.row(order[1]).iter().copied().collect::<Vec<_>>());
    // det(f2 + α (f1 − f2)) = c0 + c1 α + c2 α² + c3 α³.
    let d = f1 - f2;
    let c0 = f2.determinant();
    let c3 = d.determinant();
    let c1 = adj_trace(&f2, &d);
    let c2 = adj_trace(&d, &f2);
    let mut out = Vec::new();
    for alpha in cubic_roots(c3, c2, c1, c0) {
        let f = f2 + d * alpha;
        let f = t2.transpose() * f * t1;
        if f.iter().all(|v| v.is_finite()) && f.norm() > 0.0 {
            out.push(normalized_unit(f));
        }
    }
    Ok(out)
}

/// tr(adj(A) B), computed from cofactors so it also holds for singular A. With it,
/// det(A + tB) = det A + t tr(adj(A) B) + t² tr(adj(B) A) + t³ det B.
pub(crate) fn adj_trace(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let cof = |r: usize, c: usize| {
        let rows: Vec<usize> = (0..3).filter(|&i| i != r).collect();
        let cols: Vec<usize> = (0..3).filter(|&j| j != c).collect();
        let m = a[(rows[0], cols[0])] * a[(rows[1], cols[1])]
            - a[(rows[0], cols[1])] * a[(rows[1], cols[0])];
        if (r + c) % 2 == 0 { m } else { -m }
    };
    // adj(A)[c][r] = cof(r, c); tr(adj(A) B) = Σ_{r,c} cof(r, c) B[r][c].
    let mut s = 0.0;
    for r in 0..3 {
        for c in 0..3 {
            s += cof(r, c) * b[(r, c)];
        }
    }
    s
}

/// RANSAC estimator of F from pixel correspondences; residuals are Sampson distances in pixels².
pub struct FundamentalEstimator<'a> {
    /// Pixels in the first image.
    pub p1: &'a [Vector2<f64>],
    /// Pixels in the second image.
    pub p2: &'a [Vector2<f64>],
}

impl Estimator for FundamentalEstimator<'_> {
    type Model = Matrix3<f64>;
    const NAME: &'static str = "fundamental RANSAC";
    fn min_samples(&self) -> usize {
        7
    }
    fn num_data(&self) -> usize {
        self.p1.len().min(self.p2.len())
    }
    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Matrix3<f64>>) {
        let a: Vec<_> = sample.iter().map(|&i| self.p1[i]).collect();
        let b: Vec<_> = sample.iter().map(|&i| self.p2[i]).collect();
        if let Ok(f) = seven_point(&a, &b) {
            models.extend(f);
        }
    }
    fn fit_nonminimal(
        &self,
        idx: &[usize],
        w: Option<&[f64]>,
        _: &Matrix3<f64>,
    ) -> Option<Matrix3<f64>> {
        let a: Vec<_> = idx.iter().map(|&i| self.p1[i]).collect();
        let b: Vec<_> = idx.iter().map(|&i| self.p2[i]).collect();
        eight_point(&a, &b, w).ok()
    }
    fn residual_sq(&self, f: &Matrix3<f64>, i: usize) -> f64 {
        sampson_distance_sq(f, &self.p1[i].push(1.0), &self.p2[i].push(1.0))
    }
}
