//! Spatial correlation of the errors of a DEM of difference, and what it does to the uncertainty
//! of a volume.
//!
//! Why: DEM errors are not independent from cell to cell. Dense matching smooths over a window,
//! a DEM is gridded from clouds several cells wide, a small tilt or bend of a block shifts whole
//! areas together. A volume's random error summed as if every cell were independent
//! (`σ · a · √n`) shrinks with the number of cells and claims centimetres where the truth is
//! metres. So the errors' variogram is measured over stable ground — where the DoD is error
//! only — a spherical model is fitted (a nugget for the independent part, a partial sill and a
//! range for the correlated part, as Rolstad et al. 2009 do), and the σ of a volume is the double
//! sum of that covariance over the volume's cells (Hugonnet et al. 2022 integrate the same way).

use serde::{Deserialize, Serialize};

use crate::ChangeError;
use crate::grid::Dem;
use crate::mask::Mask;

/// Fewest pairs for a lag of the empirical variogram.
const MIN_PAIRS: usize = 30;
/// Most pairs used per lag (rows and columns are strided beyond it).
const MAX_PAIRS_PER_LAG: usize = 200_000;
/// Most blocks of the double sum; beyond, cells are grouped into square blocks.
const MAX_BLOCKS: usize = 1500;

/// Correlation of the spherical model at distance `d` for range `range`: 1 at 0, 0 from the
/// range on.
fn spherical(d: f64, range: f64) -> f64 {
    if d >= range {
        0.0
    } else {
        let t = d / range;
        1.0 - 1.5 * t + 0.5 * t * t * t
    }
}

/// The share of a DEM-difference error that is correlated, and over which distance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Correlation {
    /// Distance from which errors no longer correlate, metres.
    pub range_m: f64,
    /// Partial sill over total sill: 0 (independent errors) to 1 (no nugget).
    pub correlated_fraction: f64,
}

/// One lag of the empirical variogram.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Lag {
    /// Distance, metres.
    pub distance_m: f64,
    /// Semivariance (robust: half the squared NMAD of the pair differences), m².
    pub semivariance: f64,
    /// Pairs.
    pub pairs: usize,
}

/// The fitted spherical variogram `γ(h) = nugget + partial_sill · (1 − ρ(h))`, with
/// `ρ(h) = 1 − 1.5 h/r + 0.5 (h/r)³` below the range `r` and 0 beyond.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Variogram {
    /// Independent part, m².
    pub nugget: f64,
    /// Correlated part, m².
    pub partial_sill: f64,
    /// Range, metres.
    pub range_m: f64,
    /// The empirical lags the model was fitted to.
    pub lags: Vec<Lag>,
}

impl Variogram {
    /// The model's correlation structure.
    pub fn correlation(&self) -> Correlation {
        let sill = self.nugget + self.partial_sill;
        Correlation {
            range_m: self.range_m,
            correlated_fraction: if sill > 0.0 {
                self.partial_sill / sill
            } else {
                0.0
            },
        }
    }

    /// The model at distance `h`, m².
    pub fn at(&self, h: f64) -> f64 {
        self.nugget + self.partial_sill * (1.0 - spherical(h, self.range_m))
    }
}

/// The empirical variogram of `dod` over the cells of `mask` (every cell when `None`) along rows
/// and columns, and the spherical model fitted to it.
///
/// Errors: fewer than three lags with enough pairs (a stable area too small or too thin)
/// ([`ChangeError::NotEnoughData`]); a mask on another grid ([`ChangeError::InvalidInput`]).
pub fn variogram(dod: &Dem, mask: Option<&Mask>) -> Result<Variogram, ChangeError> {
    let grid = &dod.grid;
    Mask::check_fits(mask, grid)?;
    let (w, h) = (grid.width, grid.height);
    let (cw, ch) = grid.metric_cell_size_at_row(h / 2);
    let value = |c: usize, r: usize| -> Option<f64> {
        let i = r * w + c;
        let v = dod.values[i];
        (v.is_finite() && mask.is_none_or(|m| m.cells[i])).then_some(v as f64)
    };
    let selected = (0..w * h)
        .filter(|&i| value(i % w, i / w).is_some())
        .count();
    let mut lags = Vec::new();
    let mut differences = Vec::new();
    let mut step = 1usize;
    while step < w.max(h) / 2 {
        // Pairs `step` cells apart along rows and along columns; strided to bound the work.
        let per_direction = selected.max(1);
        let stride = (2 * per_direction / MAX_PAIRS_PER_LAG).max(1);
        differences.clear();
        let mut distance_sum = 0.0;
        for r in (0..h).step_by(stride) {
            for c in 0..w.saturating_sub(step) {
                if let (Some(a), Some(b)) = (value(c, r), value(c + step, r)) {
                    differences.push(b - a);
                    distance_sum += step as f64 * cw;
                }
            }
        }
        for c in (0..w).step_by(stride) {
            for r in 0..h.saturating_sub(step) {
                if let (Some(a), Some(b)) = (value(c, r), value(c, r + step)) {
                    differences.push(b - a);
                    distance_sum += step as f64 * ch;
                }
            }
        }
        if differences.len() >= MIN_PAIRS {
            let n = differences.len();
            let nmad = crate::stats::nmad(&mut differences);
            lags.push(Lag {
                distance_m: distance_sum / n as f64,
                semivariance: 0.5 * nmad * nmad,
                pairs: n,
            });
        }
        // Lags grow by about 40 %: fine near the origin, where the range is read.
        step = (step * 7).div_ceil(5).max(step + 1);
    }
    if lags.len() < 3 {
        return Err(ChangeError::NotEnoughData(format!(
            "{} lags of at least {MIN_PAIRS} pairs in the stable area; 3 are needed for a \
             variogram",
            lags.len()
        )));
    }
    Ok(fit(lags, cw.min(ch)))
}

/// The spherical model by weighted least squares: a grid of ranges, for each the non-negative
/// nugget and partial sill solved in closed form; the best fit wins.
fn fit(lags: Vec<Lag>, cell: f64) -> Variogram {
    let longest = lags.iter().map(|l| l.distance_m).fold(cell, f64::max);
    let (lo, hi) = (0.25 * cell, 3.0 * longest);
    let mut best = (f64::INFINITY, 0.0, 0.0, lo);
    for k in 0..=60 {
        let range = lo * (hi / lo).powf(k as f64 / 60.0);
        let basis: Vec<f64> = lags
            .iter()
            .map(|l| 1.0 - spherical(l.distance_m, range))
            .collect();
        // Weighted normal equations of γ = n + p·f, weights √pairs.
        let (mut s11, mut s1f, mut sff, mut s1g, mut sfg) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (l, f) in lags.iter().zip(&basis) {
            let wt = (l.pairs as f64).sqrt();
            s11 += wt;
            s1f += wt * f;
            sff += wt * f * f;
            s1g += wt * l.semivariance;
            sfg += wt * f * l.semivariance;
        }
        let det = s11 * sff - s1f * s1f;
        let (mut nugget, mut psill) = if det.abs() > 1e-12 * s11 * sff {
            ((s1g * sff - s1f * sfg) / det, (s11 * sfg - s1f * s1g) / det)
        } else {
            (0.0, sfg / sff.max(f64::MIN_POSITIVE))
        };
        // Keep both parts non-negative: refit the other alone when one goes below zero.
        if nugget < 0.0 {
            nugget = 0.0;
            psill = (sfg / sff.max(f64::MIN_POSITIVE)).max(0.0);
        }
        if psill < 0.0 {
            psill = 0.0;
            nugget = (s1g / s11).max(0.0);
        }
        let sse: f64 = lags
            .iter()
            .zip(&basis)
            .map(|(l, f)| (l.pairs as f64).sqrt() * (nugget + psill * f - l.semivariance).powi(2))
            .sum();
        if sse < best.0 {
            best = (sse, nugget, psill, range);
        }
    }
    Variogram {
        nugget: best.1,
        partial_sill: best.2,
        range_m: best.3,
        lags,
    }
}

/// `sqrt(ΣΣ aᵢ aⱼ ρ(dᵢⱼ))` over cells given as (x, y, area) in metres, ρ the correlation of the
/// spherical model: the σ of Σ aᵢ eᵢ for errors of unit variance. Independent errors give
/// `sqrt(Σ aᵢ²)`; fully correlated ones `Σ aᵢ`. Beyond `MAX_BLOCKS` cells, cells are grouped
/// into square blocks (the within-block pairs at the mean distance of two points in a square,
/// 0.52 × its side) so that the cost stays bounded whatever the region.
pub fn correlated_area(cells: &[(f64, f64, f64)], correlation: Correlation) -> f64 {
    let f = correlation.correlated_fraction.clamp(0.0, 1.0);
    let independent: f64 = cells.iter().map(|c| c.2 * c.2).sum();
    if cells.is_empty() || f == 0.0 || !(correlation.range_m > 0.0) {
        return independent.sqrt();
    }
    let rho = |d: f64| spherical(d, correlation.range_m);
    let (blocks, within) = if cells.len() <= MAX_BLOCKS {
        (cells.to_vec(), 0.0)
    } else {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for c in cells {
            x0 = x0.min(c.0);
            y0 = y0.min(c.1);
            x1 = x1.max(c.0);
            y1 = y1.max(c.1);
        }
        let total: f64 = cells.iter().map(|c| c.2).sum();
        let mut side = (total / MAX_BLOCKS as f64).sqrt();
        loop {
            let nx = ((x1 - x0) / side).floor() as usize + 1;
            let mut sums: std::collections::HashMap<usize, (f64, f64, f64)> =
                std::collections::HashMap::new();
            for c in cells {
                let k = ((c.1 - y0) / side) as usize * nx + ((c.0 - x0) / side) as usize;
                let e = sums.entry(k).or_insert((0.0, 0.0, 0.0));
                e.0 += c.0 * c.2;
                e.1 += c.1 * c.2;
                e.2 += c.2;
            }
            if sums.len() <= MAX_BLOCKS {
                let mut blocks: Vec<(f64, f64, f64)> = sums
                    .into_values()
                    .map(|(sx, sy, a)| (sx / a, sy / a, a))
                    .collect();
                blocks.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
                break (blocks, 0.52 * side);
            }
            side *= 1.25;
        }
    };
    let mut correlated = 0.0;
    for (i, a) in blocks.iter().enumerate() {
        // A block with itself: its cells' pairs at the mean within-block distance (one cell:
        // distance 0).
        correlated += a.2 * a.2 * rho(within);
        for b in &blocks[i + 1..] {
            correlated += 2.0 * a.2 * b.2 * rho((a.0 - b.0).hypot(a.1 - b.1));
        }
    }
    ((1.0 - f) * independent + f * correlated).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use timesift_core::SeededRng;
    use timesift_io::coords::Crs;
    use timesift_io::geotiff::GeoTransform;

    fn grid(n: usize) -> Grid {
        Grid {
            transform: GeoTransform {
                origin_x: 0.0,
                origin_y: n as f64,
                pixel_width: 1.0,
                pixel_height: -1.0,
            },
            width: n,
            height: n,
            crs: Crs::Local,
        }
    }

    /// White noise of σ `white` plus white noise smoothed by a box of half-width `radius`
    /// (rescaled to σ `smooth`): a field correlated over about 2 · radius cells.
    fn field(n: usize, radius: usize, white: f64, smooth: f64, rng: &mut SeededRng) -> Dem {
        let raw: Vec<f64> = (0..n * n).map(|_| rng.normal()).collect();
        let mut blurred = vec![0.0; n * n];
        let width = (2 * radius + 1) as f64;
        for r in 0..n {
            for c in 0..n {
                let mut s = 0.0;
                for dr in 0..=2 * radius {
                    for dc in 0..=2 * radius {
                        let rr = (r + dr + n - radius) % n;
                        let cc = (c + dc + n - radius) % n;
                        s += raw[rr * n + cc];
                    }
                }
                blurred[r * n + c] = s / width;
            }
        }
        let values = (0..n * n)
            .map(|i| (white * rng.normal() + smooth * blurred[i]) as f32)
            .collect();
        Dem {
            grid: grid(n),
            values,
        }
    }

    #[test]
    fn white_noise_has_no_correlated_part() {
        let mut rng = SeededRng::new(3);
        let dem = field(120, 0, 0.1, 0.0, &mut rng);
        let v = variogram(&dem, None).expect("variogram");
        let c = v.correlation();
        let sill = v.nugget + v.partial_sill;
        assert!((sill.sqrt() - 0.1).abs() < 0.01, "{v:?}");
        // Whatever the split, nothing is correlated beyond a cell.
        assert!(c.correlated_fraction < 0.2 || c.range_m < 1.0, "{c:?}");
    }

    #[test]
    fn a_smoothed_field_shows_its_range_and_the_volume_sigma_matches_monte_carlo() {
        let (n, radius) = (96, 4);
        let mut rng = SeededRng::new(5);
        // The model from one realisation.
        let dem = field(n, radius, 0.02, 0.1, &mut rng);
        let v = variogram(&dem, None).expect("variogram");
        let c = v.correlation();
        assert!(
            c.correlated_fraction > 0.8 && c.range_m > 4.0 && c.range_m < 30.0,
            "{c:?} {:?}",
            v.lags
        );
        // σ of the sum over a 20 × 20 square, predicted and over 150 realisations.
        let square: Vec<(f64, f64, f64)> = (0..400)
            .map(|k| ((k % 20) as f64 + 0.5, (k / 20) as f64 + 0.5, 1.0))
            .collect();
        let sigma = (v.nugget + v.partial_sill).sqrt();
        let predicted = sigma * correlated_area(&square, c);
        let independent = sigma * 20.0;
        let sums: Vec<f64> = (0..150)
            .map(|_| {
                let f = field(n, radius, 0.02, 0.1, &mut rng);
                (0..400)
                    .map(|k| f.values[(k / 20) * n + k % 20] as f64)
                    .sum::<f64>()
            })
            .collect();
        let mean = sums.iter().sum::<f64>() / sums.len() as f64;
        let measured =
            (sums.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / (sums.len() - 1) as f64).sqrt();
        println!(
            "σ of the sum: predicted {predicted:.3}, measured {measured:.3}, independent {independent:.3}"
        );
        assert!(
            (predicted / measured - 1.0).abs() < 0.2,
            "predicted {predicted}, measured {measured}"
        );
        assert!(measured > 3.0 * independent, "the field is correlated");
    }

    #[test]
    fn blocks_agree_with_the_exact_double_sum() {
        let c = Correlation {
            range_m: 15.0,
            correlated_fraction: 0.7,
        };
        // 60 × 60 cells: the blocked sum against the exact one over the same cells.
        let cells: Vec<(f64, f64, f64)> = (0..3600)
            .map(|k| ((k % 60) as f64 + 0.5, (k / 60) as f64 + 0.5, 1.0))
            .collect();
        let blocked = correlated_area(&cells, c);
        let rho = |d: f64| spherical(d, 15.0);
        let mut exact = 0.0;
        for a in &cells {
            for b in &cells {
                exact += rho((a.0 - b.0).hypot(a.1 - b.1));
            }
        }
        let exact = (0.3 * 3600.0 + 0.7 * exact).sqrt();
        assert!((blocked / exact - 1.0).abs() < 0.05, "{blocked} vs {exact}");
        // The two limits.
        let none = Correlation {
            range_m: 15.0,
            correlated_fraction: 0.0,
        };
        assert!((correlated_area(&cells, none) - 60.0).abs() < 1e-9);
        let few = &cells[..4];
        let full = Correlation {
            range_m: 1e12,
            correlated_fraction: 1.0,
        };
        assert!((correlated_area(few, full) - 4.0).abs() < 1e-6);
    }

    #[test]
    fn a_tiny_stable_area_is_an_error() {
        let mut rng = SeededRng::new(1);
        let dem = field(4, 0, 0.1, 0.0, &mut rng);
        assert!(matches!(
            variogram(&dem, None),
            Err(ChangeError::NotEnoughData(_))
        ));
    }
}
