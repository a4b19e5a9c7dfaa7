//! The dense stage timed as a separate process, so that its CPU time and peak memory are its
//! own: `xtask run-dense DIR` (this build's stage) or `timesift run DIR --from dense --to dense`
//! of another build (the before of a before/after table), on a given number of threads.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};

/// Which build runs the stage.
#[derive(Debug, Clone)]
pub enum DenseBinary {
    /// This xtask's own `run-dense` (the working tree's code).
    This,
    /// A `timesift` executable of another build.
    Timesift(PathBuf),
}

/// What one run of the dense stage cost.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct DenseRun {
    /// Rayon threads.
    pub threads: usize,
    /// Wall seconds.
    pub wall: f64,
    /// User + system CPU seconds of the process.
    pub cpu: f64,
    /// Peak resident memory, MiB.
    pub peak_mib: f64,
}

/// Runs the dense stage of the project in `dir` from scratch (its depth maps and clouds
/// removed first) with `threads` rayon threads.
pub fn time_dense(binary: &DenseBinary, dir: &Path, threads: usize) -> anyhow::Result<DenseRun> {
    let _ = std::fs::remove_dir_all(dir.join("work/dense"));
    let _ = std::fs::remove_dir_all(dir.join("out/epochs"));
    let _ = std::fs::remove_file(dir.join("out/dense.json"));
    resume_dense(binary, dir, threads)
}

/// Runs the dense stage of the project in `dir` as a user's rerun does: the depth maps its
/// settings still allow are kept, so a changed filtering or fusion option redoes only the cloud.
pub fn resume_dense(binary: &DenseBinary, dir: &Path, threads: usize) -> anyhow::Result<DenseRun> {
    let mut command = match binary {
        DenseBinary::This => {
            let mut c = Command::new(std::env::current_exe()?);
            c.arg("run-dense").arg(dir);
            c
        }
        DenseBinary::Timesift(exe) => {
            let mut c = Command::new(exe);
            c.args(["run", "-q", "--from", "dense", "--to", "dense"])
                .arg(dir);
            c
        }
    };
    command.env("RAYON_NUM_THREADS", threads.to_string());
    time_command(&mut command, threads)
}

/// Runs a command to its end: its wall and CPU seconds and peak resident memory (`threads` as
/// the caller asked it to use).
pub fn time_command(command: &mut Command, threads: usize) -> anyhow::Result<DenseRun> {
    match time_command_within(command, threads, None)? {
        (run, false) => Ok(run),
        (_, true) => bail!("{command:?} was killed"),
    }
}

/// [`time_command`], the command killed (SIGKILL) once it has run `limit`: what it cost up to
/// then and whether it was killed.
pub fn time_command_within(
    command: &mut Command,
    threads: usize,
    limit: Option<std::time::Duration>,
) -> anyhow::Result<(DenseRun, bool)> {
    let start = Instant::now();
    let child = command
        .spawn()
        .with_context(|| format!("starting {command:?}"))?;
    let deadline = limit.map(|l| start + l);
    let (status, usage, peak_kib, killed) = wait_with_usage(child.id(), deadline)?;
    let wall = start.elapsed().as_secs_f64();
    if status != 0 && !killed {
        bail!("{command:?} failed (wait status {status})");
    }
    let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    let run = DenseRun {
        threads,
        wall,
        cpu: seconds(usage.ru_utime) + seconds(usage.ru_stime),
        peak_mib: peak_kib as f64 / 1024.0,
    };
    Ok((run, killed))
}

/// Waits for the child `pid`; its wait status, resource usage and peak resident memory (KiB).
///
/// The peak is the child's `VmHWM`, read every 50 ms while it runs: `ru_maxrss` will not do, as
/// a child's starts from its parent's peak when forked and exec keeps it (this bench's process
/// holds scenes and clouds of hundreds of MiB).
///
/// Past `deadline` the child is killed (SIGKILL); the last value says so.
fn wait_with_usage(
    pid: u32,
    deadline: Option<Instant>,
) -> anyhow::Result<(i32, libc::rusage, u64, bool)> {
    let status_file = format!("/proc/{pid}/status");
    let mut peak_kib = 0;
    let mut killed = false;
    loop {
        if !killed && deadline.is_some_and(|d| Instant::now() > d) {
            // SAFETY: pid is our own child, not reaped yet, so the id names it.
            unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) };
            killed = true;
        }
        if let Some(kib) = std::fs::read_to_string(&status_file)
            .ok()
            .and_then(|s| vm_hwm_kib(&s))
        {
            peak_kib = peak_kib.max(kib);
        }
        let mut status = 0;
        // SAFETY: rusage is plain data, zero is a valid value; wait4 fills it for our own child.
        let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
        // SAFETY: pointers to live locals; pid is a child this process spawned and has not reaped.
        let reaped =
            unsafe { libc::wait4(pid as libc::pid_t, &mut status, libc::WNOHANG, &mut usage) };
        if reaped == pid as libc::pid_t {
            return Ok((status, usage, peak_kib, killed));
        }
        if reaped != 0 {
            bail!(
                "wait4 for a timed command: {}",
                std::io::Error::last_os_error()
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

/// The `VmHWM` line of a `/proc/<pid>/status` text, KiB.
fn vm_hwm_kib(status: &str) -> Option<u64> {
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}
