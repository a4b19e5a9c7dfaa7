//! The error type of matching.

use std::path::PathBuf;

use thiserror::Error;

/// Failures of matching, verification and the feature and match files.
#[derive(Debug, Error)]
pub enum MatchingError {
    /// The two descriptor sets cannot be compared.
    #[error("cannot match {a} against {b} descriptors")]
    IncompatibleDescriptors { a: String, b: String },
    /// An option is outside its domain.
    #[error("invalid option `{name}` = {value}: {expected}")]
    InvalidOption {
        name: &'static str,
        value: f64,
        expected: &'static str,
    },
    /// A feature or match file is damaged or of another kind.
    #[error("{}: {message}", path.display())]
    Corrupt { path: PathBuf, message: String },
    /// Writing a file failed (the message names it).
    #[error(transparent)]
    Write(#[from] timesift_io::IoError),
    /// Reading a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A match refers to a keypoint that does not exist.
    #[error("match refers to keypoint {index} but the image has {count}")]
    KeypointIndex { index: usize, count: usize },
}
