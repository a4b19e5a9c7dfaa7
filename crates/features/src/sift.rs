//! The SIFT descriptor (Lowe 2004, §6): a 4×4 grid of 8-bin gradient-orientation histograms over
//! the oriented patch, with trilinear interpolation and a Gaussian window; normalised, clamped at
//! 0.2 and normalised again. RootSIFT (Arandjelović & Zisserman 2012) then takes the square root
//! of the L1-normalised vector, so that Euclidean distance compares like the Hellinger kernel.

use std::f32::consts::{SQRT_2, TAU};

use crate::extract::{Describer, LocalKeypoint};
use crate::fastmath::atan2_positive;
use crate::image::Plane;

/// Spatial cells per side.
const CELLS: usize = 4;
/// Orientation bins per cell.
const BINS: usize = 8;
/// Width of a cell, in units of the keypoint's σ.
const CELL_WIDTH: f32 = 3.0;
/// Values per descriptor.
pub const SIFT_DIM: usize = CELLS * CELLS * BINS;
/// Clamp of normalised values (Lowe: 0.2), against non-linear illumination changes.
const CLAMP: f32 = 0.2;
/// Largest sampling radius, pixels of the layer (`DetectorOptions::validate` keeps σ small
/// enough that no window reaches it).
const MAX_RADIUS: usize = 96;
/// Side of the histogram's grid: the cells and one more on each side, which trilinear
/// interpolation spreads samples into.
const SIDE: usize = CELLS + 2;
/// Values of the histogram: `SIDE²` cells of `BINS + 2` orientation bins (two wrap around).
const HIST_LEN: usize = SIDE * SIDE * (BINS + 2);
/// Samples along one side of the largest window.
const WINDOW: usize = 2 * MAX_RADIUS + 1;

/// How the descriptor is normalised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SiftNormalization {
    /// Unit L2 norm after the 0.2 clamp (Lowe).
    L2,
    /// RootSIFT: square root of the L1-normalised descriptor (unit L2 norm too).
    Root,
}

pub(crate) struct SiftDescriber {
    pub normalization: SiftNormalization,
}

impl Describer for SiftDescriber {
    type Elem = f32;

    fn width(&self) -> usize {
        SIFT_DIM
    }

    fn support(&self) -> f64 {
        (CELL_WIDTH * SQRT_2 * (CELLS as f32 + 1.0) * 0.5) as f64
    }

    fn describe(&self, layer: &Plane, kp: &LocalKeypoint, out: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            unsafe { describe_avx2(layer, kp, out) };
            normalise(out, self.normalization);
            return;
        }
        describe_portable(layer, kp, out);
        normalise(out, self.normalization);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn describe_avx2(layer: &Plane, kp: &LocalKeypoint, out: &mut [f32]) {
    describe_portable(layer, kp, out)
}

/// The raw (unnormalised) histogram descriptor.
#[inline(always)]
fn describe_portable(layer: &Plane, kp: &LocalKeypoint, out: &mut [f32]) {
    let window = Window::new(kp);
    let mut hist = [0.0f32; HIST_LEN];
    let mut samples = RowSamples {
        rbins: [0.0f32; WINDOW],
        cbins: [0.0f32; WINDOW],
        obins: [0.0f32; WINDOW],
        magnitudes: [0.0f32; WINDOW],
    };
    for i in -window.r..=window.r {
        if let Some(n) = window.sample_row(layer, i, &mut samples) {
            spread_row(&samples, n, &mut hist);
        }
    }
    fold_and_copy_cells(&mut hist, out);
}

/// The oriented, Gaussian-weighted sampling window of one keypoint.
struct Window {
    /// The pixel the sampled grid is centred on (the keypoint, rounded).
    cx: isize,
    cy: isize,
    /// Half the side of the sampled square, pixels.
    r: isize,
    /// Offsets of the sampled grid from the true (sub-pixel) keypoint.
    fx: f32,
    fy: f32,
    /// Cosine and sine of the keypoint's angle over the cell width: pixels to cells.
    cos_t: f32,
    sin_t: f32,
    /// The keypoint's angle, radians.
    angle: f32,
    /// Gaussian weights of the columns and rows (σ = half the descriptor width; separable).
    wx: [f32; WINDOW],
    wy: [f32; WINDOW],
}

/// One row's gradient samples: their row, column and orientation bins (fractional) and weighted
/// magnitudes.
struct RowSamples {
    rbins: [f32; WINDOW],
    cbins: [f32; WINDOW],
    obins: [f32; WINDOW],
    magnitudes: [f32; WINDOW],
}

impl Window {
    /// The window of `kp`.
    #[inline(always)]
    fn new(kp: &LocalKeypoint) -> Window {
        let cell = CELL_WIDTH * kp.sigma;
        let radius =
            ((cell * SQRT_2 * (CELLS as f32 + 1.0) * 0.5).round() as usize).min(MAX_RADIUS);
        let r = radius as isize;
        let (cx, cy) = (kp.x.round() as isize, kp.y.round() as isize);
        let (fx, fy) = ((cx as f64 - kp.x) as f32, (cy as f64 - kp.y) as f32);
        let (cos_t, sin_t) = (kp.angle.cos() / cell, kp.angle.sin() / cell);
        let exp_scale = -1.0 / (0.5 * (CELLS * CELLS) as f32) / (cell * cell);
        let mut wx = [0.0f32; WINDOW];
        let mut wy = [0.0f32; WINDOW];
        for k in 0..=2 * radius {
            let d = k as f32 - radius as f32;
            wx[k] = ((d + fx) * (d + fx) * exp_scale).exp();
            wy[k] = ((d + fy) * (d + fy) * exp_scale).exp();
        }
        Window {
            cx,
            cy,
            r,
            fx,
            fy,
            cos_t,
            sin_t,
            angle: kp.angle,
            wx,
            wy,
        }
    }

    /// Samples row `i` of the window (relative to the centre) into `samples`, in a loop that
    /// vectorises: only the columns whose rotated position falls inside the (CELLS + 2)² bins
    /// (the rotated square is about half of the sampling square). Returns how many; `None`
    /// when the row is outside the layer or none falls inside.
    #[inline(always)]
    fn sample_row(&self, layer: &Plane, i: isize, samples: &mut RowSamples) -> Option<usize> {
        let (cx, cy, r) = (self.cx, self.cy, self.r);
        let (cos_t, sin_t) = (self.cos_t, self.sin_t);
        let half = CELLS as f32 / 2.0 - 0.5;
        let bins_per_radian = BINS as f32 / TAU;
        let (w, h) = (layer.width as isize, layer.height as isize);
        let limit = CELLS as f32;
        let py = cy + i;
        if py <= 0 || py >= h - 1 {
            return None;
        }
        let dy = i as f32 + self.fy;
        let (c_lo, c_hi) = open_interval(cos_t, dy * sin_t + half, -1.0, limit);
        let (r_lo, r_hi) = open_interval(-sin_t, dy * cos_t + half, -1.0, limit);
        let lo = c_lo.max(r_lo).max(-(r as f32) - 1.0).max(-(cx as f32));
        let hi = c_hi.min(r_hi).min(r as f32 + 1.0).min((w - 1 - cx) as f32);
        if !(lo < hi) {
            return None;
        }
        let j_first = lo.floor() as isize + 1;
        let j_last = hi.ceil() as isize - 1;
        if j_last < j_first {
            return None;
        }
        let row = layer.row(py as usize);
        let (above, below) = (layer.row(py as usize - 1), layer.row(py as usize + 1));
        let weight_y = self.wy[(i + r) as usize];
        let n = (j_last - j_first + 1) as usize;
        let first_px = (cx + j_first) as usize;
        for k in 0..n {
            let p = first_px + k;
            let j = j_first + k as isize;
            let dx = j as f32 + self.fx;
            let gx = row[p + 1] - row[p - 1];
            let gy = below[p] - above[p];
            samples.cbins[k] = dx * cos_t + dy * sin_t + half;
            samples.rbins[k] = -dx * sin_t + dy * cos_t + half;
            samples.magnitudes[k] =
                (gx * gx + gy * gy).sqrt() * weight_y * self.wx[(j + r) as usize];
            let mut obin = (atan2_positive(gy, gx) - self.angle) * bins_per_radian;
            if obin < 0.0 {
                obin += BINS as f32;
            }
            if obin >= BINS as f32 {
                obin -= BINS as f32;
            }
            samples.obins[k] = obin;
        }
        Some(n)
    }
}

/// Spreads the first `n` samples of a row into the histogram by trilinear interpolation.
#[inline(always)]
fn spread_row(samples: &RowSamples, n: usize, hist: &mut [f32; HIST_LEN]) {
    let limit = CELLS as f32;
    let row_step = SIDE * (BINS + 2);
    let col_step = BINS + 2;
    for k in 0..n {
        let (rbin, cbin, obin) = (samples.rbins[k], samples.cbins[k], samples.obins[k]);
        // Guard against rounding at the interval ends.
        if !(rbin > -1.0 && rbin < limit && cbin > -1.0 && cbin < limit) {
            continue;
        }
        // Both bins exceed −1, so truncation after +1 is a floor (capped: just below CELLS,
        // the sum can round up to CELLS + 1).
        let r0 = ((rbin + 1.0) as usize).min(CELLS);
        let c0 = ((cbin + 1.0) as usize).min(CELLS);
        let o0 = (obin as usize).min(BINS - 1);
        let (fr, fc, fo) = (
            rbin + 1.0 - r0 as f32,
            cbin + 1.0 - c0 as f32,
            obin - o0 as f32,
        );
        let index = (r0 * SIDE + c0) * (BINS + 2) + o0;
        let magnitude = samples.magnitudes[k];
        let v_r1 = magnitude * fr;
        let v_r0 = magnitude - v_r1;
        let v_rc11 = v_r1 * fc;
        let v_rc10 = v_r1 - v_rc11;
        let v_rc01 = v_r0 * fc;
        let v_rc00 = v_r0 - v_rc01;
        for (offset, v) in [
            (0, v_rc00),
            (col_step, v_rc01),
            (row_step, v_rc10),
            (row_step + col_step, v_rc11),
        ] {
            let v1 = v * fo;
            hist[index + offset] += v - v1;
            hist[index + offset + 1] += v1;
        }
    }
}

/// Folds the wrapped-around bins of the inner CELLS² cells of the histogram back in and copies
/// those cells to `out`.
#[inline(always)]
fn fold_and_copy_cells(hist: &mut [f32; HIST_LEN], out: &mut [f32]) {
    for i in 0..CELLS {
        for j in 0..CELLS {
            let index = ((i + 1) * SIDE + j + 1) * (BINS + 2);
            hist[index] += hist[index + BINS];
            hist[index + 1] += hist[index + BINS + 1];
            let dst = &mut out[(i * CELLS + j) * BINS..(i * CELLS + j + 1) * BINS];
            dst.copy_from_slice(&hist[index..index + BINS]);
        }
    }
}

/// The values of t for which `lo < a·t + b < hi`, as an open interval (empty when lo ≥ hi).
fn open_interval(a: f32, b: f32, lo: f32, hi: f32) -> (f32, f32) {
    if a.abs() < 1e-12 {
        return if lo < b && b < hi {
            (f32::NEG_INFINITY, f32::INFINITY)
        } else {
            (1.0, 0.0)
        };
    }
    let (t1, t2) = ((lo - b) / a, (hi - b) / a);
    (t1.min(t2), t1.max(t2))
}

/// Unit L2 norm, clamp, unit L2 norm again; then the RootSIFT mapping if asked for. A descriptor
/// of a flat patch stays zero.
fn normalise(d: &mut [f32], normalization: SiftNormalization) {
    let norm = d.iter().map(|v| v * v).sum::<f32>().sqrt();
    if norm <= f32::MIN_POSITIVE {
        d.fill(0.0);
        return;
    }
    let limit = CLAMP * norm;
    d.iter_mut().for_each(|v| *v = v.min(limit));
    let norm = d.iter().map(|v| v * v).sum::<f32>().sqrt();
    d.iter_mut().for_each(|v| *v /= norm);
    if normalization == SiftNormalization::Root {
        let l1: f32 = d.iter().sum();
        d.iter_mut().for_each(|v| *v = (*v / l1).sqrt());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalised_descriptors_have_unit_norm_and_bounded_values() {
        let mut d: Vec<f32> = (0..SIFT_DIM).map(|i| ((i * 37) % 11) as f32).collect();
        d[5] = 100.0;
        let mut root = d.clone();
        let norm0: f32 = d.iter().map(|v| v * v).sum::<f32>().sqrt();
        let ten = (0..SIFT_DIM).find(|&i| d[i] == 10.0).unwrap();
        normalise(&mut d, SiftNormalization::L2);
        let norm: f32 = d.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-5);
        // The peak was clamped to 0.2 of the first norm; unclamped values keep their ratios.
        let ratio = d[5] / d[ten];
        assert!((ratio - 0.2 * norm0 / 10.0).abs() < 1e-4, "{ratio}");
        normalise(&mut root, SiftNormalization::Root);
        let norm: f32 = root.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-5);
        let mut flat = vec![0.0f32; SIFT_DIM];
        normalise(&mut flat, SiftNormalization::Root);
        assert!(flat.iter().all(|v| *v == 0.0));
    }
}
