//! Keypoint orientation from a histogram of gradient directions (Lowe 2004, §5).
//!
//! Angles are in the image frame (x right, y down): an angle θ points along (cos θ, sin θ) in
//! pixel coordinates, so rotating the image by α about any point adds α to every orientation.

use std::f32::consts::TAU;

use crate::fastmath::atan2_positive;
use crate::image::Plane;

const BINS: usize = 36;
/// Gaussian window σ in units of the keypoint's σ.
const WINDOW_SIGMA: f32 = 1.5;
/// The window extends to this many window σ.
const WINDOW_RADIUS: f32 = 3.0;
/// Largest window radius, pixels of the layer (`DetectorOptions::validate` keeps σ small enough
/// that no window reaches it).
const MAX_RADIUS: usize = 96;

/// Orientations (radians in [0, 2π)) of the keypoint at (x, y) (plane coordinates) with scale
/// `sigma` (plane pixels): every smoothed-histogram peak within `peak_ratio` of the highest, with
/// its position refined by a parabola through the peak and its neighbours.
pub(crate) fn orientations(layer: &Plane, x: f64, y: f64, sigma: f64, peak_ratio: f32) -> Vec<f32> {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { orientations_avx2(layer, x, y, sigma, peak_ratio) };
    }
    orientations_portable(layer, x, y, sigma, peak_ratio)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn orientations_avx2(
    layer: &Plane,
    x: f64,
    y: f64,
    sigma: f64,
    peak_ratio: f32,
) -> Vec<f32> {
    orientations_portable(layer, x, y, sigma, peak_ratio)
}

#[inline(always)]
fn orientations_portable(layer: &Plane, x: f64, y: f64, sigma: f64, peak_ratio: f32) -> Vec<f32> {
    let window_sigma = WINDOW_SIGMA * sigma as f32;
    let radius = ((WINDOW_RADIUS * window_sigma).round() as usize).min(MAX_RADIUS);
    let r = radius as isize;
    let (cx, cy) = (x.round() as isize, y.round() as isize);
    // The window is centred on the sub-pixel keypoint, not on the pixel it falls in; its
    // Gaussian weight is separable.
    let (fx, fy) = ((cx as f64 - x) as f32, (cy as f64 - y) as f32);
    let inv = -1.0 / (2.0 * window_sigma * window_sigma);
    let mut wx = [0.0f32; 2 * MAX_RADIUS + 1];
    let mut wy = [0.0f32; 2 * MAX_RADIUS + 1];
    for k in 0..=2 * radius {
        let d = k as f32 - radius as f32;
        wx[k] = ((d + fx) * (d + fx) * inv).exp();
        wy[k] = ((d + fy) * (d + fy) * inv).exp();
    }
    let mut hist = [0.0f32; BINS];
    let (w, h) = (layer.width as isize, layer.height as isize);
    let bins_per_radian = BINS as f32 / TAU;
    let mut bins = [0.0f32; 2 * MAX_RADIUS + 1];
    let mut votes = [0.0f32; 2 * MAX_RADIUS + 1];
    // Columns with both horizontal neighbours inside the plane.
    let j_first = (-r).max(1 - cx);
    let j_last = r.min(w - 2 - cx);
    if j_last < j_first {
        return Vec::new();
    }
    let n = (j_last - j_first + 1) as usize;
    let first_px = (cx + j_first) as usize;
    for dy in -r..=r {
        let py = cy + dy;
        if py <= 0 || py >= h - 1 {
            continue;
        }
        let (row, above, below) = (
            layer.row(py as usize),
            layer.row(py as usize - 1),
            layer.row(py as usize + 1),
        );
        let weight_y = wy[(dy + r) as usize];
        for k in 0..n {
            let p = first_px + k;
            let gx = row[p + 1] - row[p - 1];
            let gy = below[p] - above[p];
            let weight = weight_y * wx[(j_first + r) as usize + k];
            votes[k] = weight * (gx * gx + gy * gy).sqrt();
            bins[k] = atan2_positive(gy, gx) * bins_per_radian;
        }
        // Linear interpolation between the two nearest bins: no quantisation of directions.
        for k in 0..n {
            let bin = bins[k];
            let lower = (bin as usize).min(BINS - 1);
            let fraction = bin - lower as f32;
            hist[lower] += votes[k] * (1.0 - fraction);
            hist[(lower + 1) % BINS] += votes[k] * fraction;
        }
    }
    // Smooth circularly with [1 4 6 4 1] / 16.
    let mut smooth = [0.0f32; BINS];
    for (i, s) in smooth.iter_mut().enumerate() {
        let at = |o: isize| hist[(i as isize + o).rem_euclid(BINS as isize) as usize];
        *s = (at(-2) + at(2)) / 16.0 + (at(-1) + at(1)) * (4.0 / 16.0) + at(0) * (6.0 / 16.0);
    }
    let max = smooth.iter().cloned().fold(0.0f32, f32::max);
    if max <= 0.0 {
        return Vec::new();
    }
    let mut out = Vec::new();
    for i in 0..BINS {
        let left = smooth[(i + BINS - 1) % BINS];
        let right = smooth[(i + 1) % BINS];
        let v = smooth[i];
        if v > left && v > right && v >= peak_ratio * max {
            let offset = 0.5 * (left - right) / (left - 2.0 * v + right);
            let bin = (i as f32 + offset).rem_euclid(BINS as f32);
            out.push((bin / bins_per_radian).rem_euclid(TAU));
        }
    }
    out
}
