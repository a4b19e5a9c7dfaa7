//! Helpers shared by the precision tests.

use nalgebra::Vector3;
use timesift_bundle::{BundleProblem, PointPrior};
use timesift_core::{CameraModel, SeededRng};

/// A control-point prior at `truth` plus survey noise of `sigma_xy` / `sigma_z`.
pub fn surveyed(
    point: usize,
    truth: &Vector3<f64>,
    sigma_xy: f64,
    sigma_z: f64,
    rng: &mut SeededRng,
) -> PointPrior {
    PointPrior {
        point,
        position: truth
            + Vector3::new(
                rng.normal() * sigma_xy,
                rng.normal() * sigma_xy,
                rng.normal() * sigma_z,
            ),
        sigma_xy,
        sigma_z,
        slope: [0.0; 2],
    }
}

/// Intrinsic parameter `k` (BROWN_PARAMS order) of the first camera group.
pub fn intrinsic(p: &BundleProblem, k: usize) -> f64 {
    let mut params = [0.0; 11];
    let n = p.groups[0].camera.num_params();
    p.groups[0].camera.params(&mut params[..n]);
    params[k]
}

/// Sample standard deviation.
pub fn spread(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}
