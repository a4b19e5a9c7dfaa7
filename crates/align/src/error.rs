//! The error type of orientation.

use thiserror::Error;

/// Failures of orientation.
#[derive(Debug, Error)]
pub enum AlignError {
    /// The input is inconsistent (an index out of range, a feature that does not exist, …).
    #[error("invalid orientation input: {0}")]
    InvalidInput(String),
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
    /// No pair of images could start a reconstruction.
    #[error(
        "no initial pair: none of the {tried} most connected image pairs has {min_inliers} \
         essential-matrix inliers with a median triangulation angle of {min_angle_deg}°, nor \
         with those thresholds halved three times (too little overlap, texture or baseline)"
    )]
    NoInitialPair {
        /// How many candidate pairs were evaluated.
        tried: usize,
        /// The inliers a pair needs.
        min_inliers: usize,
        /// The median triangulation angle a pair needs, degrees.
        min_angle_deg: f64,
    },
    /// Every candidate pair shows the same view: nothing can be triangulated.
    #[error("{}", no_baseline_text(*.pairs, &image_label(.first), &image_label(.second), *.displacement_px))]
    NoBaseline {
        /// How many candidate pairs were evaluated.
        pairs: usize,
        /// One such pair: the first image's index.
        first: usize,
        /// One such pair: the second image's index.
        second: usize,
        /// That pair's median displacement, pixels.
        displacement_px: f64,
    },
    /// Georeferencing is impossible with the given priors.
    #[error("cannot georeference: {0}")]
    Georeferencing(String),
    /// The descriptor matching of stable tie points failed.
    #[error("stable tie-point matching: {0}")]
    StableMatching(String),
    /// A strategy failed on one epoch.
    #[error("epoch \"{epoch}\": {source}")]
    Epoch {
        /// The epoch's name.
        epoch: String,
        /// What failed.
        source: Box<AlignError>,
    },
    /// A geometric solver failed where the orientation needed it.
    #[error(transparent)]
    Geometry(#[from] timesift_geometry::GeometryError),
    /// The bundle adjustment rejected or failed a problem.
    #[error(transparent)]
    Bundle(#[from] timesift_bundle::BundleError),
}

impl AlignError {
    /// The message with images called by `name` (the caller's paths: this crate knows only
    /// indices) where it names any.
    pub fn to_string_naming(&self, name: &dyn Fn(usize) -> String) -> String {
        match self {
            AlignError::NoBaseline {
                pairs,
                first,
                second,
                displacement_px,
            } => no_baseline_text(*pairs, &name(*first), &name(*second), *displacement_px),
            AlignError::Epoch { epoch, source } => {
                format!("epoch \"{epoch}\": {}", source.to_string_naming(name))
            }
            other => other.to_string(),
        }
    }
}

fn image_label(index: &usize) -> String {
    format!("image {index}")
}

fn no_baseline_text(pairs: usize, first: &str, second: &str, displacement_px: f64) -> String {
    format!(
        "no baseline: each of the {pairs} most connected image pairs shows the same view pixel \
         for pixel (e.g. {first} and {second}, median displacement {displacement_px:.2} px): the \
         images are identical or were taken from one spot; the block needs photos taken from \
         different places"
    )
}
