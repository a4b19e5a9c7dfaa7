//! The crate's one error type.

use std::path::PathBuf;

use thiserror::Error;
use timesift_io::IoError;

/// Why an output could not be compared with the truth. Messages name the file.
#[derive(Debug, Error)]
pub enum EvalError {
    /// A file could not be read or parsed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A truth file or output holds something other than expected.
    #[error("{}: {message}", path.display())]
    Truth {
        /// The file.
        path: PathBuf,
        /// What was expected.
        message: String,
    },
    /// A change computation on the outputs failed; `context` names the inputs.
    #[error("{context}: {source}")]
    Change {
        /// The inputs (files, regions or epochs).
        context: String,
        /// What failed.
        source: timesift_change::ChangeError,
    },
    /// The synthetic scene could not be rebuilt.
    #[error("scene: {0}")]
    Scene(String),
}
