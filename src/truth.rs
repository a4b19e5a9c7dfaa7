//! Comparison of an orientation (`out/cameras.json`, `out/report.json`) with the truth a
//! synthetic project carries (`truth/cameras.json`, check points): per epoch, images oriented,
//! reprojection RMS, check-point RMSE in metres and in ground sampling distances, the check
//! points' disagreement with the reference epoch, camera-centre RMSE. Used by `timesift demo` and
//! `cargo xtask bench-methods`.

use std::path::Path;

use nalgebra::Vector3;
use timesift_core::Pose;
use timesift_geometry::triangulation::{PixelObservation, intersect_weighted};
use timesift_io::cameras_json::{Reconstruction, read_cameras_json};
use timesift_io::csv_inputs::{ControlPoint, Marker};

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

/// How a set of points sits on a true surface: the height residuals' median and the plane
/// fitted to them, which shows a tilt (a roll about a corridor's axis) that check points along
/// the corridor cannot.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SurfaceAgreement {
    /// Points compared.
    pub count: usize,
    /// Median height residual (point − surface), metres.
    pub median_m: f64,
    /// Slope of the plane fitted to the residuals, mm per m.
    pub tilt_mm_per_m: f64,
    /// Downhill direction of that plane, degrees clockwise from north.
    pub tilt_azimuth_deg: f64,
}

/// Least points for a plane fit of residuals.
const MIN_PLANE_POINTS: usize = 20;

/// The plane `dz = a + b·x + c·y` through height residuals at `xy`, fitted by least squares,
/// then again without the residuals beyond 3 NMAD of the first fit (blunders among tie
/// points); `None` with fewer than 20 points or a degenerate spread.
pub fn residual_plane(points: &[(f64, f64, f64)]) -> Option<SurfaceAgreement> {
    if points.len() < MIN_PLANE_POINTS {
        return None;
    }
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(sx, sy), p| (sx + p.0 / n, sy + p.1 / n));
    // Points along a line fix no plane across it.
    let (sxx, syy, sxy) = points.iter().fold((0.0, 0.0, 0.0), |(a, b, c), p| {
        let (x, y) = (p.0 - mx, p.1 - my);
        (a + x * x, b + y * y, c + x * y)
    });
    if sxx * syy - sxy * sxy <= 1e-9 * (sxx + syy).powi(2) {
        return None;
    }
    let fit = |keep: &dyn Fn(&(f64, f64, f64)) -> bool| -> Option<nalgebra::Vector3<f64>> {
        let mut normal = nalgebra::Matrix3::<f64>::zeros();
        let mut rhs = nalgebra::Vector3::<f64>::zeros();
        for p in points.iter().filter(|p| keep(p)) {
            let row = nalgebra::Vector3::new(1.0, p.0 - mx, p.1 - my);
            normal += row * row.transpose();
            rhs += row * p.2;
        }
        normal.cholesky().map(|c| c.solve(&rhs))
    };
    let first = fit(&|_| true)?;
    let residual = |c: &nalgebra::Vector3<f64>, p: &(f64, f64, f64)| {
        p.2 - (c[0] + c[1] * (p.0 - mx) + c[2] * (p.1 - my))
    };
    let stats = timesift_change::stats::statistics(points.iter().map(|p| residual(&first, p)))?;
    let bound = 3.0 * stats.nmad.max(1e-9);
    let plane = fit(&|p| residual(&first, p).abs() <= bound)?;
    let median = timesift_change::stats::statistics(points.iter().map(|p| p.2))?.median;
    let (gx, gy) = (plane[1], plane[2]);
    Some(SurfaceAgreement {
        count: points.len(),
        median_m: median,
        tilt_mm_per_m: 1000.0 * gx.hypot(gy),
        // Downhill: against the gradient; azimuth from north (y) clockwise towards east (x).
        tilt_azimuth_deg: (-gx).atan2(-gy).to_degrees().rem_euclid(360.0),
    })
}

/// The true surface of `epoch` (`truth/dem_<epoch>.tif`).
fn true_dem(project: &Project, epoch: &str) -> Result<timesift_change::grid::Dem, ProjectError> {
    let path = project
        .layout()
        .truth_dir()
        .join(format!("dem_{epoch}.tif"));
    timesift_change::grid::Dem::from_raster(timesift_io::geotiff::read_f32(&path)?, None).map_err(
        |source| ProjectError::Change {
            context: path.display().to_string(),
            source,
        },
    )
}

/// The tie points observed in `epoch`'s images (the COLMAP model in `colmap`, world
/// coordinates) against that epoch's true surface, on stable ground (`stable`, the scene's
/// `truth/stable.tif`): [`residual_plane`] of their height residuals. `None` for wall scenes
/// (their truth is in the wall's frame) and where too few points fall on stable ground.
pub fn stable_tie_agreement(
    project: &Project,
    model: &timesift_io::colmap::ColmapModel,
    stable: &timesift_io::geotiff::GeoRaster<f32>,
    epoch: &str,
) -> Result<Option<SurfaceAgreement>, ProjectError> {
    let truth_dir = project.layout().truth_dir();
    if truth_dir.join(format!("surface_{epoch}.ply")).exists() {
        return Ok(None);
    }
    let truth = true_dem(project, epoch)?;
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
            let z = truth.bilinear(p.xyz.x, p.xyz.y);
            (on_stable && z.is_finite()).then(|| (p.xyz.x, p.xyz.y, p.xyz.z - z))
        })
        .collect();
    Ok(residual_plane(&residuals))
}

/// Each epoch's true GNSS bias from `truth/gnss_bias.csv` (`epoch,east,north,up`); empty when
/// the scene has no GNSS.
pub fn true_gnss_bias(
    project: &Project,
) -> Result<std::collections::BTreeMap<String, [f64; 3]>, ProjectError> {
    let path = project.layout().truth_dir().join("gnss_bias.csv");
    let mut biases = std::collections::BTreeMap::new();
    if !path.is_file() {
        return Ok(biases);
    }
    let text = std::fs::read_to_string(&path).map_err(|e| timesift_io::IoError::io(&path, e))?;
    for (k, line) in text.lines().enumerate().skip(1) {
        let fields: Vec<&str> = line.split(',').collect();
        let values: Vec<f64> = fields
            .iter()
            .skip(1)
            .filter_map(|v| v.trim().parse().ok())
            .collect();
        if fields.len() != 4 || values.len() != 3 {
            return Err(ProjectError::Path {
                path: path.clone(),
                message: format!("line {}: expected epoch,east,north,up", k + 1),
            });
        }
        biases.insert(fields[0].to_string(), [values[0], values[1], values[2]]);
    }
    Ok(biases)
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

/// Per point named in both, `a`'s vector minus `b`'s.
fn differences(a: &[(String, Vector3<f64>)], b: &[(String, Vector3<f64>)]) -> Vec<Vector3<f64>> {
    a.iter()
        .filter_map(|(n, d)| b.iter().find(|r| &r.0 == n).map(|r| d - r.1))
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
    let biases = true_gnss_bias(project)?;
    // The tie points and the stable mask, read once for every epoch.
    let model = timesift_io::colmap::read_colmap_text(&out.join("colmap")).ok();
    let stable = model
        .as_ref()
        .map(|_| timesift_io::geotiff::read_f32(&project.layout().truth_dir().join("stable.tif")))
        .transpose()?;
    let reference = epochs
        .get(reference_name)
        .map(check_residuals)
        .unwrap_or_default();
    let reference_alone = orientation_check_errors(project, &ours, &truth, reference_name);
    let mut rows = Vec::new();
    for (name, epoch) in epochs {
        let checks = check_residuals(epoch);
        let alone = orientation_check_errors(project, &ours, &truth, name);
        let vectors: Vec<Vector3<f64>> = checks.iter().map(|c| c.1).collect();
        let disagreement = differences(&checks, &reference);
        let centres: Vec<Vector3<f64>> = ours
            .images
            .iter()
            .zip(&truth.images)
            .filter(|(o, _)| &o.epoch == name)
            .filter_map(|(o, t)| Some(o.pose?.center() - t.pose?.center()))
            .collect();
        let check = rms3(&vectors);
        let offset_error = match (epoch.gnss_offset, biases.get(name)) {
            (Some(o), Some(b)) => Some(([0, 1, 2].map(|k| o.offset[k] - b[k]), o.std)),
            _ => None,
        };
        rows.push(EpochAccuracy {
            epoch: name.clone(),
            images_given: epoch.images_given as u64,
            images_oriented: epoch.images_oriented as u64,
            rms_px: epoch.rms_reprojection_px,
            observations: epoch.observations as u64,
            datum_tilt_sigma_mm_per_m: epoch.datum_tilt.map(|t| t.sigma_max_mm_per_m),
            check_rmse_m: check,
            check_rmse_gsd: check.map(|c| c.map(|v| v / gsd)),
            orientation_check_rmse_m: rms3(&alone.iter().map(|c| c.1).collect::<Vec<_>>()),
            orientation_disagreement_m: rms3(&differences(&alone, &reference_alone)),
            check_markers_rmse_m: epoch.check_points.markers_rmse.map(|r| [r.de, r.dn, r.dh]),
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
    project: &Project,
    ours: &Reconstruction,
    truth: &Reconstruction,
    epoch: &str,
) -> Vec<(String, Vector3<f64>)> {
    let film = project
        .epochs
        .iter()
        .position(|e| e.name == epoch)
        .is_none_or(|e| project.image_kind(e) == crate::config::ImageKind::FilmScan);
    if film {
        return Vec::new();
    }
    exact_check_errors(&project.checkpoints, &project.markers, ours, truth, epoch)
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

/// `a / b / c` with `digits` decimals, or a dash.
pub fn triple(v: Option<[f64; 3]>, digits: usize) -> String {
    v.map_or("–".to_string(), |v| {
        format!("{:.d$} / {:.d$} / {:.d$}", v[0], v[1], v[2], d = digits)
    })
}

/// Where the centre of a four-quadrant target (black and white quadrants alternating, the
/// targets `synth` paints) lies in an RGBA raster, searched within `search` cells of `near`.
/// Positions are in cells with the pixel convention of docs/design.md (the centre of cell (i, j) is
/// (i + 0.5, j + 0.5)); `radius` is the target's radius in cells.
///
/// The score of a candidate centre is the X-corner response on rings inside the disc: opposite
/// points agree (|I(c + d) − I(c − d)| small), points a quarter turn apart differ
/// (|I(c + d) − I(c + d⊥)| large). The best cell centre is
/// refined on a 0.05-cell grid. `None` when the window leaves the raster or touches transparent cells.
pub fn locate_target(
    rgba: &[u8],
    width: usize,
    height: usize,
    near: (f64, f64),
    radius: f64,
    search: f64,
) -> Option<(f64, f64)> {
    let grey = |x: f64, y: f64| -> Option<f64> {
        // Bilinear between cell centres.
        let (fx, fy) = (x - 0.5, y - 0.5);
        let (x0, y0) = (fx.floor(), fy.floor());
        if x0 < 0.0 || y0 < 0.0 || x0 + 1.0 >= width as f64 || y0 + 1.0 >= height as f64 {
            return None;
        }
        let (tx, ty) = (fx - x0, fy - y0);
        let mut v = 0.0;
        for (dx, dy, w) in [
            (0, 0, (1.0 - tx) * (1.0 - ty)),
            (1, 0, tx * (1.0 - ty)),
            (0, 1, (1.0 - tx) * ty),
            (1, 1, tx * ty),
        ] {
            let i = 4 * ((y0 as usize + dy) * width + x0 as usize + dx);
            if rgba[i + 3] == 0 {
                return None;
            }
            v += w * (rgba[i] as f64 + rgba[i + 1] as f64 + rgba[i + 2] as f64) / 3.0;
        }
        Some(v)
    };
    let score = |cx: f64, cy: f64| -> Option<f64> {
        let mut s = 0.0;
        for ring in [0.35, 0.55, 0.75] {
            let r = ring * radius;
            for k in 0..16 {
                let a = k as f64 * std::f64::consts::PI / 8.0;
                let (dx, dy) = (r * a.cos(), r * a.sin());
                let p = grey(cx + dx, cy + dy)?;
                let opposite = grey(cx - dx, cy - dy)?;
                let quarter = grey(cx - dy, cy + dx)?;
                s += (p - quarter).abs() - (p - opposite).abs();
            }
        }
        Some(s)
    };
    let reach = search.ceil() as i64;
    let (c0, r0) = (near.0.floor() as i64, near.1.floor() as i64);
    let mut best: Option<(f64, i64, i64)> = None;
    for r in r0 - reach..=r0 + reach {
        for c in c0 - reach..=c0 + reach {
            let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
            if (x - near.0).hypot(y - near.1) > search {
                continue;
            }
            let s = score(x, y)?;
            if best.is_none_or(|b| s > b.0) {
                best = Some((s, c, r));
            }
        }
    }
    // Sub-cell: the best of a 0.05-cell grid around the best cell centre (the response is a
    // cone, which a parabola would bias).
    let (_, c, r) = best?;
    let mut fine = (f64::NEG_INFINITY, c as f64 + 0.5, r as f64 + 0.5);
    for j in -12..=12 {
        for i in -12..=12 {
            let (x, y) = (
                c as f64 + 0.5 + i as f64 * 0.05,
                r as f64 + 0.5 + j as f64 * 0.05,
            );
            let s = score(x, y)?;
            if s > fine.0 {
                fine = (s, x, y);
            }
        }
    }
    Some((fine.1, fine.2))
}

/// The painted targets of a synthetic project (`truth/points.csv`) located in an RGBA ortho
/// with [`locate_target`]: how many were found and the RMS distance of the found ones from
/// their true positions, in ortho cells. `target_radius` is the targets' radius in metres.
pub fn ortho_target_errors(
    project_dir: &Path,
    ortho: &timesift_io::geotiff::GeoRaster<u8>,
    target_radius: f64,
) -> Result<(usize, Option<f64>), ProjectError> {
    let path = project_dir.join("truth/points.csv");
    let text = timesift_io::fsutil::read_text(&path)?;
    let header: Vec<&str> = text.lines().next().unwrap_or("").split(',').collect();
    let col = |k: &str| header.iter().position(|h| *h == k);
    let (Some(ix), Some(iy)) = (col("x"), col("y")) else {
        return Err(ProjectError::Path {
            path,
            message: "no x and y columns".into(),
        });
    };
    let t = ortho.georef.transform;
    let radius = target_radius / t.pixel_width;
    let (mut sq, mut found) = (0.0, 0usize);
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let (Some(x), Some(y)) = (
            f.get(ix).and_then(|v| v.parse::<f64>().ok()),
            f.get(iy).and_then(|v| v.parse::<f64>().ok()),
        ) else {
            continue;
        };
        let near = t.world_to_pixel(x, y);
        let located = locate_target(
            &ortho.data,
            ortho.width,
            ortho.height,
            near,
            radius,
            0.5 * radius,
        );
        if let Some((c, r)) = located {
            sq += (c - near.0).powi(2) + (r - near.1).powi(2);
            found += 1;
        }
    }
    Ok((found, (found > 0).then(|| (sq / found as f64).sqrt())))
}

/// Height errors (DEM − truth, metres) of the measured cells of a DEM (`count` > 0, not
/// nodata) whose centre `keep` accepts, against a truth DEM sampled bilinearly.
pub fn dem_height_errors(
    dem: &timesift_io::geotiff::GeoRaster<f32>,
    count: &timesift_io::geotiff::GeoRaster<f32>,
    truth: &timesift_change::grid::Dem,
    keep: impl Fn(f64, f64) -> bool,
) -> Vec<f64> {
    let t = dem.georef.transform;
    let nodata = dem.georef.nodata.map(|v| v as f32);
    let mut err = Vec::new();
    for r in 0..dem.height {
        for c in 0..dem.width {
            let h = dem.get(c, r, 0);
            if Some(h) == nodata || !h.is_finite() || count.get(c, r, 0) == 0.0 {
                continue;
            }
            let (x, y) = t.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            if !keep(x, y) {
                continue;
            }
            let z = truth.bilinear(x, y);
            if z.is_finite() {
                err.push(h as f64 - z);
            }
        }
    }
    err
}

/// `truth/change.json` as `synth` writes it: the regions that changed and their true volumes.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct ChangeTruth {
    /// Epoch names in order.
    pub epochs: Vec<String>,
    /// Changed regions.
    pub regions: Vec<TrueRegion>,
}

/// One region of [`ChangeTruth`].
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct TrueRegion {
    /// Region name.
    pub name: String,
    /// What happens there.
    #[serde(default)]
    pub description: String,
    /// Outline in world coordinates (E, N).
    pub polygon_wkt: String,
    /// True volume change between pairs of epochs.
    pub volumes: Vec<TrueVolume>,
}

/// The true volume change of a region between two epochs, m³ (positive: material added).
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct TrueVolume {
    /// Earlier epoch.
    pub from: String,
    /// Later epoch.
    pub to: String,
    /// Net volume, m³.
    pub volume_m3: f64,
}

/// A region's measured volume change next to the true one.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RegionVolume {
    /// Region name.
    pub region: String,
    /// Earlier epoch.
    pub from: String,
    /// Later epoch.
    pub to: String,
    /// True net volume, m³.
    pub true_m3: f64,
    /// Net volume of the DoD of the two epochs' DEMs inside the region, m³; NaN when no cell of
    /// the region has a height in both DEMs (`coverage` 0).
    pub measured_m3: f64,
    /// Its 1-σ uncertainty (random from the stable-area NMAD correlated as the stable-area
    /// variogram says, systematic from the stable-area median), m³; NaN with the volume.
    pub sigma_m3: f64,
    /// Fraction of the region's cells with a difference.
    pub coverage: f64,
}

/// Every true volume of `truth/change.json` measured on the project's DEMs (the DoD later −
/// earlier inside the region's polygon, with the uncertainty model of the change stage).
pub fn region_volumes(project: &Project) -> Result<Vec<RegionVolume>, ProjectError> {
    use std::collections::BTreeMap;
    use timesift_change::grid::Dem;
    use timesift_change::mask::Mask;
    use timesift_change::volume::{VolumeOptions, volumes};
    let layout = project.layout();
    let truth: ChangeTruth = read_json(&layout.truth_dir().join("change.json"))?;
    let stable_polygons = match crate::stages::stable_file(project) {
        Some(path) => crate::commands::compare::read_polygons(&path)?,
        None => Vec::new(),
    };
    let change_err = |context: String| move |source| ProjectError::Change { context, source };
    // Each epoch's DEM read once, each pair's DoD and uncertainty made once: the regions share
    // them.
    let mut dems: BTreeMap<String, Dem> = BTreeMap::new();
    let mut dods: BTreeMap<(String, String), (Dem, VolumeOptions)> = BTreeMap::new();
    let mut rows = Vec::new();
    for region in &truth.regions {
        let polygons = timesift_io::wkt::parse_polygons(&region.polygon_wkt).map_err(|e| {
            ProjectError::Path {
                path: layout.truth_dir().join("change.json"),
                message: format!("region {}: {e}", region.name),
            }
        })?;
        for v in &region.volumes {
            let context = format!("region {} from {} to {}", region.name, v.from, v.to);
            let key = (v.from.clone(), v.to.clone());
            if !dods.contains_key(&key) {
                for epoch in [&v.from, &v.to] {
                    if !dems.contains_key(epoch) {
                        let path = layout.dem(epoch);
                        let raster = timesift_io::geotiff::read_f32(&path)?;
                        let dem = Dem::from_raster(raster, None)
                            .map_err(change_err(path.display().to_string()))?;
                        dems.insert(epoch.clone(), dem);
                    }
                }
                let dod = timesift_change::dod::dem_of_difference(&dems[&v.from], &dems[&v.to])
                    .map_err(change_err(context.clone()))?;
                let stable = Mask::from_polygons(dod.grid, &stable_polygons);
                let stable_dz = timesift_change::stats::statistics(
                    dod.values
                        .iter()
                        .zip(&stable.cells)
                        .filter(|(_, s)| **s)
                        .map(|(v, _)| *v as f64),
                );
                let stable_variogram =
                    timesift_change::correlation::variogram(&dod, Some(&stable)).ok();
                let options = timesift_change::pair::volume_uncertainty(
                    None,
                    stable_dz.as_ref(),
                    stable_variogram.as_ref(),
                );
                dods.insert(key.clone(), (dod, options));
            }
            let (dod, options) = &dods[&key];
            let mask = Mask::from_polygons(dod.grid, &polygons);
            let inside = mask.count().max(1);
            let measured_cells = mask
                .cells
                .iter()
                .zip(&dod.values)
                .filter(|(m, v)| **m && v.is_finite())
                .count();
            if measured_cells == 0 {
                // The region lies outside what both DEMs cover: nothing measured, said so.
                rows.push(RegionVolume {
                    region: region.name.clone(),
                    from: v.from.clone(),
                    to: v.to.clone(),
                    true_m3: v.volume_m3,
                    measured_m3: f64::NAN,
                    sigma_m3: f64::NAN,
                    coverage: 0.0,
                });
                continue;
            }
            let measured = volumes(dod, Some(&mask), *options).map_err(change_err(context))?;
            rows.push(RegionVolume {
                region: region.name.clone(),
                from: v.from.clone(),
                to: v.to.clone(),
                true_m3: v.volume_m3,
                measured_m3: measured.net,
                sigma_m3: measured.sigma_net,
                coverage: measured.cells as f64 / inside as f64,
            });
        }
    }
    Ok(rows)
}

/// An epoch's DEM against its true surface (`truth/dem_<epoch>.tif`) over the cells measured
/// from the cloud: (cells, mean, median, NMAD), metres.
pub fn epoch_dem_error(
    project: &Project,
    epoch: &str,
) -> Result<Option<(usize, f64, f64, f64)>, ProjectError> {
    let layout = project.layout();
    let truth = true_dem(project, epoch)?;
    let dem = timesift_io::geotiff::read_f32(&layout.dem(epoch))?;
    let count = timesift_io::geotiff::read_f32(&layout.dem_count(epoch))?;
    let errors = dem_height_errors(&dem, &count, &truth, |_, _| true);
    Ok(timesift_change::stats::statistics(errors.iter().copied())
        .map(|s| (s.count, s.mean, s.median, s.nmad)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tilted_plane_of_residuals_is_recovered_despite_blunders() {
        let mut rng = timesift_core::SeededRng::new(4);
        // 2 mm/m rising towards the north-east (downhill to the south-west, 225°), 5 cm above.
        let g = 0.002 / std::f64::consts::SQRT_2;
        let mut points: Vec<(f64, f64, f64)> = (0..400)
            .map(|_| {
                let (x, y) = (
                    rng.uniform_range(-150.0, 150.0),
                    rng.uniform_range(-40.0, 40.0),
                );
                (500_000.0 + x, 5_000_000.0 + y, 0.05 + g * x + g * y)
            })
            .collect();
        for p in points.iter_mut().step_by(40) {
            p.2 += 3.0;
        }
        let a = residual_plane(&points).unwrap();
        assert_eq!(a.count, 400);
        assert!((a.tilt_mm_per_m - 2.0).abs() < 1e-6, "{a:?}");
        assert!((a.tilt_azimuth_deg - 225.0).abs() < 1e-4, "{a:?}");
        assert!((a.median_m - 0.05).abs() < 0.02, "{a:?}");
        // Too few points, or points along a line, fix no plane.
        assert_eq!(residual_plane(&points[..10]), None);
        let line: Vec<(f64, f64, f64)> = (0..50)
            .map(|k| (k as f64, 2.0 * k as f64 + 1.0, 0.0))
            .collect();
        assert_eq!(residual_plane(&line), None);
    }

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

    #[test]
    fn a_four_quadrant_target_is_found_to_a_sixth_of_a_cell() {
        let (w, h) = (60usize, 50usize);
        let (cx, cy, radius) = (27.3, 21.8, 9.0);
        let angle: f64 = 0.4;
        let mut rgba = vec![0u8; w * h * 4];
        for r in 0..h {
            for c in 0..w {
                // Area-averaged over 4 × 4 sub-samples, as a rendered image is.
                let mut v = 0.0;
                for s in 0..16 {
                    let x = c as f64 + (s % 4) as f64 / 4.0 + 0.125 - cx;
                    let y = r as f64 + (s / 4) as f64 / 4.0 + 0.125 - cy;
                    let (u, t) = (
                        x * angle.cos() + y * angle.sin(),
                        -x * angle.sin() + y * angle.cos(),
                    );
                    v += if x.hypot(y) > radius {
                        120.0
                    } else if (u > 0.0) == (t > 0.0) {
                        240.0
                    } else {
                        15.0
                    };
                }
                let i = 4 * (r * w + c);
                rgba[i..i + 3].fill((v / 16.0) as u8);
                rgba[i + 3] = 255;
            }
        }
        let (x, y) = locate_target(&rgba, w, h, (29.0, 20.0), radius, 4.0).unwrap();
        assert!((x - cx).abs() < 0.16 && (y - cy).abs() < 0.16, "{x} {y}");
        // A window that reaches transparent cells gives no answer.
        rgba[4 * (21 * w + 27) + 3] = 0;
        assert_eq!(locate_target(&rgba, w, h, (29.0, 20.0), radius, 4.0), None);
    }
}
