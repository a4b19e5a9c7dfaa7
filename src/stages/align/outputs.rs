//! What the align stage writes: `out/cameras.json`, `out/colmap/`, `out/tiepoints.ply` and
//! `out/report.json` with each epoch's orientation.

use super::*;
use timesift_io::ply::EpochSet;

pub(super) fn write_outputs(
    project: &Project,
    input: &SfmInput,
    geo: &GeoreferenceInput,
    frame: &LocalFrame,
    block: &Georeferenced,
    strategy: &dyn Strategy,
    seconds: f64,
) -> Result<AlignReport, ProjectError> {
    let layout = project.layout();
    let rec = &block.reconstruction;
    let crs = if block.datum == Datum::Local {
        "local".to_string()
    } else {
        project.config.crs.clone()
    };
    let origin = if block.datum == Datum::Local {
        Vector3::zeros()
    } else {
        frame.origin
    };
    let shifted = LocalFrame {
        origin,
        priors: Vec::new(),
    };
    let file = cameras_file(project, input, rec, crs, &shifted);
    timesift_io::cameras_json::write_cameras_json(&layout.cameras_json(), &file)?;
    let model = colmap_model(&file, input, rec, origin)?;
    timesift_io::colmap::write_colmap_text(&layout.colmap_dir(), &model)?;
    // Tie points with their epochs.
    let epoch_of: Vec<usize> = project.images.iter().map(|im| im.epoch.index()).collect();
    let tiepoints: Vec<timesift_io::ply::TiePoint> = rec
        .points
        .iter()
        .map(|p| timesift_io::ply::TiePoint {
            position: p.position + origin,
            observations: p.observations.len().min(u16::MAX as usize) as u16,
            epochs: p
                .observations
                .iter()
                .map(|e| epoch_of[e.image.index()])
                .collect(),
        })
        .collect();
    let epoch_names: Vec<String> = project.epochs.iter().map(|e| e.name.clone()).collect();
    timesift_io::ply::write_tiepoints(&layout.tiepoints_ply(), &epoch_names, &tiepoints)?;
    let report = report(project, input, geo, block, strategy, &tiepoints, seconds);
    write_json(&layout.report_json(), &report)?;
    Ok(report)
}

/// `cameras.json`: every camera group (named by its first epoch's group) and every image's pose
/// in the world frame (`shifted` from the block's local frame).
fn cameras_file(
    project: &Project,
    input: &SfmInput,
    rec: &timesift_align::Reconstruction,
    crs: String,
    shifted: &LocalFrame,
) -> CamerasFile {
    let mut group_names: Vec<String> = vec![String::new(); input.cameras.len()];
    for epoch in &project.epochs {
        if let Some(&first) = epoch.images.first() {
            group_names[input.images[first.index()].group] = epoch.camera_group.clone();
        }
    }
    CamerasFile {
        crs,
        cameras: group_names
            .iter()
            .cloned()
            .zip(rec.cameras.iter().cloned())
            .collect(),
        images: project
            .images
            .iter()
            .enumerate()
            .map(|(i, im)| OrientedImage {
                name: im.name.clone(),
                epoch: project.epochs[im.epoch.index()].name.clone(),
                camera: group_names[input.images[i].group].clone(),
                pose: rec.poses[i].map(|p| shifted.world_pose(&p)),
            })
            .collect(),
    }
}

/// The COLMAP text model of `file` with the block's tie points (shifted by `origin` into the
/// world frame), each with its mean reprojection error.
fn colmap_model(
    file: &CamerasFile,
    input: &SfmInput,
    rec: &timesift_align::Reconstruction,
    origin: Vector3<f64>,
) -> Result<timesift_io::colmap::ColmapModel, ProjectError> {
    let mut model = timesift_io::colmap::from_reconstruction(file)
        .map_err(|e| stage_error(format!("COLMAP export: {e}")))?;
    for (k, point) in rec.points.iter().enumerate() {
        let id = k as u64 + 1;
        let mut track = Vec::with_capacity(point.observations.len());
        let mut error_sum = 0.0;
        for e in &point.observations {
            let image_id = e.image.index() as u32 + 1;
            let Some(image) = model.images.get_mut(&image_id) else {
                continue;
            };
            let pixel = input.pixel(e);
            track.push((image_id, image.points2d.len() as u32));
            image.points2d.push((pixel.x, pixel.y, id as i64));
            if let Some(pose) = rec.poses[e.image.index()] {
                let camera = rec.camera_of(input, e.image.index());
                error_sum += timesift_core::project_world(camera, &pose, &point.position)
                    .map_or(0.0, |u| (u - pixel).norm());
            }
        }
        model.points.insert(
            id,
            timesift_io::colmap::ColmapPoint {
                xyz: point.position + origin,
                rgb: [128, 128, 128],
                error: error_sum / track.len().max(1) as f64,
                track,
            },
        );
    }
    Ok(model)
}

fn residuals_of(residuals: &[PointResidual], check: bool) -> PointResiduals {
    let rows: Vec<&PointResidual> = residuals.iter().filter(|r| r.check == check).collect();
    let measured: Vec<Vector3<f64>> = rows.iter().filter_map(|r| r.residual).collect();
    // Both come from one intersection: a point with a residual has its σ.
    let sigmas: Vec<Vector3<f64>> = rows.iter().filter_map(|r| r.markers_sigma).collect();
    PointResiduals {
        points: rows
            .iter()
            .map(|r| ResidualRow {
                name: r.name.clone(),
                images: r.images,
                de: r.residual.map(|d| d.x),
                dn: r.residual.map(|d| d.y),
                dh: r.residual.map(|d| d.z),
                markers_sigma: r.markers_sigma.map(|s| s.into()),
            })
            .collect(),
        rmse: rmse_of(&measured),
        markers_rmse: rmse_of(&sigmas),
    }
}

/// RMS per component of `vectors`, `None` when there are none.
fn rmse_of(vectors: &[Vector3<f64>]) -> Option<Rmse> {
    let rms =
        |k: usize| (vectors.iter().map(|d| d[k] * d[k]).sum::<f64>() / vectors.len() as f64).sqrt();
    (!vectors.is_empty()).then(|| Rmse {
        de: rms(0),
        dn: rms(1),
        dh: rms(2),
        n: vectors.len(),
    })
}

/// Per pair of epochs, the tie points both observe, and their spread across and along the
/// principal horizontal axes of every tie point; the tilt σ of their DoD from the block's
/// covariance of the epochs' rigid motions.
fn epoch_pair_ties(
    project: &Project,
    tiepoints: &[timesift_io::ply::TiePoint],
    set_motion_covariance: Option<&nalgebra::DMatrix<f64>>,
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
    let mut pairs = Vec::new();
    for a in 0..project.epochs.len() {
        for b in a + 1..project.epochs.len() {
            let both: EpochSet = [a, b].into_iter().collect();
            let shared: Vec<Vector2<f64>> = tiepoints
                .iter()
                .filter(|p| p.epochs.contains_all(&both))
                .map(|p| p.position.xy() - mean)
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
                dod_tilt: set_motion_covariance.and_then(|c| tilt_of(c, &[(b, 1.0), (a, -1.0)])),
            });
        }
    }
    pairs
}

/// The tilt σ of a combination `Σ w·motion(set)` of the rigid motions whose covariance `c`
/// holds (6 rows per set, rotation first): the horizontal components of the rotation are the
/// surface's slope (radians), their covariance's eigenvalues the loosest and firmest tilt.
fn tilt_of(c: &nalgebra::DMatrix<f64>, combination: &[(usize, f64)]) -> Option<DatumTiltReport> {
    let mut cov = nalgebra::Matrix2::<f64>::zeros();
    for &(s, ws) in combination {
        for &(t, wt) in combination {
            for r in 0..2 {
                for q in 0..2 {
                    cov[(r, q)] += ws * wt * *c.get((6 * s + r, 6 * t + q))?;
                }
            }
        }
    }
    let eigen = cov.symmetric_eigen();
    let (loose, firm) = match eigen.eigenvalues[0] >= eigen.eigenvalues[1] {
        true => (0, 1),
        false => (1, 0),
    };
    let (max, min) = (eigen.eigenvalues[loose], eigen.eigenvalues[firm]);
    if !(max.is_finite() && min >= -1e-18) {
        return None;
    }
    // A rotation (θx, θy) raises the ground by θx·y − θy·x: its gradient is (−θy, θx).
    let axis = eigen.eigenvectors.column(loose);
    Some(DatumTiltReport {
        sigma_max_mm_per_m: 1000.0 * max.sqrt(),
        sigma_min_mm_per_m: 1000.0 * min.max(0.0).sqrt(),
        loose_azimuth_deg: (axis[0]).atan2(-axis[1]).to_degrees().rem_euclid(180.0),
    })
}

/// How loosely the control an epoch's orientation rests on fixes its datum's tilt
/// ([`timesift_align::datum_tilt`]), by whose control fixes it ([`DatumControl`]): in a single
/// block the control of every epoch, oriented alone (and the reference epoch of the strategies
/// that go through it) its own; `None` for the later epochs of those (their datum comes through
/// the reference epoch, which the prediction does not follow) and without a datum.
fn datum_tilt_of_epoch(
    project: &Project,
    geo: &GeoreferenceInput,
    block: &Georeferenced,
    control: DatumControl,
    epoch: usize,
) -> Option<DatumTiltReport> {
    let single_block = control == DatumControl::WholeBlock;
    let own_only = control == DatumControl::OwnEpoch || epoch == project.reference_epoch.index();
    if block.datum == Datum::Local || !(single_block || own_only) {
        return None;
    }
    let counts = |image: usize| single_block || project.images[image].epoch.index() == epoch;
    let oriented = |image: usize| block.reconstruction.poses[image].is_some();
    let mut heights = Vec::new();
    for point in geo.points.iter().filter(|p| !p.check) {
        let images = point
            .markers
            .iter()
            .filter(|m| counts(m.image) && oriented(m.image))
            .count();
        if images >= 2 {
            heights.push(HeightObservation {
                xy: point.position.xy(),
                sigma_z: point.sigma_z,
                offset: None,
            });
        }
    }
    for prior in geo
        .centre_priors
        .iter()
        .filter(|p| counts(p.image) && oriented(p.image))
    {
        // Weighed as the final adjustment weighed it.
        let sigma_z = prior
            .offset
            .and_then(|o| block.gnss_offsets.get(o))
            .map_or(prior.sigma_z, |o| {
                o.prior_sigma(prior.sigma_xy, prior.sigma_z).1
            });
        heights.push(HeightObservation {
            xy: prior.position.xy(),
            sigma_z,
            offset: prior.offset,
        });
    }
    let offsets: Vec<f64> = geo.prior_offsets.iter().map(|o| o.sigma_z).collect();
    datum_tilt(&heights, &offsets).map(|t| DatumTiltReport {
        sigma_max_mm_per_m: t.sigma_max_mm_per_m,
        sigma_min_mm_per_m: t.sigma_min_mm_per_m,
        loose_azimuth_deg: t.loose_azimuth_deg,
    })
}

fn report(
    project: &Project,
    input: &SfmInput,
    geo: &GeoreferenceInput,
    block: &Georeferenced,
    strategy: &dyn Strategy,
    tiepoints: &[timesift_io::ply::TiePoint],
    seconds: f64,
) -> AlignReport {
    let rec = &block.reconstruction;
    let mut epochs = BTreeMap::new();
    let residuals: Vec<(timesift_core::TrackElement, f64)> = rec.residuals(input).collect();
    let of_block = OrientedBlock {
        project,
        input,
        geo,
        block,
        control: strategy.datum_control(),
        residuals: &residuals,
        tiepoints,
    };
    for (e, epoch) in project.epochs.iter().enumerate() {
        epochs.insert(epoch.name.clone(), epoch_orientation(&of_block, e));
    }
    AlignReport {
        epoch_pairs: epoch_pair_ties(project, tiepoints, block.set_motion_covariance.as_ref()),
        method: strategy.method(),
        datum: format!("{:?}", block.datum),
        images_given: project.images.len(),
        images_oriented: rec.num_oriented(),
        rms_reprojection_px: block.rms_px.is_finite().then_some(block.rms_px),
        tie_points: rec.points.len(),
        inter_epoch_ties_split_as_moved: block.diagnostics.moved_ties_split,
        inter_epoch_ties_split_off_stable: block.diagnostics.unstable_ties_split,
        inter_epoch_ties_joined: block.diagnostics.joined_ties,
        inter_epoch_ties_guided: block.diagnostics.guided_ties,
        changed_regions: block.diagnostics.changed_regions,
        observation_bound_px: block.observation_bound_px,
        group_noise: (0..rec.cameras.len())
            .map(|g| GroupNoise {
                sigma_px: block.group_sigma_px.get(g).copied().flatten(),
                bound_px: block.group_bound_px.get(g).copied(),
            })
            .collect(),
        components_dropped: block.diagnostics.dropped_components,
        gnss_priors_rejected: block.diagnostics.rejected_priors,
        focal_length_held: block.focal_held.clone(),
        cameras: rec
            .cameras
            .iter()
            .map(|c| {
                let mut p = vec![0.0; c.num_params()];
                c.params(&mut p);
                c.param_names()
                    .iter()
                    .map(|n| n.to_string())
                    .zip(p)
                    .collect::<BTreeMap<_, _>>()
            })
            .collect(),
        seconds,
        epochs,
    }
}

/// The oriented block and what the report reads of it.
struct OrientedBlock<'a> {
    project: &'a Project,
    input: &'a SfmInput,
    geo: &'a GeoreferenceInput,
    block: &'a Georeferenced,
    control: DatumControl,
    /// Every observation's reprojection error.
    residuals: &'a [(timesift_core::TrackElement, f64)],
    tiepoints: &'a [timesift_io::ply::TiePoint],
}

/// Epoch `e`'s orientation: its images, reprojection errors, tie points, control and check
/// points, datum tilt and GNSS offset.
fn epoch_orientation(of: &OrientedBlock<'_>, e: usize) -> EpochOrientation {
    let OrientedBlock {
        project,
        input,
        geo,
        block,
        control,
        residuals,
        tiepoints,
    } = *of;
    let rec = &block.reconstruction;
    let epoch = &project.epochs[e];
    let in_epoch = |i: usize| project.images[i].epoch.index() == e;
    let given = epoch.images.len();
    let oriented = epoch
        .images
        .iter()
        .filter(|i| rec.poses[i.index()].is_some())
        .count();
    let errors: Vec<f64> = residuals
        .iter()
        .filter(|(el, _)| in_epoch(el.image.index()))
        .map(|(_, r)| *r)
        .collect();
    let rms = (errors.iter().map(|r| r * r).sum::<f64>() / errors.len() as f64).sqrt();
    let tie = tiepoints.iter().filter(|p| p.epochs.contains(e)).count();
    let inter = tiepoints
        .iter()
        .filter(|p| p.epochs.contains(e) && p.epochs.has_other_than(e))
        .count();
    let per_epoch = if block.datum == Datum::Local {
        Vec::new()
    } else {
        ground_point_residuals(input, rec, geo, &in_epoch)
    };
    EpochOrientation {
        images_given: given,
        images_oriented: oriented,
        rms_reprojection_px: (!errors.is_empty()).then_some(rms),
        observations: errors.len(),
        tie_points: tie,
        inter_epoch_tie_points: inter,
        control_points: residuals_of(&per_epoch, false),
        check_points: residuals_of(&per_epoch, true),
        datum_tilt: datum_tilt_of_epoch(project, geo, block, control, e),
        block_tilt: block
            .set_motion_covariance
            .as_ref()
            .and_then(|c| tilt_of(c, &[(e, 1.0)])),
        gnss_offset: block
            .gnss_offsets
            .iter()
            .find(|o| o.name == epoch.name && o.priors > 0)
            .map(|o| GnssOffset {
                offset: [o.value.x, o.value.y, o.value.z],
                std: o.std,
                priors: o.priors,
                focal_correlation: o.focal_correlation,
                within_flight_sigma_m: o.within_flight_sigma,
                scatter_weighs_priors: o.scatter_weighs_priors,
            }),
    }
}
