//! Injected I/O faults, for the tests that prove a failed write, rename or fsync loses nothing:
//! compiled only with the `fault-injection` feature (the root package's tests turn it on), and
//! armed only by the environment variable `TIMESIFT_FAULT=<op>:<n>` (`op` one of `write`,
//! `rename`, `fsync`): the n-th such operation of the process (from 1) fails with an error
//! saying it was injected. Every durable output goes through [`crate::fsutil`], which asks here
//! before each of the three operations. `TIMESIFT_FAULT_LOG=<file>` lists every operation with
//! its count and file, to choose faults from.

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

    /// The armed fault: which operation, and its count.
    fn armed() -> Option<(Op, u64)> {
        static ARMED: OnceLock<Option<(Op, u64)>> = OnceLock::new();
        *ARMED.get_or_init(|| {
            let spec = std::env::var("TIMESIFT_FAULT").ok()?;
            let (op, n) = spec.split_once(':')?;
            let op = match op {
                "write" => Op::Write,
                "rename" => Op::Rename,
                "fsync" => Op::Fsync,
                _ => return None,
            };
            Some((op, n.parse().ok()?))
        })
    }

    /// Operations of each kind so far.
    static COUNTS: [AtomicU64; 3] = [AtomicU64::new(0), AtomicU64::new(0), AtomicU64::new(0)];

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
        if let Some(Ok(mut file)) = log().map(|l| l.lock()) {
            use std::io::Write;
            let _ = writeln!(file, "{op:?} {count} {}", path.display());
        }
        armed().is_some_and(|(armed_op, n)| armed_op == op && count == n)
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
