//! Hartley normalisation of 2-D points: centroid to the origin, mean distance √2.

use nalgebra::{Matrix3, SMatrix, Vector2};

use crate::GeometryError;
use crate::error::{check_finite, check_pairs};

/// The similarity `T` with `T [x; 1]` normalised, and the normalised points.
pub(crate) fn normalize_points(
    points: &[Vector2<f64>],
) -> Option<(Matrix3<f64>, Vec<Vector2<f64>>)> {
    let n = points.len() as f64;
    let centroid = points.iter().fold(Vector2::zeros(), |a, p| a + p) / n;
    let mean_dist = points.iter().map(|p| (p - centroid).norm()).sum::<f64>() / n;
    if !(mean_dist > 0.0) || !mean_dist.is_finite() {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / mean_dist;
    let t = Matrix3::new(
        s,
        0.0,
        -s * centroid.x,
        0.0,
        s,
        -s * centroid.y,
        0.0,
        0.0,
        1.0,
    );
    let normalized = points.iter().map(|p| (p - centroid) * s).collect();
    Some((t, normalized))
}

/// Checks the inputs of a (weighted) linear solver on point pairs and normalises both sets.
pub(crate) type NormalizedPair = (
    (Matrix3<f64>, Vec<Vector2<f64>>),
    (Matrix3<f64>, Vec<Vector2<f64>>),
);

pub(crate) fn normalized_pair(
    solver: &'static str,
    p1: &[Vector2<f64>],
    p2: &[Vector2<f64>],
    weights: Option<&[f64]>,
    needed: usize,
) -> Result<NormalizedPair, GeometryError> {
    check_pairs(solver, p1.len(), p2.len(), needed)?;
    check_finite(solver, p1.iter().chain(p2).flat_map(|v| v.iter()))?;
    if let Some(w) = weights {
        check_pairs(solver, p1.len(), w.len(), needed)?;
    }
    match (normalize_points(p1), normalize_points(p2)) {
        (Some(a), Some(b)) => Ok((a, b)),
        _ => Err(GeometryError::Degenerate {
            solver,
            reason: "all points coincide",
        }),
    }
}

/// The 3×3 matrix of the eigenvector of the smallest eigenvalue of a 9×9 normal matrix `AᵀA`,
/// or `Degenerate` when the null space is not one-dimensional (second smallest eigenvalue below
/// `tolerance` times the largest).
pub(crate) fn null_matrix(
    ata: &SMatrix<f64, 9, 9>,
    tolerance: f64,
    solver: &'static str,
    reason: &'static str,
) -> Result<Matrix3<f64>, GeometryError> {
    let eig = ata.symmetric_eigen();
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    if !(eig.eigenvalues[order[1]] > tolerance * eig.eigenvalues[order[8]]) {
        return Err(GeometryError::Degenerate { solver, reason });
    }
    let v = eig.eigenvectors.column(order[0]);
    Ok(Matrix3::new(
        v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8],
    ))
}
