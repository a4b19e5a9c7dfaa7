//! Completion records: `work/tasks/<step>/<i>-of-<n>.json`, written after a unit's outputs.
//!
//! A record lists each output with its size and modification time, so a unit counts as complete
//! only while its files are still the ones it wrote: a later settings change that removes or
//! rewrites them (a stage's cache check) makes the unit missing again without anyone deleting
//! records. A record also names the project's inputs it was made from (a fingerprint of
//! `project.toml` and the files beside it): after an edit every unit counts as missing, and the
//! next submission runs them all, each finding through its stage's own caches what is still up
//! to date.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::Part;
use crate::ProjectError;

/// This machine's name (`HOSTNAME`, else `/etc/hostname`): where a unit ran, who holds a lock.
pub(super) fn host_name() -> Option<String> {
    std::env::var("HOSTNAME")
        .ok()
        .or_else(|| std::fs::read_to_string("/etc/hostname").ok())
        .map(|h| h.trim().to_string())
}

/// Files larger than this enter [`project_fingerprint`] by size and time, not content.
const LARGEST_HASHED: u64 = 16 << 20;

/// One output of a unit as it was when the unit finished.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OutputStamp {
    /// The file.
    pub path: PathBuf,
    /// Its length, bytes.
    pub bytes: u64,
    /// Its modification time, nanoseconds since the Unix epoch.
    pub modified_ns: u128,
}

impl OutputStamp {
    /// The file's stamp now (`None` when it does not exist).
    fn of(path: &Path) -> Option<OutputStamp> {
        let meta = std::fs::metadata(path).ok()?;
        let modified_ns = meta
            .modified()
            .ok()?
            .duration_since(std::time::UNIX_EPOCH)
            .ok()?
            .as_nanos();
        Some(OutputStamp {
            path: path.to_path_buf(),
            bytes: meta.len(),
            modified_ns,
        })
    }
}

/// The completion record of one unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnitRecord {
    /// The step.
    pub step: String,
    /// `i/n`.
    pub part: String,
    /// Its outputs, as written.
    pub outputs: Vec<OutputStamp>,
    /// Wall seconds it took.
    pub seconds: f64,
    /// Where it ran (`HOSTNAME`, and the Slurm job when there is one).
    pub ran_on: String,
    /// The project's inputs it was made from ([`project_fingerprint`]).
    pub project: String,
}

/// A fingerprint of `project.toml` and every other file directly in the project directory (the
/// CSV and area inputs; of a file over 16 MiB, such as a reference DEM, its size and time):
/// what a completion record was made from.
pub fn project_fingerprint(project: &crate::Project) -> String {
    let mut files: Vec<PathBuf> = std::fs::read_dir(&project.dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    let mut hash = crate::stages::Fnv1a::new();
    for f in &files {
        hash.write(
            f.file_name()
                .map(|n| n.as_encoded_bytes())
                .unwrap_or_default(),
        );
        match std::fs::metadata(f) {
            Ok(meta) if meta.len() > LARGEST_HASHED => {
                let modified = meta
                    .modified()
                    .ok()
                    .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                    .map_or(0, |d| d.as_nanos());
                hash.write(&meta.len().to_le_bytes());
                hash.write(&modified.to_le_bytes());
            }
            _ => hash.write(&std::fs::read(f).unwrap_or_default()),
        }
    }
    hash.hex()
}

impl UnitRecord {
    /// The record of a unit that has just written `outputs` (files that do not exist, such as
    /// a product a unit legitimately skips, are left out).
    pub fn of(
        step: &str,
        part: Part,
        outputs: &[PathBuf],
        seconds: f64,
        project: &str,
    ) -> UnitRecord {
        let host = host_name().unwrap_or_default();
        let job = std::env::var("SLURM_JOB_ID")
            .map(|id| format!(" job {id}"))
            .unwrap_or_default();
        UnitRecord {
            step: step.to_string(),
            part: part.to_string(),
            outputs: outputs.iter().filter_map(|p| OutputStamp::of(p)).collect(),
            seconds,
            ran_on: format!("{host}{job} pid {}", std::process::id()),
            project: project.to_string(),
        }
    }

    /// Writes it atomically.
    pub fn write(&self, path: &Path) -> Result<(), ProjectError> {
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|e| timesift_io::IoError::io(parent, e))?;
        }
        crate::report::write_sealed_json(path, self)
    }

    /// The record at `path`, if it is there and readable.
    pub fn read(path: &Path) -> Option<UnitRecord> {
        crate::report::read_sealed_json(path).ok()
    }
}

/// Whether the unit whose record is at `path` is complete: the record is there, made from the
/// project's inputs as they are (`project`, [`project_fingerprint`]), and every file it lists
/// is still the one it wrote.
pub fn unit_complete(path: &Path, project: &str) -> bool {
    UnitRecord::read(path).is_some_and(|record| {
        record.project == project
            && record
                .outputs
                .iter()
                .all(|o| OutputStamp::of(&o.path).as_ref() == Some(o))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_unit_is_complete_only_while_its_outputs_are_the_ones_it_wrote() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("a.bin");
        std::fs::write(&out, b"abc").unwrap();
        let record = dir.path().join("tasks/x/1-of-2.json");
        assert!(!unit_complete(&record, "p1"), "no record yet");
        UnitRecord::of(
            "x",
            Part::new(1, 2).unwrap(),
            std::slice::from_ref(&out),
            0.5,
            "p1",
        )
        .write(&record)
        .unwrap();
        assert!(unit_complete(&record, "p1"));
        // The project's inputs were edited since.
        assert!(!unit_complete(&record, "p2"));
        // Rewritten with other bytes (a settings change redid it, or another run's file).
        std::fs::write(&out, b"abcd").unwrap();
        assert!(!unit_complete(&record, "p1"));
        std::fs::remove_file(&out).unwrap();
        assert!(!unit_complete(&record, "p1"));
        // A truncated record (a kill while it was written would leave a temporary, but a
        // damaged file must not count either).
        std::fs::write(&record, b"{\"step\": ").unwrap();
        assert!(!unit_complete(&record, "p1"));
    }
}
