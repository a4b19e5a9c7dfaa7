//! Units of work: how every stage splits into independent tasks, the same for every executor.
//!
//! A stage is a sequence of **steps**; a step is `units` independent **units** that may run in
//! any order, on any machine, at the same time; a step starts when every unit of the step
//! before it is complete. `timesift task <step> DIR --part i/n` runs one unit as a plain
//! command, which is all a cluster scheduler needs (`slurm`). The contract every unit keeps:
//! - it writes its outputs atomically (a temporary name, then a rename) and never a file that
//!   another unit of any step writes;
//! - it writes its completion record (`work/tasks/<step>/<i>-of-<n>.json`, the size and time
//!   of each output) after its outputs, so a record names only finished files;
//! - it skips itself when its record is there and its outputs are still what the record says,
//!   and is otherwise simply run again: a failed, killed or pre-empted unit leaves at most
//!   temporaries no reader accepts.
//!
//! The local executor (`timesift run`) runs each stage's steps in the same order in one
//! process, a step's whole list as one unit with rayon inside it: the same functions on a
//! coarser split. Units are deterministic, so the split does not change a product's bits.

mod lock;
mod plan;
mod record;
pub mod slurm;
mod status;

use std::path::PathBuf;

pub use crate::stages::Part;
pub use lock::ProjectLock;
pub use plan::{ClusterPlan, ImageSizes, PlanOptions, Step, cluster_plan};
pub use record::{OutputStamp, UnitRecord, project_fingerprint, unit_complete};
pub use status::{StepStatus, UnitState, status, status_table};

use crate::stages::Stage;
use crate::{Project, ProjectError};

/// What running a unit did.
#[derive(Debug, Clone, PartialEq)]
pub enum UnitOutcome {
    /// It ran and wrote its outputs and record.
    Ran {
        /// The files it owns.
        outputs: Vec<PathBuf>,
        /// Wall seconds.
        seconds: f64,
    },
    /// Its record was there and its outputs unchanged: nothing was done.
    AlreadyComplete,
}

/// Runs unit `part` of step `step` of the project's cluster plan (`timesift task`): skips it
/// when its completion record is valid, otherwise runs it and writes the record after its
/// outputs.
pub fn run_task(project: &Project, step: &str, part: Part) -> Result<UnitOutcome, ProjectError> {
    let stage = step_stage(step)?;
    let layout = project.layout();
    let record_path = layout.task_record(step, part.index, part.count);
    let fingerprint = project_fingerprint(project);
    if unit_complete(&record_path, &fingerprint) {
        return Ok(UnitOutcome::AlreadyComplete);
    }
    let start = std::time::Instant::now();
    let mut outputs = crate::stages::run_unit(project, stage, step, part)?;
    // What a unit may write but need not (a film project's fiducial sheets, say).
    outputs.retain(|p| p.exists());
    let seconds = start.elapsed().as_secs_f64();
    UnitRecord::of(step, part, &outputs, seconds, &fingerprint).write(&record_path)?;
    Ok(UnitOutcome::Ran { outputs, seconds })
}

/// The stage a step belongs to: its name up to the first `-` (`dense-pass-3` is `dense`'s).
pub fn step_stage(step: &str) -> Result<Stage, ProjectError> {
    let head = step.split('-').next().unwrap_or(step);
    Stage::ALL
        .into_iter()
        .find(|s| s.name() == head)
        .ok_or_else(|| ProjectError::Stage {
            stage: "task",
            message: format!(
                "unknown step \"{step}\": expected a step of `timesift run --executor slurm --dry-run`'s plan \
                 (features, match, dense-pass-0, ...)"
            ),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_belong_to_the_stage_their_name_starts_with() {
        assert_eq!(step_stage("dense-pass-3").unwrap(), Stage::Dense);
        assert_eq!(step_stage("match").unwrap(), Stage::Match);
        let e = step_stage("densify").unwrap_err().to_string();
        assert!(e.contains("densify"), "{e}");
    }
}
