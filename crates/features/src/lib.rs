//! Feature extraction: Gaussian scale space, SIFT (with RootSIFT) and binary LDB descriptors behind
//! one [`FeatureExtractor`] trait.
//!
//! This stage decides whether epochs years apart can be joined at all, so both descriptors are
//! computed on the same scale-invariant, oriented keypoints (Lowe 2004): SIFT for accuracy,
//! LDB for speed and compact storage on large blocks.
//!
//! Map: [`options`] (detector options) → `pyramid` (octaves in bands of rows, memory-bounded) →
//! `detect` (DoG extrema, refinement) → `orientation` → [`limit`] (budget spread over the image) →
//! [`sift`] / [`ldb`] descriptors; [`text`] is the inspection format of docs/design.md and [`files`]
//! runs many images in parallel.
//!
//! Invariants: depends only on `timesift-core` (keypoint and descriptor types) and `timesift-io`
//! (image decoding); knows nothing of epochs, matching or geometry. Pixel coordinates follow
//! docs/design.md (the centre of the top-left pixel is (0.5, 0.5)); `Keypoint::scale` is the σ of the
//! blob the keypoint stands for, in full-resolution pixels; orientations are radians in the image
//! frame (x right, y down). Results do not depend on the number of threads or the memory budget.
//!
//! # Example
//!
//! SIFT keypoints of an image of soft blobs (any grey image in [0, 1] will do; from a file,
//! [`GreyImage::from_io`] wraps what `timesift_io::image` decodes):
//!
//! ```
//! use timesift_features::{FeatureExtractor, GreyImage, SiftExtractor};
//!
//! let (width, height) = (160, 120);
//! let pixels = timesift_features::doc_example::blobs(width, height, 0.0);
//! let image = GreyImage::new(width, height, &pixels)?;
//! let features = SiftExtractor::default().extract(&image, None)?;
//! assert!(features.keypoints.len() >= 20);
//! assert_eq!(features.descriptors.len(), features.keypoints.len());
//! assert_eq!(features.descriptors.width(), 128);
//! let inside = |k: &timesift_core::Keypoint| {
//!     k.x > 0.0 && k.x < width as f64 && k.y > 0.0 && k.y < height as f64
//! };
//! assert!(features.keypoints.iter().all(inside));
//! # Ok::<(), timesift_features::FeatureError>(())
//! ```

#![warn(missing_docs, unnameable_types)]

mod blur;
mod detect;
pub mod doc_example;
mod error;
mod extract;
mod fastmath;
pub mod files;
mod image;
pub mod ldb;
pub mod limit;
pub mod options;
mod orientation;
mod pyramid;
pub mod sift;
pub mod text;

pub use error::FeatureError;
pub use extract::MIN_IMAGE_SIDE;
pub use image::{GreyImage, Mask};
pub use options::{DetectorOptions, KeypointLimit, Orientation, Upsample};
pub use sift::SiftNormalization;

use timesift_core::{Descriptors, Keypoint};

/// Keypoints and their descriptors (`descriptors.len() == keypoints.len()`).
#[derive(Debug, Clone, PartialEq)]
pub struct Features {
    /// The keypoints, in the order of the descriptors.
    pub keypoints: Vec<Keypoint>,
    /// One descriptor per keypoint.
    pub descriptors: Descriptors,
}

/// Image (grey, optional mask) → keypoints and descriptors.
pub trait FeatureExtractor: Sync {
    /// Short name: `sift`, `rootsift`, `ldb`.
    fn name(&self) -> &'static str;
    /// Extracts the features of one image.
    fn extract(&self, image: &GreyImage, mask: Option<&Mask>) -> Result<Features, FeatureError>;
}

/// SIFT keypoints with SIFT or RootSIFT descriptors (128 floats, unit L2 norm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SiftExtractor {
    /// Scale space, detection and orientation options.
    pub detector: DetectorOptions,
    /// SIFT (L2) or RootSIFT normalisation of the descriptors.
    pub normalization: SiftNormalization,
}

impl Default for SiftExtractor {
    fn default() -> Self {
        Self {
            detector: DetectorOptions::default(),
            normalization: SiftNormalization::L2,
        }
    }
}

impl FeatureExtractor for SiftExtractor {
    fn name(&self) -> &'static str {
        match self.normalization {
            SiftNormalization::L2 => "sift",
            SiftNormalization::Root => "rootsift",
        }
    }

    fn extract(&self, image: &GreyImage, mask: Option<&Mask>) -> Result<Features, FeatureError> {
        let describer = sift::SiftDescriber {
            normalization: self.normalization,
        };
        let (keypoints, data) = extract::extract(image, mask, &self.detector, &describer)?;
        Ok(Features {
            keypoints,
            descriptors: Descriptors::Float {
                dim: sift::SIFT_DIM,
                data,
            },
        })
    }
}

/// SIFT keypoints with binary LDB descriptors (61 bytes, Hamming distance).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LdbExtractor {
    /// Scale space, detection and orientation options.
    pub detector: DetectorOptions,
}

impl FeatureExtractor for LdbExtractor {
    fn name(&self) -> &'static str {
        "ldb"
    }

    fn extract(&self, image: &GreyImage, mask: Option<&Mask>) -> Result<Features, FeatureError> {
        let (keypoints, data) = extract::extract(image, mask, &self.detector, &ldb::LdbDescriber)?;
        Ok(Features {
            keypoints,
            descriptors: Descriptors::Binary {
                bytes: ldb::LDB_BYTES,
                data,
            },
        })
    }
}

/// Keypoints only (no descriptor): the detector of every extractor.
pub fn detect(
    image: &GreyImage,
    mask: Option<&Mask>,
    options: &DetectorOptions,
) -> Result<Vec<Keypoint>, FeatureError> {
    Ok(extract::extract(image, mask, options, &extract::NoDescriptor)?.0)
}
