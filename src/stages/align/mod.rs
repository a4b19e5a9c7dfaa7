//! The `align` stage of `timesift run`: tracks from the verified matches under `work/`, incremental
//! structure from motion, georeferencing from GNSS priors and control points, then the outputs
//! of docs/design.md: `out/cameras.json`, `out/colmap/`, `out/tiepoints.ply` and `out/report.json`.
//!
//! The orientation runs in a local frame: the project CRS minus an origin (the mean of the priors
//! and control points, whole metres) so that solvers never see UTM-sized coordinates; the origin
//! is added back when writing.

mod checks;
mod input;
mod motions;
mod outputs;
mod pairs;
mod reference_dem;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;
use timesift_align::{
    Block, CentrePrior, ChangeDetection, Datum, DatumControl, FocalSource, GeoreferenceInput,
    Georeferenced, GroundPoint, HeightObservation, Mapper, Marker, NaturalPoint, OffsetPrior,
    OutlierBound, PointResidual, ScatterWeighing, SfmImage, SfmInput, SfmOptions, StableGround,
    Strategy, datum_tilt, ground_point_residuals,
};
use timesift_core::{BrownCamera, Camera, CameraModel, ImageId, Pose};
use timesift_io::cameras_json::{OrientedImage, Reconstruction as CamerasFile};
use timesift_matching::storage::{read_features, read_matches};
use timesift_matching::tracks::{PairMatches, build_tracks};

use super::{PipelineStage, Stage};
use crate::config::{
    GnssOffsets, InterEpochTies, MapperConfig, OutlierBoundConfig, WeighByScatter,
};
use crate::film::ImageSource;
use crate::layout::Layout;
use crate::project::GivenFocal;
use crate::report::{
    AlignReport, DatumTiltReport, EpochOrientation, GnssOffset, GroupNoise,
    PointResidual as ResidualRow, PointResiduals, Rmse, read_json, read_sealed_json, write_json,
    write_sealed_json,
};
use crate::stable_matcher::FeatureFileMatcher;
use crate::{Project, ProjectError};
use input::{LocalFrame, ground_input, load_input, stable_ground};
use outputs::write_outputs;

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
        let up_to_date = read_sealed_json::<serde_json::Value>(&record).ok().as_ref()
            == Some(&settings)
            && self.outputs(project).iter().all(|p| p.exists());
        let report = match up_to_date {
            true => read_json::<AlignReport>(&layout.report_json())?,
            false => {
                let report = align_stage(project)?;
                write_sealed_json(&record, &settings)?;
                report
            }
        };
        let mut summary = format!(
            "{}{} of {} images oriented, RMS {:.3} px",
            if up_to_date { "up to date: " } else { "" },
            report.images_oriented,
            report.images_given,
            report.rms_reprojection_px.unwrap_or(f64::NAN)
        );
        if !report.control_points_rejected.is_empty() {
            summary.push_str(&format!(
                "; control points left out (their markers miss them by far more than their σ, \
                 see out/report.json): {}",
                report.control_points_rejected.join(", ")
            ));
        }
        for name in &report.not_co_registered {
            summary.push_str(&format!(
                "; epoch {name} NOT co-registered (fewer than {} tie points with the others: \
                 it rests on its own priors and control)",
                crate::report::MIN_CO_REGISTERING_TIES
            ));
        }
        Ok(summary)
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
        "reference_dem": c.align.reference_dem.as_ref().map(|p| super::cache::file_stamp(&project.dir.join(p))),
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

/// The intrinsics every camera model of the project has, by name.
const INTRINSIC_NAMES: [&str; 11] = [
    "f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2",
];

/// `[align] self_calibration`: the final adjustments' list as given, for every camera group
/// with 3 oriented images or more (the user asked for it: no larger group size is waited for);
/// the growing block's the part of it among f, k1, k2 (the principal point and decentring need
/// the whole block).
fn self_calibration(
    project: &Project,
    names: &[String],
) -> Result<timesift_align::SelfCalibration, ProjectError> {
    if let Some(bad) = names
        .iter()
        .find(|n| !INTRINSIC_NAMES.contains(&n.as_str()))
    {
        return Err(stage_error(format!(
            "{}: [align] self_calibration names \"{bad}\"; expected some of {}",
            project.layout().project_toml().display(),
            INTRINSIC_NAMES.join(", ")
        )));
    }
    Ok(timesift_align::SelfCalibration {
        parameters: names
            .iter()
            .filter(|n| ["f", "k1", "k2"].contains(&n.as_str()))
            .cloned()
            .collect(),
        final_parameters: names.to_vec(),
        min_images: 3,
        final_min_images: 3,
        held: Vec::new(),
    })
}

/// Orients the block by the configured strategy and writes the outputs. Returns the report.
pub fn align_stage(project: &Project) -> Result<AlignReport, ProjectError> {
    let start = Instant::now();
    let source = ImageSource::of(project)?;
    let input = load_input(project, &source)?;
    let frame = LocalFrame::of(project)?;
    let (mut geo, natural_points) = ground_input(project, &frame, &source)?;
    geo.reference_dem = reference_dem::reference_dem(project, &frame)?;
    let single_block = matches!(
        project.config.align.method,
        timesift_align::Method::Timesift | timesift_align::Method::Msfm
    );
    if geo.reference_dem.is_some() && !single_block {
        return Err(stage_error(format!(
            "[align] reference_dem is used by the single-block methods (timesift, msfm), not by \
             method = \"{}\"",
            project.config.align.method
        )));
    }
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
        guided_epoch_ties: project.config.align.guided_epoch_ties,
        surface_ties: project.config.align.surface_ties,
        mapper: match project.config.align.mapper {
            MapperConfig::Auto => Mapper::Auto,
            MapperConfig::Incremental => Mapper::Incremental,
            MapperConfig::Global => Mapper::Global,
        },
        ..SfmOptions::default()
    };
    options.self_calibration.min_images = 3;
    if let Some(names) = &project.config.align.self_calibration {
        options.self_calibration = self_calibration(project, names)?;
    }
    options.self_calibration.held = input::group_names(project)
        .iter()
        .map(
            |g| match project.calibrations.get(g).and_then(|c| c.radial) {
                Some(_) => vec!["k1".into(), "k2".into(), "k3".into()],
                None => Vec::new(),
            },
        )
        .collect();
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
        .map_err(|e| stage_error(align_error_text(project, &e)))?;
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

/// An orientation error in the project's words: images by their paths, not their indices.
fn align_error_text(project: &Project, error: &timesift_align::AlignError) -> String {
    error.to_string_naming(&|i| {
        project
            .images
            .get(i)
            .map_or_else(|| format!("image {i}"), |im| im.name.clone())
    })
}
