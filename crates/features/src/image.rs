//! The inputs of extraction (a borrowed grey image and an optional mask) and the owned plane the
//! scale space is built of.

use crate::FeatureError;

/// A grey image borrowed from the caller: row-major, values in [0, 1] (the contrast threshold is
/// expressed on that range, as in Lowe's and OpenCV's SIFT).
#[derive(Debug, Clone, Copy)]
pub struct GreyImage<'a> {
    width: usize,
    height: usize,
    data: &'a [f32],
}

impl<'a> GreyImage<'a> {
    /// Wraps `data` (`width × height` values, row-major). Non-finite values are an error, so that
    /// a NaN never spreads through the scale space into keypoints.
    pub fn new(width: usize, height: usize, data: &'a [f32]) -> Result<Self, FeatureError> {
        if width.checked_mul(height) != Some(data.len()) {
            return Err(FeatureError::BufferSize {
                width,
                height,
                got: data.len(),
            });
        }
        let mut bad = data.iter().enumerate().filter(|(_, v)| !v.is_finite());
        if let Some((first, _)) = bad.next() {
            return Err(FeatureError::NonFinitePixels {
                count: 1 + bad.count(),
                col: first % width,
                row: first / width,
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Wraps a decoded grey image of `timesift-io`.
    pub fn from_io(image: &'a timesift_io::image::ImageF32) -> Result<Self, FeatureError> {
        if image.channels != 1 {
            return Err(FeatureError::InvalidOption {
                name: "channels",
                value: image.channels as f64,
                expected: "a grey image (1 channel)",
            });
        }
        Self::new(image.width as usize, image.height as usize, &image.data)
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The pixel values, row-major.
    pub fn data(&self) -> &'a [f32] {
        self.data
    }
}

/// Where keypoints may be detected: non-zero allows, zero excludes (scan frames and fiducials, sky,
/// water). Same size as the image.
#[derive(Debug, Clone, Copy)]
pub struct Mask<'a> {
    width: usize,
    height: usize,
    data: &'a [u8],
}

impl<'a> Mask<'a> {
    /// Wraps `data` (`width × height` bytes, row-major).
    pub fn new(width: usize, height: usize, data: &'a [u8]) -> Result<Self, FeatureError> {
        if width.checked_mul(height) != Some(data.len()) {
            return Err(FeatureError::BufferSize {
                width,
                height,
                got: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Whether a keypoint at pixel coordinates (x, y) (docs/design.md convention) is allowed.
    pub fn allows(&self, x: f64, y: f64) -> bool {
        if !(x >= 0.0 && y >= 0.0) {
            return false;
        }
        let (col, row) = (x as usize, y as usize);
        col < self.width && row < self.height && self.data[row * self.width + col] != 0
    }

    pub(crate) fn check_size(&self, width: usize, height: usize) -> Result<(), FeatureError> {
        if self.width != width || self.height != height {
            return Err(FeatureError::MaskSize {
                width,
                height,
                mask_width: self.width,
                mask_height: self.height,
            });
        }
        Ok(())
    }
}

/// An owned single-channel f32 raster, row-major.
#[derive(Debug, Clone, Default)]
pub(crate) struct Plane {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Plane {
    pub fn zeros(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    pub fn row(&self, y: usize) -> &[f32] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// Bilinear sample at index coordinates (pixel centres at integers), clamped to the plane.
    /// Coordinates are f64 and split into whole and fractional parts before any rounding to f32,
    /// so the sample does not depend on where the plane starts (bands of rows give the values
    /// the whole image would).
    #[inline]
    pub fn bilinear(&self, x: f64, y: f64) -> f32 {
        let x = x.clamp(0.0, (self.width - 1) as f64);
        let y = y.clamp(0.0, (self.height - 1) as f64);
        let x0 = (x as usize).min(self.width.saturating_sub(2));
        let y0 = (y as usize).min(self.height.saturating_sub(2));
        let fx = (x - x0 as f64) as f32;
        let fy = (y - y0 as f64) as f32;
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x1, y0) * fx;
        let bottom = self.at(x0, y1) * (1.0 - fx) + self.at(x1, y1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}
