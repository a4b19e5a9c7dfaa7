//! The per-thread scratch folder the bytes of an input are written to before a reader opens them.

use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

thread_local! {
    static FOLDER: RefCell<Option<Scratch>> = const { RefCell::new(None) };
    static PROJECT: RefCell<Option<Scratch>> = const { RefCell::new(None) };
}

/// The files of the built-in example project (`data/example`) besides `project.toml`: what a
/// fuzzed `project.toml` is validated against, so that the validation of its inputs runs too.
const EXAMPLE: &[(&str, &[u8])] = &[
    ("gcps.csv", include_bytes!("../../../data/example/gcps.csv")),
    (
        "checkpoints.csv",
        include_bytes!("../../../data/example/checkpoints.csv"),
    ),
    (
        "markers.csv",
        include_bytes!("../../../data/example/markers.csv"),
    ),
    ("gnss.csv", include_bytes!("../../../data/example/gnss.csv")),
    (
        "stable.csv",
        include_bytes!("../../../data/example/stable.csv"),
    ),
    (
        "images/2018-06/IMG_0001.png",
        include_bytes!("../../../data/example/images/2018-06/IMG_0001.png"),
    ),
    (
        "images/2018-06/IMG_0002.png",
        include_bytes!("../../../data/example/images/2018-06/IMG_0002.png"),
    ),
    (
        "images/2018-06/IMG_0003.png",
        include_bytes!("../../../data/example/images/2018-06/IMG_0003.png"),
    ),
    (
        "images/2019-03/IMG_0001.png",
        include_bytes!("../../../data/example/images/2019-03/IMG_0001.png"),
    ),
    (
        "images/2019-03/IMG_0002.png",
        include_bytes!("../../../data/example/images/2019-03/IMG_0002.png"),
    ),
    (
        "images/2019-03/IMG_0003.png",
        include_bytes!("../../../data/example/images/2019-03/IMG_0003.png"),
    ),
];

/// Calls `f` with this thread's copy of the example project, made once: a project file is only
/// read, so the same folder serves every input (each writes its own `project.toml`).
pub(crate) fn with_project<R>(f: impl FnOnce(&Path) -> R) -> R {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    PROJECT.with(|cell| {
        let mut slot = cell.borrow_mut();
        let scratch = slot.get_or_insert_with(|| {
            let n = NEXT.fetch_add(1, Ordering::Relaxed);
            let dir = base().join(format!("timesift-fuzz-project-{}-{n}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            for (name, bytes) in EXAMPLE {
                put(&dir, name, bytes);
            }
            Scratch(dir)
        });
        let dir = scratch.0.clone();
        drop(slot);
        f(&dir)
    })
}

/// A folder of this thread's own, removed when the thread ends.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The folder under which scratch folders are made: memory-backed when the machine has one, so
/// that writing an input costs no disk I/O.
fn base() -> PathBuf {
    let shm = Path::new("/dev/shm");
    if shm.is_dir() {
        shm.to_path_buf()
    } else {
        std::env::temp_dir()
    }
}

/// Calls `f` with this thread's scratch folder, emptied first (a reader may have been handed a
/// folder of files by the previous input).
pub(crate) fn with_folder<R>(f: impl FnOnce(&Path) -> R) -> R {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    FOLDER.with(|cell| {
        let mut slot = cell.borrow_mut();
        let scratch = slot.get_or_insert_with(|| {
            let n = NEXT.fetch_add(1, Ordering::Relaxed);
            Scratch(base().join(format!("timesift-fuzz-{}-{n}", std::process::id())))
        });
        let dir = scratch.0.clone();
        drop(slot);
        let _ = std::fs::remove_dir_all(&dir);
        // The scratch folder lives on a local file system of this machine; failing to make it
        // is an environment fault the fuzzer cannot work around, not a finding about the input.
        std::fs::create_dir_all(&dir)
            .unwrap_or_else(|e| panic!("cannot make the scratch folder {}: {e}", dir.display()));
        f(&dir)
    })
}

/// Writes `bytes` to `dir/name`, making the folders between.
pub(crate) fn put(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    if let Some(parent) = path.parent() {
        let _ = std::fs::create_dir_all(parent);
    }
    // As above: the scratch folder is ours; a write failing there is the environment's fault.
    std::fs::write(&path, bytes)
        .unwrap_or_else(|e| panic!("cannot write the scratch file {}: {e}", path.display()));
    path
}
