//! `timesift status`: per step, which units are complete, queued, running, failed or missing,
//! worked out from the completion records and the outputs they list, and from what Slurm says
//! of the last submission's jobs (`squeue` for queued and running, `sacct` for failed), never
//! from status files written at submission.

use std::collections::BTreeMap;

use super::record::{project_fingerprint, unit_complete};
use super::slurm::{JobStates, Submission, TaskState};
use super::{ClusterPlan, Part};
use crate::Project;

/// The state of one unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum UnitState {
    /// Its record is there and its outputs are the ones it wrote.
    Complete,
    /// Slurm runs it now.
    Running,
    /// Slurm holds it, waiting for its dependency or resources (or requeued).
    Queued,
    /// Its last attempt failed (exit code, time limit, memory, node): see its log.
    Failed,
    /// Neither complete nor in Slurm's hands (never submitted, cancelled, or its dependency
    /// failed): the next submission runs it.
    Missing,
}

/// The states of one step's units.
#[derive(Debug, Clone, PartialEq)]
pub struct StepStatus {
    /// The step.
    pub step: String,
    /// Each unit's state, unit `i` (1-based) at `i − 1`.
    pub units: Vec<UnitState>,
}

impl StepStatus {
    /// How many units are in `state`.
    pub fn count(&self, state: UnitState) -> usize {
        self.units.iter().filter(|&&s| s == state).count()
    }

    /// The 1-based indices of the units in `state`.
    pub fn indices(&self, state: UnitState) -> Vec<usize> {
        self.units
            .iter()
            .enumerate()
            .filter(|(_, s)| **s == state)
            .map(|(i, _)| i + 1)
            .collect()
    }
}

/// The status of every step of `plan`: unit counts from the last submission where there is one
/// (the split its records are named by), else from the plan.
pub fn status(
    project: &Project,
    plan: &ClusterPlan,
    submission: Option<&Submission>,
    jobs: &JobStates,
) -> Vec<StepStatus> {
    let layout = project.layout();
    let fingerprint = project_fingerprint(project);
    let submitted: BTreeMap<&str, &super::slurm::SubmittedStep> = submission
        .map(|s| s.steps.iter().map(|st| (st.step.as_str(), st)).collect())
        .unwrap_or_default();
    plan.steps
        .iter()
        .map(|step| {
            let sub = submitted.get(step.name.as_str());
            let count = sub.map_or(step.units, |s| s.units);
            let units = (1..=count)
                .map(|index| {
                    let part = Part { index, count };
                    if unit_complete(
                        &layout.task_record(&step.name, part.index, part.count),
                        &fingerprint,
                    ) {
                        return UnitState::Complete;
                    }
                    sub.and_then(|s| s.job_of(index))
                        .and_then(|(job, task)| jobs.state(&job, task))
                        .map_or(UnitState::Missing, |state| match state {
                            TaskState::Running => UnitState::Running,
                            TaskState::Queued => UnitState::Queued,
                            TaskState::Failed => UnitState::Failed,
                        })
                })
                .collect();
            StepStatus {
                step: step.name.clone(),
                units,
            }
        })
        .collect()
}

/// The status as a table for people.
pub fn status_table(steps: &[StepStatus]) -> String {
    let mut text = format!(
        "{:<16} {:>6} {:>9} {:>7} {:>7} {:>7} {:>7}\n",
        "step", "units", "complete", "running", "queued", "failed", "missing"
    );
    for s in steps {
        text.push_str(&format!(
            "{:<16} {:>6} {:>9} {:>7} {:>7} {:>7} {:>7}",
            s.step,
            s.units.len(),
            s.count(UnitState::Complete),
            s.count(UnitState::Running),
            s.count(UnitState::Queued),
            s.count(UnitState::Failed),
            s.count(UnitState::Missing),
        ));
        let missing = s.indices(UnitState::Missing);
        let failed = s.indices(UnitState::Failed);
        let show = |v: &[usize]| {
            let head: Vec<String> = v.iter().take(8).map(|i| i.to_string()).collect();
            format!(
                "{}{}",
                head.join(","),
                if v.len() > 8 { ",..." } else { "" }
            )
        };
        if !failed.is_empty() {
            text.push_str(&format!("  failed: {}", show(&failed)));
        }
        if !missing.is_empty() && missing.len() < s.units.len() {
            text.push_str(&format!("  missing: {}", show(&missing)));
        }
        text.push('\n');
    }
    text
}
