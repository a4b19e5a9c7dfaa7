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
    let recorded: Option<serde_json::Value> = std::fs::read_to_string(&path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok());
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
    let text = serde_json::to_string_pretty(settings).unwrap_or_default();
    timesift_io::fsutil::write_atomically(&path, |w| {
        use std::io::Write;
        w.write_all(text.as_bytes())
            .map_err(|e| timesift_io::IoError::io(&path, e))
    })?;
    Ok(())
}

/// The error of a stage.
pub(crate) fn stage_error(stage: &'static str, message: String) -> ProjectError {
    ProjectError::Stage { stage, message }
}
