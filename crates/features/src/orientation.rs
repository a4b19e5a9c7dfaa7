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

/// Orientations (radians in [0, 2π)) of the keypoint at (x, y) (plane coordinates) with scale
/// `sigma` (plane pixels): every smoothed-histogram peak within `peak_ratio` of the highest, with
/// its position refined by a parabola through the peak and its neighbours.
pub(crate) fn orientations(layer: &Plane, x: f64, y: f64, sigma: f64, peak_ratio: f32) -> Vec<f32> {
    let window_sigma = WINDOW_SIGMA * sigma as f32;
    let radius = (WINDOW_RADIUS * window_sigma).round() as isize;
    let (cx, cy) = (x.round() as isize, y.round() as isize);
    // The window is centred on the sub-pixel keypoint, not on the pixel it falls in.
    let (fx, fy) = ((cx as f64 - x) as f32, (cy as f64 - y) as f32);
    let inv = -1.0 / (2.0 * window_sigma * window_sigma);
    let mut hist = [0.0f32; BINS];
    let (w, h) = (layer.width as isize, layer.height as isize);
    let bins_per_radian = BINS as f32 / TAU;
    for dy in -radius..=radius {
        let py = cy + dy;
        if py <= 0 || py >= h - 1 {
            continue;
        }
        let oy = dy as f32 + fy;
        for dx in -radius..=radius {
            let px = cx + dx;
            if px <= 0 || px >= w - 1 {
                continue;
            }
            let ox = dx as f32 + fx;
            let (px, py) = (px as usize, py as usize);
            let gx = layer.at(px + 1, py) - layer.at(px - 1, py);
            let gy = layer.at(px, py + 1) - layer.at(px, py - 1);
            let weight = ((ox * ox + oy * oy) * inv).exp();
            // Linear interpolation between the two nearest bins: no quantisation of directions.
            let bin = atan2_positive(gy, gx) * bins_per_radian;
            let lower = bin.floor();
            let fraction = bin - lower;
            let lower = lower as usize % BINS;
            let vote = weight * (gx * gx + gy * gy).sqrt();
            hist[lower] += vote * (1.0 - fraction);
            hist[(lower + 1) % BINS] += vote * fraction;
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
