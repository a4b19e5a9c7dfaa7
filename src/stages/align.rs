//! The `align` stage of `timesift run`: tracks from the verified matches under `work/`, incremental
//! structure from motion, georeferencing from GNSS priors and control points, then the outputs
//! of docs/design.md: `out/cameras.json`, `out/colmap/`, `out/tiepoints.ply` and `out/report.json`.
//!
//! The orientation runs in a local frame: the project CRS minus an origin (the mean of the priors
//! and control points, whole metres) so that solvers never see UTM-sized coordinates; the origin
//! is added back when writing.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;
use timesift_align::{
    Block, CentrePrior, ChangeDetection, Datum, DatumControl, FocalSource, GeoreferenceInput,
    Georeferenced, GroundPoint, HeightObservation, Marker, NaturalPoint, OffsetPrior, OutlierBound,
    PointResidual, ScatterWeighing, SfmImage, SfmInput, SfmOptions, StableGround, Strategy,
    datum_tilt, ground_point_residuals,
};
use timesift_core::{BrownCamera, Camera, CameraModel, ImageId, Pose};
use timesift_io::cameras_json::{OrientedImage, Reconstruction as CamerasFile};
use timesift_matching::storage::{read_features, read_matches};
use timesift_matching::tracks::{PairMatches, build_tracks};

use super::{PipelineStage, Stage};
use crate::config::{GnssOffsets, InterEpochTies, OutlierBoundConfig, WeighByScatter};
use crate::film::ImageSource;
use crate::layout::Layout;
use crate::project::GivenFocal;
use crate::report::{
    AlignReport, DatumTiltReport, EpochOrientation, GnssOffset, GroupNoise,
    PointResidual as ResidualRow, PointResiduals, Rmse, read_json, write_json,
};
use crate::stable_matcher::FeatureFileMatcher;
use crate::{Project, ProjectError};

/// The `align` stage.
pub(super) struct AlignStage;

impl PipelineStage for AlignStage {
    fn stage(&self) -> Stage {
        Stage::Align
    }
    fn inputs(&self, project: &Project) -> Vec<(PathBuf, Stage)> {
        let layout = project.layout();
        (0..project.images.len())
            .map(|i| (layout.feature_file(i), Stage::Features))
            .chain(std::iter::once((layout.matches_dir(), Stage::Match)))
            .collect()
    }
    fn outputs(&self, project: &Project) -> Vec<PathBuf> {
        let layout = project.layout();
        vec![
            layout.cameras_json(),
            layout.colmap_dir(),
            layout.tiepoints_ply(),
            layout.report_json(),
        ]
    }
    fn run(&self, project: &Project) -> Result<String, ProjectError> {
        let layout = project.layout();
        let settings = align_settings(project);
        let record = layout.align_settings();
        let up_to_date = read_json::<serde_json::Value>(&record).ok().as_ref() == Some(&settings)
            && self.outputs(project).iter().all(|p| p.exists());
        let report = match up_to_date {
            true => read_json::<AlignReport>(&layout.report_json())?,
            false => {
                let report = align_stage(project)?;
                write_json(&record, &settings)?;
                report
            }
        };
        Ok(format!(
            "{}{} of {} images oriented, RMS {:.3} px",
            if up_to_date { "up to date: " } else { "" },
            report.images_oriented,
            report.images_given,
            report.rms_reprojection_px.unwrap_or(f64::NAN)
        ))
    }
}

/// What the orientation is made from: the match files' contents, the images, the ground data
/// and the settings that steer it. Recorded in `work/align.json` after a run, so an unchanged
/// project is not oriented again.
fn align_settings(project: &Project) -> serde_json::Value {
    let layout = project.layout();
    let mut matches: Vec<PathBuf> = std::fs::read_dir(layout.matches_dir())
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    matches.sort();
    let features: Vec<PathBuf> = (0..project.images.len())
        .map(|i| layout.feature_file(i))
        .collect();
    let c = &project.config;
    serde_json::json!({
        "matches": super::cache::content_fingerprint(&matches),
        "features": features.iter().map(|f| super::cache::file_stamp(f)).collect::<Vec<_>>(),
        "images": project.images.iter().map(|i| &i.name).collect::<Vec<_>>(),
        "config": format!("{:?}", (&c.crs, &c.epochs, &c.inputs, &c.gnss, &c.align, &c.cameras)),
        "ground": format!("{:?}", (&project.gcps, &project.checkpoints, &project.markers, &project.stable_points,
            &project.gnss, &project.stable_areas, &project.scale_bars, &project.calibrations)),
    })
}

/// Default standard deviations of control points that give none (m): RTK GNSS or total station.
const DEFAULT_GCP_SIGMA: (f64, f64) = (0.02, 0.03);

/// Focal length of a camera without EXIF focal length, in units of its longer side (COLMAP's
/// default prior).
const DEFAULT_FOCAL_FACTOR: f64 = 1.2;

fn stage_error(message: String) -> ProjectError {
    ProjectError::Stage {
        stage: "align",
        message,
    }
}

/// Orients the block by the configured strategy and writes the outputs. Returns the report.
pub fn align_stage(project: &Project) -> Result<AlignReport, ProjectError> {
    let start = Instant::now();
    let source = ImageSource::of(project)?;
    let input = load_input(project, &source)?;
    let frame = LocalFrame::of(project)?;
    let (geo, natural_points) = ground_input(project, &frame, &source)?;
    let mut options = SfmOptions {
        tie_point_sigma_px: project.config.align.tie_point_accuracy_px,
        change_detection: match project.config.align.inter_epoch_ties {
            InterEpochTies::Auto => ChangeDetection::Regional,
            InterEpochTies::Stable | InterEpochTies::All => ChangeDetection::MovedPointsOnly,
        },
        outlier_bound: match project.config.align.outlier_bound {
            OutlierBoundConfig::Group => OutlierBound::PerGroup,
            OutlierBoundConfig::Pooled => OutlierBound::Pooled,
        },
        scatter_weighing: match project.config.gnss.weigh_by_scatter {
            WeighByScatter::Controlled => ScatterWeighing::Controlled,
            WeighByScatter::All => ScatterWeighing::All,
            WeighByScatter::NoFlight => ScatterWeighing::NoFlight,
        },
        join_epoch_ties: project.config.align.join_epoch_ties,
        ..SfmOptions::default()
    };
    options.self_calibration.min_images = 3;
    tracing::debug!(cameras = ?input.cameras, "initial cameras");
    let matcher = FeatureFileMatcher {
        features_dir: project.layout().features_dir(),
        seed: options.seed,
    };
    let strategy = timesift_align::strategy(project.config.align.method, &matcher);
    let block_input = Block {
        sfm: input,
        ground: geo,
        epoch_of: project.images.iter().map(|im| im.epoch.index()).collect(),
        epoch_names: project.epochs.iter().map(|e| e.name.clone()).collect(),
        reference: project.reference_epoch.index(),
        stable_ground: stable_ground(project, &frame)?,
        natural_points,
    };
    let block = strategy
        .orient(&block_input, &options)
        .map_err(|e| stage_error(e.to_string()))?;
    let (input, geo) = (&block_input.sfm, &block_input.ground);
    write_outputs(
        project,
        input,
        geo,
        &frame,
        &block,
        &*strategy,
        start.elapsed().as_secs_f64(),
    )
}

/// Cells of the stable-ground grid along the longer side of the stable areas' extent (0.3 m on
/// a 300 m site): finer than the areas are drawn, coarser than a tie point is placed.
const STABLE_CELLS_PER_SIDE: f64 = 1000.0;

/// The stable areas as a grid in the block's local frame, when `inter_epoch_ties = "stable"`
/// and the project has some.
fn stable_ground(
    project: &Project,
    frame: &LocalFrame,
) -> Result<Option<StableGround>, ProjectError> {
    if project.config.align.inter_epoch_ties == InterEpochTies::All
        || project.stable_areas.is_empty()
    {
        return Ok(None);
    }
    let polygons: Vec<&timesift_io::wkt::Polygon> = project
        .stable_areas
        .iter()
        .flat_map(|a| &a.polygons)
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in polygons.iter().flat_map(|p| &p.exterior) {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    if !(extent > 0.0) {
        return Err(stage_error(
            "the stable areas enclose no ground: inter_epoch_ties = \"stable\" needs polygons \
             with an area (or set it to \"all\")"
                .into(),
        ));
    }
    let cell = extent / STABLE_CELLS_PER_SIDE;
    let width = ((hi[0] - lo[0]) / cell).ceil().max(1.0) as usize;
    let height = ((hi[1] - lo[1]) / cell).ceil().max(1.0) as usize;
    let (ox, oy) = (frame.origin.x, frame.origin.y);
    let ground = StableGround::rasterise([lo[0] - ox, lo[1] - oy], cell, width, height, |x, y| {
        polygons.iter().any(|p| p.contains(x + ox, y + oy))
    })
    .map_err(|e| stage_error(e.to_string()))?;
    tracing::info!(
        cell,
        stable = ground.stable_fraction(),
        "inter-epoch ties only on the stable areas"
    );
    Ok(Some(ground))
}

/// Keypoints of every image, tracks over every verified pair, initial cameras per group.
fn load_input(project: &Project, source: &ImageSource) -> Result<SfmInput, ProjectError> {
    let n = project.images.len();
    let keypoints = (0..n)
        .into_par_iter()
        .map(|i| {
            let path = project.layout().feature_file(i);
            read_features(&path)
                .map(|(k, _)| k.iter().map(|k| Vector2::new(k.x, k.y)).collect::<Vec<_>>())
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| stage_error(format!("{e} (run the features and match stages first)")))?;
    let pairs = match_files(&project.layout().matches_dir())?;
    if pairs.is_empty() {
        return Err(stage_error(format!(
            "{}: no match files (run the match stage first)",
            project.layout().matches_dir().display()
        )));
    }
    let verified = pairs
        .par_iter()
        .map(|(a, b, path)| {
            read_matches(path).map(|matches| PairMatches {
                a: ImageId::from(*a),
                b: ImageId::from(*b),
                matches,
            })
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| stage_error(e.to_string()))?;
    let verified: Vec<PairMatches> = verified
        .into_iter()
        .filter(|p| !p.matches.is_empty() && p.a.index() < n && p.b.index() < n)
        .collect();
    let counts: Vec<usize> = keypoints.iter().map(Vec::len).collect();
    let tracks = build_tracks(&counts, &verified).map_err(|e| stage_error(e.to_string()))?;
    // One camera per group, from the first image of the group's first epoch.
    let mut group_index: BTreeMap<String, usize> = BTreeMap::new();
    let mut cameras = Vec::new();
    let mut focal = Vec::new();
    let mut group_of_epoch = Vec::new();
    for epoch in &project.epochs {
        let g = match group_index.get(&epoch.camera_group) {
            Some(&g) => g,
            None => {
                let first =
                    epoch.images.first().copied().ok_or_else(|| {
                        stage_error(format!("epoch \"{}\" has no image", epoch.name))
                    })?;
                let given = project.calibrations.get(&epoch.camera_group);
                let size = source.dimensions(project, first.index())?;
                let (camera, focal_source) =
                    initial_camera(&project.image_path(first), size, given)?;
                cameras.push(camera);
                focal.push(focal_source);
                group_index.insert(epoch.camera_group.clone(), cameras.len() - 1);
                cameras.len() - 1
            }
        };
        group_of_epoch.push(g);
    }
    let images = project
        .images
        .iter()
        .zip(keypoints)
        .map(|(im, keypoints)| SfmImage {
            group: group_of_epoch[im.epoch.index()],
            keypoints,
        })
        .collect();
    Ok(SfmInput {
        cameras,
        images,
        tracks: tracks.tracks,
        focal,
    })
}

/// `work/matches/<a>_<b>.match` files, sorted.
fn match_files(dir: &Path) -> Result<Vec<(usize, usize, PathBuf)>, ProjectError> {
    let entries = std::fs::read_dir(dir).map_err(|e| {
        stage_error(format!(
            "{}: {e} (run the match stage first)",
            dir.display()
        ))
    })?;
    let mut files = Vec::new();
    for entry in entries.flatten() {
        let path = entry.path();
        if let Some((a, b)) = Layout::match_file_pair(&path) {
            files.push((a, b, path));
        }
    }
    files.sort();
    Ok(files)
}

/// A distortion-free `brown` camera of the image's size as the stages see it (a scan: its
/// camera's frame) with the given focal length and principal point (a certificate's), the EXIF
/// focal length (known), or the default focal length (a guess).
fn initial_camera(
    path: &Path,
    (w, h): (u32, u32),
    given: Option<&GivenFocal>,
) -> Result<(Camera, FocalSource), ProjectError> {
    let (f, source) = match given {
        Some(g) if g.adjust => (g.focal_px, FocalSource::Nominal),
        Some(g) => (g.focal_px, FocalSource::Calibrated),
        None => match timesift_io::exif::read_exif(path)
            .ok()
            .and_then(|e| e.focal_length_px(w, h))
        {
            Some(f) => (f, FocalSource::Nominal),
            None => (DEFAULT_FOCAL_FACTOR * w.max(h) as f64, FocalSource::Guessed),
        },
    };
    let mut camera =
        BrownCamera::new(w, h, f).map_err(|e| stage_error(format!("{}: {e}", path.display())))?;
    if let Some((cx, cy)) = given.and_then(|g| g.principal_point) {
        camera.cx = cx;
        camera.cy = cy;
    }
    Ok((Camera::Brown(camera), source))
}

/// The local frame: project CRS minus `origin`.
struct LocalFrame {
    origin: Vector3<f64>,
    priors: Vec<Option<crate::project::CameraPrior>>,
}

impl LocalFrame {
    fn of(project: &Project) -> Result<Self, ProjectError> {
        let priors = project.camera_priors()?;
        let positions: Vec<Vector3<f64>> = priors
            .iter()
            .flatten()
            .map(|p| p.position)
            .chain(project.gcps.iter().map(|g| g.position))
            .collect();
        let origin = if positions.is_empty() {
            Vector3::zeros()
        } else {
            let mean = positions.iter().sum::<Vector3<f64>>() / positions.len() as f64;
            mean.map(f64::round)
        };
        Ok(LocalFrame { origin, priors })
    }

    /// `cam_from_world` in the project CRS from `cam_from_local`.
    fn world_pose(&self, pose: &Pose) -> Pose {
        Pose::new(
            pose.rotation,
            pose.translation - pose.rotation * self.origin,
        )
    }
}

/// GNSS priors, control points (markers of the reference epoch only unless
/// `gcps_in_all_epochs`) and check points, in the local frame; and the natural stable points
/// (their markers in every epoch).
fn ground_input(
    project: &Project,
    frame: &LocalFrame,
    source: &ImageSource,
) -> Result<(GeoreferenceInput, Vec<NaturalPoint>), ProjectError> {
    let index_of: BTreeMap<&str, usize> = project
        .images
        .iter()
        .enumerate()
        .map(|(i, im)| (im.name.as_str(), i))
        .collect();
    let reference = project.reference_epoch;
    let markers_of = |name: &str, control: bool| -> Vec<Marker> {
        project
            .markers
            .iter()
            .filter(|m| m.name == name)
            .filter_map(|m| {
                let image = *index_of.get(m.image.as_str())?;
                let in_reference = project.images[image].epoch == reference;
                (!control || in_reference || project.config.align.gcps_in_all_epochs).then_some(
                    Marker {
                        image,
                        // Measured on the file: a scan's marker moves to the camera's frame.
                        pixel: source.stage_pixel(image, &m.pixel),
                    },
                )
            })
            .collect()
    };
    let mut points = Vec::new();
    for (list, check) in [(&project.gcps, false), (&project.checkpoints, true)] {
        for g in list {
            let (sxy, sz) = g.sigma.unwrap_or(DEFAULT_GCP_SIGMA);
            points.push(GroundPoint {
                name: g.name.clone(),
                position: g.position - frame.origin,
                sigma_xy: sxy,
                sigma_z: sz,
                check,
                markers: markers_of(&g.name, !check),
                marker_sigma_px: None,
            });
        }
    }
    // One GNSS offset per epoch with priors, its prior σ the epoch's mean stated accuracy.
    let mut prior_offsets = Vec::new();
    let mut offset_of_epoch = vec![None; project.epochs.len()];
    if project.config.gnss.offsets == GnssOffsets::Epoch {
        for (e, epoch) in project.epochs.iter().enumerate() {
            let stated: Vec<(f64, f64)> = epoch
                .images
                .iter()
                .filter_map(|i| frame.priors[i.index()].as_ref().map(|p| (p.sxy, p.sz)))
                .collect();
            if stated.is_empty() {
                continue;
            }
            let n = stated.len() as f64;
            offset_of_epoch[e] = Some(prior_offsets.len());
            prior_offsets.push(OffsetPrior {
                name: epoch.name.clone(),
                sigma_xy: stated.iter().map(|s| s.0).sum::<f64>() / n,
                sigma_z: stated.iter().map(|s| s.1).sum::<f64>() / n,
            });
        }
    }
    let centre_priors = frame
        .priors
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            p.as_ref().map(|p| CentrePrior {
                image: i,
                position: p.position - frame.origin,
                sigma_xy: p.sxy,
                sigma_z: p.sz,
                offset: offset_of_epoch[project.images[i].epoch.index()],
            })
        })
        .collect();
    let natural_points = project
        .stable_points
        .iter()
        .map(|s| NaturalPoint {
            name: s.name.clone(),
            stability: s.sigma,
            markers: markers_of(&s.name, false),
        })
        .collect();
    Ok((
        GeoreferenceInput {
            centre_priors,
            prior_offsets,
            points,
            marker_sigma_px: project.config.align.marker_accuracy_px,
        },
        natural_points,
    ))
}

fn write_outputs(
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
                .fold(0u32, |m, e| m | 1u32 << (epoch_of[e.image.index()] % 32)),
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
/// principal horizontal axes of every tie point.
fn epoch_pair_ties(
    project: &Project,
    tiepoints: &[timesift_io::ply::TiePoint],
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
    for a in 0..project.epochs.len().min(32) {
        for b in a + 1..project.epochs.len().min(32) {
            let both = (1u32 << a) | (1u32 << b);
            let shared: Vec<Vector2<f64>> = tiepoints
                .iter()
                .filter(|p| p.epochs & both == both)
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
            });
        }
    }
    pairs
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
        epoch_pairs: epoch_pair_ties(project, tiepoints),
        method: strategy.method(),
        datum: format!("{:?}", block.datum),
        images_given: project.images.len(),
        images_oriented: rec.num_oriented(),
        rms_reprojection_px: block.rms_px.is_finite().then_some(block.rms_px),
        tie_points: rec.points.len(),
        inter_epoch_ties_split_as_moved: block.diagnostics.moved_ties_split,
        inter_epoch_ties_split_off_stable: block.diagnostics.unstable_ties_split,
        inter_epoch_ties_joined: block.diagnostics.joined_ties,
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
    let bit = 1u32 << (e % 32);
    let tie = tiepoints.iter().filter(|p| p.epochs & bit != 0).count();
    let inter = tiepoints
        .iter()
        .filter(|p| p.epochs & bit != 0 && p.epochs & !bit != 0)
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
