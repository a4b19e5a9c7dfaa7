//! The planar trend of a difference grid over a set of cells: the least-squares plane
//! `dz = a + b·x + c·y` through the stable cells of a DoD ([`plane_trend`]), and the same of
//! scattered height residuals, robust to blunders ([`residual_plane`]: tie points against a
//! surface).
//!
//! Why: a co-registration error that tilts one epoch (a roll about a corridor's axis, a bent
//! block) leaves the stable area's median near zero while the DoD climbs from one side to the
//! other. Check points along a corridor cannot see it; this plane does. The gain across the cells'
//! extent is the figure to compare with the level of detection.

use serde::{Deserialize, Serialize};

use crate::ChangeError;
use crate::grid::Dem;
use crate::mask::Mask;

/// Fewest cells for a plane fit.
const MIN_CELLS: usize = 10;

/// The least-squares plane of a DoD over some cells.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlaneTrend {
    /// Cells used.
    pub cells: usize,
    /// The plane's value at the cells' centroid, m.
    pub offset: f64,
    /// Its gradient magnitude, metres of difference per metre on the ground.
    pub slope: f64,
    /// Direction in which the difference grows, degrees clockwise from north (0–360).
    pub azimuth_deg: f64,
    /// Diagonal of the cells' bounding box, m.
    pub extent_m: f64,
    /// What the plane gains across that extent (`slope × extent_m`), m.
    pub gain_m: f64,
}

/// Fits the plane through the finite cells of `dod` selected by `mask` (every cell when `None`).
/// Distances are metric (geographic grids use the cell's metric size at the grid's middle row).
///
/// Errors: fewer than ten usable cells, or cells on one line ([`ChangeError::NotEnoughData`],
/// [`ChangeError::Degenerate`]); a mask on another grid ([`ChangeError::InvalidInput`]).
pub fn plane_trend(dod: &Dem, mask: Option<&Mask>) -> Result<PlaneTrend, ChangeError> {
    let grid = &dod.grid;
    Mask::check_fits(mask, grid)?;
    let (cw, ch) = grid.metric_cell_size_at_row(grid.height / 2);
    let cells = || {
        (0..grid.height)
            .flat_map(move |r| (0..grid.width).map(move |c| (c, r)))
            .filter_map(move |(c, r)| {
                let i = r * grid.width + c;
                let v = dod.values[i];
                let selected = mask.is_none_or(|m| m.cells[i]);
                // x east, y north, in metres from the north-west corner.
                (selected && v.is_finite())
                    .then(|| ((c as f64 + 0.5) * cw, -(r as f64 + 0.5) * ch, v as f64))
            })
    };
    let (mut n, mut sx, mut sy, mut sz) = (0usize, 0.0, 0.0, 0.0);
    for (x, y, z) in cells() {
        n += 1;
        sx += x;
        sy += y;
        sz += z;
    }
    if n < MIN_CELLS {
        return Err(ChangeError::NotEnoughData(format!(
            "a plane needs {MIN_CELLS} cells with a difference; {n} given"
        )));
    }
    let nf = n as f64;
    let (mx, my, mz) = (sx / nf, sy / nf, sz / nf);
    let (mut sxx, mut sxy, mut syy, mut sxz, mut syz) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (x, y, z) in cells() {
        let (dx, dy, dz) = (x - mx, y - my, z - mz);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
        sxz += dx * dz;
        syz += dy * dz;
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    let det = sxx * syy - sxy * sxy;
    // Relative test: cells on one line leave the 2 × 2 system singular.
    if !(det > 1e-9 * (sxx * syy).max(f64::MIN_POSITIVE)) {
        return Err(ChangeError::Degenerate(
            "the cells lie on one line: a plane is not determined".into(),
        ));
    }
    let b = (syy * sxz - sxy * syz) / det;
    let c = (sxx * syz - sxy * sxz) / det;
    let slope = b.hypot(c);
    let extent_m = (x1 - x0).hypot(y1 - y0);
    Ok(PlaneTrend {
        cells: n,
        offset: mz,
        slope,
        azimuth_deg: b.atan2(c).to_degrees().rem_euclid(360.0),
        extent_m,
        gain_m: slope * extent_m,
    })
}

/// How a set of points sits on a true surface: the height residuals' median and the plane
/// fitted to them, which shows a tilt (a roll about a corridor's axis) that check points along
/// the corridor cannot.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurfaceAgreement {
    /// Points compared.
    pub count: usize,
    /// Median height residual (point − surface), metres.
    pub median_m: f64,
    /// Slope of the plane fitted to the residuals, mm per m.
    pub tilt_mm_per_m: f64,
    /// Downhill direction of that plane, degrees clockwise from north.
    pub tilt_azimuth_deg: f64,
}

/// Least points for a plane fit of residuals.
const MIN_PLANE_POINTS: usize = 20;

/// The plane `dz = a + b·x + c·y` through height residuals at `xy`, fitted by least squares,
/// then again without the residuals beyond 3 NMAD of the first fit (blunders among tie
/// points); `None` with fewer than 20 points or a degenerate spread.
pub fn residual_plane(points: &[(f64, f64, f64)]) -> Option<SurfaceAgreement> {
    if points.len() < MIN_PLANE_POINTS {
        return None;
    }
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(sx, sy), p| (sx + p.0 / n, sy + p.1 / n));
    // Points along a line fix no plane across it.
    let (sxx, syy, sxy) = points.iter().fold((0.0, 0.0, 0.0), |(a, b, c), p| {
        let (x, y) = (p.0 - mx, p.1 - my);
        (a + x * x, b + y * y, c + x * y)
    });
    if sxx * syy - sxy * sxy <= 1e-9 * (sxx + syy).powi(2) {
        return None;
    }
    let fit = |keep: &dyn Fn(&(f64, f64, f64)) -> bool| -> Option<nalgebra::Vector3<f64>> {
        let mut normal = nalgebra::Matrix3::<f64>::zeros();
        let mut rhs = nalgebra::Vector3::<f64>::zeros();
        for p in points.iter().filter(|p| keep(p)) {
            let row = nalgebra::Vector3::new(1.0, p.0 - mx, p.1 - my);
            normal += row * row.transpose();
            rhs += row * p.2;
        }
        normal.cholesky().map(|c| c.solve(&rhs))
    };
    let first = fit(&|_| true)?;
    let residual = |c: &nalgebra::Vector3<f64>, p: &(f64, f64, f64)| {
        p.2 - (c[0] + c[1] * (p.0 - mx) + c[2] * (p.1 - my))
    };
    let stats = crate::stats::statistics(points.iter().map(|p| residual(&first, p)))?;
    let bound = 3.0 * stats.nmad.max(1e-9);
    let plane = fit(&|p| residual(&first, p).abs() <= bound)?;
    let median = crate::stats::statistics(points.iter().map(|p| p.2))?.median;
    let (gx, gy) = (plane[1], plane[2]);
    Some(SurfaceAgreement {
        count: points.len(),
        median_m: median,
        tilt_mm_per_m: 1000.0 * gx.hypot(gy),
        // Downhill: against the gradient; azimuth from north (y) clockwise towards east (x).
        tilt_azimuth_deg: (-gx).atan2(-gy).to_degrees().rem_euclid(360.0),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use timesift_io::coords::Crs;
    use timesift_io::geotiff::GeoTransform;

    fn dod(width: usize, height: usize, f: impl Fn(f64, f64) -> f64) -> Dem {
        let grid = Grid {
            transform: GeoTransform {
                origin_x: 500_000.0,
                origin_y: 4_000_000.0,
                pixel_width: 2.0,
                pixel_height: -2.0,
            },
            width,
            height,
            crs: Crs::Epsg(32633),
        };
        let values = (0..height)
            .flat_map(|r| (0..width).map(move |c| (c, r)))
            .map(|(c, r)| {
                let (x, y) = grid.cell_center(c, r);
                f(x - 500_000.0, y - 4_000_000.0) as f32
            })
            .collect();
        Dem { grid, values }
    }

    #[test]
    fn recovers_a_tilted_plane_exactly() {
        // Rises 3 mm per metre towards the east and 4 mm/m towards the south: 5 mm/m, azimuth
        // atan2(3, −4) = 143.13°.
        let d = dod(60, 40, |x, y| 0.25 + 0.003 * x - 0.004 * y);
        let t = plane_trend(&d, None).expect("plane");
        assert_eq!(t.cells, 2400);
        assert!((t.slope - 0.005).abs() < 1e-7, "{}", t.slope);
        assert!(
            (t.azimuth_deg - 143.130_102).abs() < 1e-3,
            "{}",
            t.azimuth_deg
        );
        let extent = (118.0f64).hypot(78.0);
        assert!((t.extent_m - extent).abs() < 1e-9);
        assert!((t.gain_m - 0.005 * extent).abs() < 1e-6);
        // The value at the centroid (60, −40) of the cell centres.
        assert!(
            (t.offset - (0.25 + 0.18 + 0.16)).abs() < 1e-5,
            "{}",
            t.offset
        );
    }

    #[test]
    fn a_mask_selects_the_cells_and_nodata_is_skipped() {
        // Flat on the west half, steep (and partly missing) on the east half.
        let mut d = dod(40, 20, |x, _| if x < 40.0 { 0.1 } else { x });
        d.values[39] = f32::NAN;
        let west = Mask {
            grid: d.grid,
            cells: (0..800).map(|i| i % 40 < 20).collect(),
        };
        let t = plane_trend(&d, Some(&west)).expect("plane");
        assert_eq!(t.cells, 400);
        assert!(t.slope < 1e-9 && (t.offset - 0.1).abs() < 1e-6, "{t:?}");
        let all = plane_trend(&d, None).expect("plane");
        assert_eq!(all.cells, 799);
        assert!(all.slope > 0.5, "{all:?}");
    }

    #[test]
    fn degenerate_cells_are_errors_not_nan() {
        let d = dod(30, 1, |x, _| x);
        assert!(matches!(
            plane_trend(&d, None),
            Err(ChangeError::Degenerate(_))
        ));
        let mut few = dod(3, 3, |x, _| x);
        few.values[0] = f32::NAN;
        assert!(matches!(
            plane_trend(&few, None),
            Err(ChangeError::NotEnoughData(_))
        ));
        let other = Mask {
            grid: few.grid,
            cells: vec![true; 4],
        };
        assert!(matches!(
            plane_trend(&few, Some(&other)),
            Err(ChangeError::InvalidInput(_))
        ));
    }

    #[test]
    fn a_tilted_plane_of_residuals_is_recovered_despite_blunders() {
        let mut rng = timesift_core::SeededRng::new(4);
        // 2 mm/m rising towards the north-east (downhill to the south-west, 225°), 5 cm above.
        let g = 0.002 / std::f64::consts::SQRT_2;
        let mut points: Vec<(f64, f64, f64)> = (0..400)
            .map(|_| {
                let (x, y) = (
                    rng.uniform_range(-150.0, 150.0),
                    rng.uniform_range(-40.0, 40.0),
                );
                (500_000.0 + x, 5_000_000.0 + y, 0.05 + g * x + g * y)
            })
            .collect();
        for p in points.iter_mut().step_by(40) {
            p.2 += 3.0;
        }
        let a = residual_plane(&points).unwrap();
        assert_eq!(a.count, 400);
        assert!((a.tilt_mm_per_m - 2.0).abs() < 1e-6, "{a:?}");
        assert!((a.tilt_azimuth_deg - 225.0).abs() < 1e-4, "{a:?}");
        assert!((a.median_m - 0.05).abs() < 0.02, "{a:?}");
        // Too few points, or points along a line, fix no plane.
        assert_eq!(residual_plane(&points[..10]), None);
        let line: Vec<(f64, f64, f64)> = (0..50)
            .map(|k| (k as f64, 2.0 * k as f64 + 1.0, 0.0))
            .collect();
        assert_eq!(residual_plane(&line), None);
    }
}
