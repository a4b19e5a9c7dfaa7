//! The error type of feature extraction.

use std::path::PathBuf;

use thiserror::Error;

/// Failures of feature extraction and of the feature text format. Each variant says what was
/// expected.
#[derive(Debug, Error)]
pub enum FeatureError {
    /// The pixel buffer does not hold `width × height` values.
    #[error("image buffer holds {got} values, expected {width} × {height}")]
    BufferSize {
        width: usize,
        height: usize,
        got: usize,
    },
    /// The image is smaller than the scale space can work on.
    #[error(
        "image of {width} × {height} px is too small: features need at least {min} px on each side"
    )]
    TooSmall {
        width: usize,
        height: usize,
        min: usize,
    },
    /// The image holds NaN or infinite values.
    #[error("image holds {count} non-finite pixel values (first at column {col}, row {row})")]
    NonFinitePixels {
        count: usize,
        col: usize,
        row: usize,
    },
    /// The mask does not have the image's size.
    #[error("mask is {mask_width} × {mask_height} px but the image is {width} × {height} px")]
    MaskSize {
        width: usize,
        height: usize,
        mask_width: usize,
        mask_height: usize,
    },
    /// An option is outside its domain.
    #[error("invalid option `{name}` = {value}: {expected}")]
    InvalidOption {
        name: &'static str,
        value: f64,
        expected: &'static str,
    },
    /// A feature file is malformed.
    #[error("{}:{line}: {message}", path.display())]
    Format {
        path: PathBuf,
        line: usize,
        message: String,
    },
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// Decoding an image failed.
    #[error(transparent)]
    Image(#[from] timesift_io::IoError),
}
