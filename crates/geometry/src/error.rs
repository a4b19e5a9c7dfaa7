//! Errors of the geometric solvers.

use thiserror::Error;

/// Why a solver produced no result.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum GeometryError {
    /// Fewer correspondences than the solver needs.
    #[error("{solver} needs at least {needed} correspondences, got {got}")]
    NotEnoughData {
        /// The solver.
        solver: &'static str,
        /// The minimum it needs.
        needed: usize,
        /// How many were given.
        got: usize,
    },
    /// The configuration does not determine the model (planar points for the eight-point
    /// solver, collinear points, zero baseline, …).
    #[error("degenerate configuration for {solver}: {reason}")]
    Degenerate {
        /// The solver.
        solver: &'static str,
        /// Why the configuration is degenerate.
        reason: &'static str,
    },
    /// The input holds NaN or infinite values.
    #[error("non-finite input to {solver}")]
    NonFinite {
        /// The solver.
        solver: &'static str,
    },
    /// No model satisfied the constraints (e.g. cheirality) or robust estimation found none.
    #[error("{solver} found no valid model: {reason}")]
    NoSolution {
        /// The solver.
        solver: &'static str,
        /// Why no model was accepted.
        reason: &'static str,
    },
    /// Inputs of mismatched lengths.
    #[error("{solver}: inputs have different lengths ({a} and {b})")]
    LengthMismatch {
        /// The solver.
        solver: &'static str,
        /// Length of the first input.
        a: usize,
        /// Length of the second input.
        b: usize,
    },
}

/// Checks that every value is finite.
pub(crate) fn check_finite<'a>(
    solver: &'static str,
    values: impl IntoIterator<Item = &'a f64>,
) -> Result<(), GeometryError> {
    if values.into_iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(GeometryError::NonFinite { solver })
    }
}

/// Checks lengths and minimum count of paired inputs.
pub(crate) fn check_pairs(
    solver: &'static str,
    a: usize,
    b: usize,
    needed: usize,
) -> Result<(), GeometryError> {
    if a != b {
        return Err(GeometryError::LengthMismatch { solver, a, b });
    }
    if a < needed {
        return Err(GeometryError::NotEnoughData {
            solver,
            needed,
            got: a,
        });
    }
    Ok(())
}
