//! Level of detection and volumes of cut and fill from a DEM of difference.
//!
//! LoD95 = 1.96 · sqrt(σa² + σb²). When σ comes from the spread of the DoD over stable ground, that
//! spread already combines both DEMs, so LoD95 = 1.96 · σ_stable.
//!
//! Volume uncertainty has two parts (as in the DEM-differencing literature): a random per-cell error
//! σ_r, independent between cells, giving A·σ_r·√n; and a systematic error (residual vertical bias)
//! σ_s common to all cells, giving A·n·σ_s. They add in quadrature. Spatially correlated errors lie
//! between the two: with a [`Correlation`] (the variogram of the stable areas' errors), the random
//! part is the double sum of the correlated covariance over the region's cells instead.

use serde::{Deserialize, Serialize};

use crate::ChangeError;
use crate::correlation::{Correlation, correlated_area};
use crate::grid::Dem;
use crate::mask::Mask;
use crate::stats::Statistics;

/// 95 % level of detection from the σ of two DEMs.
pub fn lod95(sigma_a: f64, sigma_b: f64) -> f64 {
    1.96 * (sigma_a * sigma_a + sigma_b * sigma_b).sqrt()
}

/// Per-cell flags of significant change: 1 where |dz| > lod, 0 where not, 255 where nodata.
pub fn significance(dod: &Dem, lod: f64) -> Vec<u8> {
    dod.values
        .iter()
        .map(|&v| {
            if v.is_nan() {
                255
            } else {
                ((v as f64).abs() > lod) as u8
            }
        })
        .collect()
}

/// How volumes are computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeOptions {
    /// Cells with |dz| ≤ threshold count as no change (use the LoD95 to keep only significant change;
    /// 0 keeps every cell).
    pub threshold: f64,
    /// Random per-cell σ of dz (m), independent between cells.
    pub sigma_random: f64,
    /// Systematic σ of dz (m), shared by all cells (residual bias).
    pub sigma_systematic: f64,
    /// How the random errors correlate between cells; `None`: independent.
    pub correlation: Option<Correlation>,
}

impl Default for VolumeOptions {
    fn default() -> Self {
        VolumeOptions {
            threshold: 0.0,
            sigma_random: 0.0,
            sigma_systematic: 0.0,
            correlation: None,
        }
    }
}

impl VolumeOptions {
    /// Every cell counted, the uncertainty judged from the DoD's stable areas: the per-cell
    /// random σ is their NMAD, the systematic σ the magnitude of their median (an offset left
    /// between the DEMs).
    pub fn from_stable(stable: &Statistics) -> VolumeOptions {
        VolumeOptions {
            threshold: 0.0,
            sigma_random: stable.nmad,
            sigma_systematic: stable.median.abs(),
            correlation: None,
        }
    }
}

/// Volumes over a region, in cubic metres (cells in m² even on geographic grids).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Volumes {
    /// Material removed (positive number): Σ |dz|·A over cells with dz < −threshold.
    pub cut: f64,
    /// Material added: Σ dz·A over cells with dz > threshold.
    pub fill: f64,
    /// fill − cut.
    pub net: f64,
    /// Area of the region's cells holding a difference, m².
    pub area: f64,
    /// Cells holding a difference in the region.
    pub cells: usize,
    /// Cells above the threshold.
    pub changed_cells: usize,
    /// The threshold used, m.
    pub threshold: f64,
    /// 1-σ uncertainty of `net` (random and systematic parts in quadrature), m³.
    pub sigma_net: f64,
    /// Random part, m³.
    pub sigma_random: f64,
    /// Systematic part, m³.
    pub sigma_systematic: f64,
}

/// Cut, fill and net volumes of a DoD over `region` (every cell when `None`).
pub fn volumes(
    dod: &Dem,
    region: Option<&Mask>,
    options: VolumeOptions,
) -> Result<Volumes, ChangeError> {
    for (name, v) in [
        ("threshold", options.threshold),
        ("sigma_random", options.sigma_random),
        ("sigma_systematic", options.sigma_systematic),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(ChangeError::InvalidParameter {
                name,
                reason: format!("{v} given; a finite value ≥ 0 was expected"),
            });
        }
    }
    let region = match region {
        Some(m) => Some(m.onto(&dod.grid)?),
        None => None,
    };
    let grid = &dod.grid;
    let (mut cut, mut fill, mut area, mut cells, mut changed) = (0.0, 0.0, 0.0, 0usize, 0usize);
    // Σ A² over cells, for the random part; Σ A for the systematic part; the cells themselves
    // (metric x, y, area) when their errors correlate.
    let mut area_sq = 0.0;
    let mut located: Vec<(f64, f64, f64)> = Vec::new();
    let mut y = 0.0;
    for row in 0..grid.height {
        let (dx, dy) = grid.metric_cell_size_at_row(row);
        let a = dx * dy;
        y += dy;
        for col in 0..grid.width {
            let i = row * grid.width + col;
            if region.as_ref().is_some_and(|m| !m.cells[i]) {
                continue;
            }
            let dz = dod.values[i] as f64;
            if dz.is_nan() {
                continue;
            }
            cells += 1;
            area += a;
            area_sq += a * a;
            if options.correlation.is_some() {
                located.push(((col as f64 + 0.5) * dx, y - 0.5 * dy, a));
            }
            if dz > options.threshold {
                fill += dz * a;
                changed += 1;
            } else if dz < -options.threshold {
                cut -= dz * a;
                changed += 1;
            }
        }
    }
    if cells == 0 {
        return Err(ChangeError::EmptyStable(
            "the volume region holds no cell with a difference".into(),
        ));
    }
    let sigma_random = options.sigma_random
        * match options.correlation {
            Some(c) => correlated_area(&located, c),
            None => area_sq.sqrt(),
        };
    let sigma_systematic = options.sigma_systematic * area;
    Ok(Volumes {
        cut,
        fill,
        net: fill - cut,
        area,
        cells,
        changed_cells: changed,
        threshold: options.threshold,
        sigma_net: sigma_random.hypot(sigma_systematic),
        sigma_random,
        sigma_systematic,
    })
}
