//! Atomic file output: write beside the target, then rename over it.

use std::fs::File;
use std::io::{BufWriter, ErrorKind, Write};
use std::path::{Path, PathBuf};

use crate::IoError;
use crate::faults::{self, Op};

/// The temporary path used while writing `path`: same folder, so the final rename is atomic.
pub(crate) fn temporary_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

/// The process that was writing a file, when `file_name` is one of the temporary names of
/// [`write_atomically`] or [`temporary_sibling`] (`.<name>.tmp-<pid>[.<ext>]`): lets a later run
/// remove what a killed one left behind.
pub fn temporary_owner(file_name: &str) -> Option<u32> {
    let (_, rest) = file_name.strip_prefix('.')?.split_once(".tmp-")?;
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

/// Writes a file atomically and durably: `write` fills a buffered writer on a temporary file
/// beside `path`, which is flushed to the disk, renamed to `path` only when everything
/// succeeded, and the rename itself made durable by flushing the folder (write-then-rename
/// alone can leave an empty or missing file after a power cut). On failure the temporary file
/// is removed and an existing `path` is left untouched.
pub fn write_atomically<F>(path: &Path, write: F) -> Result<(), IoError>
where
    F: FnOnce(&mut BufWriter<File>) -> Result<(), IoError>,
{
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| IoError::io(parent, e))?;
    }
    let tmp = temporary_path(path);
    let result = (|| {
        let file = File::create(&tmp).map_err(|e| IoError::io(&tmp, e))?;
        let mut writer = BufWriter::new(file);
        write(&mut writer)?;
        faults::check(Op::Write, path).map_err(|e| IoError::io(path, e))?;
        writer.flush().map_err(|e| IoError::io(path, e))?;
        let file = writer
            .into_inner()
            .map_err(|e| IoError::io(path, e.into_error()))?;
        faults::check(Op::Fsync, path)
            .and_then(|()| file.sync_all())
            .map_err(|e| IoError::io(path, e))?;
        rename_durably(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// A temporary path beside `path` that keeps its extension (for writers that choose the encoding
/// from it), to be renamed over `path` with [`commit_temporary`].
pub fn temporary_sibling(path: &Path) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    path.with_file_name(format!(".{stem}.tmp-{}{ext}", std::process::id()))
}

/// Renames a finished temporary file over its target, durably (the file and then the folder
/// flushed to the disk), or removes it when writing failed or cannot be made durable.
pub fn commit_temporary<T>(
    tmp: &Path,
    path: &Path,
    written: Result<T, IoError>,
) -> Result<T, IoError> {
    let committed = written.and_then(|value| {
        faults::check(Op::Write, path)
            .and_then(|()| faults::check(Op::Fsync, path))
            .and_then(|()| File::open(tmp))
            .and_then(|file| file.sync_all())
            .map_err(|e| IoError::io(path, e))?;
        rename_durably(tmp, path)?;
        Ok(value)
    });
    if committed.is_err() {
        let _ = std::fs::remove_file(tmp);
    }
    committed
}

/// Renames `tmp` over `path`, then flushes their folder so that the rename survives a power
/// cut (a folder that cannot be opened for that, on some network file systems, is let be).
fn rename_durably(tmp: &Path, path: &Path) -> Result<(), IoError> {
    faults::check(Op::Rename, path)
        .and_then(|()| std::fs::rename(tmp, path))
        .map_err(|e| IoError::io(path, e))?;
    let folder = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    faults::check(Op::Fsync, folder).map_err(|e| IoError::io(path, e))?;
    if let Ok(dir) = File::open(folder) {
        match dir.sync_all() {
            // File systems that cannot flush a folder say so; nothing more can be done there.
            Err(e) if !matches!(e.kind(), ErrorKind::InvalidInput | ErrorKind::Unsupported) => {
                return Err(IoError::io(folder, e));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Writes a folder of files that belong together (a COLMAP model's three files) atomically:
/// `fill` writes them into a temporary folder beside `dir`, which then takes `dir`'s place. A
/// process killed on the way leaves either the old folder, or none (between the two renames),
/// never a mixture of old and new files; a later run removes the temporary folders left.
pub fn write_dir_atomically<F>(dir: &Path, fill: F) -> Result<(), IoError>
where
    F: FnOnce(&Path) -> Result<(), IoError>,
{
    let tmp = temporary_path(dir);
    let old = temporary_sibling(&dir.with_extension("old"));
    let result = (|| {
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp).map_err(|e| IoError::io(&tmp, e))?;
        fill(&tmp)?;
        if dir.exists() {
            faults::check(Op::Rename, dir)
                .and_then(|()| std::fs::rename(dir, &old))
                .map_err(|e| IoError::io(dir, e))?;
        }
        rename_durably(&tmp, dir)
    })();
    let _ = std::fs::remove_dir_all(&old);
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result
}

/// Writes a whole file from bytes, atomically.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    write_atomically(path, |w| {
        w.write_all(bytes).map_err(|e| IoError::io(path, e))
    })
}

/// Reads a whole text file, naming it on failure; a UTF-8 byte-order mark (spreadsheet exports) is
/// dropped.
pub fn read_text(path: &Path) -> Result<String, IoError> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))?;
    Ok(match text.strip_prefix('\u{feff}') {
        Some(rest) => rest.to_string(),
        None => text,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temporary_names_know_their_writer() {
        let me = std::process::id();
        for tmp in [
            temporary_path(Path::new("/p/out/dem.tif")),
            temporary_sibling(Path::new("/p/out/dense.laz")),
        ] {
            let name = tmp.file_name().unwrap().to_string_lossy().into_owned();
            assert_eq!(temporary_owner(&name), Some(me), "{name}");
        }
        assert_eq!(temporary_owner("dem.tif"), None);
        assert_eq!(temporary_owner(".dem.tif.tmp-"), None);
    }
}
