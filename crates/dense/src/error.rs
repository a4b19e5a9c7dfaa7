//! Why dense matching could not run.

use thiserror::Error;

/// Failures of the dense stage's computations. Each says what was expected; the caller adds the
/// file or epoch it was working on.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum DenseError {
    /// An option is outside its domain.
    #[error("invalid dense option: {0}")]
    InvalidOption(String),
    /// The input is inconsistent (sizes, indices, counts).
    #[error("{0}")]
    InvalidInput(String),
    /// An image does not have the size of its camera.
    #[error("image of {} × {} pixels, its camera expects {} × {}", found.0, found.1, expected.0, expected.1)]
    ImageSize {
        /// The camera's size.
        expected: (usize, usize),
        /// The image's size.
        found: (usize, usize),
    },
    /// Fewer oriented views than multi-view stereo needs.
    #[error("{found} oriented image(s): dense matching needs at least {needed}")]
    TooFewViews {
        /// Oriented views given.
        found: usize,
        /// Views needed.
        needed: usize,
    },
    /// A view has no source view to match with (no shared sparse points at a usable angle).
    #[error("view {view} shares no sparse points at a usable angle with any other view")]
    NoSources {
        /// The view's index in the epoch.
        view: usize,
    },
    /// A view sees no sparse point, so its depth range is unknown.
    #[error("view {view} sees {points} sparse point(s): too few to bound its depths")]
    NoDepthRange {
        /// The view's index in the epoch.
        view: usize,
        /// Sparse points in front of it.
        points: usize,
    },
}
