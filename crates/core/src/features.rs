//! Keypoints and descriptors: what the features stage produces and the matching stage consumes.

/// A detected keypoint in pixel coordinates (docs/design.md convention: centre of the top-left pixel at
/// (0.5, 0.5)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    /// Column coordinate, pixels.
    pub x: f64,
    /// Row coordinate, pixels.
    pub y: f64,
    /// Detection scale (σ of the blob in pixels of the full-resolution image).
    pub scale: f64,
    /// Dominant orientation, radians.
    pub orientation: f64,
    /// Detector response; larger is stronger.
    pub response: f32,
    /// Octave of the scale space the keypoint came from (−1 for the doubled image).
    pub octave: i16,
}

/// The descriptors of all keypoints of one image, stored contiguously.
#[derive(Debug, Clone, PartialEq)]
pub enum Descriptors {
    /// Real-valued descriptors (e.g. SIFT, RootSIFT): `data.len() == count * dim`.
    Float {
        /// Values per descriptor.
        dim: usize,
        /// The descriptors, one after another.
        data: Vec<f32>,
    },
    /// Binary descriptors compared by Hamming distance (e.g. LDB): `data.len() == count * bytes`.
    Binary {
        /// Bytes per descriptor.
        bytes: usize,
        /// The descriptors, one after another.
        data: Vec<u8>,
    },
}

impl Descriptors {
    /// Number of descriptors held.
    pub fn len(&self) -> usize {
        match self {
            Descriptors::Float { dim, data } => data.len().checked_div(*dim).unwrap_or(0),
            Descriptors::Binary { bytes, data } => data.len().checked_div(*bytes).unwrap_or(0),
        }
    }

    /// Whether no descriptor is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Length of one descriptor: values for float, bytes for binary.
    pub fn width(&self) -> usize {
        match self {
            Descriptors::Float { dim, .. } => *dim,
            Descriptors::Binary { bytes, .. } => *bytes,
        }
    }
}
