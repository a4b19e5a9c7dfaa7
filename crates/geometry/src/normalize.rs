//! Hartley normalisation of 2-D points: centroid to the origin, mean distance √2.

use nalgebra::{Matrix3, Vector2};

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
