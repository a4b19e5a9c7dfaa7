//! Separable Gaussian blur and the ×2 resampling steps of the scale space.
//!
//! Borders reflect without repeating the edge pixel (OpenCV's `BORDER_REFLECT_101`), the usual
//! choice for SIFT. Both passes run over rows in parallel, with the tap loop outside the pixel loop
//! so that the pixel loop vectorises.

use rayon::prelude::*;

use crate::image::Plane;

/// Half of a normalised symmetric Gaussian kernel: `taps[0]` is the centre weight, `taps[k]` the
/// weight at ±k.
#[derive(Debug, Clone)]
pub(crate) struct Kernel {
    pub taps: Vec<f32>,
}

impl Kernel {
    /// Gaussian of standard deviation `sigma` (pixels), truncated at 4σ.
    pub fn gaussian(sigma: f64) -> Self {
        let radius = ((4.0 * sigma).ceil() as usize).max(1);
        let weights: Vec<f64> = (0..=radius)
            .map(|k| (-((k * k) as f64) / (2.0 * sigma * sigma)).exp())
            .collect();
        let total = weights[0] + 2.0 * weights[1..].iter().sum::<f64>();
        Self {
            taps: weights.iter().map(|w| (w / total) as f32).collect(),
        }
    }

    pub fn radius(&self) -> usize {
        self.taps.len() - 1
    }
}

/// Index `i` reflected into `0..n` without repeating the edge (…, 2, 1, 0, 1, 2, …).
#[inline]
pub(crate) fn reflect(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let period = 2 * (n as isize - 1);
    let m = i.rem_euclid(period);
    if m < n as isize {
        m as usize
    } else {
        (period - m) as usize
    }
}

/// Rows handled by one parallel job: enough work to amortise scheduling.
fn rows_per_job(width: usize) -> usize {
    (16_384 / width.max(1)).clamp(1, 64)
}

/// Blurs `src` (`width` values per row) into `dst` with `kernel` in both directions: the vertical
/// pass writes `dst`, the horizontal pass then works in place, row by row, so no second plane is
/// needed. `dst` is resized as needed.
pub(crate) fn blur(src: &[f32], width: usize, kernel: &Kernel, dst: &mut Plane) {
    let w = width;
    let h = src.len() / w;
    dst.width = w;
    dst.height = h;
    dst.data.resize(w * h, 0.0);
    let taps = &kernel.taps;
    let pad = kernel.radius();
    let chunk = rows_per_job(w);
    dst.data
        .par_chunks_mut(w * chunk)
        .enumerate()
        .for_each_init(
            || vec![0.0f32; w + 2 * pad],
            |padded, (job, out_rows)| {
                for (k, out) in out_rows.chunks_mut(w).enumerate() {
                    // Vertical: each output row is a weighted sum of whole input rows.
                    vertical_row(&mut padded[pad..pad + w], src, w, job * chunk + k, taps);
                    // Horizontal, from a reflected copy of the row.
                    let (left, rest) = padded.split_at_mut(pad);
                    let (row, right) = rest.split_at_mut(w);
                    for i in 0..pad {
                        left[i] = row[reflect(i as isize - pad as isize, w)];
                        right[i] = row[reflect((w + i) as isize, w)];
                    }
                    horizontal_row(out, padded, taps);
                }
            },
        );
}

/// Row `y` of `src` (`w` values per row) blurred vertically into `out`.
fn vertical_row(out: &mut [f32], src: &[f32], w: usize, y: usize, taps: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { vertical_row_avx2(out, src, w, y, taps) };
    }
    vertical_row_portable(out, src, w, y, taps)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn vertical_row_avx2(out: &mut [f32], src: &[f32], w: usize, y: usize, taps: &[f32]) {
    vertical_row_portable(out, src, w, y, taps)
}

#[inline(always)]
fn vertical_row_portable(out: &mut [f32], src: &[f32], w: usize, y: usize, taps: &[f32]) {
    let h = src.len() / w;
    let row = |r: usize| &src[r * w..(r + 1) * w];
    let centre = row(y);
    for (o, &c) in out.iter_mut().zip(centre) {
        *o = taps[0] * c;
    }
    for (d, &t) in taps.iter().enumerate().skip(1) {
        let up = row(reflect(y as isize - d as isize, h));
        let down = row(reflect((y + d) as isize, h));
        for ((o, &a), &b) in out.iter_mut().zip(up).zip(down) {
            *o += t * (a + b);
        }
    }
}

/// A row padded by the kernel radius on both sides, blurred horizontally into `out`.
fn horizontal_row(out: &mut [f32], padded: &[f32], taps: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { horizontal_row_avx2(out, padded, taps) };
    }
    horizontal_row_portable(out, padded, taps)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn horizontal_row_avx2(out: &mut [f32], padded: &[f32], taps: &[f32]) {
    horizontal_row_portable(out, padded, taps)
}

#[inline(always)]
fn horizontal_row_portable(out: &mut [f32], padded: &[f32], taps: &[f32]) {
    let w = out.len();
    let pad = taps.len() - 1;
    let centre = &padded[pad..pad + w];
    for (o, &c) in out.iter_mut().zip(centre) {
        *o = taps[0] * c;
    }
    for (d, &t) in taps.iter().enumerate().skip(1) {
        let left = &padded[pad - d..pad - d + w];
        let right = &padded[pad + d..pad + d + w];
        for ((o, &a), &b) in out.iter_mut().zip(left).zip(right) {
            *o += t * (a + b);
        }
    }
}

/// The image at twice the resolution, such that pixel index `j` of the result sits at index `j/2`
/// of the source: even pixels copy the source, odd ones interpolate linearly. (Index-exact, so
/// keypoint coordinates map back by a factor of 2 with no half-pixel shift.)
pub(crate) fn upsample2(src: &[f32], w: usize) -> Plane {
    let h = src.len() / w;
    let row = |r: usize| &src[r * w..(r + 1) * w];
    let (w2, h2) = (2 * w, 2 * h);
    let mut out = Plane::zeros(w2, h2);
    out.data
        .par_chunks_mut(w2)
        .enumerate()
        .for_each(|(y2, out_row)| {
            let y0 = y2 / 2;
            let y1 = (y0 + 1).min(h - 1);
            let fy = if y2 % 2 == 1 { 0.5 } else { 0.0 };
            let (r0, r1) = (row(y0), row(y1));
            for (x2, o) in out_row.iter_mut().enumerate() {
                let x0 = x2 / 2;
                let x1 = (x0 + 1).min(w - 1);
                let fx = if x2 % 2 == 1 { 0.5 } else { 0.0 };
                let top = r0[x0] * (1.0 - fx) + r0[x1] * fx;
                let bottom = r1[x0] * (1.0 - fx) + r1[x1] * fx;
                *o = top * (1.0 - fy) + bottom * fy;
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_is_normalised_and_reflect_stays_in_range() {
        let k = Kernel::gaussian(1.6);
        let total: f32 = k.taps[0] + 2.0 * k.taps[1..].iter().sum::<f32>();
        assert!((total - 1.0).abs() < 1e-6);
        assert_eq!(k.radius(), 7);
        assert_eq!(reflect(-1, 5), 1);
        assert_eq!(reflect(5, 5), 3);
        assert_eq!(reflect(-9, 5), 1);
        assert_eq!(reflect(0, 1), 0);
        for i in -40..40 {
            assert!(reflect(i, 3) < 3);
        }
    }

    #[test]
    fn blur_preserves_a_constant_and_the_mean_of_an_impulse() {
        let mut p = Plane::zeros(31, 17);
        p.data.iter_mut().for_each(|v| *v = 0.25);
        let mut out = Plane::default();
        blur(&p.data, p.width, &Kernel::gaussian(2.0), &mut out);
        assert!(out.data.iter().all(|v| (v - 0.25).abs() < 1e-6));
        // An impulse far from the borders: the blur is a sampled Gaussian of the right variance.
        let mut p = Plane::zeros(41, 41);
        p.data[20 * 41 + 20] = 1.0;
        blur(&p.data, p.width, &Kernel::gaussian(2.0), &mut out);
        let sum: f32 = out.data.iter().sum();
        let var: f32 = (0..41)
            .map(|x| (x as f32 - 20.0).powi(2) * out.at(x, 20))
            .sum::<f32>()
            / (0..41).map(|x| out.at(x, 20)).sum::<f32>();
        assert!((sum - 1.0).abs() < 1e-5);
        assert!((var - 4.0).abs() < 0.01, "variance {var}");
    }

    #[test]
    fn upsample_is_index_exact() {
        let mut p = Plane::zeros(4, 3);
        for (i, v) in p.data.iter_mut().enumerate() {
            *v = i as f32;
        }
        let up = upsample2(&p.data, p.width);
        assert_eq!((up.width, up.height), (8, 6));
        assert_eq!(up.at(2, 2), p.at(1, 1));
        assert_eq!(up.at(3, 2), 0.5 * (p.at(1, 1) + p.at(2, 1)));
        assert_eq!(
            up.at(3, 3),
            0.25 * (p.at(1, 1) + p.at(2, 1) + p.at(1, 2) + p.at(2, 2))
        );
    }
}
