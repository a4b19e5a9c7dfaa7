//! The error type of matching.

use std::path::PathBuf;

use thiserror::Error;

/// Failures of matching, verification and the feature and match files.
#[derive(Debug, Error)]
pub enum MatchingError {
    /// The two descriptor sets cannot be compared.
    #[error("cannot match {a} against {b} descriptors")]
    IncompatibleDescriptors {
        /// The first set's kind and length.
        a: String,
        /// The second set's kind and length.
        b: String,
    },
    /// An option is outside its domain.
    #[error("invalid option `{name}` = {value}: {expected}")]
    InvalidOption {
        /// The option's name.
        name: &'static str,
        /// The value given.
        value: f64,
        /// What the value must be.
        expected: &'static str,
    },
    /// A feature or match file is damaged or of another kind.
    #[error("{}: {message}", path.display())]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Writing a file failed (the message names it).
    #[error(transparent)]
    Write(#[from] timesift_io::IoError),
    /// Reading a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A match refers to a keypoint that does not exist.
    #[error("match refers to keypoint {index} but the image has {count}")]
    KeypointIndex {
        /// The keypoint index of the match.
        index: usize,
        /// The image's keypoint count.
        count: usize,
    },
}
