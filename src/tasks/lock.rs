//! The project lock: one `timesift run` (local, or submitting to a cluster) per project at a
//! time. An OS file lock (`flock` on `work/lock`), so the kernel releases it when its holder
//! exits however it exits: a killed run leaves no stale lock to clean up. The file's text names
//! the holder for the message the next one gets. Cluster tasks of different units never take
//! it: they never write the same file.

use std::fs::{File, TryLockError};
use std::io::Write as _;
use std::path::Path;

use crate::{Project, ProjectError};

/// The held lock; released when dropped (or when the process ends).
#[derive(Debug)]
pub struct ProjectLock {
    _file: File,
}

impl ProjectLock {
    /// Takes the project's lock for `what` (e.g. "timesift run"), or fails at once naming the
    /// process that holds it.
    pub fn acquire(project: &Project, what: &str) -> Result<ProjectLock, ProjectError> {
        Self::acquire_at(&project.layout().lock_file(), what)
    }

    /// [`ProjectLock::acquire`] on a lock file.
    pub fn acquire_at(path: &Path, what: &str) -> Result<ProjectLock, ProjectError> {
        let io = |e| ProjectError::Io(timesift_io::IoError::io(path, e));
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|e| timesift_io::IoError::io(parent, e))?;
        }
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .map_err(io)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let holder = std::fs::read_to_string(path).unwrap_or_default();
                let holder = holder.trim();
                return Err(ProjectError::Path {
                    path: path.to_path_buf(),
                    message: format!(
                        "the project is in use by {}; wait for it to finish or stop it",
                        if holder.is_empty() {
                            "another process"
                        } else {
                            holder
                        }
                    ),
                });
            }
            Err(TryLockError::Error(e)) => {
                return Err(ProjectError::Path {
                    path: path.to_path_buf(),
                    message: format!(
                        "cannot lock it ({e}); the file system must support file locks (flock), \
                         as local disks and NFSv4 do"
                    ),
                });
            }
        }
        let host = super::record::host_name().unwrap_or_else(|| "this machine".into());
        let started = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        file.set_len(0).map_err(io)?;
        write!(
            file,
            "{what} (pid {} on {host}, started at Unix time {started})",
            std::process::id()
        )
        .map_err(io)?;
        Ok(ProjectLock { _file: file })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_holder_is_refused_with_the_first_named_and_a_released_lock_is_free() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("work/lock");
        let first = ProjectLock::acquire_at(&path, "timesift run").unwrap();
        let e = ProjectLock::acquire_at(&path, "timesift run")
            .unwrap_err()
            .to_string();
        assert!(e.contains("in use by timesift run (pid"), "{e}");
        assert!(e.contains(&std::process::id().to_string()), "{e}");
        drop(first);
        ProjectLock::acquire_at(&path, "timesift run").unwrap();
    }
}
