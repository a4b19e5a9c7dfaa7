//! What the align stage writes: `out/cameras.json`, `out/colmap/`, `out/tiepoints.ply` and
//! `out/report.json` with each epoch's orientation.

use super::motions::EpochMotions;
use super::pairs::{HeldPoint, WorldPoints, epoch_pair_ties, held_points};
use super::*;

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
    // A camera term COLMAP has no model for (a film camera's skew `b2` freed) is left out of
    // the COLMAP copy, said so in the report: cameras.json carries the cameras exactly, and the
    // stages after align read only the tie points from out/colmap/.
    let (model, colmap_terms_dropped) = colmap_model(&file, input, rec, origin)?;
    for dropped in &colmap_terms_dropped {
        tracing::warn!("out/colmap/: {dropped}");
    }
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
    let held: Vec<HeldPoint> = held_points(&block.surface_held, origin);
    let points = WorldPoints {
        tiepoints: &tiepoints,
        held: &held,
    };
    let mut report = report(project, input, geo, block, strategy, &points, seconds);
    report.colmap_terms_dropped = colmap_terms_dropped;
    write_json(&layout.report_json(), &report)?;
    write_stable_found(project, block, origin, &tiepoints)?;
    Ok(report)
}

/// Cell of `out/stable_found.tif`, metres: tie points lie a few metres apart.
const STABLE_FOUND_CELL_M: f64 = 5.0;

/// `out/stable_found.tif` where no stable areas were given, for a block that ties its epochs:
/// 1 in a cell where the block found the ground unchanged — an inter-epoch tie point that
/// survived the moved-point and changed-region tests, or a later epoch's point that met the
/// reference epoch's surface (`Georeferenced::surface_fits`) — and no point of a later epoch
/// missed that surface; 0 elsewhere. Otherwise the file is removed: an earlier run's must not
/// stand for this one's.
fn write_stable_found(
    project: &Project,
    block: &Georeferenced,
    origin: Vector3<f64>,
    tiepoints: &[timesift_io::ply::TiePoint],
) -> Result<(), ProjectError> {
    let path = project.layout().stable_found();
    let given = crate::stages::stable_file(project).is_some();
    // Everything in the world frame.
    let world = |p: &[f64; 2]| [p[0] + origin.x, p[1] + origin.y];
    let fits = &block.surface_fits;
    let unchanged: Vec<[f64; 2]> = fits
        .iter()
        .flat_map(|f| f.unchanged.iter().map(world))
        .chain(
            tiepoints
                .iter()
                .filter(|p| p.epochs.len() >= 2)
                .map(|p| [p.position.x, p.position.y]),
        )
        .collect();
    let changed: Vec<[f64; 2]> = fits
        .iter()
        .flat_map(|f| f.changed.iter().map(world))
        .collect();
    let single_block = matches!(
        project.config.align.method,
        timesift_align::Method::Timesift | timesift_align::Method::Msfm
    );
    if given || !single_block || block.datum == Datum::Local || unchanged.is_empty() {
        if path.is_file() {
            std::fs::remove_file(&path).map_err(|e| timesift_io::IoError::io(&path, e))?;
        }
        return Ok(());
    }
    let crs: timesift_io::coords::Crs = project.config.crs.parse().map_err(|e: String| {
        stage_error(format!(
            "{}: crs = \"{}\": {e}",
            project.layout().project_toml().display(),
            project.config.crs
        ))
    })?;
    let cell = STABLE_FOUND_CELL_M;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in unchanged.iter().chain(&changed) {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let (left, top) = ((lo[0] / cell).floor() * cell, (hi[1] / cell).ceil() * cell);
    let width = (((hi[0] - left) / cell).floor() as usize) + 1;
    let height = (((top - lo[1]) / cell).floor() as usize) + 1;
    let index = |p: &[f64; 2]| {
        let col = ((p[0] - left) / cell).floor() as usize;
        let row = ((top - p[1]) / cell).floor() as usize;
        (row.min(height - 1)) * width + col.min(width - 1)
    };
    // 0 unknown, 1 agreed, 2 missed (wins).
    let mut cells = vec![0u8; width * height];
    for p in &unchanged {
        let c = &mut cells[index(p)];
        *c = (*c).max(1);
    }
    for p in &changed {
        cells[index(p)] = 2;
    }
    let raster = timesift_io::geotiff::GeoRaster {
        width,
        height,
        bands: 1,
        data: cells.into_iter().map(|c| u8::from(c == 1)).collect(),
        georef: timesift_io::geotiff::GeoReference {
            transform: timesift_io::geotiff::GeoTransform {
                origin_x: left,
                origin_y: top,
                pixel_width: cell,
                pixel_height: -cell,
            },
            crs,
            nodata: None,
            pixel_is_point: false,
        },
    };
    timesift_io::geotiff::write_u8(&path, &raster)?;
    timesift_io::qgis::write_qml(&path, &crate::stages::product_styles::stable_found())?;
    Ok(())
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
/// world frame), each with its mean reprojection error, and the camera terms it could not hold
/// ([`timesift_io::colmap::nearest_colmap_camera`]).
fn colmap_model(
    file: &CamerasFile,
    input: &SfmInput,
    rec: &timesift_align::Reconstruction,
    origin: Vector3<f64>,
) -> Result<(timesift_io::colmap::ColmapModel, Vec<String>), ProjectError> {
    let (mut model, dropped) = timesift_io::colmap::from_reconstruction_nearest(file)
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
    Ok((model, dropped))
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

/// How loosely the control an epoch's orientation rests on fixes its datum's tilt
/// ([`timesift_align::datum_tilt`]), by whose control fixes it ([`DatumControl`]): in a single
/// block the control of every epoch, oriented alone (and the reference epoch of the strategies
/// that go through it) its own; `None` for the later epochs of those (their datum comes through
/// the reference epoch, which the prediction does not follow) and without a datum.
///
/// A control point's height counts with its survey σ and the σ its markers' intersection has
/// through the adjusted cameras, combined: a point clicked on 2.7 m film pixels is known to
/// metres in height however well it was surveyed, and the datum rests on it only as far as
/// that (on `synth archival` the survey σ alone predicted 0.16 mm/m where the block's
/// covariance gives 1.6). `intersected`: the control points intersected through the images
/// whose control counts (every image in a single block, else the epoch's), as
/// [`ground_point_residuals`] gives them.
fn datum_tilt_of_epoch(
    project: &Project,
    geo: &GeoreferenceInput,
    block: &Georeferenced,
    control: DatumControl,
    epoch: usize,
    intersected: &[PointResidual],
) -> Option<DatumTiltReport> {
    let single_block = control == DatumControl::WholeBlock;
    let own_only = control == DatumControl::OwnEpoch || epoch == project.reference_epoch.index();
    if block.datum == Datum::Local || !(single_block || own_only) {
        return None;
    }
    let counts = |image: usize| single_block || project.images[image].epoch.index() == epoch;
    let oriented = |image: usize| block.reconstruction.poses[image].is_some();
    let mut heights = Vec::new();
    for (point, residual) in geo.points.iter().zip(intersected) {
        if point.check || residual.images < 2 {
            continue;
        }
        let markers_z = residual.markers_sigma.map_or(0.0, |s| s.z);
        heights.push(HeightObservation {
            xy: point.position.xy(),
            sigma_z: point.sigma_z.hypot(markers_z),
            offset: None,
        });
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
    // A reference DEM holds the whole block's tilt through its heights.
    heights.extend(block.dem_heights.iter().map(|h| HeightObservation {
        xy: nalgebra::Vector2::from(h.at),
        sigma_z: h.sigma,
        offset: None,
    }));
    let offsets: Vec<f64> = geo.prior_offsets.iter().map(|o| o.sigma_z).collect();
    datum_tilt(&heights, &offsets).map(|t| DatumTiltReport {
        sigma_max_mm_per_m: t.sigma_max_mm_per_m,
        sigma_min_mm_per_m: t.sigma_min_mm_per_m,
        loose_azimuth_deg: t.loose_azimuth_deg,
        sigma_height_m: t.sigma_height_m,
    })
}

fn report(
    project: &Project,
    input: &SfmInput,
    geo: &GeoreferenceInput,
    block: &Georeferenced,
    strategy: &dyn Strategy,
    points: &WorldPoints<'_>,
    seconds: f64,
) -> AlignReport {
    let tiepoints = points.tiepoints;
    let rec = &block.reconstruction;
    let mut epochs = BTreeMap::new();
    let residuals: Vec<(timesift_core::TrackElement, f64)> = rec.residuals(input).collect();
    let motions = EpochMotions::of(block, project.reference_epoch.index(), project.epochs.len());
    // A single block's datum rests on every epoch's control: intersected once, through all.
    let control = strategy.datum_control();
    let whole_block = match control == DatumControl::WholeBlock && block.datum != Datum::Local {
        true => ground_point_residuals(input, rec, geo, &|_| true),
        false => Vec::new(),
    };
    let of_block = OrientedBlock {
        project,
        input,
        geo,
        block,
        control,
        residuals: &residuals,
        tiepoints,
        motions: motions.as_ref(),
        whole_block: &whole_block,
    };
    for (e, epoch) in project.epochs.iter().enumerate() {
        epochs.insert(epoch.name.clone(), epoch_orientation(&of_block, e));
    }
    let epoch_pairs = epoch_pair_ties(project, tiepoints, points.held, motions.as_ref());
    let not_co_registered = match strategy.method() {
        timesift_align::Method::Timesift | timesift_align::Method::Msfm => {
            super::checks::not_co_registered(project, &epoch_pairs)
        }
        _ => Vec::new(),
    };
    AlignReport {
        epoch_pairs,
        not_co_registered,
        control_points_rejected: block.rejected_control.clone(),
        method: strategy.method(),
        datum: format!("{:?}", block.datum),
        images_given: project.images.len(),
        images_oriented: rec.num_oriented(),
        rms_reprojection_px: block.rms_px.is_finite().then_some(block.rms_px),
        tie_points: rec.points.len(),
        mapper: Some(
            match block.diagnostics.mapper {
                Mapper::Incremental | Mapper::Auto => "incremental",
                Mapper::Global => "global",
            }
            .to_string(),
        ),
        inter_epoch_ties_split_as_moved: block.diagnostics.moved_ties_split,
        inter_epoch_ties_split_off_stable: block.diagnostics.unstable_ties_split,
        inter_epoch_ties_joined: block.diagnostics.joined_ties,
        inter_epoch_ties_guided: block.diagnostics.guided_ties,
        changed_regions: block.diagnostics.changed_regions,
        surface_heights: block.diagnostics.surface_heights,
        reference_dem: block
            .fits_against_dem
            .then_some(project.config.align.reference_dem.as_ref())
            .flatten()
            .map(|p| p.display().to_string()),
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
        colmap_terms_dropped: Vec::new(),
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
    /// The epochs' rigid motions as the block holds them, when it has their covariance.
    motions: Option<&'a EpochMotions<'a>>,
    /// A single block's control points intersected through every image (empty otherwise).
    whole_block: &'a [PointResidual],
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
        motions,
        whole_block,
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
        datum_tilt: datum_tilt_of_epoch(
            project,
            geo,
            block,
            control,
            e,
            match control {
                DatumControl::WholeBlock => whole_block,
                _ => &per_epoch,
            },
        ),
        block_tilt: motions.and_then(|m| m.epoch(e)),
        surface_fit: block
            .surface_fits
            .iter()
            .find(|f| f.epoch == e)
            .map(|f| surface_fit_report(f, points_held_in(block, e))),
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

/// How many of epoch `e`'s points the final adjustment held to the surface its fit is against:
/// the reference DEM's heights, or the reference epoch's.
fn points_held_in(block: &Georeferenced, e: usize) -> usize {
    let held = match block.fits_against_dem {
        true => &block.dem_heights,
        false => &block.surface_held,
    };
    held.iter().filter(|h| h.epoch == e).count()
}

/// An epoch's surface fit in the report's units, with how many of its points were held.
fn surface_fit_report(
    f: &timesift_align::SurfaceFit,
    points_held: usize,
) -> crate::report::SurfaceFitReport {
    use crate::report::Term;
    let (tilt, tilt_sigma) = f.tilt_mm_per_m();
    let term = |value: f64, sigma: f64, unit: f64| Term {
        value: value * unit,
        sigma: sigma * unit,
    };
    crate::report::SurfaceFitReport {
        points_compared: f.compared,
        points_kept: f.kept,
        points_held,
        sigma_m: f.sigma,
        offset_m: term(f.plane[0], f.plane_std[0], 1.0),
        slope_east_mm_per_m: term(f.plane[1], f.plane_std[1], 1e3),
        slope_north_mm_per_m: term(f.plane[2], f.plane_std[2], 1e3),
        tilt_mm_per_m: Term {
            value: tilt,
            sigma: tilt_sigma,
        },
        // m per m², times (100 m)², in mm.
        dome_mm_at_100m: f.dome.map(|(v, s)| term(v, s, 1e4 * 1e3)),
        height_scale_mm_per_m: f.height_scale.map(|(v, s)| term(v, s, 1e3)),
    }
}
