//! Scans and frames as the crate sees them: borrowed row-major f32 pixels of one or more
//! channels, sampled between pixel centres by bicubic convolution (Keys, a = −½), which keeps
//! the sharpness that keypoints and dense matching need and has an exact derivative for
//! least-squares matching.

use crate::FilmError;

/// A borrowed image: `width × height` pixels of `channels` interleaved f32 values, row-major,
/// pixel centres at (i + ½, j + ½) (docs/design.md).
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    width: usize,
    height: usize,
    channels: usize,
    data: &'a [f32],
}

impl<'a> ImageView<'a> {
    /// Wraps `data`; its length must be `width × height × channels`, with 1 to 4 channels.
    pub fn new(
        width: usize,
        height: usize,
        channels: usize,
        data: &'a [f32],
    ) -> Result<Self, FilmError> {
        if !(1..=4).contains(&channels)
            || width
                .checked_mul(height)
                .and_then(|n| n.checked_mul(channels))
                != Some(data.len())
        {
            return Err(FilmError::InvalidScan(format!(
                "{width} × {height} pixels of {channels} channels cannot hold {} values",
                data.len()
            )));
        }
        Ok(ImageView {
            width,
            height,
            channels,
            data,
        })
    }

    /// Columns.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Values per pixel.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// The values, row-major, channels interleaved.
    pub fn data(&self) -> &'a [f32] {
        self.data
    }

    /// Value of channel `c` at pixel (col, row), clamped to the image (edge replicated).
    #[inline]
    pub(crate) fn at(&self, col: isize, row: isize, c: usize) -> f32 {
        let i = col.clamp(0, self.width as isize - 1) as usize;
        let j = row.clamp(0, self.height as isize - 1) as usize;
        self.data[(j * self.width + i) * self.channels + c]
    }

    /// Whether a bicubic sample at (x, y) reads only pixels of the image (its 4 × 4 support).
    #[inline]
    pub(crate) fn supports(&self, x: f64, y: f64) -> bool {
        x >= 1.5 && y >= 1.5 && x <= self.width as f64 - 1.5 && y <= self.height as f64 - 1.5
    }

    /// Bicubic value of channel `c` at (x, y) in pixel coordinates.
    #[inline]
    pub(crate) fn bicubic(&self, x: f64, y: f64, c: usize) -> f64 {
        let (fx, fy) = (x - 0.5, y - 0.5);
        let (i0, j0) = (fx.floor(), fy.floor());
        let (wx, wy) = (keys_weights(fx - i0), keys_weights(fy - j0));
        let (i0, j0) = (i0 as isize - 1, j0 as isize - 1);
        let mut sum = 0.0;
        for (dj, wyj) in wy.iter().enumerate() {
            let mut row = 0.0;
            for (di, wxi) in wx.iter().enumerate() {
                row += wxi * self.at(i0 + di as isize, j0 + dj as isize, c) as f64;
            }
            sum += wyj * row;
        }
        sum
    }

    /// Bicubic value of channel 0 at (x, y) and its gradient (∂/∂x, ∂/∂y).
    #[inline]
    pub(crate) fn bicubic_with_gradient(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let (fx, fy) = (x - 0.5, y - 0.5);
        let (i0, j0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - i0, fy - j0);
        let (wx, wy) = (keys_weights(tx), keys_weights(ty));
        let (dx, dy) = (keys_derivatives(tx), keys_derivatives(ty));
        let (i0, j0) = (i0 as isize - 1, j0 as isize - 1);
        let (mut v, mut gx, mut gy) = (0.0, 0.0, 0.0);
        for j in 0..4 {
            let (mut row, mut drow) = (0.0, 0.0);
            for i in 0..4 {
                let p = self.at(i0 + i as isize, j0 + j as isize, 0) as f64;
                row += wx[i] * p;
                drow += dx[i] * p;
            }
            v += wy[j] * row;
            gx += wy[j] * drow;
            gy += dy[j] * row;
        }
        (v, gx, gy)
    }
}

/// Keys' cubic convolution weights (a = −½) of the four samples around a fraction `t` ∈ [0, 1).
#[inline]
fn keys_weights(t: f64) -> [f64; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        -0.5 * t3 + t2 - 0.5 * t,
        1.5 * t3 - 2.5 * t2 + 1.0,
        -1.5 * t3 + 2.0 * t2 + 0.5 * t,
        0.5 * t3 - 0.5 * t2,
    ]
}

/// The derivatives of [`keys_weights`] with respect to `t`.
#[inline]
fn keys_derivatives(t: f64) -> [f64; 4] {
    let t2 = t * t;
    [
        -1.5 * t2 + 2.0 * t - 0.5,
        4.5 * t2 - 5.0 * t,
        -4.5 * t2 + 4.0 * t + 0.5,
        1.5 * t2 - t,
    ]
}

/// An owned single-channel raster (a reduced scan, a template).
#[derive(Debug, Clone, PartialEq)]
pub struct GreyRaster {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Values, row-major.
    pub data: Vec<f32>,
}

impl GreyRaster {
    /// The raster as a view.
    pub fn view(&self) -> ImageView<'_> {
        ImageView {
            width: self.width,
            height: self.height,
            channels: 1,
            data: &self.data,
        }
    }

    /// The luminance of channel 0 (or the mean of the first three channels of a colour image).
    pub fn luminance(image: &ImageView<'_>) -> GreyRaster {
        let n = image.width * image.height;
        let c = image.channels;
        let data = if c == 1 {
            image.data.to_vec()
        } else {
            let k = c.min(3);
            (0..n)
                .map(|p| image.data[p * c..p * c + k].iter().sum::<f32>() / k as f32)
                .collect()
        };
        GreyRaster {
            width: image.width,
            height: image.height,
            data,
        }
    }

    /// The raster reduced by an integer `factor` (mean of each `factor × factor` block; a
    /// partial block at the right or bottom edge is dropped).
    pub fn reduced(&self, factor: usize) -> GreyRaster {
        if factor <= 1 {
            return self.clone();
        }
        let (w, h) = (self.width / factor, self.height / factor);
        let mut data = vec![0.0f32; w * h];
        let scale = 1.0 / (factor * factor) as f32;
        for (j, row) in data.chunks_mut(w.max(1)).enumerate().take(h) {
            for (i, out) in row.iter_mut().enumerate() {
                let mut s = 0.0;
                for y in j * factor..(j + 1) * factor {
                    let line = &self.data[y * self.width + i * factor..][..factor];
                    s += line.iter().sum::<f32>();
                }
                *out = s * scale;
            }
        }
        GreyRaster {
            width: w,
            height: h,
            data,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bicubic_interpolates_pixel_centres_and_linear_ramps_exactly() {
        let (w, h) = (9, 7);
        let data: Vec<f32> = (0..w * h)
            .map(|k| 2.0 * (k % w) as f32 + 3.0 * (k / w) as f32)
            .collect();
        let view = ImageView::new(w, h, 1, &data).unwrap();
        assert_eq!(view.bicubic(3.5, 2.5, 0), data[2 * w + 3] as f64);
        // A ramp v = 2 (x − ½) + 3 (y − ½) inside the image, and its gradient.
        let (v, gx, gy) = view.bicubic_with_gradient(4.3, 3.9);
        assert!((v - (2.0 * 3.8 + 3.0 * 3.4)).abs() < 1e-9, "{v}");
        assert!(
            (gx - 2.0).abs() < 1e-9 && (gy - 3.0).abs() < 1e-9,
            "{gx} {gy}"
        );
    }

    #[test]
    fn the_bicubic_gradient_is_the_derivative_of_the_value() {
        let (w, h) = (12, 12);
        let data: Vec<f32> = (0..w * h)
            .map(|k| ((k % w) as f32 * 0.7).sin() * ((k / w) as f32 * 0.4).cos())
            .collect();
        let view = ImageView::new(w, h, 1, &data).unwrap();
        let (x, y, e) = (5.37, 6.81, 1e-6);
        let (_, gx, gy) = view.bicubic_with_gradient(x, y);
        let fx = (view.bicubic(x + e, y, 0) - view.bicubic(x - e, y, 0)) / (2.0 * e);
        let fy = (view.bicubic(x, y + e, 0) - view.bicubic(x, y - e, 0)) / (2.0 * e);
        assert!((gx - fx).abs() < 1e-6 && (gy - fy).abs() < 1e-6);
    }

    #[test]
    fn a_buffer_of_the_wrong_size_is_an_error() {
        assert!(ImageView::new(4, 4, 1, &[0.0; 15]).is_err());
        assert!(ImageView::new(4, 4, 5, &[0.0; 80]).is_err());
    }

    #[test]
    fn reduction_averages_blocks() {
        let r = GreyRaster {
            width: 4,
            height: 2,
            data: vec![0.0, 2.0, 4.0, 6.0, 2.0, 4.0, 6.0, 8.0],
        };
        assert_eq!(r.reduced(2).data, vec![2.0, 6.0]);
    }
}
