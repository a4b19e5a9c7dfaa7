//! `--executor slurm`: the plan's steps as Slurm job arrays over the shared project directory.
//!
//! No server of our own: Slurm schedules, the project directory is the only state, and every
//! task is `timesift task <step> DIR --part i/n`. Per step one batch script
//! (`work/slurm/<step>.sh`, its memory and how it was worked out written in it) and one job
//! array per `MaxArraySize − 1` missing units, each depending on every array of the step
//! before with `afterok` and `--kill-on-invalid-dep=yes`, so that no step runs on a failed
//! one's output. A failed task requeues itself up to `retries` times (`--requeue`,
//! `SLURM_RESTART_COUNT`). The job ids go to `work/slurm/submitted.json`, which `status` reads
//! to ask `squeue` and `sacct` about them.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use serde::{Deserialize, Serialize};

use super::plan::{ClusterPlan, Step};
use super::record::{project_fingerprint, unit_complete};
use crate::config::ClusterConfig;
use crate::{Project, ProjectError};

/// Slurm's default `MaxArraySize`: array task ids run from 0 to 1000.
pub const DEFAULT_MAX_ARRAY_SIZE: usize = 1001;

/// The submission settings (`[cluster]`, overridden by the command line).
#[derive(Debug, Clone, PartialEq)]
pub struct SlurmOptions {
    /// `--partition`.
    pub partition: Option<String>,
    /// `--account`.
    pub account: Option<String>,
    /// `--time`.
    pub time: Option<String>,
    /// `--cpus-per-task`.
    pub cpus_per_task: usize,
    /// The `%N` throttle of every array.
    pub max_array: Option<usize>,
    /// Further `sbatch` arguments.
    pub sbatch_args: Vec<String>,
    /// Requeues of a failed task.
    pub retries: u32,
}

impl SlurmOptions {
    /// The settings of `[cluster]`.
    pub fn from_config(c: &ClusterConfig) -> SlurmOptions {
        SlurmOptions {
            partition: c.partition.clone(),
            account: c.account.clone(),
            time: c.time.clone(),
            cpus_per_task: c.cpus_per_task,
            max_array: c.max_array,
            sbatch_args: c.sbatch_args.clone(),
            retries: c.retries,
        }
    }
}

/// One job array of a step: array task `t` runs unit `offset + t`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SubmittedArray {
    /// Slurm's job id of the array (empty in a dry run).
    pub job: String,
    /// Added to the array task id to give the unit.
    pub offset: usize,
    /// The array task ids submitted.
    pub tasks: Vec<usize>,
}

/// The arrays of one step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SubmittedStep {
    /// The step.
    pub step: String,
    /// Its units (`--part i/units`).
    pub units: usize,
    /// Its arrays (none when every unit was complete).
    pub arrays: Vec<SubmittedArray>,
    /// Memory per task, MiB.
    pub memory_mib: u64,
}

impl SubmittedStep {
    /// The array job and task id that run unit `index`, if it was submitted.
    pub fn job_of(&self, index: usize) -> Option<(String, usize)> {
        self.arrays.iter().find_map(|a| {
            let task = index.checked_sub(a.offset)?;
            a.tasks.contains(&task).then(|| (a.job.clone(), task))
        })
    }
}

/// `work/slurm/submitted.json`: the last submission.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Submission {
    /// The steps, in order.
    pub steps: Vec<SubmittedStep>,
}

impl Submission {
    /// The project's last submission, if any.
    pub fn read(project: &Project) -> Option<Submission> {
        let text = std::fs::read_to_string(submission_file(project)).ok()?;
        serde_json::from_str(&text).ok()
    }

    /// The ids of every array submitted.
    pub fn jobs(&self) -> Vec<String> {
        self.steps
            .iter()
            .flat_map(|s| s.arrays.iter().map(|a| a.job.clone()))
            .filter(|j| !j.is_empty())
            .collect()
    }
}

fn submission_file(project: &Project) -> PathBuf {
    project.layout().slurm_dir().join("submitted.json")
}

fn write_submission(project: &Project, submission: &Submission) -> Result<(), ProjectError> {
    let text = serde_json::to_string_pretty(submission).unwrap_or_default();
    timesift_io::fsutil::write_bytes_atomically(&submission_file(project), text.as_bytes())?;
    Ok(())
}

/// Splits the 1-based `units` to submit into arrays whose task ids stay below
/// `max_array_size`: `(offset, task ids)`, unit = offset + task id.
pub fn arrays_of(units: &[usize], max_array_size: usize) -> Vec<(usize, Vec<usize>)> {
    let block = max_array_size.saturating_sub(1).max(1);
    let mut arrays: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for &u in units {
        let offset = (u - 1) / block * block;
        arrays.entry(offset).or_default().push(u - offset);
    }
    arrays.into_iter().collect()
}

/// Slurm's `--array` value for task ids (runs as ranges), throttled with `%N`.
pub fn array_spec(tasks: &[usize], throttle: Option<usize>) -> String {
    let mut spec = String::new();
    let mut i = 0;
    while i < tasks.len() {
        let mut j = i;
        while j + 1 < tasks.len() && tasks[j + 1] == tasks[j] + 1 {
            j += 1;
        }
        if !spec.is_empty() {
            spec.push(',');
        }
        if j > i {
            let _ = write!(spec, "{}-{}", tasks[i], tasks[j]);
        } else {
            let _ = write!(spec, "{}", tasks[i]);
        }
        i = j + 1;
    }
    if let Some(n) = throttle {
        let _ = write!(spec, "%{n}");
    }
    spec
}

/// Quotes a word for bash.
fn quoted(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// The batch script of a step: its `#SBATCH` settings (memory with its formula), then one
/// unit, requeued on failure up to `retries` times.
pub fn batch_script(
    project_dir: &Path,
    step: &Step,
    units: usize,
    options: &SlurmOptions,
    exe: &Path,
    logs: &Path,
) -> String {
    let mut s = String::from("#!/bin/bash\n");
    let _ = writeln!(
        s,
        "# timesift step {}: {} units of {}",
        step.name, units, step.unit
    );
    let _ = writeln!(s, "# memory per task: {}", step.memory_formula);
    let _ = writeln!(s, "#SBATCH --job-name=timesift-{}", step.name);
    let _ = writeln!(s, "#SBATCH --cpus-per-task={}", options.cpus_per_task);
    let _ = writeln!(s, "#SBATCH --mem={}M", step.memory_mib);
    let _ = writeln!(s, "#SBATCH --requeue");
    // Every attempt's output in the one log: a requeued task would truncate it.
    let _ = writeln!(s, "#SBATCH --open-mode=append");
    let _ = writeln!(
        s,
        "#SBATCH --output={}/{}-%A_%a.log",
        logs.display(),
        step.name
    );
    for (key, value) in [
        ("partition", &options.partition),
        ("account", &options.account),
        ("time", &options.time),
    ] {
        if let Some(v) = value {
            let _ = writeln!(s, "#SBATCH --{key}={v}");
        }
    }
    let _ = writeln!(s, "set -u");
    let _ = writeln!(s, "offset=${{1:-0}}");
    let _ = writeln!(s, "unit=$(( offset + ${{SLURM_ARRAY_TASK_ID:-1}} ))");
    let _ = writeln!(s, "export RAYON_NUM_THREADS=${{SLURM_CPUS_PER_TASK:-1}}");
    let _ = writeln!(
        s,
        "{} -v task {} {} --part \"$unit/{units}\"",
        quoted(&exe.to_string_lossy()),
        quoted(&step.name),
        quoted(&project_dir.to_string_lossy())
    );
    let _ = writeln!(s, "code=$?");
    let _ = writeln!(s, "[ $code -eq 0 ] && exit 0");
    let _ = writeln!(
        s,
        "if [ \"${{SLURM_RESTART_COUNT:-0}}\" -lt {} ]; then",
        options.retries
    );
    let _ = writeln!(
        s,
        "  echo \"timesift: unit $unit/{units} of {} failed (exit $code); requeued, attempt $(( ${{SLURM_RESTART_COUNT:-0}} + 2 ))\" >&2",
        step.name
    );
    let _ = writeln!(
        s,
        "  scontrol requeue \"${{SLURM_ARRAY_JOB_ID:-$SLURM_JOB_ID}}_${{SLURM_ARRAY_TASK_ID:-0}}\" && sleep 60"
    );
    let _ = writeln!(s, "fi");
    let _ = writeln!(s, "exit $code");
    s
}

/// `MaxArraySize` of the cluster `scontrol` talks to, or Slurm's default when it cannot say.
pub fn max_array_size() -> Option<usize> {
    let out = Command::new("scontrol")
        .args(["show", "config"])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    String::from_utf8_lossy(&out.stdout).lines().find_map(|l| {
        let (key, value) = l.split_once('=')?;
        (key.trim() == "MaxArraySize")
            .then(|| value.trim().parse().ok())
            .flatten()
    })
}

/// What a submission (or its dry run) did, for the command's output.
#[derive(Debug, Clone, PartialEq)]
pub struct SubmitReport {
    /// The submission.
    pub submission: Submission,
    /// The table of arrays, tasks, memory and files.
    pub table: String,
}

/// Submits the units of `steps` that are not complete (`dry_run`: only plans them), one job
/// array per `max_array_size − 1` units, each step after the one before.
pub fn submit(
    project: &Project,
    plan: &ClusterPlan,
    steps: &[&Step],
    options: &SlurmOptions,
    max_array_size: usize,
    dry_run: bool,
) -> Result<SubmitReport, ProjectError> {
    let layout = project.layout();
    let slurm_dir = layout.slurm_dir();
    let logs = slurm_dir.join("logs");
    let project_dir =
        std::path::absolute(&project.dir).map_err(|e| timesift_io::IoError::io(&project.dir, e))?;
    let exe = std::env::current_exe().map_err(|e| ProjectError::Stage {
        stage: "run",
        message: format!("cannot find the timesift executable for the batch scripts: {e}"),
    })?;
    if !dry_run {
        refuse_while_queued(project)?;
        std::fs::create_dir_all(&logs).map_err(|e| timesift_io::IoError::io(&logs, e))?;
    }
    let mut table = format!(
        "{:<16} {:>7} {:>7} {:>8} {:>10} {:>5} {:>9}  {}\n",
        "step", "units", "to run", "arrays", "tasks/arr", "cpus", "mem/task", "files"
    );
    let fingerprint = project_fingerprint(project);
    let mut submission = Submission::default();
    let mut previous: Vec<String> = Vec::new();
    // Once a step runs again, the steps after it are submitted whole: a preparing step may
    // remove what their records name (new settings), and a unit still up to date returns at
    // once.
    let mut rerun_from_here = false;
    for step in steps {
        let todo: Vec<usize> = (1..=step.units)
            .filter(|&i| {
                rerun_from_here
                    || !unit_complete(&layout.task_record(&step.name, i, step.units), &fingerprint)
            })
            .collect();
        rerun_from_here |= !todo.is_empty();
        let arrays = arrays_of(&todo, max_array_size);
        let widest = arrays.iter().map(|(_, t)| t.len()).max().unwrap_or(0);
        let _ = writeln!(
            table,
            "{:<16} {:>7} {:>7} {:>8} {:>10} {:>5} {:>7} M  {}",
            step.name,
            step.units,
            todo.len(),
            arrays.len(),
            widest,
            options.cpus_per_task,
            step.memory_mib,
            step.files
        );
        let mut submitted = SubmittedStep {
            step: step.name.clone(),
            units: step.units,
            arrays: Vec::new(),
            memory_mib: step.memory_mib,
        };
        if !todo.is_empty() {
            let script_path = slurm_dir.join(format!("{}.sh", step.name));
            if !dry_run {
                let script = batch_script(&project_dir, step, step.units, options, &exe, &logs);
                timesift_io::fsutil::write_bytes_atomically(&script_path, script.as_bytes())?;
            }
            let mut ids = Vec::new();
            for (offset, tasks) in arrays {
                let job = if dry_run {
                    String::new()
                } else {
                    sbatch(&script_path, offset, &tasks, &previous, options)?
                };
                ids.push(job.clone());
                submitted.arrays.push(SubmittedArray { job, offset, tasks });
                if !dry_run {
                    // Recorded as it goes: after a failed sbatch, the arrays already submitted
                    // are still known to status and to the next submission's check.
                    let mut so_far = submission.clone();
                    so_far.steps.push(submitted.clone());
                    write_submission(project, &so_far)?;
                }
            }
            previous = ids;
        }
        submission.steps.push(submitted);
    }
    for note in &plan.notes {
        let _ = writeln!(table, "note: {note}");
    }
    if !dry_run {
        write_submission(project, &submission)?;
    }
    Ok(SubmitReport { submission, table })
}

/// An error when Slurm still holds tasks of the project's last submission: submitting their
/// units again would run them twice.
pub fn refuse_while_queued(project: &Project) -> Result<(), ProjectError> {
    let Some(last) = Submission::read(project) else {
        return Ok(());
    };
    let jobs = JobStates::query(&last.jobs());
    let held = jobs
        .states
        .values()
        .filter(|s| matches!(s, TaskState::Running | TaskState::Queued))
        .count();
    if held > 0 {
        return Err(ProjectError::Stage {
            stage: "run",
            message: format!(
                "{held} tasks of the last submission (jobs {}) are still queued or running: wait \
                 for them (timesift status) or cancel them (scancel) before submitting again",
                last.jobs().join(", ")
            ),
        });
    }
    Ok(())
}

/// Submits one array; returns its job id.
fn sbatch(
    script: &Path,
    offset: usize,
    tasks: &[usize],
    after: &[String],
    options: &SlurmOptions,
) -> Result<String, ProjectError> {
    let mut cmd = Command::new("sbatch");
    cmd.arg("--parsable")
        .arg(format!("--array={}", array_spec(tasks, options.max_array)));
    if !after.is_empty() {
        cmd.arg(format!("--dependency=afterok:{}", after.join(":")))
            .arg("--kill-on-invalid-dep=yes");
    }
    cmd.args(&options.sbatch_args)
        .arg(script)
        .arg(offset.to_string());
    let out = cmd.output().map_err(|e| ProjectError::Stage {
        stage: "run",
        message: format!("cannot run sbatch (is Slurm installed and on PATH?): {e}"),
    })?;
    if !out.status.success() {
        return Err(ProjectError::Stage {
            stage: "run",
            message: format!(
                "sbatch {} failed: {}",
                script.display(),
                String::from_utf8_lossy(&out.stderr).trim()
            ),
        });
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let id = text.trim().split(';').next().unwrap_or("").to_string();
    if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
        return Err(ProjectError::Stage {
            stage: "run",
            message: format!(
                "sbatch {}: unexpected output \"{}\"",
                script.display(),
                text.trim()
            ),
        });
    }
    Ok(id)
}

/// What Slurm says of an array task it holds or held.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TaskState {
    /// Running now.
    Running,
    /// Waiting: for its dependency, resources or its begin time (also after a requeue).
    Queued,
    /// Its last attempt failed (exit code, time limit, memory, node).
    Failed,
}

/// What Slurm says of the array tasks of a submission: `(array job, task id)` to state.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JobStates {
    states: BTreeMap<(String, usize), TaskState>,
    /// What could not be asked (no `sacct` without Slurm's accounting database: failed tasks
    /// then show as missing).
    pub notes: Vec<String>,
}

impl JobStates {
    /// Asks `sacct` (ended tasks) then `squeue` (queued and running ones, which win) about
    /// `jobs`; tasks neither knows are left out. Without Slurm's commands, knows nothing.
    pub fn query(jobs: &[String]) -> JobStates {
        let mut states = JobStates::default();
        if jobs.is_empty() {
            return states;
        }
        let list = jobs.join(",");
        match Command::new("sacct")
            .args(["-n", "-P", "-X", "--format=JobID,State", "-j", &list])
            .output()
        {
            Ok(out) if out.status.success() => {
                states.add_sacct(&String::from_utf8_lossy(&out.stdout))
            }
            Ok(out) => states.notes.push(format!(
                "sacct: {} (without accounting, failed units show as missing; their logs say why)",
                String::from_utf8_lossy(&out.stderr).trim()
            )),
            Err(e) => states.notes.push(format!("sacct: {e}")),
        }
        if let Ok(out) = Command::new("squeue")
            .args(["-h", "-r", "-o", "%i|%T", "-j", &list])
            .output()
            && out.status.success()
        {
            states.add_squeue(&String::from_utf8_lossy(&out.stdout));
        }
        states
    }

    /// The state of an array task, if Slurm knows it.
    pub fn state(&self, job: &str, task: usize) -> Option<TaskState> {
        self.states.get(&(job.to_string(), task)).copied()
    }

    /// Lines `<job>_<task>|<STATE>` of `sacct -n -P -X --format=JobID,State`: a failure is
    /// failed; a cancellation (`scancel`, or a dependency that can no longer be met) leaves the
    /// unit missing; completed and running ones are left to the records and `squeue`.
    pub fn add_sacct(&mut self, text: &str) {
        for (key, state) in parse_lines(text) {
            let first = state.split_whitespace().next().unwrap_or("");
            let unit = match first {
                "FAILED" | "TIMEOUT" | "OUT_OF_MEMORY" | "NODE_FAIL" | "BOOT_FAIL" | "DEADLINE" => {
                    Some(TaskState::Failed)
                }
                _ => None,
            };
            if let Some(u) = unit {
                self.states.insert(key, u);
            }
        }
    }

    /// Lines `<job>_<task>|<STATE>` of `squeue -h -r -o %i|%T`.
    pub fn add_squeue(&mut self, text: &str) {
        for (key, state) in parse_lines(text) {
            let unit = match state.as_str() {
                "RUNNING" | "COMPLETING" | "CONFIGURING" | "STAGE_OUT" => TaskState::Running,
                "PENDING" | "REQUEUED" | "REQUEUE_HOLD" | "REQUEUE_FED" | "SUSPENDED"
                | "RESV_DEL_HOLD" => TaskState::Queued,
                _ => continue,
            };
            self.states.insert(key, unit);
        }
    }
}

/// `(job, task)` and state of each `<job>_<task>|<STATE>` line (other lines skipped).
fn parse_lines(text: &str) -> Vec<((String, usize), String)> {
    text.lines()
        .filter_map(|line| {
            let (id, state) = line.trim().split_once('|')?;
            let (job, task) = id.split_once('_')?;
            let task = task.parse().ok()?;
            Some(((job.to_string(), task), state.trim().to_string()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arrays_keep_task_ids_below_the_clusters_limit_and_cover_every_unit_once() {
        let units: Vec<usize> = (1..=2500).collect();
        let arrays = arrays_of(&units, 1001);
        assert_eq!(arrays.len(), 3);
        let mut covered = Vec::new();
        for (offset, tasks) in &arrays {
            assert!(tasks.iter().all(|&t| (1..1001).contains(&t)));
            covered.extend(tasks.iter().map(|t| offset + t));
        }
        assert_eq!(covered, units);
        // Only what is missing: units 3 and 1700.
        assert_eq!(
            arrays_of(&[3, 1700], 1001),
            vec![(0, vec![3]), (1000, vec![700])]
        );
    }

    #[test]
    fn a_batch_script_runs_its_unit_with_the_stated_memory_and_requeues_a_bounded_number_of_times()
    {
        let step = Step {
            name: "dense-pass-2".into(),
            stage: crate::stages::Stage::Dense,
            units: 12,
            unit: "8 reference images".into(),
            memory_mib: 1360,
            memory_formula: "512 MiB + maps".into(),
            files: 96,
        };
        let options = SlurmOptions {
            partition: Some("batch".into()),
            account: None,
            time: Some("01:00:00".into()),
            cpus_per_task: 2,
            max_array: Some(4),
            sbatch_args: Vec::new(),
            retries: 3,
        };
        let script = batch_script(
            Path::new("/data/my project"),
            &step,
            12,
            &options,
            Path::new("/opt/timesift"),
            Path::new("/data/my project/work/slurm/logs"),
        );
        for line in [
            "#!/bin/bash",
            "# memory per task: 512 MiB + maps",
            "#SBATCH --mem=1360M",
            "#SBATCH --cpus-per-task=2",
            "#SBATCH --requeue",
            "#SBATCH --partition=batch",
            "#SBATCH --time=01:00:00",
            "unit=$(( offset + ${SLURM_ARRAY_TASK_ID:-1} ))",
            "'/opt/timesift' -v task 'dense-pass-2' '/data/my project' --part \"$unit/12\"",
            "if [ \"${SLURM_RESTART_COUNT:-0}\" -lt 3 ]; then",
        ] {
            assert!(script.lines().any(|l| l == line), "{line}\n{script}");
        }
        assert!(!script.contains("--account"), "{script}");
        assert_eq!(quoted("it's"), "'it'\\''s'");
    }

    #[test]
    fn array_specs_are_ranges_with_the_throttle() {
        assert_eq!(array_spec(&[1, 2, 3, 5, 7, 8], Some(4)), "1-3,5,7-8%4");
        assert_eq!(array_spec(&[9], None), "9");
    }

    #[test]
    fn slurms_states_map_to_units_cancelled_ones_missing() {
        let mut states = JobStates::default();
        states.add_sacct("41_1|COMPLETED\n41_2|CANCELLED by 0\n41_3|FAILED\n41_4|OUT_OF_MEMORY\n");
        states.add_squeue("41_5|RUNNING\n41_6|PENDING\n41_[7-9]|PENDING\n");
        assert_eq!(states.state("41", 1), None);
        assert_eq!(states.state("41", 2), None);
        assert_eq!(states.state("41", 3), Some(TaskState::Failed));
        assert_eq!(states.state("41", 4), Some(TaskState::Failed));
        assert_eq!(states.state("41", 5), Some(TaskState::Running));
        assert_eq!(states.state("41", 6), Some(TaskState::Queued));
        assert_eq!(states.state("41", 7), None);
    }

    #[test]
    fn a_units_job_is_found_through_its_arrays_offset() {
        let step = SubmittedStep {
            step: "features".into(),
            units: 2500,
            arrays: vec![
                SubmittedArray {
                    job: "10".into(),
                    offset: 0,
                    tasks: vec![1, 2],
                },
                SubmittedArray {
                    job: "11".into(),
                    offset: 1000,
                    tasks: vec![700],
                },
            ],
            memory_mib: 1024,
        };
        assert_eq!(step.job_of(2), Some(("10".into(), 2)));
        assert_eq!(step.job_of(1700), Some(("11".into(), 700)));
        assert_eq!(step.job_of(3), None);
    }
}
