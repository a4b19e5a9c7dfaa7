//! A fiducial mark's template and the two ways it is found in a scan: normalised cross
//! correlation over a window (integer positions, a parabola through the peak), then
//! least-squares matching (Gruen 1985) — the template's pixels fitted to the scan under an
//! affine warp and a linear brightness change — for a sub-pixel centre that is unbiased by the
//! pixel grid and by the scan's slight rotation and scale.

use nalgebra::{Matrix2, SMatrix, SVector, Vector2};

use crate::FilmError;
use crate::raster::{GreyRaster, ImageView};

/// A mark as it looks in a scan; its centre, (width / 2, height / 2) in its pixel coordinates,
/// is the mark's centre.
///
/// Invariant: at least 5 × 5 pixels, not constant.
#[derive(Debug, Clone, PartialEq)]
pub struct Template {
    raster: GreyRaster,
    /// Values minus their mean.
    centred: Vec<f32>,
    /// Σ centred².
    energy: f64,
}

impl Template {
    /// The template of a grey raster.
    pub fn new(raster: GreyRaster) -> Result<Template, FilmError> {
        if raster.width < 5 || raster.height < 5 {
            return Err(FilmError::InvalidTemplate(format!(
                "{} × {} pixels; at least 5 × 5 are needed",
                raster.width, raster.height
            )));
        }
        if raster.data.len() != raster.width * raster.height
            || raster.data.iter().any(|v| !v.is_finite())
        {
            return Err(FilmError::InvalidTemplate(
                "its pixels do not fill it or are not finite".into(),
            ));
        }
        let mean = raster.data.iter().map(|&v| v as f64).sum::<f64>() / raster.data.len() as f64;
        let centred: Vec<f32> = raster
            .data
            .iter()
            .map(|&v| (v as f64 - mean) as f32)
            .collect();
        let energy: f64 = centred.iter().map(|&v| (v as f64) * (v as f64)).sum();
        if energy < 1e-8 * raster.data.len() as f64 {
            return Err(FilmError::InvalidTemplate(
                "it is constant: a mark must have contrast".into(),
            ));
        }
        Ok(Template {
            raster,
            centred,
            energy,
        })
    }

    /// Columns.
    pub fn width(&self) -> usize {
        self.raster.width
    }

    /// Rows.
    pub fn height(&self) -> usize {
        self.raster.height
    }

    /// The template's pixels.
    pub fn raster(&self) -> &GreyRaster {
        &self.raster
    }

    /// Half its diagonal, pixels: how far from its centre the mark can reach.
    pub fn half_diagonal(&self) -> f64 {
        0.5 * ((self.width() * self.width() + self.height() * self.height()) as f64).sqrt()
    }

    /// The template reduced by `factor` (for a search on a reduced scan).
    pub(crate) fn reduced(&self, factor: usize) -> Result<Template, FilmError> {
        Template::new(self.raster.reduced(factor))
    }
}

/// The best match of a template in a window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Peak {
    /// Where the template's centre lies, pixels of the searched image.
    pub centre: Vector2<f64>,
    /// Normalised cross-correlation there, −1 to 1.
    pub correlation: f64,
}

/// The template position (its centre) within `radius` pixels (a square window) of `around`
/// where the normalised cross-correlation with `image` peaks; `None` when the window holds no
/// complete template position or the image is flat there.
pub(crate) fn ncc_search(
    image: &GreyRaster,
    template: &Template,
    around: &Vector2<f64>,
    radius: f64,
) -> Option<Peak> {
    let (tw, th) = (template.width(), template.height());
    if image.width < tw || image.height < th {
        return None;
    }
    // Top-left corners whose template centre lies within the window.
    let first = |c: f64, half: f64, size: usize, limit: usize| -> (isize, isize) {
        let lo = (c - radius - half).ceil().max(0.0) as isize;
        let hi = ((c + radius - half).floor() as isize).min((limit - size) as isize);
        (lo, hi)
    };
    let (x0, x1) = first(around.x, 0.5 * tw as f64, tw, image.width);
    let (y0, y1) = first(around.y, 0.5 * th as f64, th, image.height);
    if x0 > x1 || y0 > y1 {
        return None;
    }
    let (nx, ny) = ((x1 - x0 + 1) as usize, (y1 - y0 + 1) as usize);
    let mut scores = vec![f64::NEG_INFINITY; nx * ny];
    let n = (tw * th) as f64;
    for (k, score) in scores.iter_mut().enumerate() {
        let (i, j) = (x0 as usize + k % nx, y0 as usize + k / nx);
        let (mut s, mut s2, mut ts) = (0.0f64, 0.0f64, 0.0f64);
        for r in 0..th {
            let row = &image.data[(j + r) * image.width + i..][..tw];
            let trow = &template.centred[r * tw..][..tw];
            let (mut a, mut b, mut c) = (0.0f32, 0.0f32, 0.0f32);
            for (&v, &t) in row.iter().zip(trow) {
                a += v;
                b += v * v;
                c += v * t;
            }
            s += a as f64;
            s2 += b as f64;
            ts += c as f64;
        }
        let var = s2 - s * s / n;
        if var > 1e-12 * n {
            *score = ts / (template.energy * var).sqrt();
        }
    }
    let (best, &correlation) = scores
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    if !correlation.is_finite() {
        return None;
    }
    let (bi, bj) = (best % nx, best / nx);
    // A parabola through the peak and its neighbours along each axis.
    let offset = |minus: Option<f64>, plus: Option<f64>| -> f64 {
        match (minus, plus) {
            (Some(m), Some(p)) if m.is_finite() && p.is_finite() => {
                let d = m - 2.0 * correlation + p;
                if d < 0.0 {
                    (0.5 * (m - p) / d).clamp(-0.5, 0.5)
                } else {
                    0.0
                }
            }
            _ => 0.0,
        }
    };
    let at = |i: usize, j: usize| scores[j * nx + i];
    let dx = offset(
        (bi > 0).then(|| at(bi - 1, bj)),
        (bi + 1 < nx).then(|| at(bi + 1, bj)),
    );
    let dy = offset(
        (bj > 0).then(|| at(bi, bj - 1)),
        (bj + 1 < ny).then(|| at(bi, bj + 1)),
    );
    Some(Peak {
        centre: Vector2::new(
            (x0 as usize + bi) as f64 + dx + 0.5 * tw as f64,
            (y0 as usize + bj) as f64 + dy + 0.5 * th as f64,
        ),
        correlation,
    })
}

/// A mark's centre refined by least-squares matching.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Refined {
    /// The template centre's position in the scan.
    pub centre: Vector2<f64>,
    /// Correlation of the template with the warped scan at the solution.
    pub correlation: f64,
}

/// Least-squares matching of `template` to `scan` (channel 0) from a start position and warp
/// (`scan_from_template`, the linear part of the scan's transform against the frame). Fails
/// when the solution leaves the scan, moves more than `max_shift` pixels from the start, or
/// does not converge.
pub(crate) fn least_squares_match(
    scan: &ImageView<'_>,
    template: &Template,
    start: &Vector2<f64>,
    scan_from_template: &Matrix2<f64>,
    max_shift: f64,
) -> Option<Refined> {
    let (tw, th) = (template.width(), template.height());
    let offsets: Vec<Vector2<f64>> = (0..th)
        .flat_map(|j| {
            (0..tw).map(move |i| {
                Vector2::new(
                    i as f64 + 0.5 - 0.5 * tw as f64,
                    j as f64 + 0.5 - 0.5 * th as f64,
                )
            })
        })
        .collect();
    let fit = LsmFit {
        scan,
        offsets: &offsets,
        values: &template.raster.data,
    };
    let a0 = *scan_from_template;
    // Brightness: template ≈ r0 + r1 · scan, from a linear regression at the start.
    let (r0, r1) = {
        let samples: Vec<f64> = offsets.iter().map(|x| fit.sample(&a0, start, x)).collect();
        regression(&samples, fit.values)?
    };
    let mut warp = Warp {
        a: a0,
        t: *start,
        r0,
        r1,
    };
    let mut converged = false;
    let mut last_step = f64::INFINITY;
    // Robust weights (Huber): a scratch or a speck of dust across the mark must not pull it.
    let mut residuals = vec![0.0f64; offsets.len()];
    let contrast = (template.energy / offsets.len() as f64).sqrt();
    let mut scale = f64::INFINITY;
    for iteration in 0..40 {
        let (mut jtj, mut jte) = fit.normal_equations(&warp, scale, &mut residuals)?;
        if iteration >= 2 {
            // Flat film around a mark fits exactly: a floor keeps its edges' interpolation
            // error from counting as outliers.
            scale = robust_scale(&residuals).max(0.05 * contrast);
        }
        pull_warp_towards(&mut jtj, &mut jte, &a0, &warp.a);
        let step = jtj.cholesky()?.solve(&jte);
        warp.t += Vector2::new(step[0], step[1]);
        warp.a += Matrix2::new(step[2], step[3], step[4], step[5]);
        warp.r0 += step[6];
        warp.r1 += step[7];
        let t = warp.t;
        if !(t.x.is_finite() && t.y.is_finite()) || (t - start).norm() > max_shift {
            return None;
        }
        // The warp may not fold or shrink the template away.
        let det = warp.a.determinant();
        if !(0.5..2.0).contains(&det.abs()) {
            return None;
        }
        last_step = step[0].hypot(step[1]);
        if last_step < 1e-4 {
            converged = true;
            break;
        }
    }
    // Grain can keep the last digits moving: a step of a few thousandths of a pixel is done.
    if !converged && last_step > 5e-3 {
        return None;
    }
    Some(Refined {
        centre: warp.t,
        correlation: fit.kept_correlation(&warp, &residuals, scale)?,
    })
}

/// The unknowns of least-squares matching: template offset x lies at scan pixel `a · x + t`,
/// and template ≈ `r0 + r1 · scan`.
struct Warp {
    a: Matrix2<f64>,
    t: Vector2<f64>,
    r0: f64,
    r1: f64,
}

/// What least-squares matching fits: the scan, and the template's pixels (offsets from its
/// centre and values).
struct LsmFit<'a> {
    scan: &'a ImageView<'a>,
    offsets: &'a [Vector2<f64>],
    values: &'a [f32],
}

impl LsmFit<'_> {
    /// The scan (channel 0) at `a · x + t` for template offset `x`.
    fn sample(&self, a: &Matrix2<f64>, t: &Vector2<f64>, x: &Vector2<f64>) -> f64 {
        let p = a * x + t;
        self.scan.bicubic(p.x, p.y, 0)
    }

    /// The Gauss-Newton normal equations (JᵀWJ, JᵀWe) of the 8 unknowns (t, a, r0, r1) at
    /// `warp`, Huber-weighted at `scale`, with every pixel's residual written to `residuals`;
    /// `None` when a pixel falls outside what the scan supports.
    fn normal_equations(
        &self,
        warp: &Warp,
        scale: f64,
        residuals: &mut [f64],
    ) -> Option<(SMatrix<f64, 8, 8>, SVector<f64, 8>)> {
        let (r0, r1) = (warp.r0, warp.r1);
        let mut jtj = SMatrix::<f64, 8, 8>::zeros();
        let mut jte = SVector::<f64, 8>::zeros();
        for (k, (x, &v)) in self.offsets.iter().zip(self.values).enumerate() {
            let p = warp.a * x + warp.t;
            if !self.scan.supports(p.x, p.y) {
                return None;
            }
            let (s, gx, gy) = self.scan.bicubic_with_gradient(p.x, p.y);
            let e = v as f64 - r0 - r1 * s;
            residuals[k] = e;
            let w = huber_weight(e, scale);
            let (gx, gy) = (r1 * gx, r1 * gy);
            let j = SVector::<f64, 8>::from_row_slice(&[
                gx,
                gy,
                gx * x.x,
                gx * x.y,
                gy * x.x,
                gy * x.y,
                1.0,
                s,
            ]);
            jtj += w * j * j.transpose();
            jte += w * j * e;
        }
        Some((jtj, jte))
    }

    /// The correlation of the template with the scan under `warp`, over the pixels the robust
    /// fit kept (a scratch is not the mark's fault); `None` when it kept fewer than half.
    fn kept_correlation(&self, warp: &Warp, residuals: &[f64], scale: f64) -> Option<f64> {
        let (samples, kept): (Vec<f64>, Vec<f32>) = self
            .offsets
            .iter()
            .zip(self.values)
            .zip(residuals)
            .filter(|(_, e)| huber_weight(**e, scale) >= 0.5)
            .map(|((x, &v), _)| (self.sample(&warp.a, &warp.t, x), v))
            .unzip();
        if samples.len() * 2 < self.offsets.len() {
            return None;
        }
        Some(correlation(&samples, &kept))
    }
}

/// Adds a weak pull of the warp `a` towards its start `a0` to the normal equations: a round
/// mark does not tell its rotation, and a warp the data cannot see must not wander.
fn pull_warp_towards(
    jtj: &mut SMatrix<f64, 8, 8>,
    jte: &mut SVector<f64, 8>,
    a0: &Matrix2<f64>,
    a: &Matrix2<f64>,
) {
    let pull = 1e-3 * 0.5 * (jtj[(0, 0)] + jtj[(1, 1)]);
    for (k, start) in [
        (2, a0[(0, 0)]),
        (3, a0[(0, 1)]),
        (4, a0[(1, 0)]),
        (5, a0[(1, 1)]),
    ] {
        let current = a[((k - 2) / 2, (k - 2) % 2)];
        jtj[(k, k)] += pull;
        jte[k] += pull * (start - current);
    }
}

/// Huber's weight of a residual for a scale (1 within 2 scales, falling beyond).
fn huber_weight(e: f64, scale: f64) -> f64 {
    let bound = 2.0 * scale;
    if e.abs() <= bound {
        1.0
    } else {
        bound / e.abs()
    }
}

/// 1.4826 × the median absolute residual (a robust σ).
fn robust_scale(residuals: &[f64]) -> f64 {
    let mut a: Vec<f64> = residuals.iter().map(|e| e.abs()).collect();
    let mid = a.len() / 2;
    a.select_nth_unstable_by(mid, f64::total_cmp);
    1.4826 * a[mid]
}

/// (r0, r1) of `template ≈ r0 + r1 · samples`; `None` when the samples are flat.
fn regression(samples: &[f64], template: &[f32]) -> Option<(f64, f64)> {
    let n = samples.len() as f64;
    let ms = samples.iter().sum::<f64>() / n;
    let mt = template.iter().map(|&v| v as f64).sum::<f64>() / n;
    let (mut sst, mut ss) = (0.0, 0.0);
    for (s, &t) in samples.iter().zip(template) {
        sst += (s - ms) * (t as f64 - mt);
        ss += (s - ms) * (s - ms);
    }
    if ss <= 1e-12 * n {
        return None;
    }
    let r1 = sst / ss;
    Some((mt - r1 * ms, r1))
}

/// Pearson correlation of the samples with the template.
fn correlation(samples: &[f64], template: &[f32]) -> f64 {
    let n = samples.len() as f64;
    let ms = samples.iter().sum::<f64>() / n;
    let mt = template.iter().map(|&v| v as f64).sum::<f64>() / n;
    let (mut st, mut ss, mut tt) = (0.0, 0.0, 0.0);
    for (s, &t) in samples.iter().zip(template) {
        let (ds, dt) = (s - ms, t as f64 - mt);
        st += ds * dt;
        ss += ds * ds;
        tt += dt * dt;
    }
    if ss <= 0.0 || tt <= 0.0 {
        0.0
    } else {
        st / (ss * tt).sqrt()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A bright ring with a dot, drawn with 8 × 8 samples per pixel, centred at `centre`,
    /// rotated by `angle` and scaled by `scale`, on a dark background; `size` × `size`.
    pub(crate) fn ring_and_dot(
        size: usize,
        centre: Vector2<f64>,
        angle: f64,
        scale: f64,
    ) -> GreyRaster {
        let (s, c) = angle.sin_cos();
        let mut data = vec![0.0f32; size * size];
        for j in 0..size {
            for i in 0..size {
                let mut sum = 0.0;
                for sj in 0..8 {
                    for si in 0..8 {
                        let p = Vector2::new(
                            i as f64 + (si as f64 + 0.5) / 8.0,
                            j as f64 + (sj as f64 + 0.5) / 8.0,
                        ) - centre;
                        // Back to the mark's own frame.
                        let q = Vector2::new(c * p.x + s * p.y, -s * p.x + c * p.y) / scale;
                        let r = q.norm();
                        let bar = q.y.abs() < 0.8 && q.x > 2.0 && q.x < 6.5;
                        if r < 1.5 || (r > 4.5 && r < 6.0) || bar {
                            sum += 1.0;
                        }
                    }
                }
                data[j * size + i] = 0.1 + 0.8 * (sum / 64.0) as f32;
            }
        }
        GreyRaster {
            width: size,
            height: size,
            data,
        }
    }

    /// Least-squares matching from a start, no warp, at most 3 px away.
    fn refine(scan: &GreyRaster, template: &Template, start: &Vector2<f64>) -> Refined {
        least_squares_match(&scan.view(), template, start, &Matrix2::identity(), 3.0)
            .expect("converges")
    }

    #[test]
    fn a_mark_is_found_to_a_twentieth_of_a_pixel_under_rotation_and_scale() {
        let template = Template::new(ring_and_dot(17, Vector2::new(8.5, 8.5), 0.0, 1.0)).unwrap();
        for (centre, angle, scale) in [
            (Vector2::new(40.3, 37.8), 0.0, 1.0),
            (Vector2::new(41.77, 36.12), 0.015, 0.9996),
            (Vector2::new(38.5, 44.49), -0.017, 1.0004),
        ] {
            let scan = ring_and_dot(80, centre, angle, scale);
            let peak = ncc_search(&scan, &template, &Vector2::new(45.0, 40.0), 20.0).unwrap();
            assert!(
                (peak.centre - centre).norm() < 0.5,
                "{} vs {centre}",
                peak.centre
            );
            assert!(peak.correlation > 0.7, "{}", peak.correlation);
            let refined = refine(&scan, &template, &peak.centre);
            let error = (refined.centre - centre).norm();
            assert!(error < 0.05, "{} vs {centre}: {error}", refined.centre);
            assert!(refined.correlation > 0.95, "{}", refined.correlation);
        }
    }

    #[test]
    fn a_scratch_across_the_mark_does_not_pull_it() {
        let template = Template::new(ring_and_dot(17, Vector2::new(8.5, 8.5), 0.0, 1.0)).unwrap();
        let centre = Vector2::new(40.37, 38.81);
        let mut scan = ring_and_dot(80, centre, 0.01, 1.0);
        // A bright scratch, two pixels wide, through the ring.
        for j in 0..80 {
            let x = 36.0 + 0.15 * j as f64;
            for dx in 0..2 {
                scan.data[j * 80 + x as usize + dx] = 0.95;
            }
        }
        let peak = ncc_search(&scan, &template, &Vector2::new(42.0, 40.0), 12.0).unwrap();
        let refined = refine(&scan, &template, &peak.centre);
        let error = (refined.centre - centre).norm();
        assert!(error < 0.1, "{error}");
        assert!(refined.correlation > 0.9, "{}", refined.correlation);
    }

    #[test]
    fn flat_or_tiny_templates_are_errors() {
        let flat = GreyRaster {
            width: 9,
            height: 9,
            data: vec![0.5; 81],
        };
        assert!(Template::new(flat).is_err());
        let tiny = GreyRaster {
            width: 3,
            height: 9,
            data: (0..27).map(|k| k as f32).collect(),
        };
        assert!(Template::new(tiny).is_err());
    }

    #[test]
    fn a_window_without_the_mark_gives_a_low_correlation() {
        let template = Template::new(ring_and_dot(17, Vector2::new(8.5, 8.5), 0.0, 1.0)).unwrap();
        let mut rng = timesift_core::SeededRng::new(5);
        let noise = GreyRaster {
            width: 80,
            height: 80,
            data: (0..6400).map(|_| rng.uniform() as f32).collect(),
        };
        let peak = ncc_search(&noise, &template, &Vector2::new(40.0, 40.0), 20.0).unwrap();
        assert!(peak.correlation < 0.5, "{}", peak.correlation);
    }
}
