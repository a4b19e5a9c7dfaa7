//! Point-cloud neighbourhoods and local plane fits by PCA.
//!
//! The k-d tree holds f32 coordinates relative to the cloud's centre (half the memory traffic of
//! f64 and wider SIMD in the leaves), and every candidate it returns is checked again on the f64
//! positions: radius queries widen the f32 radius by the rounding bound, so results are exact in
//! f64 whatever the coordinates' magnitude.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, Vector3};

use crate::ChangeError;

/// Squared Euclidean distance.
#[inline]
pub fn distance_squared(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// A k-d tree over a cloud's positions; items are indices into the cloud.
pub struct PointIndex<'a> {
    points: &'a [[f64; 3]],
    tree: ImmutableKdTree<f32, 3>,
    origin: [f64; 3],
    /// Bound on |f32 position − true position − origin| per point, m.
    rounding: f64,
}

impl<'a> PointIndex<'a> {
    /// Builds the tree (in parallel). Points must be finite.
    pub fn new(points: &'a [[f64; 3]]) -> Result<PointIndex<'a>, ChangeError> {
        if points.is_empty() {
            return Err(ChangeError::NotEnoughData(
                "the point cloud is empty".into(),
            ));
        }
        if let Some(i) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(ChangeError::InvalidInput(format!(
                "point {i} has a non-finite coordinate"
            )));
        }
        if points.len() > u32::MAX as usize {
            return Err(ChangeError::InvalidInput(format!(
                "{} points; at most {} per cloud are supported",
                points.len(),
                u32::MAX
            )));
        }
        let (lo, hi) = points.iter().fold(
            ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
            |(lo, hi), p| {
                (
                    [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                    [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
                )
            },
        );
        let origin = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
        let half_extent = (0..3).map(|k| 0.5 * (hi[k] - lo[k])).fold(0.0, f64::max);
        // Rounding to f32 (half an ulp, relative 2⁻²⁴) on each axis, three axes.
        let rounding = 3f64.sqrt() * half_extent * f64::from(f32::EPSILON);
        let local: Vec<[f32; 3]> = points
            .iter()
            .map(|p| [0, 1, 2].map(|k| (p[k] - origin[k]) as f32))
            .collect();
        let tree = ImmutableKdTree::new_from_slice_parallel(&local).map_err(|e| {
            ChangeError::InvalidInput(format!("k-d tree construction failed: {e:?}"))
        })?;
        Ok(PointIndex {
            points,
            tree,
            origin,
            rounding,
        })
    }

    /// The indexed points.
    pub fn points(&self) -> &'a [[f64; 3]] {
        self.points
    }

    fn local(&self, p: &[f64; 3]) -> [f32; 3] {
        [0, 1, 2].map(|k| (p[k] - self.origin[k]) as f32)
    }

    /// Indices of the points within `radius` (inclusive) of `centre`, appended to `out` (cleared
    /// first), in no particular order.
    pub fn within(&self, centre: &[f64; 3], radius: f64, out: &mut Vec<u32>) {
        out.clear();
        self.visit_within(centre, radius, |i, _| out.push(i));
    }

    /// Calls `visit(index, position)` for every point within `radius` (inclusive, exact in f64) of
    /// `centre`, streaming from the tree's leaves: no result vector is built.
    pub fn visit_within(
        &self,
        centre: &[f64; 3],
        radius: f64,
        mut visit: impl FnMut(u32, &[f64; 3]),
    ) {
        let r2 = radius * radius;
        // Query and points each rounded by at most `rounding`.
        let wide = radius + 2.0 * self.rounding + 1e-6 * radius;
        let query = self.local(centre);
        self.tree
            .query(&query)
            .within::<SquaredEuclidean<f32>>((wide * wide) as f32)
            .unsorted()
            .visit(|n| {
                let p = &self.points[n.item as usize];
                let d2 = distance_squared(p, centre);
                if d2 <= r2 {
                    visit(n.item, p);
                }
            });
    }

    /// The nearest point's index and squared distance.
    /// (Nearest in f32; ties within the rounding bound may resolve either way.)
    pub fn nearest(&self, centre: &[f64; 3]) -> (u32, f64) {
        let query = self.local(centre);
        let n = self
            .tree
            .query(&query)
            .nearest_one::<SquaredEuclidean<f32>>()
            .execute();
        let p = &self.points[n.item as usize];
        let d2 = distance_squared(p, centre);
        (n.item, d2)
    }

    /// Indices of the `k` nearest points.
    pub fn nearest_k(&self, centre: &[f64; 3], k: usize, out: &mut Vec<u32>) {
        out.clear();
        let Some(k) = std::num::NonZeroUsize::new(k) else {
            return;
        };
        let query = self.local(centre);
        let found = self
            .tree
            .query(&query)
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .execute();
        out.extend(found.iter().map(|n| n.item));
    }
}

/// A local plane fitted by PCA.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneFit {
    /// Unit normal (eigenvector of the smallest eigenvalue), oriented towards `orientation`.
    pub normal: Vector3<f64>,
    /// Centroid of the points.
    pub centroid: Vector3<f64>,
    /// Eigenvalues of the covariance (divisor n − 1), ascending.
    pub eigenvalues: [f64; 3],
    /// Points used.
    pub count: usize,
}

impl PlaneFit {
    /// Planarity (λ1 − λ0) / λ2, the multi-scale criterion of py4dgeo/CloudCompare.
    pub fn planarity(&self) -> f64 {
        let [l0, l1, l2] = self.eigenvalues;
        (l1 - l0) / l2
    }
}

/// PCA plane of `positions`, or `None` with fewer than three points or a degenerate (collinear)
/// neighbourhood. Coordinates are centred on `reference` first, so UTM-sized coordinates keep their
/// precision.
pub fn fit_plane(
    positions: &[[f64; 3]],
    reference: &[f64; 3],
    orientation: &Vector3<f64>,
) -> Option<PlaneFit> {
    let n = positions.len();
    if n < 3 {
        return None;
    }
    let local = |p: &[f64; 3]| {
        Vector3::new(
            p[0] - reference[0],
            p[1] - reference[1],
            p[2] - reference[2],
        )
    };
    let mean = positions.iter().fold(Vector3::zeros(), |s, p| s + local(p)) / n as f64;
    let mut cov = Matrix3::zeros();
    for p in positions {
        let d = local(p) - mean;
        cov += d * d.transpose();
    }
    cov /= (n - 1) as f64;
    let (eigenvalues, mut normal) = smallest_eigenpair(&cov)?;
    let norm = normal.norm();
    if !(norm > 0.0)
        || !(eigenvalues[2] > 0.0)
        || !((eigenvalues[1] - eigenvalues[0]) / eigenvalues[2] > 0.0)
    {
        return None;
    }
    normal /= norm;
    if normal.dot(orientation) < 0.0 {
        normal = -normal;
    }
    Some(PlaneFit {
        normal,
        centroid: mean + Vector3::new(reference[0], reference[1], reference[2]),
        eigenvalues,
        count: n,
    })
}

/// Eigenvalues (ascending) of a symmetric 3 × 3 matrix in closed form (trigonometric solution of
/// the characteristic cubic), and an eigenvector of the smallest one from the largest cross product
/// of two rows of A − λ₀I. No iteration: a fixed, small cost per neighbourhood.
pub fn smallest_eigenpair(a: &Matrix3<f64>) -> Option<([f64; 3], Vector3<f64>)> {
    if !a.iter().all(|v| v.is_finite()) {
        return None;
    }
    let off = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
    let q = a.trace() / 3.0;
    let p2 =
        (a[(0, 0)] - q).powi(2) + (a[(1, 1)] - q).powi(2) + (a[(2, 2)] - q).powi(2) + 2.0 * off;
    let p = (p2 / 6.0).sqrt();
    let eigenvalues = if p == 0.0 {
        [q; 3]
    } else {
        let b = (a - Matrix3::identity() * q) / p;
        let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
        let phi = r.acos() / 3.0;
        let largest = q + 2.0 * p * phi.cos();
        let smallest = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
        [smallest, 3.0 * q - largest - smallest, largest]
    };
    let m = a - Matrix3::identity() * eigenvalues[0];
    let rows = [
        m.row(0).transpose(),
        m.row(1).transpose(),
        m.row(2).transpose(),
    ];
    let candidates = [
        rows[0].cross(&rows[1]),
        rows[0].cross(&rows[2]),
        rows[1].cross(&rows[2]),
    ];
    let best = candidates
        .into_iter()
        .max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared()))?;
    let n = best.norm();
    if !(n > 0.0) {
        return None;
    }
    Some((eigenvalues, best / n))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_form_eigenpair_matches_nalgebra() {
        let mut rng = timesift_core::SeededRng::new(17);
        let mut rng = move || rng.uniform_range(-1.0, 1.0);
        for _ in 0..500 {
            let m = Matrix3::from_fn(|_, _| rng());
            let a =
                m * m.transpose() + Matrix3::from_diagonal(&Vector3::new(rng().abs(), 0.0, 0.0));
            let (values, vector) = smallest_eigenpair(&a).expect("eigen");
            let reference = nalgebra::SymmetricEigen::new(a);
            let mut sorted: Vec<f64> = reference.eigenvalues.iter().copied().collect();
            sorted.sort_by(f64::total_cmp);
            for k in 0..3 {
                assert!(
                    (values[k] - sorted[k]).abs() < 1e-9 * sorted[2].max(1.0),
                    "{values:?} {sorted:?}"
                );
            }
            // A v = λ v, relative to the matrix scale, where the smallest eigenvalue is separated.
            if sorted[1] - sorted[0] > 1e-3 * sorted[2] {
                let residual = (a * vector - vector * values[0]).norm();
                assert!(residual < 1e-8 * sorted[2], "{residual}");
            }
        }
    }
}
