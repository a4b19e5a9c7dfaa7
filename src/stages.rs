//! The stages of `timesift run`, in order, and the runner that walks a range of them.

use std::fmt;

use crate::{Project, ProjectError};

/// A stage of the pipeline, in execution order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, clap::ValueEnum)]
pub enum Stage {
    /// Keypoints and descriptors per image.
    Features,
    /// Pair selection, matching, geometric verification, tracks.
    Match,
    /// Orientation of the block by the chosen strategy.
    Align,
    /// Dense clouds per epoch.
    Dense,
    /// DEM per epoch.
    Dem,
    /// Orthomosaic per epoch.
    Ortho,
    /// Change products between epochs.
    Change,
    /// report.json and report.html.
    Report,
}

impl Stage {
    /// All stages in order.
    pub const ALL: [Stage; 8] = [
        Stage::Features,
        Stage::Match,
        Stage::Align,
        Stage::Dense,
        Stage::Dem,
        Stage::Ortho,
        Stage::Change,
        Stage::Report,
    ];

    /// The stage's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Features => "features",
            Stage::Match => "match",
            Stage::Align => "align",
            Stage::Dense => "dense",
            Stage::Dem => "dem",
            Stage::Ortho => "ortho",
            Stage::Change => "change",
            Stage::Report => "report",
        }
    }
}

impl fmt::Display for Stage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The stages from `from` to `to` inclusive (defaults: first and last).
pub fn stage_range(from: Option<Stage>, to: Option<Stage>) -> Result<Vec<Stage>, ProjectError> {
    let from = from.unwrap_or(Stage::Features);
    let to = to.unwrap_or(Stage::Report);
    if from > to {
        return Err(ProjectError::StageRange {
            from: from.name(),
            to: to.name(),
        });
    }
    Ok(Stage::ALL
        .into_iter()
        .filter(|s| *s >= from && *s <= to)
        .collect())
}

/// Runs one stage on a validated project. Stages whose crates are not built yet fail with
/// [`ProjectError::StageNotAvailable`], leaving earlier outputs untouched.
pub fn run_stage(project: &Project, stage: Stage) -> Result<(), ProjectError> {
    match stage {
        Stage::Features => {
            crate::matching_stages::features_stage(project)?;
            Ok(())
        }
        Stage::Match => {
            let summary = crate::matching_stages::match_stage(project)?;
            tracing::info!(%summary, "match stage done");
            Ok(())
        }
        Stage::Align => {
            let report = crate::align_stage::align_stage(project)?;
            tracing::info!(
                oriented = %report["images_oriented"],
                rms_px = %report["rms_reprojection_px"],
                "align stage done"
            );
            Ok(())
        }
        Stage::Change => {
            for dir in crate::compare::change_stage(project)? {
                tracing::info!(out = %dir.display(), "change products written");
            }
            Ok(())
        }
        other => Err(ProjectError::StageNotAvailable(other.name())),
    }
}

/// Runs the stages from `from` to `to` in order, stopping at the first failure.
pub fn run(project: &Project, from: Option<Stage>, to: Option<Stage>) -> Result<(), ProjectError> {
    for stage in stage_range(from, to)? {
        tracing::info!(stage = stage.name(), "running stage");
        run_stage(project, stage)?;
    }
    Ok(())
}
