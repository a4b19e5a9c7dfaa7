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
        /// Image width, pixels.
        width: usize,
        /// Image height, pixels.
        height: usize,
        /// Values the buffer holds.
        got: usize,
    },
    /// The image is smaller than the scale space can work on.
    #[error(
        "image of {width} × {height} px is too small: features need at least {min} px on each side"
    )]
    TooSmall {
        /// Image width, pixels.
        width: usize,
        /// Image height, pixels.
        height: usize,
        /// The least side length, pixels.
        min: usize,
    },
    /// The image holds NaN or infinite values.
    #[error("image holds {count} non-finite pixel values (first at column {col}, row {row})")]
    NonFinitePixels {
        /// How many values are not finite.
        count: usize,
        /// Column of the first.
        col: usize,
        /// Row of the first.
        row: usize,
    },
    /// The mask does not have the image's size.
    #[error("mask is {mask_width} × {mask_height} px but the image is {width} × {height} px")]
    MaskSize {
        /// Image width, pixels.
        width: usize,
        /// Image height, pixels.
        height: usize,
        /// Mask width, pixels.
        mask_width: usize,
        /// Mask height, pixels.
        mask_height: usize,
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
    /// A feature file is malformed.
    #[error("{}:{line}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// The line, counted from 1.
        line: usize,
        /// What is wrong with it.
        message: String,
    },
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// Decoding an image failed.
    #[error(transparent)]
    Image(#[from] timesift_io::IoError),
}
