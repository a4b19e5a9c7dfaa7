//! The one error type of the crate.

/// What went wrong with a film camera, a template or a scan.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilmError {
    /// The certificate's fiducial marks cannot define a frame.
    #[error("fiducial marks: {0}")]
    InvalidMarks(String),
    /// A template that cannot be matched (too small, constant, or larger than the search).
    #[error("fiducial template: {0}")]
    InvalidTemplate(String),
    /// A scan that does not fit the certificate (too small for the marks, wrong buffer).
    #[error("scan: {0}")]
    InvalidScan(String),
    /// An option out of its range.
    #[error("option {name} = {value}: expected {expected}")]
    InvalidOption {
        /// The option.
        name: &'static str,
        /// The value given.
        value: f64,
        /// What it must be.
        expected: &'static str,
    },
    /// Too few marks to fit a transform of the scan.
    #[error("{found} marks measured; the {model} interior orientation needs at least {needed}")]
    TooFewMarks {
        /// Marks available.
        found: usize,
        /// Marks needed.
        needed: usize,
        /// The transform.
        model: &'static str,
    },
    /// Marks that do not determine a transform (collinear, coincident).
    #[error("the marks do not determine a {model} transform: {reason}")]
    Degenerate {
        /// The transform.
        model: &'static str,
        /// Why.
        reason: String,
    },
}
