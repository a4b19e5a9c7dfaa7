//! Cached work of a stage: a folder of `work/` records the settings its results were made with,
//! so that a resumed run reuses only what the current settings would produce.

use std::path::Path;

use crate::ProjectError;
use crate::layout::Layout;

/// Makes `dir` hold only results made with `settings`: when `dir/settings.json` records other
/// settings (or is missing while results of an earlier run are there), the files with extension
/// `ext` are removed, as are those of every folder in `dependents`; then the settings are
/// recorded. A resumed run thus reuses only what the current settings would produce.
pub(crate) fn start_with_settings(
    stage: &'static str,
    dir: &Path,
    ext: &str,
    settings: &serde_json::Value,
    dependents: &[(&Path, &str)],
) -> Result<(), ProjectError> {
    let path = Layout::settings_file(dir);
    let recorded: Option<serde_json::Value> = crate::report::read_sealed_json(&path).ok();
    if recorded.as_ref() == Some(settings) {
        return Ok(());
    }
    for (folder, extension) in std::iter::once((dir, ext)).chain(dependents.iter().copied()) {
        let Ok(entries) = std::fs::read_dir(folder) else {
            continue;
        };
        for entry in entries.flatten() {
            let file = entry.path();
            if file.extension().is_some_and(|e| e == extension) {
                std::fs::remove_file(&file).map_err(|e| {
                    stage_error(stage, format!("{}: cannot remove: {e}", file.display()))
                })?;
            }
        }
    }
    if recorded.is_some() {
        tracing::info!(stage, "settings changed: earlier results removed");
    }
    crate::report::write_sealed_json(&path, settings)
}

/// Size and modification time of a file: enough to notice that an earlier stage rewrote it.
pub(crate) fn file_stamp(path: &Path) -> serde_json::Value {
    let meta = std::fs::metadata(path).ok();
    let modified = meta
        .as_ref()
        .and_then(|m| m.modified().ok())
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_nanos().to_string());
    serde_json::json!([meta.map(|m| m.len()), modified])
}

pub(crate) use timesift_io::fingerprint::Fnv1a;

/// A fingerprint of the contents of files (names and bytes, in the order given): what a stage
/// that reads whole folders records, since a rewrite with the same bytes changes no result.
/// Missing files count as empty.
pub(crate) fn content_fingerprint(files: &[std::path::PathBuf]) -> String {
    let mut hash = Fnv1a::new();
    for f in files {
        hash.write(f.to_string_lossy().as_bytes());
        hash.write(&std::fs::read(f).unwrap_or_default());
    }
    hash.hex()
}

/// [`Fnv1a`] of a file's bytes, read a megabyte at a time; `None` when it cannot be read.
pub(crate) fn file_content_hash(path: &Path) -> Option<String> {
    use std::io::Read;
    let mut file = std::fs::File::open(path).ok()?;
    let mut hash = Fnv1a::new();
    let mut buffer = vec![0u8; 1 << 20];
    loop {
        match file.read(&mut buffer) {
            Ok(0) => return Some(hash.hex()),
            Ok(n) => hash.write(&buffer[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(_) => return None,
        }
    }
}

/// The error of a stage.
pub(crate) fn stage_error(stage: &'static str, message: String) -> ProjectError {
    ProjectError::Stage { stage, message }
}
