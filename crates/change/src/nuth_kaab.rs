//! DEM co-registration by Nuth & Kääb (2011): on stable terrain, a horizontal shift s of a DEM makes
//! the elevation difference dh ≈ −tan(α) · (s · d), d the downslope direction of aspect ψ. So
//! (dh − median dh) / tan α = a·cos(b − ψ) + c is fitted (Tukey-weighted linear least squares in
//! sin ψ, cos ψ, 1), the shift is
//! updated and the fit repeated on the re-sampled DEM until the update is below a tolerance. A
//! vertical bias is removed last (median of dh by default).
//!
//! Conventions: the result is the translation (east, north, up) to apply to the DEM being aligned,
//! i.e. `aligned(p) = to_align(p − (sx, sy)) + sz`; it is reported in metres, in world units and in
//! reference-grid pixels (columns right, rows down). Slope and aspect come from the reference DEM.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::grid::{Dem, check_same_crs};
use crate::mask::Mask;
use crate::stats::{median, nmad};
use crate::terrain::{GradientMethod, gradients};
use crate::{ChangeError, error::positive};

/// Estimator of the vertical shift.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VerticalEstimator {
    /// Median of dh (robust; the default).
    Median,
    /// Mean of dh.
    Mean,
}

/// Options of the co-registration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NuthKaabOptions {
    /// Maximum number of fit iterations.
    pub max_iterations: usize,
    /// Stop when a shift update is smaller than this, in pixels.
    pub tolerance_px: f64,
    /// Cells flatter than this slope (degrees) are left out of the horizontal fit (dh / tan α
    /// explodes there).
    pub min_slope_deg: f64,
    /// Cells steeper than this slope (degrees) are left out (cliffs, DEM artefacts).
    pub max_slope_deg: f64,
    /// Outlier cut-off on dh − median, in NMADs: cells beyond it are left out of the fit. The
    /// weighted fit also weights the others by the Tukey biweight (1 − (r / (k·NMAD))²)² — smooth
    /// weights keep its iteration from flipping between two inlier sets.
    pub outlier_nmads: f64,
    /// Vertical shift estimator.
    pub vertical: VerticalEstimator,
    /// When false, only the vertical shift is estimated.
    pub horizontal: bool,
    /// How the cosine is fitted.
    pub fit: NuthKaabFit,
    /// How slope and aspect of the reference are computed.
    pub gradient: GradientMethod,
}

/// How the cosine model is fitted to (dh − median) / tan α against aspect.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NuthKaabFit {
    /// Every cell, Tukey-weighted on dh (the default).
    Weighted,
    /// Unweighted fit to the medians of `bins` equal aspect bins spanning the data's aspects (xdem's
    /// `bin_before_fit`, 72 bins there): robust, and fast on huge grids.
    AspectBins {
        /// Number of bins.
        bins: usize,
    },
}

impl NuthKaabOptions {
    /// The settings of xdem's `NuthKaab` (0.2): central-difference gradients, no slope limits, 72
    /// aspect bins, no weights. For comparisons with xdem.
    pub fn xdem_like() -> NuthKaabOptions {
        NuthKaabOptions {
            max_iterations: 10,
            tolerance_px: 1e-3,
            min_slope_deg: 0.0,
            max_slope_deg: 90.0,
            outlier_nmads: 1e9,
            vertical: VerticalEstimator::Median,
            horizontal: true,
            fit: NuthKaabFit::AspectBins { bins: 72 },
            gradient: GradientMethod::Central,
        }
    }
}

impl Default for NuthKaabOptions {
    fn default() -> Self {
        NuthKaabOptions {
            max_iterations: 20,
            tolerance_px: 1e-3,
            min_slope_deg: 1.0,
            max_slope_deg: 70.0,
            outlier_nmads: 4.685,
            vertical: VerticalEstimator::Median,
            horizontal: true,
            fit: NuthKaabFit::AspectBins { bins: 72 },
            gradient: GradientMethod::Horn,
        }
    }
}

/// One iteration of the fit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NuthKaabIteration {
    /// Shift after this iteration, east and north, metres.
    pub shift_m: [f64; 2],
    /// Size of the update, pixels.
    pub update_px: f64,
    /// NMAD of dh over the stable cells within the slope limits, before this iteration's update, m.
    pub nmad: f64,
    /// Cells used in the fit.
    pub cells: usize,
}

/// The estimated translation and how it was found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NuthKaabResult {
    /// Translation east, north, metres.
    pub shift_east_m: f64,
    /// Translation north, metres.
    pub shift_north_m: f64,
    /// Vertical translation (added to the aligned DEM's heights), m.
    pub shift_z: f64,
    /// Translation in the grid's world units (x, y): degrees for geographic grids.
    pub shift_world: [f64; 2],
    /// Translation in reference pixels: columns (right) and rows (down).
    pub shift_px: [f64; 2],
    /// Whether the update fell below the tolerance before the iteration limit.
    pub converged: bool,
    /// The iterations.
    pub iterations: Vec<NuthKaabIteration>,
    /// Stable cells compared before alignment.
    pub cells_before: usize,
    /// NMAD of dh over stable cells before / after (m).
    pub nmad_before: f64,
    /// NMAD after applying the translation.
    pub nmad_after: f64,
    /// Median of dh before / after.
    pub median_before: f64,
    /// Median of dh after applying the translation.
    pub median_after: f64,
}

impl NuthKaabResult {
    /// `to_align` moved by the estimated translation (its grid moves; no resampling).
    pub fn apply(&self, to_align: &Dem) -> Dem {
        to_align.translated(self.shift_world[0], self.shift_world[1], self.shift_z)
    }
}

/// A stable reference cell usable for the fit.
struct Sample {
    x: f64,
    y: f64,
    z_ref: f64,
    tan_slope: f64,
    sin_aspect: f64,
    cos_aspect: f64,
    /// Whether slope is in range for the horizontal fit.
    in_slope_range: bool,
}

/// Co-registers `to_align` onto `reference`, using only cells selected by `stable` (every cell when
/// `None`).
pub fn nuth_kaab(
    reference: &Dem,
    to_align: &Dem,
    stable: Option<&Mask>,
    options: &NuthKaabOptions,
) -> Result<NuthKaabResult, ChangeError> {
    check_same_crs(reference.grid.crs, to_align.grid.crs)?;
    check_options(options)?;
    let stable = match stable {
        Some(m) => Some(m.onto(&reference.grid)?),
        None => None,
    };
    if stable.as_ref().is_some_and(|m| m.count() == 0) {
        return Err(ChangeError::EmptyStable(
            "the stable mask selects no cell of the reference DEM".into(),
        ));
    }
    let samples = reference_samples(reference, stable.as_ref(), options);
    if samples.is_empty() {
        return Err(ChangeError::EmptyStable(
            "no stable reference cell has a height and a slope".into(),
        ));
    }
    let grid = reference.grid;
    let (cell_e, cell_n) = grid.metric_cell_size();
    // World units per metre, east and north (north-up: y grows north).
    let scales = GridScales {
        world_per_m: [
            grid.transform.pixel_width.abs() / cell_e,
            grid.transform.pixel_height.abs() / cell_n,
        ],
        cell_e,
        cell_n,
    };
    let mut dh = vec![f64::NAN; samples.len()];
    let (cells_before, median_before, nmad_before) = spread_before(&samples, to_align, &mut dh)?;
    let (shift_m, iterations, converged) = if options.horizontal {
        horizontal_shift(&samples, to_align, options, &scales, &mut dh)?
    } else {
        ([0.0f64; 2], Vec::new(), true)
    };
    let world = scales.world(shift_m);
    differences(&samples, to_align, world, &mut dh);
    let (shift_z, median_after, nmad_after) = vertical_shift(&dh, options.vertical)?;
    Ok(NuthKaabResult {
        shift_east_m: shift_m[0],
        shift_north_m: shift_m[1],
        shift_z,
        shift_world: world,
        shift_px: [
            world[0] / grid.transform.pixel_width,
            world[1] / grid.transform.pixel_height,
        ],
        converged,
        iterations,
        cells_before,
        nmad_before,
        nmad_after,
        median_before,
        median_after,
    })
}

/// Checks the tolerance, the outlier cut-off and the slope limits.
fn check_options(options: &NuthKaabOptions) -> Result<(), ChangeError> {
    positive("tolerance_px", options.tolerance_px)?;
    positive("outlier_nmads", options.outlier_nmads)?;
    if !(options.min_slope_deg >= 0.0
        && options.min_slope_deg < options.max_slope_deg
        && options.max_slope_deg <= 90.0)
    {
        return Err(ChangeError::InvalidParameter {
            name: "min_slope_deg/max_slope_deg",
            reason: format!(
                "{}..{} given; 0 ≤ min < max ≤ 90 was expected",
                options.min_slope_deg, options.max_slope_deg
            ),
        });
    }
    Ok(())
}

/// The reference grid's metric scales: world units per metre (east, north) and its cell size in
/// metres.
struct GridScales {
    world_per_m: [f64; 2],
    cell_e: f64,
    cell_n: f64,
}

impl GridScales {
    /// A shift in metres (east, north) in world units.
    fn world(&self, shift_m: [f64; 2]) -> [f64; 2] {
        [
            shift_m[0] * self.world_per_m[0],
            shift_m[1] * self.world_per_m[1],
        ]
    }
}

/// The stable cells compared before alignment, and the median and NMAD of their dh (left in
/// `dh`); an error when fewer than three hold a height in both DEMs.
fn spread_before(
    samples: &[Sample],
    to_align: &Dem,
    dh: &mut [f64],
) -> Result<(usize, f64, f64), ChangeError> {
    differences(samples, to_align, [0.0; 2], dh);
    let mut valid: Vec<f64> = dh.iter().copied().filter(|v| v.is_finite()).collect();
    if valid.len() < 3 {
        return Err(ChangeError::NoOverlap(format!(
            "only {} stable cells hold a height in both DEMs",
            valid.len()
        )));
    }
    let n = valid.len();
    let m = median(&mut valid);
    Ok((n, m, nmad(&mut valid)))
}

/// The horizontal shift (east, north, metres) by repeated fits on the re-sampled DEM, the
/// iterations, and whether an update fell below the tolerance; `dh` is scratch.
fn horizontal_shift(
    samples: &[Sample],
    to_align: &Dem,
    options: &NuthKaabOptions,
    scales: &GridScales,
    dh: &mut [f64],
) -> Result<([f64; 2], Vec<NuthKaabIteration>, bool), ChangeError> {
    let mut shift_m = [0.0f64; 2];
    let mut iterations = Vec::new();
    let mut converged = false;
    for _ in 0..options.max_iterations {
        let world = scales.world(shift_m);
        differences(samples, to_align, world, dh);
        let (update, cells, spread) = fit_shift(samples, dh, options)?;
        shift_m[0] += update[0];
        shift_m[1] += update[1];
        let update_px = (update[0] / scales.cell_e).hypot(update[1] / scales.cell_n);
        iterations.push(NuthKaabIteration {
            shift_m,
            update_px,
            nmad: spread,
            cells,
        });
        if !(shift_m[0].is_finite() && shift_m[1].is_finite()) {
            return Err(ChangeError::Degenerate(
                "the Nuth & Kääb fit diverged (non-finite shift)".into(),
            ));
        }
        if update_px < options.tolerance_px {
            converged = true;
            break;
        }
    }
    Ok((shift_m, iterations, converged))
}

/// The vertical shift (minus the bias of `dh` by the estimator) and the median and NMAD of dh
/// after it; an error when no cell holds a height in both DEMs.
fn vertical_shift(
    dh: &[f64],
    estimator: VerticalEstimator,
) -> Result<(f64, f64, f64), ChangeError> {
    let mut valid: Vec<f64> = dh.iter().copied().filter(|v| v.is_finite()).collect();
    if valid.is_empty() {
        return Err(ChangeError::NoOverlap(
            "after the horizontal shift no stable cell holds a height in both DEMs".into(),
        ));
    }
    let bias = match estimator {
        VerticalEstimator::Median => median(&mut valid),
        VerticalEstimator::Mean => valid.iter().sum::<f64>() / valid.len() as f64,
    };
    let shift_z = -bias;
    let mut after: Vec<f64> = valid.iter().map(|v| v + shift_z).collect();
    let median_after = median(&mut after);
    let nmad_after = nmad(&mut after);
    Ok((shift_z, median_after, nmad_after))
}

fn reference_samples(
    reference: &Dem,
    stable: Option<&Mask>,
    options: &NuthKaabOptions,
) -> Vec<Sample> {
    let gradients = gradients(reference, options.gradient);
    let tan_min = options.min_slope_deg.to_radians().tan();
    let tan_max = options.max_slope_deg.to_radians().tan();
    let grid = reference.grid;
    (0..grid.len())
        .filter_map(|i| {
            if stable.is_some_and(|m| !m.cells[i]) {
                return None;
            }
            let z = reference.values[i];
            if z.is_nan() {
                return None;
            }
            // Vertical-only fits need no slope: cells without a gradient (borders, next to
            // nodata) still count there.
            let Some(g) = gradients[i] else {
                let (x, y) = grid.cell_center(i % grid.width, i / grid.width);
                return (!options.horizontal).then_some(Sample {
                    x,
                    y,
                    z_ref: z as f64,
                    tan_slope: 0.0,
                    sin_aspect: 0.0,
                    cos_aspect: 0.0,
                    in_slope_range: false,
                });
            };
            let tan_slope = g.tan_slope();
            let (x, y) = grid.cell_center(i % grid.width, i / grid.width);
            let (sin_aspect, cos_aspect) = if tan_slope > 0.0 {
                (-g.east / tan_slope, -g.north / tan_slope)
            } else {
                (0.0, 0.0)
            };
            Some(Sample {
                x,
                y,
                z_ref: z as f64,
                tan_slope,
                sin_aspect,
                cos_aspect,
                in_slope_range: tan_slope >= tan_min && tan_slope <= tan_max && tan_slope > 0.0,
            })
        })
        .collect()
}

/// dh = to_align(p − shift) − reference(p) at every sample (NaN where to_align has no height).
fn differences(samples: &[Sample], to_align: &Dem, shift_world: [f64; 2], dh: &mut [f64]) {
    dh.par_iter_mut()
        .zip(samples.par_iter())
        .for_each(|(d, s)| {
            *d = to_align.bilinear(s.x - shift_world[0], s.y - shift_world[1]) - s.z_ref;
        });
}

/// One Nuth & Kääb fit: returns the shift update (east, north, metres), the cells used and the NMAD
/// of dh.
fn fit_shift(
    samples: &[Sample],
    dh: &[f64],
    options: &NuthKaabOptions,
) -> Result<([f64; 2], usize, f64), ChangeError> {
    let mut valid: Vec<f64> = samples
        .iter()
        .zip(dh)
        .filter(|(s, d)| s.in_slope_range && d.is_finite())
        .map(|(_, &d)| d)
        .collect();
    if valid.len() < 10 {
        return Err(ChangeError::NotEnoughData(format!(
            "{} stable cells with slope between {}° and {}° overlap; at least 10 are needed for \
             the horizontal fit",
            valid.len(),
            options.min_slope_deg,
            options.max_slope_deg
        )));
    }
    let m = median(&mut valid);
    let spread = nmad(&mut valid);
    // A floor of 1 µm keeps exact data (NMAD 0) from rejecting everything.
    let limit = options.outlier_nmads * spread.max(1e-6);
    if let NuthKaabFit::AspectBins { bins } = options.fit {
        return fit_binned(samples, dh, m, limit, bins).map(|u| (u, valid.len(), spread));
    }
    // Normal equations of y = A sin ψ + B cos ψ + C.
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut atb = nalgebra::Vector3::<f64>::zeros();
    let mut cells = 0usize;
    for (s, &d) in samples.iter().zip(dh) {
        if !(s.in_slope_range && d.is_finite() && (d - m).abs() < limit) {
            continue;
        }
        let u = (d - m) / limit;
        let weight = (1.0 - u * u).powi(2);
        let row = nalgebra::Vector3::new(s.sin_aspect, s.cos_aspect, 1.0);
        // The vertical bias is removed first (as xdem does): left in, bias / tan α would correlate
        // with aspect wherever slopes differ by aspect and show up as a spurious shift.
        let y = (d - m) / s.tan_slope;
        ata += weight * row * row.transpose();
        atb += weight * row * y;
        cells += 1;
    }
    if cells < 10 {
        return Err(ChangeError::NotEnoughData(format!(
            "{cells} stable cells remain after outlier rejection; at least 10 are needed"
        )));
    }
    let solution = ata.cholesky().map(|c| c.solve(&atb)).ok_or_else(|| {
        ChangeError::Degenerate(
            "the stable terrain has too little variety of aspect to fix a horizontal shift".into(),
        )
    })?;
    // dh/tanα = −(s_e sin ψ + s_n cos ψ) + c.
    Ok(([-solution[0], -solution[1]], cells, spread))
}

/// Unweighted least squares of the cosine model through the medians of equal aspect bins.
fn fit_binned(
    samples: &[Sample],
    dh: &[f64],
    median_dh: f64,
    limit: f64,
    bins: usize,
) -> Result<[f64; 2], ChangeError> {
    if bins < 3 {
        return Err(ChangeError::InvalidParameter {
            name: "bins",
            reason: format!("{bins} given; at least 3 aspect bins are needed"),
        });
    }
    let used: Vec<(f64, f64)> = samples
        .iter()
        .zip(dh)
        .filter(|(s, d)| s.in_slope_range && d.is_finite() && (**d - median_dh).abs() < limit)
        .map(|(s, &d)| {
            (
                s.sin_aspect
                    .atan2(s.cos_aspect)
                    .rem_euclid(std::f64::consts::TAU),
                (d - median_dh) / s.tan_slope,
            )
        })
        .collect();
    let (lo, hi) = used
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &(a, _)| {
            (lo.min(a), hi.max(a))
        });
    let width = (hi - lo) / bins as f64;
    if !(width > 0.0) {
        return Err(ChangeError::Degenerate(
            "the stable terrain has a single aspect; no horizontal shift can be fixed".into(),
        ));
    }
    let mut per_bin: Vec<Vec<f64>> = vec![Vec::new(); bins];
    for &(a, y) in &used {
        let b = (((a - lo) / width) as usize).min(bins - 1);
        per_bin[b].push(y);
    }
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut atb = nalgebra::Vector3::<f64>::zeros();
    for (b, values) in per_bin.iter_mut().enumerate() {
        if values.is_empty() {
            continue;
        }
        let centre = lo + (b as f64 + 0.5) * width;
        let y = median(values);
        let row = nalgebra::Vector3::new(centre.sin(), centre.cos(), 1.0);
        ata += row * row.transpose();
        atb += row * y;
    }
    let solution = ata.cholesky().map(|c| c.solve(&atb)).ok_or_else(|| {
        ChangeError::Degenerate("too few aspect bins hold data to fix a horizontal shift".into())
    })?;
    Ok([-solution[0], -solution[1]])
}
