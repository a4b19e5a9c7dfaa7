//! Comparison of an orientation (`out/cameras.json`, `out/report.json`) with the truth a
//! synthetic project carries (`truth/cameras.json`, check points): per epoch, images oriented,
//! reprojection RMS, check-point RMSE in metres and in ground sampling distances, the check
//! points' disagreement with the reference epoch, camera-centre RMSE. Used by `timesift demo` and
//! `cargo xtask bench-methods`.

use std::path::Path;

use nalgebra::Vector3;
use timesift_io::cameras_json::read_cameras_json;

use crate::report::{AlignReport, EpochOrientation, read_json};
use crate::{Project, ProjectError};

/// One epoch of an orientation against the truth.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EpochAccuracy {
    /// Epoch name.
    pub epoch: String,
    /// Images of the epoch.
    pub images_given: u64,
    /// Images oriented.
    pub images_oriented: u64,
    /// RMS reprojection error, pixels.
    pub rms_px: Option<f64>,
    /// Check-point RMSE (dE, dN, dH), metres; `None` without measured check points.
    pub check_rmse_m: Option<[f64; 3]>,
    /// The same in ground sampling distances.
    pub check_rmse_gsd: Option<[f64; 3]>,
    /// Check points measured in the epoch.
    pub check_points: usize,
    /// RMS over check points of (this epoch's intersection − the reference epoch's), metres.
    pub disagreement_m: Option<[f64; 3]>,
    /// Camera-centre RMSE (dE, dN, dH) against the truth, metres.
    pub centre_rmse_m: Option<[f64; 3]>,
    /// Tie points also observed in another epoch.
    pub inter_epoch_tie_points: u64,
}

/// Mean distance from the true camera centres to the check points' centroid (or the control
/// points' without check points) over the true focal length: the ground sampling distance where
/// the check points are, metres.
pub fn ground_sampling_distance(project: &Project) -> Result<f64, ProjectError> {
    let truth = read_cameras_json(&project.layout().truth_cameras())?;
    let points: Vec<Vector3<f64>> = if project.checkpoints.is_empty() {
        project.gcps.iter().map(|g| g.position).collect()
    } else {
        project.checkpoints.iter().map(|g| g.position).collect()
    };
    let centroid = points.iter().sum::<Vector3<f64>>() / points.len().max(1) as f64;
    let mut sum = 0.0;
    let mut n = 0;
    for image in &truth.images {
        let (Some(pose), Some(camera)) = (image.pose, truth.cameras.get(&image.camera)) else {
            continue;
        };
        let mut p = vec![0.0; timesift_core::CameraModel::num_params(camera)];
        timesift_core::CameraModel::params(camera, &mut p);
        sum += (pose.center() - centroid).norm() / p[0];
        n += 1;
    }
    Ok(sum / n.max(1) as f64)
}

fn rms3(v: &[Vector3<f64>]) -> Option<[f64; 3]> {
    (!v.is_empty()).then(|| {
        let n = v.len() as f64;
        [0, 1, 2].map(|k| (v.iter().map(|d| d[k] * d[k]).sum::<f64>() / n).sqrt())
    })
}

/// Check-point residual vectors of one epoch of report.json, by name.
fn check_residuals(epoch: &EpochOrientation) -> Vec<(String, Vector3<f64>)> {
    epoch
        .check_points
        .points
        .iter()
        .filter_map(|p| Some((p.name.clone(), Vector3::from(p.vector()?))))
        .collect()
}

/// Compares the orientation in `out` (a folder holding cameras.json and report.json) of the
/// synthetic `project` with its truth.
pub fn epoch_accuracy(
    project: &Project,
    out: &Path,
    gsd: f64,
) -> Result<Vec<EpochAccuracy>, ProjectError> {
    let report: AlignReport = read_json(&out.join("report.json"))?;
    let ours = read_cameras_json(&out.join("cameras.json"))?;
    let truth = read_cameras_json(&project.layout().truth_cameras())?;
    let reference_name = &project.epochs[project.reference_epoch.index()].name;
    let epochs = &report.epochs;
    let reference = epochs
        .get(reference_name)
        .map(check_residuals)
        .unwrap_or_default();
    let mut rows = Vec::new();
    for (name, epoch) in epochs {
        let checks = check_residuals(epoch);
        let vectors: Vec<Vector3<f64>> = checks.iter().map(|c| c.1).collect();
        let disagreement: Vec<Vector3<f64>> = checks
            .iter()
            .filter_map(|(n, d)| reference.iter().find(|r| &r.0 == n).map(|r| d - r.1))
            .collect();
        let centres: Vec<Vector3<f64>> = ours
            .images
            .iter()
            .zip(&truth.images)
            .filter(|(o, _)| &o.epoch == name)
            .filter_map(|(o, t)| Some(o.pose?.center() - t.pose?.center()))
            .collect();
        let check = rms3(&vectors);
        rows.push(EpochAccuracy {
            epoch: name.clone(),
            images_given: epoch.images_given as u64,
            images_oriented: epoch.images_oriented as u64,
            rms_px: epoch.rms_reprojection_px,
            check_rmse_m: check,
            check_rmse_gsd: check.map(|c| c.map(|v| v / gsd)),
            check_points: vectors.len(),
            disagreement_m: rms3(&disagreement),
            centre_rmse_m: rms3(&centres),
            inter_epoch_tie_points: epoch.inter_epoch_tie_points as u64,
        });
    }
    Ok(rows)
}

/// `a / b / c` with `digits` decimals, or a dash.
pub fn triple(v: Option<[f64; 3]>, digits: usize) -> String {
    v.map_or("–".to_string(), |v| {
        format!("{:.d$} / {:.d$} / {:.d$}", v[0], v[1], v[2], d = digits)
    })
}
