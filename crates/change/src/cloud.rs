//! Point-cloud neighbourhoods (k-d tree over f64 positions) and local plane fits by PCA.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::ChangeError;

/// A k-d tree over a cloud's positions; items are indices into the cloud.
pub struct PointIndex<'a> {
    points: &'a [[f64; 3]],
    tree: ImmutableKdTree<f64, 3>,
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
        let tree = ImmutableKdTree::new_from_slice_parallel(points).map_err(|e| {
            ChangeError::InvalidInput(format!("k-d tree construction failed: {e:?}"))
        })?;
        Ok(PointIndex { points, tree })
    }

    /// The indexed points.
    pub fn points(&self) -> &'a [[f64; 3]] {
        self.points
    }

    /// Indices of the points within `radius` (inclusive) of `centre`, appended to `out` (cleared
    /// first), in no particular order.
    pub fn within(&self, centre: &[f64; 3], radius: f64, out: &mut Vec<u32>) {
        out.clear();
        let r2 = radius * radius;
        let found = self
            .tree
            .query(centre)
            .within::<SquaredEuclidean<f64>>(r2 * (1.0 + 1e-12))
            .unsorted()
            .execute();
        out.extend(found.iter().filter(|n| n.distance <= r2).map(|n| n.item));
    }

    /// The nearest point's index and squared distance.
    pub fn nearest(&self, centre: &[f64; 3]) -> (u32, f64) {
        let n = self
            .tree
            .query(centre)
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        (n.item, n.distance)
    }

    /// Indices of the `k` nearest points.
    pub fn nearest_k(&self, centre: &[f64; 3], k: usize, out: &mut Vec<u32>) {
        out.clear();
        let Some(k) = std::num::NonZeroUsize::new(k) else {
            return;
        };
        let found = self
            .tree
            .query(centre)
            .nearest_n::<SquaredEuclidean<f64>>(k)
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

/// PCA plane of `points[indices]`, or `None` with fewer than three points or a degenerate
/// (collinear) neighbourhood. Coordinates are centred on `reference` first, so UTM-sized
/// coordinates keep their precision.
pub fn fit_plane(
    points: &[[f64; 3]],
    indices: &[u32],
    reference: &[f64; 3],
    orientation: &Vector3<f64>,
) -> Option<PlaneFit> {
    let n = indices.len();
    if n < 3 {
        return None;
    }
    let mut mean = Vector3::zeros();
    for &i in indices {
        let p = points[i as usize];
        mean += Vector3::new(
            p[0] - reference[0],
            p[1] - reference[1],
            p[2] - reference[2],
        );
    }
    mean /= n as f64;
    let mut cov = Matrix3::zeros();
    for &i in indices {
        let p = points[i as usize];
        let d = Vector3::new(
            p[0] - reference[0],
            p[1] - reference[1],
            p[2] - reference[2],
        ) - mean;
        cov += d * d.transpose();
    }
    cov /= (n - 1) as f64;
    let eigen = SymmetricEigen::try_new(cov, 1e-15, 200)?;
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let eigenvalues = order.map(|k| eigen.eigenvalues[k]);
    let mut normal: Vector3<f64> = eigen.eigenvectors.column(order[0]).into_owned();
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
