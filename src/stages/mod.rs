//! The stages of `timesift run`, in order, behind one abstraction ([`PipelineStage`]: what a
//! stage reads, what it writes, how it runs), and the runner that walks a range of them.
//!
//! Every stage resumes: work files under `work/` record the settings they were made with
//! (`cache`), and a stage skips what is up to date. A failed stage leaves the outputs of
//! earlier stages intact.

mod align;
pub(crate) mod cache;
mod change;
mod dem;
mod dense;
mod features;
mod fiducials;
mod matching;
mod ortho;
mod part;
pub(crate) mod product_styles;
mod qgis_styles;
mod report;

use std::fmt;
use std::path::PathBuf;
use std::time::Instant;

pub use align::align_stage;
pub(crate) use cache::Fnv1a;
pub use change::{change_stable_areas, epoch_pairs, stable_file};
pub use dem::{dem_stage, epoch_ground_sample_distance, georeference, write_dem_files};
pub use dense::{dense_input, dense_inputs, dense_stage, dense_view};
pub use features::{extract_features, features_stage};
pub use fiducials::{FiducialsOutcome, fiducials_stage};
pub(crate) use matching::candidate_pairs;
pub use matching::match_stage;
pub use ortho::ortho_stage;
pub use part::Part;
pub use report::report_stage;

use crate::report::{RunLog, StageRun, read_json, write_json};
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

    /// The implementation of the stage.
    pub fn implementation(self) -> &'static dyn PipelineStage {
        match self {
            Stage::Features => &features::FeaturesStage,
            Stage::Match => &matching::MatchStage,
            Stage::Align => &align::AlignStage,
            Stage::Dense => &dense::DenseStage,
            Stage::Dem => &dem::DemStage,
            Stage::Ortho => &ortho::OrthoStage,
            Stage::Change => &change::ChangeStage,
            Stage::Report => &report::ReportStage,
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

/// What one stage of a run did.
#[derive(Debug, Clone, PartialEq)]
pub struct StageOutcome {
    /// The stage.
    pub stage: Stage,
    /// Its wall time, seconds.
    pub seconds: f64,
    /// Its one-line summary.
    pub summary: String,
}

/// Runs one stage on a validated project: checks its inputs, runs it and records its time and
/// summary in `work/run.json`. A failed stage leaves earlier outputs untouched.
pub fn run_stage(project: &Project, stage: Stage) -> Result<StageOutcome, ProjectError> {
    let imp = stage.implementation();
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
    let start = Instant::now();
    let summary = imp.run(project)?;
    let outcome = StageOutcome {
        stage,
        seconds: start.elapsed().as_secs_f64(),
        summary,
    };
    tracing::info!(stage = stage.name(), "{}", outcome.summary);
    record_run(project, &outcome)?;
    Ok(outcome)
}

/// Runs unit `part` of step `step` of stage `stage` (the cluster plan's split,
/// [`crate::tasks`]); returns the files the unit owns. Steps that are a whole stage run it as
/// `timesift run` would, its inputs checked and its time recorded.
pub(crate) fn run_unit(
    project: &Project,
    stage: Stage,
    step: &str,
    part: Part,
) -> Result<Vec<PathBuf>, ProjectError> {
    let single = |part: Part| {
        if part.count == 1 {
            Ok(())
        } else {
            Err(ProjectError::Stage {
                stage: "task",
                message: format!("step {step} is one unit, not {}", part.count),
            })
        }
    };
    match step {
        "features-prepare" => single(part).and_then(|()| features::prepare(project)),
        "features" => features::unit(project, part),
        "match-prepare" => single(part).and_then(|()| matching::prepare(project)),
        "match" => matching::unit(project, part),
        "match-tracks" => single(part).and_then(|()| matching::finish(project)),
        "dense-prepare" => single(part).and_then(|()| dense::prepare(project)),
        "dense-fuse" => dense::fuse_unit(project, part),
        "dense-report" => single(part).and_then(|()| dense::report_unit(project)),
        "dem-grid" => single(part).and_then(|()| dem::grid_unit(project)),
        "dem" => dem::unit(project, part),
        "ortho-gains" => ortho::gains_unit(project, part),
        "ortho" => ortho::unit(project, part),
        "ortho-merge" => ortho::merge_unit(project, part),
        "ortho-report" => single(part).and_then(|()| ortho::report_unit(project)),
        "change" => change::unit(project, part),
        _ if step.starts_with("dense-pass-") => {
            let k =
                step["dense-pass-".len()..]
                    .parse::<usize>()
                    .map_err(|_| ProjectError::Stage {
                        stage: "task",
                        message: format!("step {step}: expected dense-pass-<k> with a pass number"),
                    })?;
            dense::pass_unit(project, k, part)
        }
        _ if step == stage.name() && matches!(stage, Stage::Align | Stage::Report) => {
            single(part)?;
            run_stage(project, stage)?;
            // A file a later stage rewrites (raster.json: the DEMs', then the orthos' times)
            // is that stage's: this unit's record must not go stale when it does.
            let later: Vec<PathBuf> = Stage::ALL
                .into_iter()
                .filter(|s| *s > stage)
                .flat_map(|s| s.implementation().outputs(project))
                .collect();
            Ok(stage
                .implementation()
                .outputs(project)
                .into_iter()
                .filter(|p| !later.contains(p))
                .collect())
        }
        _ => Err(ProjectError::Stage {
            stage: "task",
            message: format!(
                "unknown step \"{step}\": expected one of the plan `timesift run --executor slurm --dry-run` prints"
            ),
        }),
    }
}

/// Adds a stage's outcome to `work/run.json`.
fn record_run(project: &Project, outcome: &StageOutcome) -> Result<(), ProjectError> {
    let path = project.layout().run_log();
    let mut log: RunLog = read_json(&path).unwrap_or_default();
    log.version = env!("CARGO_PKG_VERSION").to_string();
    log.stages.insert(
        outcome.stage.name().to_string(),
        StageRun {
            seconds: outcome.seconds,
            summary: outcome.summary.clone(),
        },
    );
    write_json(&path, &log)
}

/// Runs the stages from `from` to `to` in order, stopping at the first failure; `on_stage` sees
/// each stage as it finishes (the CLI prints a line).
pub fn run_with(
    project: &Project,
    from: Option<Stage>,
    to: Option<Stage>,
    on_stage: &mut dyn FnMut(&StageOutcome),
) -> Result<Vec<StageOutcome>, ProjectError> {
    let stages = stage_range(from, to)?;
    remove_stale_temporaries(&project.layout().out_dir());
    remove_stale_temporaries(&project.layout().work_dir());
    let mut outcomes = Vec::new();
    for stage in stages {
        tracing::info!(stage = stage.name(), "running stage");
        let outcome = run_stage(project, stage)?;
        on_stage(&outcome);
        outcomes.push(outcome);
    }
    Ok(outcomes)
}

/// Removes the temporary files and folders (`.<name>.tmp-<pid>…`) that a run killed while
/// writing left behind, where the process that wrote them is gone. Where processes cannot be checked (no
/// `/proc`), nothing is removed.
fn remove_stale_temporaries(dir: &std::path::Path) {
    let proc = std::path::Path::new("/proc");
    if !proc.is_dir() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        let stale = timesift_io::fsutil::temporary_owner(&name)
            .is_some_and(|pid| pid != std::process::id() && !proc.join(pid.to_string()).exists());
        match (path.is_dir(), stale) {
            // A folder written as a whole (`write_dir_atomically`), left by a killed run.
            (true, true) => {
                let _ = std::fs::remove_dir_all(&path);
            }
            (true, false) => remove_stale_temporaries(&path),
            (false, true) => {
                let _ = std::fs::remove_file(&path);
            }
            (false, false) => {}
        }
    }
}

/// [`run_with`] without a per-stage callback.
pub fn run(
    project: &Project,
    from: Option<Stage>,
    to: Option<Stage>,
) -> Result<Vec<StageOutcome>, ProjectError> {
    run_with(project, from, to, &mut |_| {})
}
