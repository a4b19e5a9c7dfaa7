//! Errors of the bundle adjuster.

use thiserror::Error;

/// Why a bundle adjustment could not run.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum BundleError {
    /// The problem refers to an image, point or camera group that does not exist.
    #[error("invalid problem: {0}")]
    InvalidProblem(String),
    /// A value is NaN or infinite at the start.
    #[error("non-finite {0} in the problem")]
    NonFinite(&'static str),
    /// The normal equations are singular where a regular system is needed (covariances).
    #[error("singular problem: {0}")]
    Singular(String),
    /// No parameter is free.
    #[error("nothing to adjust: every parameter is fixed")]
    NothingToAdjust,
}
