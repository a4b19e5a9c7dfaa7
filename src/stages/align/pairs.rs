//! Per pair of epochs, where the block ties them: the tie points both observe and the points
//! of either held to the reference epoch's surface, spread across the block against every tie
//! point's and the stable areas' (`report.json`'s `epoch_pairs`).

use super::*;
use timesift_io::ply::EpochSet;

use super::motions::EpochMotions;

/// The block's points in the world frame, as the report reads them.
pub(super) struct WorldPoints<'a> {
    /// Every tie point, with its epochs.
    pub(super) tiepoints: &'a [timesift_io::ply::TiePoint],
    /// The later epochs' points held to the reference epoch's surface.
    pub(super) held: &'a [HeldPoint],
}

/// A later epoch's tie point held to the reference epoch's surface (surface ties): its epoch
/// and where it lies (world frame).
pub(super) struct HeldPoint {
    epoch: usize,
    xy: Vector2<f64>,
}

/// The points the final adjustment held to the reference epoch's surface, each with its epoch.
pub(super) fn held_points(
    held: &[timesift_align::SurfaceHeight],
    origin: Vector3<f64>,
) -> Vec<HeldPoint> {
    held.iter()
        .map(|h| HeldPoint {
            epoch: h.epoch,
            xy: Vector2::new(h.at[0] + origin.x, h.at[1] + origin.y),
        })
        .collect()
}

/// Per pair of epochs, the tie points both observe, and their spread across and along the
/// principal horizontal axes of every tie point, alone and with the points of either epoch held
/// to the reference epoch's surface; every tie point's on the stable areas where given; the
/// tilt σ of their DoD from the block's covariance of the epochs' rigid motions.
pub(super) fn epoch_pair_ties(
    project: &Project,
    tiepoints: &[timesift_io::ply::TiePoint],
    held: &[HeldPoint],
    motions: Option<&EpochMotions<'_>>,
) -> Vec<crate::report::EpochPairTies> {
    let n = tiepoints.len().max(1) as f64;
    let mean = tiepoints
        .iter()
        .fold(Vector2::zeros(), |m, p| m + p.position.xy() / n);
    let covariance = tiepoints.iter().fold(nalgebra::Matrix2::zeros(), |c, p| {
        let d = p.position.xy() - mean;
        c + d * d.transpose() / n
    });
    let eigen = covariance.symmetric_eigen();
    let smaller = usize::from(eigen.eigenvalues[1] < eigen.eigenvalues[0]);
    let minor: Vector2<f64> = eigen.eigenvectors.column(smaller).into_owned();
    let major: Vector2<f64> = eigen.eigenvectors.column(1 - smaller).into_owned();
    let spread = |points: &[Vector2<f64>], axis: &Vector2<f64>| -> Option<f64> {
        (points.len() >= 2).then(|| {
            let k = points.len() as f64;
            let m = points.iter().map(|p| p.dot(axis)).sum::<f64>() / k;
            (points
                .iter()
                .map(|p| (p.dot(axis) - m).powi(2))
                .sum::<f64>()
                / k)
                .sqrt()
        })
    };
    let all: Vec<Vector2<f64>> = tiepoints.iter().map(|p| p.position.xy() - mean).collect();
    let (all_across, all_along) = (
        spread(&all, &minor).unwrap_or(0.0),
        spread(&all, &major).unwrap_or(0.0),
    );
    let on_stable: Vec<Vector2<f64>> = match project.stable_areas.is_empty() {
        true => Vec::new(),
        false => tiepoints
            .iter()
            .filter(|p| super::input::on_stable_area(project, p.position.x, p.position.y))
            .map(|p| p.position.xy() - mean)
            .collect(),
    };
    let stable_across = spread(&on_stable, &minor);
    let mut pairs = Vec::new();
    for a in 0..project.epochs.len() {
        for b in a + 1..project.epochs.len() {
            let both: EpochSet = [a, b].into_iter().collect();
            let shared: Vec<Vector2<f64>> = tiepoints
                .iter()
                .filter(|p| p.epochs.contains_all(&both))
                .map(|p| p.position.xy() - mean)
                .collect();
            let with_held: Vec<Vector2<f64>> = held
                .iter()
                .filter(|h| h.epoch == a || h.epoch == b)
                .map(|h| h.xy - mean)
                .chain(shared.iter().copied())
                .collect();
            pairs.push(crate::report::EpochPairTies {
                epochs: [
                    project.epochs[a].name.clone(),
                    project.epochs[b].name.clone(),
                ],
                ties: shared.len(),
                across_std_m: spread(&shared, &minor),
                along_std_m: spread(&shared, &major),
                all_across_std_m: all_across,
                all_along_std_m: all_along,
                held_across_std_m: (with_held.len() > shared.len())
                    .then(|| spread(&with_held, &minor))
                    .flatten(),
                stable_across_std_m: stable_across,
                dod_tilt: motions.and_then(|m| m.dod(a, b)),
            });
        }
    }
    pairs
}
