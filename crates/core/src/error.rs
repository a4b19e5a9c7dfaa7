//! The error type of the core vocabulary.

use thiserror::Error;

/// Failures of camera models and poses. Each variant says what was expected.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CoreError {
    /// A camera parameter is outside its domain (non-finite, non-positive focal length, …).
    #[error("invalid camera parameter `{name}` = {value}: {expected}")]
    InvalidCameraParameter {
        /// The parameter's name.
        name: &'static str,
        /// The value given.
        value: f64,
        /// What the value must be.
        expected: &'static str,
    },
    /// The parameter slice given to a camera model has the wrong length.
    #[error("camera model `{model}` takes {expected} parameters, got {got}")]
    ParameterCount {
        /// The model's name.
        model: &'static str,
        /// How many parameters it takes.
        expected: usize,
        /// How many were given.
        got: usize,
    },
    /// The point lies on or behind the camera's image plane (Zc <= 0), so it has no projection.
    #[error("point is not in front of the camera (z = {z})")]
    BehindCamera {
        /// The point's depth in the camera frame.
        z: f64,
    },
    /// Iterative undistortion did not converge: the pixel lies where the distortion polynomial folds
    /// over or far outside the calibrated field.
    #[error(
        "undistortion of pixel ({u}, {v}) did not converge after {iterations} iterations (residual {residual:e})"
    )]
    UndistortionDiverged {
        /// The pixel's column coordinate.
        u: f64,
        /// The pixel's row coordinate.
        v: f64,
        /// Iterations spent.
        iterations: usize,
        /// The last residual, normalised image units.
        residual: f64,
    },
    /// A matrix that should be a rotation is not orthonormal with determinant +1.
    #[error("matrix is not a rotation (orthonormality error {orthonormality_error:e}, det {det})")]
    NotARotation {
        /// Largest entry of `RᵀR − I`.
        orthonormality_error: f64,
        /// The determinant.
        det: f64,
    },
    /// A value that must be finite is NaN or infinite.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// What held the value.
        what: &'static str,
    },
}
