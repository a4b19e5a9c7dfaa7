//! The stages of `timesift run`, in order, behind one abstraction ([`PipelineStage`]: what a
//! stage reads, what it writes, how it runs), and the runner that walks a range of them.
//!
//! Every stage resumes: work files under `work/` record the settings they were made with
//! ([`cache`]), and a stage skips what is up to date. A failed stage leaves the outputs of
//! earlier stages intact.

mod align;
mod cache;
mod change;
mod dem;
mod dense;
mod features;
mod matching;
mod ortho;

use std::fmt;
use std::io::IsTerminal;
use std::path::PathBuf;

use indicatif::{ProgressBar, ProgressStyle};

pub use align::align_stage;
pub use dem::{dem_stage, epoch_ground_sample_distance, georeference, write_dem_files};
pub use dense::{dense_input, dense_inputs, dense_stage};
pub use features::features_stage;
pub use matching::match_stage;
pub use ortho::ortho_stage;

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

    /// The implementation of the stage; `None` for stages not built yet.
    pub fn implementation(self) -> Option<&'static dyn PipelineStage> {
        match self {
            Stage::Features => Some(&features::FeaturesStage),
            Stage::Match => Some(&matching::MatchStage),
            Stage::Align => Some(&align::AlignStage),
            Stage::Dense => Some(&dense::DenseStage),
            Stage::Dem => Some(&dem::DemStage),
            Stage::Ortho => Some(&ortho::OrthoStage),
            Stage::Change => Some(&change::ChangeStage),
            Stage::Report => None,
        }
    }
}

impl fmt::Display for Stage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One stage of `timesift run`.
pub trait PipelineStage: Sync {
    /// Which stage this is.
    fn stage(&self) -> Stage;
    /// Files of earlier stages it reads; the runner checks them before running, so a missing
    /// one is an error naming it and the stage that makes it.
    fn inputs(&self, project: &Project) -> Vec<(PathBuf, Stage)>;
    /// The products it writes (under `out/`).
    fn outputs(&self, project: &Project) -> Vec<PathBuf>;
    /// Runs it (resuming from its cache); returns a one-line summary for the log.
    fn run(&self, project: &Project) -> Result<String, ProjectError>;
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

/// A progress bar for one epoch of a stage on a terminal (hidden otherwise): `what` names the
/// unit counted.
pub(crate) fn progress_bar(stage: &str, epoch: &str, total: u64, what: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total);
    if let Ok(style) = ProgressStyle::with_template(&format!(
        "{{prefix}} [{{bar:30}}] {{pos}}/{{len}} {what}, {{eta}} left"
    )) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_prefix(format!("{stage} {epoch}"));
    bar
}

/// Runs one stage on a validated project. Stages not built yet fail with
/// [`ProjectError::StageNotAvailable`], leaving earlier outputs untouched.
pub fn run_stage(project: &Project, stage: Stage) -> Result<(), ProjectError> {
    let imp = stage
        .implementation()
        .ok_or(ProjectError::StageNotAvailable(stage.name()))?;
    if let Some((path, maker)) = imp.inputs(project).into_iter().find(|(p, _)| !p.exists()) {
        return Err(ProjectError::Path {
            path,
            message: format!(
                "missing; stage {} reads it (run the {} stage first)",
                stage.name(),
                maker.name()
            ),
        });
    }
    let summary = imp.run(project)?;
    tracing::info!(stage = stage.name(), "{summary}");
    Ok(())
}

/// Runs the stages from `from` to `to` in order, stopping at the first failure.
pub fn run(project: &Project, from: Option<Stage>, to: Option<Stage>) -> Result<(), ProjectError> {
    for stage in stage_range(from, to)? {
        tracing::info!(stage = stage.name(), "running stage");
        run_stage(project, stage)?;
    }
    Ok(())
}
