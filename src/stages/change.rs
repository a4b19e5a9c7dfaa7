//! The `change` stage: DEM of difference and M3C2 of every pair of epochs (`[change] pairs`),
//! through the same comparisons as `timesift compare`.

use std::path::PathBuf;

use super::{PipelineStage, Stage};
use crate::{Project, ProjectError};

/// The `change` stage.
pub(super) struct ChangeStage;

impl PipelineStage for ChangeStage {
    fn stage(&self) -> Stage {
        Stage::Change
    }
    fn inputs(&self, _: &Project) -> Vec<(PathBuf, Stage)> {
        // Either the DEMs or the dense clouds of a pair are enough; the stage checks.
        Vec::new()
    }
    fn outputs(&self, project: &Project) -> Vec<PathBuf> {
        let names: Vec<&str> = project.epochs.iter().map(|e| e.name.as_str()).collect();
        names
            .windows(2)
            .map(|w| project.layout().change_dir(w[0], w[1]))
            .collect()
    }
    fn run(&self, project: &Project) -> Result<String, ProjectError> {
        let dirs = crate::commands::compare::change_stage(project)?;
        Ok(format!(
            "change products of {} epoch pairs written",
            dirs.len()
        ))
    }
}
