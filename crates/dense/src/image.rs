//! Image planes at the working resolution: grey intensities for matching, colours for the fused
//! points, and the mask of usable pixels.
//!
//! Pixel convention of docs/design.md: pixel (i, j) covers [i, i+1) × [j, j+1), its value sits at its
//! centre (i + 0.5, j + 0.5).

/// A borrowed image with interleaved channels (1 grey or 3 RGB), values in [0, 1]: what the
/// caller decoded, in the original (distorted) pixel grid.
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// 1 (grey) or 3 (RGB).
    pub channels: usize,
    /// Row-major samples, channels interleaved, `width * height * channels` of them.
    pub data: &'a [f32],
}

/// A single-channel f32 image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width * height` values.
    pub data: Vec<f32>,
}

impl Plane {
    /// A plane filled with `value`.
    pub fn filled(width: usize, height: usize, value: f32) -> Plane {
        Plane {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// The value of pixel (i, j).
    #[inline]
    pub fn at(&self, i: usize, j: usize) -> f32 {
        self.data[j * self.width + i]
    }

    /// Bilinear interpolation at continuous pixel coordinates (u, v) between pixel centres;
    /// `None` outside the band of pixel centres (no extrapolation).
    #[inline]
    pub fn bilinear(&self, u: f32, v: f32) -> Option<f32> {
        let x = u - 0.5;
        let y = v - 0.5;
        // `!(a >= b)` also rejects NaN.
        if !(x >= 0.0 && y >= 0.0) {
            return None;
        }
        let (i, j) = (x as usize, y as usize);
        if i + 1 >= self.width || j + 1 >= self.height {
            return None;
        }
        let (fx, fy) = (x - i as f32, y - j as f32);
        let row = j * self.width + i;
        let (a, b) = (self.data[row], self.data[row + 1]);
        let (c, d) = (self.data[row + self.width], self.data[row + self.width + 1]);
        let top = a + (b - a) * fx;
        let bottom = c + (d - c) * fx;
        Some(top + (bottom - top) * fy)
    }

    /// Half the resolution by 2 × 2 box averaging (an odd last row or column is dropped), so that
    /// continuous coordinates halve exactly: `u_half = u / 2`.
    pub fn half(&self) -> Plane {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut data = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                let s = self.at(2 * i, 2 * j)
                    + self.at(2 * i + 1, 2 * j)
                    + self.at(2 * i, 2 * j + 1)
                    + self.at(2 * i + 1, 2 * j + 1);
                data.push(0.25 * s);
            }
        }
        Plane {
            width: w,
            height: h,
            data,
        }
    }
}

/// Which pixels may produce depths (film frames, fiducials and no-data borders may not).
#[derive(Debug, Clone, PartialEq)]
pub struct Mask {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `true` where the pixel is usable.
    pub usable: Vec<bool>,
}

impl Mask {
    /// Every pixel usable.
    pub fn all(width: usize, height: usize) -> Mask {
        Mask {
            width,
            height,
            usable: vec![true; width * height],
        }
    }

    /// Whether pixel (i, j) is usable.
    #[inline]
    pub fn at(&self, i: usize, j: usize) -> bool {
        self.usable[j * self.width + i]
    }

    /// Half the resolution: a pixel is usable when all four pixels it covers are.
    pub fn half(&self) -> Mask {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut usable = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                usable.push(
                    self.at(2 * i, 2 * j)
                        && self.at(2 * i + 1, 2 * j)
                        && self.at(2 * i, 2 * j + 1)
                        && self.at(2 * i + 1, 2 * j + 1),
                );
            }
        }
        Mask {
            width: w,
            height: h,
            usable,
        }
    }

    /// Number of usable pixels.
    pub fn count(&self) -> usize {
        self.usable.iter().filter(|&&u| u).count()
    }
}

/// A view resampled to its working camera: grey intensities for matching, linear RGB for the
/// colour of fused points, and the usable pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkingImage {
    /// Grey intensities (Rec. 601 luma of the colours), 0–1.
    pub grey: Plane,
    /// Colour per pixel, 0–1.
    pub rgb: Vec<[f32; 3]>,
    /// Pixels that may produce depths.
    pub mask: Mask,
}

impl WorkingImage {
    /// Columns.
    pub fn width(&self) -> usize {
        self.grey.width
    }
    /// Rows.
    pub fn height(&self) -> usize {
        self.grey.height
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_is_exact_on_a_linear_ramp_and_none_outside() {
        let mut p = Plane::filled(5, 4, 0.0);
        for j in 0..4 {
            for i in 0..5 {
                p.data[j * 5 + i] = 2.0 * (i as f32 + 0.5) - 3.0 * (j as f32 + 0.5);
            }
        }
        let v = p.bilinear(2.3, 1.7).unwrap();
        assert!((v - (2.0 * 2.3 - 3.0 * 1.7)).abs() < 1e-5);
        assert!(p.bilinear(0.4, 1.0).is_none());
        assert!(p.bilinear(4.6, 1.0).is_none());
        assert!(p.bilinear(f32::NAN, 1.0).is_none());
    }

    #[test]
    fn half_keeps_continuous_coordinates() {
        // A linear ramp in u: after halving, the value at u/2 equals the value at u.
        let mut p = Plane::filled(8, 4, 0.0);
        for j in 0..4 {
            for i in 0..8 {
                p.data[j * 8 + i] = i as f32 + 0.5;
            }
        }
        let h = p.half();
        assert_eq!((h.width, h.height), (4, 2));
        let at = h.bilinear(1.5, 1.0).unwrap();
        assert!((at - 3.0).abs() < 1e-6, "{at}");
    }
}
