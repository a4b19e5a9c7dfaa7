//! Injected I/O faults, for the tests that prove a failed write, rename or fsync loses nothing:
//! compiled only with the `fault-injection` feature (the root package's tests turn it on), and
//! armed only by the environment variable `TIMESIFT_FAULT=<op>:<n>` (`op` one of `write`,
//! `rename`, `fsync`): the n-th such operation of the process (from 1) fails with an error
//! saying it was injected; `kill:<n>[:<text>]` aborts the process at the n-th operation of any
//! kind (on a file whose path holds the text), before it is done: a kill at a chosen moment
//! inside a stage. Every durable output goes through [`crate::fsutil`], which asks here
//! before each of the three operations. `TIMESIFT_FAULT_LOG=<file>` lists every operation (kind,
//! count of its kind, count of all, file), to choose faults from.

/// The operations a fault can be injected into.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Op {
    /// Filling a temporary file.
    Write,
    /// Renaming a temporary file over its target.
    Rename,
    /// Flushing a file or a folder to the disk.
    Fsync,
}

#[cfg(feature = "fault-injection")]
mod armed {
    use std::sync::OnceLock;
    use std::sync::atomic::{AtomicU64, Ordering};

    use super::Op;

    /// What is armed: an operation failing, or the process killed.
    #[derive(Clone, Copy)]
    enum Armed {
        /// The n-th operation of this kind fails.
        Fail(Op, u64),
        /// The process dies at the n-th operation of any kind on a file whose path holds the
        /// text (any file when it is empty), before the operation is done.
        Kill(u64, &'static str),
    }

    fn armed() -> Option<Armed> {
        static ARMED: OnceLock<Option<Armed>> = OnceLock::new();
        *ARMED.get_or_init(|| {
            let spec = std::env::var("TIMESIFT_FAULT").ok()?;
            let (op, rest) = spec.split_once(':')?;
            let (n, marker) = rest.split_once(':').unwrap_or((rest, ""));
            let n = n.parse().ok()?;
            Some(match op {
                "write" => Armed::Fail(Op::Write, n),
                "rename" => Armed::Fail(Op::Rename, n),
                "fsync" => Armed::Fail(Op::Fsync, n),
                // Read once per process: leaking the text keeps `Armed` a plain value.
                "kill" => Armed::Kill(n, String::leak(marker.to_string())),
                _ => return None,
            })
        })
    }

    /// Operations of each kind so far, of all kinds, and on the files a kill waits for.
    static COUNTS: [AtomicU64; 5] = [
        AtomicU64::new(0),
        AtomicU64::new(0),
        AtomicU64::new(0),
        AtomicU64::new(0),
        AtomicU64::new(0),
    ];

    /// Where every operation is listed (`TIMESIFT_FAULT_LOG`), to choose faults from.
    fn log() -> Option<&'static std::sync::Mutex<std::fs::File>> {
        static LOG: OnceLock<Option<std::sync::Mutex<std::fs::File>>> = OnceLock::new();
        LOG.get_or_init(|| {
            let path = std::env::var_os("TIMESIFT_FAULT_LOG")?;
            let file = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(path)
                .ok()?;
            Some(std::sync::Mutex::new(file))
        })
        .as_ref()
    }

    pub(super) fn fails(op: Op, path: &std::path::Path) -> bool {
        let count = COUNTS[op as usize].fetch_add(1, Ordering::SeqCst) + 1;
        let total = COUNTS[3].fetch_add(1, Ordering::SeqCst) + 1;
        if let Some(Ok(mut file)) = log().map(|l| l.lock()) {
            use std::io::Write;
            let _ = writeln!(file, "{op:?} {count} {total} {}", path.display());
        }
        match armed() {
            Some(Armed::Fail(armed_op, n)) => armed_op == op && count == n,
            Some(Armed::Kill(n, marker)) if path.to_string_lossy().contains(marker) => {
                if COUNTS[4].fetch_add(1, Ordering::SeqCst) + 1 == n {
                    // No destructor, no flush, no cleanup: what a SIGKILL or a power cut leaves.
                    std::process::abort();
                }
                false
            }
            _ => false,
        }
    }
}

/// Fails when the armed fault is this operation's turn (never without the feature).
pub(crate) fn check(op: Op, path: &std::path::Path) -> std::io::Result<()> {
    #[cfg(feature = "fault-injection")]
    if armed::fails(op, path) {
        return Err(std::io::Error::other(format!(
            "injected {} fault (TIMESIFT_FAULT)",
            format!("{op:?}").to_lowercase()
        )));
    }
    let _ = (op, path);
    Ok(())
}
