//! The error type of every reader and writer.

use std::path::PathBuf;

use thiserror::Error;

/// A failure to read or write a file; each variant names the file, and the line or key when the
/// failure has one.
#[derive(Debug, Error)]
pub enum IoError {
    /// The operating system refused (missing file, permissions, disk full).
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A text file has a bad line.
    #[error("{}: line {line}: {message}", path.display())]
    Line {
        /// The file.
        path: PathBuf,
        /// The line, counted from 1.
        line: usize,
        /// What is wrong with it.
        message: String,
    },
    /// A structured file has a bad or missing key.
    #[error("{}: key `{key}`: {message}", path.display())]
    Key {
        /// The file.
        path: PathBuf,
        /// The key.
        key: String,
        /// What is wrong with it.
        message: String,
    },
    /// The content is corrupt or not of the expected format.
    #[error("{}: {message}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The content is valid but uses a layout this reader does not support.
    #[error("{}: unsupported {what}: {message}", path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// The kind of layout (compression, sample format, …).
        what: &'static str,
        /// What the file holds.
        message: String,
    },
    /// A coordinate transformation failed or a CRS is unknown.
    #[error("coordinate reference system {crs}: {message}")]
    Crs {
        /// The CRS as given.
        crs: String,
        /// What failed.
        message: String,
    },
}

/// Folds a message onto one line: errors are reported as one line naming the file.
fn one_line(message: impl Into<String>) -> String {
    let message = message.into();
    if !message.contains(['\n', '\r']) {
        return message;
    }
    message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join("; ")
}

impl IoError {
    /// An operating-system failure on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        IoError::Io {
            path: path.into(),
            source,
        }
    }

    /// Content of `path` that is corrupt or cannot be encoded (message folded onto one line).
    pub fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        IoError::Invalid {
            path: path.into(),
            message: one_line(message),
        }
    }

    pub(crate) fn line(path: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        IoError::Line {
            path: path.into(),
            line,
            message: one_line(message),
        }
    }

    pub(crate) fn key(
        path: impl Into<PathBuf>,
        key: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        IoError::Key {
            path: path.into(),
            key: key.into(),
            message: one_line(message),
        }
    }

    pub(crate) fn unsupported(
        path: impl Into<PathBuf>,
        what: &'static str,
        message: impl Into<String>,
    ) -> Self {
        IoError::Unsupported {
            path: path.into(),
            what,
            message: one_line(message),
        }
    }
}
