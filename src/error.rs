//! Errors of the project layer.

use std::path::PathBuf;

use thiserror::Error;
use timesift_io::IoError;

/// A failure to load, validate or run a project. Messages are one line naming the file and the
/// line or key.
#[derive(Debug, Error)]
pub enum ProjectError {
    /// A file could not be read or parsed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A configuration value is wrong.
    #[error("{}: key `{key}`: {message}", path.display())]
    Config {
        /// The file.
        path: PathBuf,
        /// The key.
        key: String,
        /// What is wrong and what was expected.
        message: String,
    },
    /// A line of an input file refers to something that does not exist.
    #[error("{}: line {line}: {message}", path.display())]
    Reference {
        /// The file.
        path: PathBuf,
        /// The line, counted from 1.
        line: usize,
        /// What it refers to that does not exist.
        message: String,
    },
    /// A path given to a command is not usable.
    #[error("{}: {message}", path.display())]
    Path {
        /// The path.
        path: PathBuf,
        /// Why it is not usable.
        message: String,
    },
    /// `--from` comes after `--to`.
    #[error("stage range is empty: --from {from} comes after --to {to}")]
    StageRange {
        /// The stage given to `--from`.
        from: &'static str,
        /// The stage given to `--to`.
        to: &'static str,
    },
    /// A change computation failed; `context` names the inputs.
    #[error("{context}: {source}")]
    Change {
        /// The inputs (files or epochs).
        context: String,
        /// What failed.
        source: timesift_change::ChangeError,
    },
    /// A comparison with a synthetic scene's truth failed.
    #[error(transparent)]
    Eval(#[from] timesift_eval::EvalError),
    /// A stage of `timesift run` failed.
    #[error("{stage}: {message}")]
    Stage {
        /// The stage's name.
        stage: &'static str,
        /// What failed.
        message: String,
    },
}

impl ProjectError {
    pub(crate) fn config(
        path: impl Into<PathBuf>,
        key: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        ProjectError::Config {
            path: path.into(),
            key: key.into(),
            message: message.into(),
        }
    }
}
