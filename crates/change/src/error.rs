//! The crate's one error type.

use thiserror::Error;

/// Why a change computation could not be done. Messages say what was given and what was expected;
/// callers that know the file name add it.
#[derive(Debug, Error)]
pub enum ChangeError {
    /// The two inputs are in different coordinate reference systems.
    #[error("the inputs are in different CRSs ({a} and {b}); reproject one of them first")]
    CrsMismatch {
        /// CRS of the first input.
        a: String,
        /// CRS of the second input.
        b: String,
    },
    /// The inputs share no valid cell or point.
    #[error("the inputs do not overlap: {0}")]
    NoOverlap(String),
    /// The stable area selects nothing usable.
    #[error("the stable area is empty: {0}")]
    EmptyStable(String),
    /// Too little data for the estimate.
    #[error("not enough data: {0}")]
    NotEnoughData(String),
    /// A parameter is out of its domain.
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter {
        /// The parameter's name (as in the configuration or on the command line).
        name: &'static str,
        /// What was expected.
        reason: String,
    },
    /// An input is malformed.
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// An iterative estimate did not converge or became degenerate.
    #[error("{0}")]
    Degenerate(String),
}

/// Checks that a parameter is finite and strictly positive.
pub(crate) fn positive(name: &'static str, value: f64) -> Result<f64, ChangeError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(ChangeError::InvalidParameter {
            name,
            reason: format!("{value} given; a finite value > 0 was expected"),
        })
    }
}
