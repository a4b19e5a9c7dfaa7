//! `cargo xtask fuzz`: every reader fuzzed for a while, and a table of what happened.
//!
//! With a nightly toolchain and cargo-fuzz installed, each target of `fuzz/` runs under
//! libFuzzer (coverage-guided) from a working copy of its committed corpus; inputs that add
//! coverage are merged back into `fuzz/corpus/<target>/` afterwards. Without them, the stable
//! fallback (`timesift_fuzz::campaign`: truncation at every offset, bit flips, chunk
//! replacement) runs each target in a child process of this program, under an address-space
//! limit, and counts the same way. Findings land in `fuzz/artifacts/<target>/`; once fixed, the
//! minimised input moves to `fuzz/regressions/<target>/`, which the replay test reads.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use timesift_fuzz::Target;
use timesift_fuzz::campaign::{self, HANG_EXIT, Summary};

/// How much memory a fuzzed reader may take (libFuzzer's `-rss_limit_mb`, the fallback's
/// address-space limit): no input of a few kilobytes justifies more.
const MEMORY_LIMIT_MB: u64 = 2048;

/// Inputs longer than this are not tried (libFuzzer's `-max_len`).
const MAX_INPUT_LEN: usize = 64 * 1024;

/// What `cargo xtask fuzz` was asked.
#[derive(Debug, Clone)]
pub struct FuzzOptions {
    /// Minutes per target.
    pub minutes: f64,
    /// Targets to run (all when empty).
    pub targets: Vec<String>,
    /// Write the seed corpus before fuzzing.
    pub seed: bool,
    /// Use the stable fallback even where libFuzzer is available.
    pub stable: bool,
    /// Targets run at once.
    pub jobs: usize,
}

/// One target's line of the table.
#[derive(Debug, Clone)]
struct Row {
    target: Target,
    engine: &'static str,
    seconds: f64,
    executions: u64,
    corpus: usize,
    crashes: usize,
    hangs: usize,
    ooms: usize,
}

fn fuzz_dir() -> PathBuf {
    crate::api::workspace_root().join("fuzz")
}

fn targets_of(names: &[String]) -> Result<Vec<Target>> {
    if names.is_empty() {
        return Ok(Target::ALL.to_vec());
    }
    names
        .iter()
        .map(|n| {
            Target::from_name(n).with_context(|| {
                let all: Vec<&str> = Target::ALL.iter().map(|t| t.name()).collect();
                format!("no fuzz target \"{n}\"; the targets are {}", all.join(", "))
            })
        })
        .collect()
}

/// Whether libFuzzer can run here: a nightly toolchain and cargo-fuzz.
fn libfuzzer_available() -> Result<(), String> {
    let ok = |cmd: &mut Command| cmd.output().is_ok_and(|o| o.status.success());
    if !ok(Command::new("rustup").args(["run", "nightly", "rustc", "--version"])) {
        return Err("no nightly toolchain (rustup toolchain install nightly)".into());
    }
    if !ok(Command::new("cargo").args(["fuzz", "--version"])) {
        return Err("no cargo-fuzz (cargo install cargo-fuzz)".into());
    }
    Ok(())
}

/// `cargo xtask fuzz`.
pub fn run(options: &FuzzOptions) -> Result<()> {
    let targets = targets_of(&options.targets)?;
    if options.seed {
        write_seeds(&targets)?;
    }
    let engine = if options.stable {
        Err("--stable".to_string())
    } else {
        libfuzzer_available()
    };
    let duration = Duration::from_secs_f64(options.minutes * 60.0);
    let rows = match engine {
        Ok(()) => {
            build_libfuzzer_targets()?;
            in_parallel(&targets, options.jobs, |t| libfuzzer(t, duration))?
        }
        Err(why) => {
            println!(
                "libFuzzer not used: {why}; the stable fallback (seeded mutation) runs instead"
            );
            in_parallel(&targets, options.jobs, |t| stable(t, duration))?
        }
    };
    print_table(&rows);
    let findings: usize = rows.iter().map(|r| r.crashes + r.hangs + r.ooms).sum();
    if findings > 0 {
        bail!("{findings} finding(s): inputs under fuzz/artifacts/<target>/");
    }
    Ok(())
}

/// Runs `f` on every target, `jobs` at a time, rows in the targets' order.
fn in_parallel(
    targets: &[Target],
    jobs: usize,
    f: impl Fn(Target) -> Result<Row> + Sync,
) -> Result<Vec<Row>> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let rows = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..jobs.max(1) {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                    let Some(&t) = targets.get(i) else { break };
                    let row = f(t);
                    if let Ok(mut rows) = rows.lock() {
                        rows.push((i, row));
                    }
                }
            });
        }
    });
    let mut rows = rows
        .into_inner()
        .map_err(|_| anyhow::anyhow!("a fuzz job panicked"))?;
    rows.sort_by_key(|(i, _)| *i);
    rows.into_iter().map(|(_, r)| r).collect()
}

/// Writes the seeds of `targets` into `fuzz/corpus/<target>/seed-<name>`.
fn write_seeds(targets: &[Target]) -> Result<()> {
    let root = crate::api::workspace_root();
    let shared = root.join("../shared/data");
    let scratch = tempfile::tempdir()?;
    for &t in targets {
        let dir = fuzz_dir().join("corpus").join(t.name());
        std::fs::create_dir_all(&dir)?;
        let seeds = timesift_fuzz::seeds::seeds(t, &root, &shared, scratch.path())
            .map_err(|e| anyhow::anyhow!("seeds of {t}: {e}"))?;
        for (name, bytes) in seeds {
            std::fs::write(dir.join(format!("seed-{name}")), bytes)?;
        }
    }
    Ok(())
}

fn count_files(dir: &Path) -> usize {
    std::fs::read_dir(dir).map_or(0, |d| d.filter(|e| e.is_ok()).count())
}

fn build_libfuzzer_targets() -> Result<()> {
    let status = Command::new("cargo")
        .args([
            "+nightly",
            "fuzz",
            "build",
            "--release",
            "--debug-assertions",
        ])
        .current_dir(crate::api::workspace_root())
        .status()
        .context("cannot run cargo fuzz build")?;
    if !status.success() {
        bail!("cargo fuzz build failed ({status})");
    }
    Ok(())
}

/// One target under libFuzzer for `duration`, from a working copy of its corpus; what adds
/// coverage is merged back into the committed corpus.
fn libfuzzer(target: Target, duration: Duration) -> Result<Row> {
    let fuzz = fuzz_dir();
    let committed = fuzz.join("corpus").join(target.name());
    let work = crate::api::workspace_root()
        .join("target/fuzz-corpus")
        .join(target.name());
    let artifacts = fuzz.join("artifacts").join(target.name());
    std::fs::create_dir_all(&work)?;
    std::fs::create_dir_all(&artifacts)?;
    let before = count_files(&artifacts);
    let binary = fuzz.join(format!(
        "target/x86_64-unknown-linux-gnu/release/{}",
        target.name()
    ));
    let started = Instant::now();
    let output = Command::new(&binary)
        .arg(&work)
        .arg(&committed)
        .arg(format!("-max_total_time={}", duration.as_secs().max(1)))
        .arg(format!("-rss_limit_mb={MEMORY_LIMIT_MB}"))
        .arg(format!("-max_len={MAX_INPUT_LEN}"))
        .arg(format!("-timeout={}", campaign::HANG_AFTER.as_secs()))
        .arg(format!("-artifact_prefix={}/", artifacts.display()))
        .arg("-print_final_stats=1")
        .output()
        .with_context(|| format!("cannot run {}", binary.display()))?;
    let seconds = started.elapsed().as_secs_f64();
    let log = String::from_utf8_lossy(&output.stderr);
    let stat = |key: &str| -> u64 {
        log.lines()
            .find_map(|l| l.strip_prefix(key))
            .and_then(|v| v.trim().trim_start_matches(':').trim().parse().ok())
            .unwrap_or(0)
    };
    let executions = stat("stat::number_of_executed_units");
    let log_path = crate::api::workspace_root()
        .join("target/fuzz-corpus")
        .join(format!("{}.log", target.name()));
    std::fs::write(&log_path, log.as_bytes())?;
    // The committed corpus becomes a small cover of everything reached: committed, so small.
    commit_cover(&binary, target, &committed, &work).with_context(|| {
        format!(
            "merging the corpus of {target}; log: {}",
            log_path.display()
        )
    })?;
    let new_findings: Vec<String> = std::fs::read_dir(&artifacts)?
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .collect();
    let kind = |prefix: &str| {
        new_findings
            .iter()
            .filter(|n| n.starts_with(prefix))
            .count()
    };
    let (crashes, hangs, ooms) = (kind("crash-"), kind("timeout-"), kind("oom-"));
    if crashes + hangs + ooms > before || !output.status.success() {
        eprintln!(
            "{target}: libFuzzer stopped on a finding; log: {}",
            log_path.display()
        );
    }
    Ok(Row {
        target,
        engine: "libFuzzer",
        seconds,
        executions,
        corpus: count_files(&committed),
        crashes,
        hangs,
        ooms: ooms + kind("leak-"),
    })
}

/// Inputs of the committed corpus longer than this are left to the working copy: the committed
/// corpus is replayed by every test run and kept in the repository.
const COMMITTED_INPUT_LEN: usize = 4096;

/// At most this many inputs per target are committed (the smallest of a cover), besides the seeds.
const COMMITTED_INPUTS: usize = 200;

/// Replaces the committed corpus of `target` by a set cover (libFuzzer's `-set_cover_merge`) of
/// what the committed corpus and the working copy reach, among inputs of at most
/// [`COMMITTED_INPUT_LEN`] bytes, the smallest [`COMMITTED_INPUTS`] of it, and the seeds.
fn commit_cover(binary: &Path, target: Target, committed: &Path, work: &Path) -> Result<()> {
    let cover = work.with_extension("cover");
    let _ = std::fs::remove_dir_all(&cover);
    std::fs::create_dir_all(&cover)?;
    let merged = Command::new(binary)
        .args([
            "-set_cover_merge=1",
            &format!("-max_len={COMMITTED_INPUT_LEN}"),
        ])
        .arg(&cover)
        .arg(committed)
        .arg(work)
        .output()
        .context("cannot run the merge")?;
    if !merged.status.success() {
        bail!("the merge of {target} failed ({})", merged.status);
    }
    let mut inputs: Vec<(u64, PathBuf)> = std::fs::read_dir(&cover)?
        .filter_map(|e| e.ok())
        .filter_map(|e| Some((e.metadata().ok()?.len(), e.path())))
        .collect();
    inputs.sort();
    inputs.truncate(COMMITTED_INPUTS);
    for entry in std::fs::read_dir(committed)?.filter_map(|e| e.ok()) {
        if !entry.file_name().to_string_lossy().starts_with("seed-") {
            std::fs::remove_file(entry.path())?;
        }
    }
    for (_, path) in inputs {
        if let Some(name) = path.file_name() {
            std::fs::copy(&path, committed.join(name))?;
        }
    }
    Ok(())
}

/// One target under the stable fallback, in a child process with an address-space limit.
fn stable(target: Target, duration: Duration) -> Result<Row> {
    let exe = std::env::current_exe()?;
    let fuzz = fuzz_dir();
    let artifacts = fuzz.join("artifacts").join(target.name());
    let started = Instant::now();
    let current = current_input_path(target);
    let mut command = Command::new(exe);
    command.args([
        "fuzz-worker",
        target.name(),
        "--seconds",
        &duration.as_secs_f64().to_string(),
    ]);
    timesift_fuzz::limit_address_space(&mut command, MEMORY_LIMIT_MB << 20);
    let output = command.output().context("cannot start the fuzz worker")?;
    let seconds = started.elapsed().as_secs_f64();
    let stdout = String::from_utf8_lossy(&output.stdout);
    let summary: Option<Summary> = stdout.lines().rev().find_map(parse_summary);
    let (mut hangs, mut ooms) = (0, 0);
    match output.status.code() {
        Some(0) => {}
        Some(HANG_EXIT) => hangs = 1,
        _ => {
            // Killed by a signal (an abort on a failed allocation under the limit) or failed:
            // the input it was reading is the finding.
            ooms = 1;
            let kept = std::fs::read(&current).ok().map(|bytes| {
                let path = artifacts.join(format!(
                    "oom-{}",
                    timesift_fuzz::mutate::content_name(&bytes)
                ));
                let _ = std::fs::create_dir_all(&artifacts);
                let _ = std::fs::write(&path, bytes);
                path
            });
            let _ = std::fs::remove_file(&current);
            let stderr = String::from_utf8_lossy(&output.stderr);
            eprintln!(
                "{target}: the worker ended with {}: {}{}",
                output.status,
                stderr.lines().take(2).collect::<Vec<_>>().join(" / "),
                kept.map(|p| format!("; input kept as {}", p.display()))
                    .unwrap_or_default()
            );
        }
    }
    let summary = summary.unwrap_or_default();
    Ok(Row {
        target,
        engine: "stable",
        seconds,
        executions: summary.executions,
        corpus: count_files(&fuzz.join("corpus").join(target.name())),
        crashes: summary
            .crashes
            .max(count_prefixed(&artifacts, "crash-") / 2),
        hangs,
        ooms,
    })
}

fn count_prefixed(dir: &Path, prefix: &str) -> usize {
    std::fs::read_dir(dir).map_or(0, |d| {
        d.filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().starts_with(prefix))
            .count()
    })
}

/// A line of the worker's counts: `summary executions accepted corpus crashes`.
fn parse_summary(line: &str) -> Option<Summary> {
    let rest = line.strip_prefix("summary ")?;
    let v: Vec<u64> = rest
        .split_whitespace()
        .map(|w| w.parse().ok())
        .collect::<Option<_>>()?;
    let [executions, accepted, corpus, crashes] = v[..] else {
        return None;
    };
    Some(Summary {
        executions,
        accepted,
        corpus: corpus as usize,
        crashes: crashes as usize,
    })
}

/// Where the worker fuzzing `target` keeps the input it is reading.
fn current_input_path(target: Target) -> PathBuf {
    let shm = Path::new("/dev/shm");
    let dir = if shm.is_dir() {
        shm.to_path_buf()
    } else {
        std::env::temp_dir()
    };
    dir.join(format!("timesift-fuzz-current-{}", target.name()))
}

/// The hidden `fuzz-worker` task: one target's stable campaign in this process.
pub fn worker(target: &str, seconds: f64, seed: u64) -> Result<()> {
    let [target] = targets_of(&[target.to_string()])?[..] else {
        bail!("one target expected");
    };
    let fuzz = fuzz_dir();
    campaign::campaign(
        target,
        &fuzz.join("corpus").join(target.name()),
        &fuzz.join("artifacts").join(target.name()),
        &current_input_path(target),
        Duration::from_secs_f64(seconds),
        seed,
    )?;
    Ok(())
}

fn print_table(rows: &[Row]) {
    println!(
        "| target | engine | minutes | executions | exec/s | corpus | crashes | hangs | out of memory |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        println!(
            "| {} | {} | {:.1} | {} | {:.0} | {} | {} | {} | {} |",
            r.target,
            r.engine,
            r.seconds / 60.0,
            r.executions,
            r.executions as f64 / r.seconds.max(1e-9),
            r.corpus,
            r.crashes,
            r.hangs,
            r.ooms
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worker_summaries_parse() {
        let s = parse_summary("summary 10 4 3 1").unwrap();
        assert_eq!(
            (s.executions, s.accepted, s.corpus, s.crashes),
            (10, 4, 3, 1)
        );
        assert!(parse_summary("summary 10 4").is_none());
        assert!(parse_summary("hang: x").is_none());
    }

    #[test]
    fn unknown_targets_are_named() {
        let e = targets_of(&["lass".to_string()]).unwrap_err().to_string();
        assert!(e.contains("\"lass\"") && e.contains("laz_positions"), "{e}");
    }
}
