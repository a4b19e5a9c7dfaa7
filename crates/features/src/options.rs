//! Options of the detector shared by every descriptor: the scale space, the extremum tests, the
//! orientation and the keypoint limit.

use crate::FeatureError;

/// Whether the first octave works on the image doubled in size (Lowe 2004, §3.3): about four times
/// more stable keypoints at the smallest scales, for four times the memory of the first octave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Upsample {
    /// Never double; the first octave is the image itself.
    Never,
    /// Always double.
    Always,
    /// Double images of at most this many pixels: keeps memory bounded on 100 MP scans, whose
    /// finest details are grain rather than ground.
    UpToPixels(u64),
}

/// How keypoints are oriented.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Orientation {
    /// Every peak of the 36-bin gradient histogram within `peak_ratio` of the highest gives one
    /// keypoint (Lowe: 0.8).
    Dominant {
        /// Least height of a secondary peak relative to the highest.
        peak_ratio: f64,
    },
    /// Orientation 0 for every keypoint: for images known to share their rotation (nadir blocks
    /// flown the same way, ortho-rectified scans), more distinctive and faster.
    Upright,
}

/// How many keypoints to keep and how to choose them (see [`crate::limit`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeypointLimit {
    /// Keep at most this many keypoints (each orientation of a location counts).
    pub max: usize,
    /// The image is cut into about this many square cells.
    pub cells: usize,
    /// Share of the budget dealt out cell by cell before the rest goes to the strongest anywhere:
    /// 0 keeps the strongest responses of the whole image (OpenCV's `nfeatures`), 1 spreads the
    /// whole budget.
    pub spread: f64,
}

impl KeypointLimit {
    /// `max` keypoints, half of them dealt over an 8 × 8 grid: a textured corner cannot take the
    /// whole budget, yet the strongest keypoints (the ones that survive years between epochs)
    /// are rarely dropped for weak ones in featureless cells.
    pub fn spread(max: usize) -> Self {
        Self {
            max,
            cells: 64,
            spread: 0.5,
        }
    }
}

/// Options of the scale-space detector (defaults: Lowe 2004 as implemented by OpenCV).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorOptions {
    /// Scales per octave at which extrema are sought (Lowe: 3).
    pub layers_per_octave: usize,
    /// Blur of each octave's first layer, in that octave's pixels (Lowe: 1.6).
    pub sigma: f64,
    /// Blur already present in the input image, in its pixels (Lowe: 0.5).
    pub assumed_blur: f64,
    /// Minimum |DoG| contrast at a keypoint, for images in [0, 1], before division by
    /// `layers_per_octave` (OpenCV: 0.04).
    pub contrast_threshold: f64,
    /// Maximum ratio of principal curvatures; edges above it are rejected (Lowe: 10).
    pub edge_ratio: f64,
    /// Whether the first octave is the doubled image.
    pub upsample: Upsample,
    /// Orientation assignment.
    pub orientation: Orientation,
    /// Keypoint budget; `None` keeps every keypoint.
    pub limit: Option<KeypointLimit>,
    /// Bytes the scale space of one image may hold at once, beyond the octave bases (which take
    /// 4/3 of the image's own f32 size without upsampling, 16/3 with). Above it, octaves are
    /// processed in horizontal bands (with enough overlap that results are identical); a quarter
    /// of it may keep the Gaussian layers of finished bands for the descriptors, which are
    /// otherwise recomputed. Smaller bands are also faster (they stay in cache), so the default
    /// is modest. `cargo xtask bench features --large` prints the peak memory of a 100 MP image
    /// for several budgets.
    pub memory_budget: usize,
}

impl Default for DetectorOptions {
    fn default() -> Self {
        Self {
            layers_per_octave: 3,
            sigma: 1.6,
            assumed_blur: 0.5,
            contrast_threshold: 0.04,
            edge_ratio: 10.0,
            upsample: Upsample::UpToPixels(30_000_000),
            orientation: Orientation::Dominant { peak_ratio: 0.8 },
            limit: None,
            memory_budget: 512 << 20,
        }
    }
}

impl DetectorOptions {
    /// Checks every option's domain.
    pub fn validate(&self) -> Result<(), FeatureError> {
        let invalid = |name, value: f64, expected| {
            Err(FeatureError::InvalidOption {
                name,
                value,
                expected,
            })
        };
        if !(1..=8).contains(&self.layers_per_octave) {
            return invalid(
                "layers_per_octave",
                self.layers_per_octave as f64,
                "between 1 and 8",
            );
        }
        // Windows are capped at 96 px of the layer: SIFT's reaches 32 σ at the top layer of the
        // last octave, so σ up to 3 keeps every window whole.
        if !(self.sigma > 0.0 && self.sigma <= 3.0) {
            return invalid("sigma", self.sigma, "in (0, 3]");
        }
        if !(self.assumed_blur >= 0.0 && self.assumed_blur < self.sigma) {
            return invalid("assumed_blur", self.assumed_blur, "in [0, sigma)");
        }
        if !(self.contrast_threshold >= 0.0 && self.contrast_threshold.is_finite()) {
            return invalid(
                "contrast_threshold",
                self.contrast_threshold,
                "a non-negative number",
            );
        }
        if !(self.edge_ratio >= 1.0 && self.edge_ratio.is_finite()) {
            return invalid("edge_ratio", self.edge_ratio, "a number ≥ 1");
        }
        if let Orientation::Dominant { peak_ratio } = self.orientation
            && !(peak_ratio > 0.0 && peak_ratio <= 1.0)
        {
            return invalid("peak_ratio", peak_ratio, "in (0, 1]");
        }
        if let Some(limit) = self.limit {
            if limit.cells == 0 {
                return invalid("limit.cells", 0.0, "at least 1");
            }
            if !(0.0..=1.0).contains(&limit.spread) {
                return invalid("limit.spread", limit.spread, "in [0, 1]");
            }
        }
        if self.memory_budget < 1 << 20 {
            return invalid("memory_budget", self.memory_budget as f64, "at least 1 MiB");
        }
        Ok(())
    }
}
