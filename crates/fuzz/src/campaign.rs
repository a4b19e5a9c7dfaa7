//! The stable fallback's campaign: a target's corpus truncated at every offset and mutated, each
//! input run under `catch_unwind` with a watchdog for hangs, for a fixed time.
//!
//! Findings are kept as files, named by content, in the artifacts folder: `crash-*` (a panic or
//! a refusal that is not one line naming the file) and `hang-*`. A hang cannot be stopped from
//! inside the process: the watchdog writes the input and ends the process with [`HANG_EXIT`].
//! Out-of-memory is the parent's to catch: it runs this under an address-space limit, and an
//! allocation that fails there aborts the process.

use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::mutate::{Rng, content_name, mutate};
use crate::{Target, Verdict, run};

/// The exit status of a campaign ended by a hung input.
pub const HANG_EXIT: i32 = 71;

/// How long one input may take before it is a hang.
pub const HANG_AFTER: Duration = Duration::from_secs(20);

/// What a campaign did.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Summary {
    /// Inputs run.
    pub executions: u64,
    /// Of which readers accepted.
    pub accepted: u64,
    /// Corpus inputs the campaign started from.
    pub corpus: usize,
    /// Distinct crashing inputs found (written to the artifacts folder).
    pub crashes: usize,
}

/// Reads every file of `dir` (none when it does not exist), in name order.
pub fn read_inputs(dir: &Path) -> std::io::Result<Vec<(PathBuf, Vec<u8>)>> {
    let mut paths: Vec<PathBuf> = match std::fs::read_dir(dir) {
        Ok(entries) => entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file())
            .collect(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(e) => return Err(e),
    };
    paths.sort();
    paths
        .into_iter()
        .map(|p| std::fs::read(&p).map(|b| (p, b)))
        .collect()
}

/// Runs one input, a panic caught: the finding's description, if it is one.
pub fn finding(target: Target, bytes: &[u8]) -> Option<String> {
    match std::panic::catch_unwind(AssertUnwindSafe(|| run(target, bytes))) {
        Ok(Ok(_)) => None,
        Ok(Err(message)) => Some(message),
        Err(payload) => Some(panic_message(&payload)),
    }
}

/// The text of a panic's payload.
pub fn panic_message(payload: &Box<dyn std::any::Any + Send>) -> String {
    let text = timesift_io::decoder_guard::panic_text(payload.as_ref());
    if text.is_empty() {
        "panic".to_string()
    } else {
        format!("panic: {text}")
    }
}

/// Fuzzes `target` for `duration` from the inputs of `corpus_dir`, writing findings to
/// `artifacts_dir`. The random mutations follow `seed`. Each input is first written to
/// `current` (best on a memory-backed file system): when an allocation aborts the process,
/// the parent finds there the input that did it.
pub fn campaign(
    target: Target,
    corpus_dir: &Path,
    artifacts_dir: &Path,
    current_file: &Path,
    duration: Duration,
    seed: u64,
) -> std::io::Result<Summary> {
    let corpus: Vec<Vec<u8>> = read_inputs(corpus_dir)?
        .into_iter()
        .map(|(_, b)| b)
        .collect();
    let mut summary = Summary {
        corpus: corpus.len(),
        ..Summary::default()
    };
    let current = Arc::new(Mutex::new(Vec::<u8>::new()));
    let started_at = Arc::new(AtomicU64::new(0));
    let clock = Instant::now();
    spawn_watchdog(
        Arc::clone(&current),
        Arc::clone(&started_at),
        clock,
        artifacts_dir.to_path_buf(),
    );
    // Panics are counted, not printed: the default hook would write each one to stderr.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let mut crashes = std::collections::BTreeSet::new();
    let mut try_input = |bytes: &[u8], summary: &mut Summary| -> std::io::Result<bool> {
        if let Ok(mut c) = current.lock() {
            c.clear();
            c.extend_from_slice(bytes);
        }
        std::fs::write(current_file, bytes)?;
        started_at.store(clock.elapsed().as_millis() as u64 + 1, Ordering::SeqCst);
        let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| run(target, bytes)));
        started_at.store(0, Ordering::SeqCst);
        summary.executions += 1;
        // The counts so far, so that a parent whose child dies still knows them.
        if summary.executions.is_multiple_of(10_000) {
            progress(summary, crashes.len());
        }
        let found = match outcome {
            Ok(Ok(Verdict::Accepted)) => {
                summary.accepted += 1;
                return Ok(true);
            }
            Ok(Ok(Verdict::Refused(_))) => return Ok(false),
            Ok(Err(message)) => message,
            Err(payload) => panic_message(&payload),
        };
        let name = format!("crash-{}", content_name(bytes));
        if crashes.insert(name.clone()) {
            std::fs::create_dir_all(artifacts_dir)?;
            std::fs::write(artifacts_dir.join(&name), bytes)?;
            std::fs::write(artifacts_dir.join(format!("{name}.txt")), found + "\n")?;
        }
        Ok(false)
    };
    let deadline = clock + duration;
    let mut pool = corpus.clone();
    // Truncation at every offset of every corpus input, as far as time allows.
    'truncations: for input in &corpus {
        for len in 0..input.len() {
            if Instant::now() >= deadline {
                break 'truncations;
            }
            try_input(&input[..len], &mut summary)?;
        }
    }
    let mut rng = Rng::new(seed);
    let mut mutant = Vec::new();
    while Instant::now() < deadline && !pool.is_empty() {
        let parent = rng.below(pool.len());
        let parent = pool[parent].clone();
        mutate(&mut rng, &parent, &pool, &mut mutant);
        // Accepted mutants got past the readers' checks: later mutations start from them too
        // (bounded, so that the pool does not fill memory).
        if try_input(&mutant, &mut summary)? && pool.len() < 4 * corpus.len() + 256 {
            pool.push(mutant.clone());
        }
    }
    std::panic::set_hook(hook);
    let _ = std::fs::remove_file(current_file);
    summary.crashes = crashes.len();
    progress(&summary, summary.crashes);
    Ok(summary)
}

/// Prints the counts as the parent reads them: `summary executions accepted corpus crashes`.
fn progress(summary: &Summary, crashes: usize) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "summary {} {} {} {crashes}",
        summary.executions, summary.accepted, summary.corpus
    );
    let _ = out.flush();
}

/// A thread that ends the process when one input has run longer than [`HANG_AFTER`], keeping
/// the input as `hang-*` first.
fn spawn_watchdog(
    current: Arc<Mutex<Vec<u8>>>,
    started_at: Arc<AtomicU64>,
    clock: Instant,
    artifacts_dir: PathBuf,
) {
    std::thread::spawn(move || {
        loop {
            std::thread::sleep(Duration::from_millis(500));
            let started = started_at.load(Ordering::SeqCst);
            let now = clock.elapsed().as_millis() as u64 + 1;
            if started == 0 || now.saturating_sub(started) < HANG_AFTER.as_millis() as u64 {
                continue;
            }
            let bytes = current.lock().map(|c| c.clone()).unwrap_or_default();
            let name = format!("hang-{}", content_name(&bytes));
            let _ = std::fs::create_dir_all(&artifacts_dir);
            let _ = std::fs::write(artifacts_dir.join(&name), &bytes);
            eprintln!(
                "hang: an input ran over {} s; kept as {}",
                HANG_AFTER.as_secs(),
                artifacts_dir.join(&name).display()
            );
            std::process::exit(HANG_EXIT);
        }
    });
}
