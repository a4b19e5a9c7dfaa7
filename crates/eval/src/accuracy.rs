//! An orientation (`out/cameras.json` and what the caller read of `out/report.json`) against
//! the truth a synthetic project carries (`truth/cameras.json`, check points): per epoch, images
//! oriented, reprojection RMS, check-point RMSE in metres and in ground sampling distances, the
//! check points' disagreement with the reference epoch, camera-centre RMSE, the GNSS offset's
//! error and how the epoch's tie points sit on the stable ground's true surface.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector3;
use timesift_change::trend::{SurfaceAgreement, residual_plane};
use timesift_core::Pose;
use timesift_geometry::triangulation::{PixelObservation, intersect_weighted};
use timesift_io::cameras_json::{Reconstruction, read_cameras_json};
use timesift_io::csv_inputs::{ControlPoint, Marker};

use crate::products::true_dem;
use crate::{EvalError, ProjectTruth};

/// What the comparisons need of one epoch of the align stage's report (`out/report.json`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct OrientedEpoch {
    /// Images of the epoch.
    pub images_given: usize,
    /// Images oriented.
    pub images_oriented: usize,
    /// RMS reprojection error, pixels.
    pub rms_px: Option<f64>,
    /// Observations kept in the epoch's images.
    pub observations: usize,
    /// Check-point residual vectors (estimated − given, E/N/H), by name.
    pub check_residuals: Vec<(String, Vector3<f64>)>,
    /// The check-point RMSE the markers' own accuracy alone gives, metres.
    pub check_markers_rmse_m: Option<[f64; 3]>,
    /// Tie points also observed in another epoch.
    pub inter_epoch_tie_points: usize,
    /// The estimated GNSS offset (E, N, H) and its standard deviations, metres.
    pub gnss_offset: Option<([f64; 3], Option<[f64; 3]>)>,
    /// The σ of the datum's tilt about its loosest axis, mm/m.
    pub datum_tilt_sigma_mm_per_m: Option<f64>,
}

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
    /// Observations kept in the epoch's images.
    pub observations: u64,
    /// Check-point RMSE (dE, dN, dH), metres; `None` without measured check points.
    pub check_rmse_m: Option<[f64; 3]>,
    /// The same in ground sampling distances.
    pub check_rmse_gsd: Option<[f64; 3]>,
    /// Check-point RMSE of the orientation alone (dE, dN, dH), metres: see
    /// [`orientation_check_errors`]. `None` for film epochs and without check points measured in
    /// two oriented images.
    pub orientation_check_rmse_m: Option<[f64; 3]>,
    /// The check-point RMSE the markers' own accuracy alone gives (report.json's
    /// `markers_rmse`), metres: the floor of `check_rmse_m` under a perfect orientation.
    pub check_markers_rmse_m: Option<[f64; 3]>,
    /// Check points measured in the epoch.
    pub check_points: usize,
    /// RMS over check points of (this epoch's intersection − the reference epoch's), metres.
    pub disagreement_m: Option<[f64; 3]>,
    /// The same of the orientations alone (each epoch's [`orientation_check_errors`]), metres:
    /// without the clicks of two epochs' markers, what the epochs' DEMs disagree by at the check
    /// points.
    pub orientation_disagreement_m: Option<[f64; 3]>,
    /// Camera-centre RMSE (dE, dN, dH) against the truth, metres.
    pub centre_rmse_m: Option<[f64; 3]>,
    /// Tie points also observed in another epoch.
    pub inter_epoch_tie_points: u64,
    /// Estimated minus true GNSS bias (E, N, H), metres, when the epoch's offset was estimated
    /// and `truth/gnss_bias.csv` exists.
    pub gnss_offset_error_m: Option<[f64; 3]>,
    /// The same in the offset's reported standard deviations.
    pub gnss_offset_error_sigmas: Option<[f64; 3]>,
    /// The epoch's tie points on stable ground against its true surface (ground scenes).
    pub stable_ties: Option<SurfaceAgreement>,
    /// The σ of the datum's tilt the epoch's control allows about its loosest axis, mm/m
    /// (report.json's `datum_tilt`): what `stable_ties`' tilt can be expected to reach.
    pub datum_tilt_sigma_mm_per_m: Option<f64>,
    /// The ground sampling distance the GSD figures are in, metres.
    pub gsd_m: f64,
}

/// The tie points observed in `epoch`'s images (the COLMAP model in `colmap`, world
/// coordinates) against that epoch's true surface, on stable ground (`stable`, the scene's
/// `truth/stable.tif`): [`residual_plane`] of their height residuals. `None` for wall scenes
/// (their truth is in the wall's frame) and where too few points fall on stable ground.
pub fn stable_tie_agreement(
    project: &ProjectTruth<'_>,
    model: &timesift_io::colmap::ColmapModel,
    stable: &timesift_io::geotiff::GeoRaster<f32>,
    epoch: &str,
) -> Result<Option<SurfaceAgreement>, EvalError> {
    let truth_dir = project.layout.truth_dir();
    if truth_dir.join(format!("surface_{epoch}.ply")).exists() {
        return Ok(None);
    }
    let surface = true_dem(&project.layout, epoch)?;
    let images: std::collections::HashSet<u32> = model
        .images
        .iter()
        .filter(|(_, im)| im.epoch.as_deref() == Some(epoch))
        .map(|(id, _)| *id)
        .collect();
    let t = stable.georef.transform;
    let residuals: Vec<(f64, f64, f64)> = model
        .points
        .values()
        .filter(|p| p.track.iter().any(|(image, _)| images.contains(image)))
        .filter_map(|p| {
            let (c, r) = t.world_to_pixel(p.xyz.x, p.xyz.y);
            let (c, r) = (c.floor(), r.floor());
            let on_stable = c >= 0.0
                && r >= 0.0
                && (c as usize) < stable.width
                && (r as usize) < stable.height
                && stable.get(c as usize, r as usize, 0) == 1.0;
            let z = surface.bilinear(p.xyz.x, p.xyz.y);
            (on_stable && z.is_finite()).then(|| (p.xyz.x, p.xyz.y, p.xyz.z - z))
        })
        .collect();
    Ok(residual_plane(&residuals))
}

/// Each epoch's true GNSS bias from `truth/gnss_bias.csv`; empty when the scene has no GNSS.
pub fn true_gnss_bias(project: &ProjectTruth<'_>) -> Result<BTreeMap<String, [f64; 3]>, EvalError> {
    let path = project.layout.truth_dir().join("gnss_bias.csv");
    if !path.is_file() {
        return Ok(BTreeMap::new());
    }
    Ok(timesift_io::truth_csv::read_gnss_bias(&path)?)
}

/// Mean distance from the true camera centres to the check points' centroid (or the control
/// points' without check points) over the true focal length: the ground sampling distance where
/// the check points are, metres.
pub fn ground_sampling_distance(project: &ProjectTruth<'_>) -> Result<f64, EvalError> {
    let cameras = read_cameras_json(&project.layout.truth_cameras())?;
    let points: Vec<Vector3<f64>> = if project.checkpoints.is_empty() {
        project.gcps.iter().map(|g| g.position).collect()
    } else {
        project.checkpoints.iter().map(|g| g.position).collect()
    };
    let centroid = points.iter().sum::<Vector3<f64>>() / points.len().max(1) as f64;
    let mut sum = 0.0;
    let mut n = 0;
    for image in &cameras.images {
        let (Some(pose), Some(camera)) = (image.pose, cameras.cameras.get(&image.camera)) else {
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

/// Per point named in both, `a`'s vector minus `b`'s.
fn differences(a: &[(String, Vector3<f64>)], b: &[(String, Vector3<f64>)]) -> Vec<Vector3<f64>> {
    a.iter()
        .filter_map(|(n, d)| b.iter().find(|r| &r.0 == n).map(|r| d - r.1))
        .collect()
}

/// Compares the orientation in `out` (a folder holding cameras.json and the COLMAP model), whose
/// report gave `epochs`, with the truth of the synthetic project.
pub fn epoch_accuracy(
    project: &ProjectTruth<'_>,
    epochs: &BTreeMap<String, OrientedEpoch>,
    out: &Path,
    gsd: f64,
) -> Result<Vec<EpochAccuracy>, EvalError> {
    let ours = read_cameras_json(&out.join("cameras.json"))?;
    let truth = read_cameras_json(&project.layout.truth_cameras())?;
    let reference_name = project.reference_epoch;
    let biases = true_gnss_bias(project)?;
    // The tie points and the stable mask, read once for every epoch.
    let model = timesift_io::colmap::read_colmap_text(&out.join("colmap")).ok();
    let stable = model
        .as_ref()
        .map(|_| timesift_io::geotiff::read_f32(&project.layout.truth_dir().join("stable.tif")))
        .transpose()?;
    let reference = epochs
        .get(reference_name)
        .map_or(&[][..], |e| e.check_residuals.as_slice());
    let reference_alone = orientation_check_errors(project, &ours, &truth, reference_name);
    let mut rows = Vec::new();
    for (name, epoch) in epochs {
        let checks = &epoch.check_residuals;
        let alone = orientation_check_errors(project, &ours, &truth, name);
        let vectors: Vec<Vector3<f64>> = checks.iter().map(|c| c.1).collect();
        let disagreement = differences(checks, reference);
        let centres: Vec<Vector3<f64>> = ours
            .images
            .iter()
            .zip(&truth.images)
            .filter(|(o, _)| &o.epoch == name)
            .filter_map(|(o, t)| Some(o.pose?.center() - t.pose?.center()))
            .collect();
        let check = rms3(&vectors);
        let offset_error = match (epoch.gnss_offset, biases.get(name)) {
            (Some((offset, std)), Some(b)) => Some(([0, 1, 2].map(|k| offset[k] - b[k]), std)),
            _ => None,
        };
        rows.push(EpochAccuracy {
            epoch: name.clone(),
            images_given: epoch.images_given as u64,
            images_oriented: epoch.images_oriented as u64,
            rms_px: epoch.rms_px,
            observations: epoch.observations as u64,
            datum_tilt_sigma_mm_per_m: epoch.datum_tilt_sigma_mm_per_m,
            check_rmse_m: check,
            check_rmse_gsd: check.map(|c| c.map(|v| v / gsd)),
            orientation_check_rmse_m: rms3(&alone.iter().map(|c| c.1).collect::<Vec<_>>()),
            orientation_disagreement_m: rms3(&differences(&alone, &reference_alone)),
            check_markers_rmse_m: epoch.check_markers_rmse_m,
            check_points: vectors.len(),
            disagreement_m: rms3(&disagreement),
            centre_rmse_m: rms3(&centres),
            inter_epoch_tie_points: epoch.inter_epoch_tie_points as u64,
            gnss_offset_error_m: offset_error.map(|(e, _)| e),
            gnss_offset_error_sigmas: offset_error
                .and_then(|(e, std)| std.map(|std| [0, 1, 2].map(|k| e[k] / std[k]))),
            gsd_m: gsd,
            stable_ties: match (&model, &stable) {
                (Some(model), Some(stable)) => stable_tie_agreement(project, model, stable, name)?,
                _ => None,
            },
        });
    }
    Ok(rows)
}

/// The error of an epoch's orientation at its check points, without the markers' own noise: each
/// check point's true position projected through the true camera of every oriented image of
/// `epoch` that measures it (markers.csv), and those exact pixels intersected with the estimated
/// cameras, minus the true position. The measured check-point error adds the click noise of the
/// markers, which with points seen in two or three images is as large as the orientation's own
/// error on the small scenes (`campus`: four check points, most in two images): comparing two
/// orientations there, this is the figure that tells them apart. Film epochs are left out (their
/// markers are measured on the scans, not in the frame the cameras describe).
pub fn orientation_check_errors(
    project: &ProjectTruth<'_>,
    ours: &Reconstruction,
    truth: &Reconstruction,
    epoch: &str,
) -> Vec<(String, Vector3<f64>)> {
    if !project.epochs.contains(&epoch) || project.film_epochs.contains(epoch) {
        return Vec::new();
    }
    exact_check_errors(project.checkpoints, project.markers, ours, truth, epoch)
}

/// [`orientation_check_errors`] for given check points and markers (any epoch kind).
fn exact_check_errors(
    checkpoints: &[ControlPoint],
    markers: &[Marker],
    ours: &Reconstruction,
    truth: &Reconstruction,
    epoch: &str,
) -> Vec<(String, Vector3<f64>)> {
    fn oriented<'r>(
        rec: &'r Reconstruction,
        image: &str,
        epoch: &str,
    ) -> Option<(&'r timesift_core::Camera, Pose)> {
        let im = rec
            .images
            .iter()
            .find(|i| i.name == image && i.epoch == epoch)?;
        Some((rec.cameras.get(&im.camera)?, im.pose?))
    }
    checkpoints
        .iter()
        .filter_map(|point| {
            let observations: Vec<PixelObservation<'_>> = markers
                .iter()
                .filter(|m| m.name == point.name)
                .filter_map(|m| {
                    let (true_camera, true_pose) = oriented(truth, &m.image, epoch)?;
                    let (camera, pose) = oriented(ours, &m.image, epoch)?;
                    let pixel = timesift_core::CameraModel::project(
                        true_camera,
                        &true_pose.transform_point(&point.position),
                    )
                    .ok()?;
                    Some(PixelObservation {
                        camera,
                        pose,
                        pixel,
                        sigma_px: 1.0,
                    })
                })
                .collect();
            let error = intersect_weighted(&observations).ok()?.position - point.position;
            Some((point.name.clone(), error))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three nadir views 120 m above a point in projected coordinates, the point marked in two.
    fn three_views(shift: Vector3<f64>) -> (Reconstruction, Vec<ControlPoint>, Vec<Marker>) {
        let ground = Vector3::new(592_400.0, 5_763_860.0, 38.0);
        let camera = timesift_core::BrownCamera::new(512, 384, 370.0).unwrap();
        let look_down = nalgebra::UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 3.1);
        let images = [(-40.0, 0.0), (0.0, 5.0), (40.0, 0.0)]
            .iter()
            .enumerate()
            .map(|(k, (dx, dy))| timesift_io::cameras_json::OrientedImage {
                name: format!("images/e/IMG_{k}.jpg"),
                epoch: "e".into(),
                camera: "c".into(),
                pose: Some(Pose::from_rotation_and_center(
                    look_down,
                    &(ground + Vector3::new(*dx, *dy, 120.0) + shift),
                )),
            })
            .collect();
        let rec = Reconstruction {
            crs: "EPSG:32633".into(),
            cameras: [("c".to_string(), timesift_core::Camera::Brown(camera))].into(),
            images,
        };
        let point = ControlPoint {
            name: "CHK1".into(),
            position: ground,
            sigma: None,
            line: 2,
        };
        let marker = |k: usize| Marker {
            image: format!("images/e/IMG_{k}.jpg"),
            name: "CHK1".into(),
            pixel: nalgebra::Vector2::zeros(),
            line: k + 2,
        };
        (rec, vec![point], vec![marker(0), marker(2)])
    }

    #[test]
    fn the_exact_check_error_is_the_orientations_own() {
        let (truth, points, markers) = three_views(Vector3::zeros());
        // The markers' pixels are not used: the true ones are projected.
        let same = exact_check_errors(&points, &markers, &truth, &truth, "e");
        assert_eq!(same.len(), 1);
        assert_eq!(same[0].0, "CHK1");
        assert!(same[0].1.norm() < 1e-6, "{:?}", same[0]);
        // Every camera moved by the same vector: the intersection moves by it.
        let shift = Vector3::new(0.1, -0.2, 0.3);
        let (moved, _, _) = three_views(shift);
        let error = exact_check_errors(&points, &markers, &moved, &truth, "e");
        assert!((error[0].1 - shift).norm() < 1e-6, "{:?}", error[0]);
        // Marked in one oriented image, or in another epoch's: no intersection.
        assert!(exact_check_errors(&points, &markers[..1], &moved, &truth, "e").is_empty());
        assert!(exact_check_errors(&points, &markers, &moved, &truth, "f").is_empty());
    }
}
