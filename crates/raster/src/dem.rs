//! Gridding a point cloud into a DEM: points are binned into the lattice's cells by a counting
//! sort (one pass, no tree), then each cell's height is a robust statistic of its own points, or
//! an inverse-distance mean within a radius; the point count and the height spread of every cell
//! are kept so that change detection can use a spatially varying level of detection.

use rayon::prelude::*;

use crate::fill::fill_gaps;
use crate::{Lattice, RasterError};

/// How a cell's height is made from the points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CellHeight {
    /// Median of the points in the cell (default; robust to a few outliers).
    Median,
    /// Highest point in the cell: a surface model of tall objects (canopy, buildings).
    Max,
    /// Inverse-distance weighted mean of the points within `radius` metres of the cell centre,
    /// weights 1 / dᵖ (`power`).
    InverseDistance {
        /// Search radius in metres.
        radius: f64,
        /// Power of the distance in the weights.
        power: f64,
    },
}

/// DEM gridding options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DemOptions {
    /// The cell statistic.
    pub height: CellHeight,
    /// Least points a cell (or the IDW radius) must hold to get a height. Default 1.
    pub min_points: usize,
    /// Holes of up to this many cells across are filled by interpolation (0: none). Default 3.
    pub max_gap: usize,
}

impl Default for DemOptions {
    fn default() -> Self {
        DemOptions {
            height: CellHeight::Median,
            min_points: 1,
            max_gap: 3,
        }
    }
}

/// A DEM and its companions, all on one lattice, row-major from the north-west cell.
#[derive(Debug, Clone, PartialEq)]
pub struct Dem {
    /// The lattice.
    pub lattice: Lattice,
    /// Height per cell; NaN where there is none.
    pub height: Vec<f32>,
    /// Points that made each cell's height (0 for filled and empty cells).
    pub count: Vec<u32>,
    /// Standard deviation of the heights of those points; NaN with fewer than 2.
    pub spread: Vec<f32>,
    /// Cells whose height was interpolated across a gap rather than measured.
    pub filled: Vec<bool>,
}

impl Dem {
    /// Cells with a height (measured or filled).
    pub fn valid_cells(&self) -> usize {
        self.height.iter().filter(|h| h.is_finite()).count()
    }
}

/// Grids `points` (world x, y, z) onto `lattice`. Points outside the lattice are ignored.
pub fn grid_cloud(
    points: &[[f64; 3]],
    lattice: &Lattice,
    options: &DemOptions,
) -> Result<Dem, RasterError> {
    validate(options)?;
    let cells = lattice.len();
    let (start, binned) = bin_by_cell(points, lattice)?;

    let width = lattice.width();
    let mut height = vec![f32::NAN; cells];
    let mut count = vec![0u32; cells];
    let mut spread = vec![f32::NAN; cells];
    let binned = &binned;
    let start = &start;
    height
        .par_chunks_mut(width)
        .zip(count.par_chunks_mut(width))
        .zip(spread.par_chunks_mut(width))
        .enumerate()
        .for_each_init(Vec::new, |scratch, (row, ((h_row, n_row), s_row))| {
            for col in 0..width {
                let cell = row * width + col;
                let own = &binned[start[cell]..start[cell + 1]];
                let (h, n) = match options.height {
                    CellHeight::Median => cell_median(own, scratch),
                    CellHeight::Max => (
                        own.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max),
                        own.len(),
                    ),
                    CellHeight::InverseDistance { radius, power } => {
                        inverse_distance(lattice, binned, start, (col, row), radius, power)
                    }
                };
                if n >= options.min_points && n > 0 && h.is_finite() {
                    h_row[col] = h as f32;
                    n_row[col] = own.len() as u32;
                    s_row[col] = standard_deviation(own);
                }
            }
        });
    let mut filled = vec![false; cells];
    if options.max_gap > 0 {
        fill_gaps(&mut height, &mut filled, lattice, options.max_gap);
    }
    Ok(Dem {
        lattice: *lattice,
        height,
        count,
        spread,
        filled,
    })
}

/// The finite points inside the lattice, sorted by cell (a counting sort, in input order within
/// a cell), and where each cell's points start: cell c holds `binned[start[c]..start[c + 1]]`.
fn bin_by_cell(
    points: &[[f64; 3]],
    lattice: &Lattice,
) -> Result<(Vec<usize>, Vec<[f64; 3]>), RasterError> {
    let cells = lattice.len();
    // Cell of every point (u32::MAX outside), then a counting sort of the heights by cell.
    let cell_of: Vec<u32> = points
        .par_iter()
        .map(|p| {
            if !(p[0].is_finite() && p[1].is_finite() && p[2].is_finite()) {
                return u32::MAX;
            }
            match lattice.cell_of(p[0], p[1]) {
                Some((c, r)) => (r * lattice.width() + c) as u32,
                None => u32::MAX,
            }
        })
        .collect();
    if cells >= u32::MAX as usize {
        return Err(RasterError::InvalidGrid(format!(
            "{cells} cells exceed the gridding index"
        )));
    }
    let mut start = vec![0usize; cells + 1];
    for &c in &cell_of {
        if c != u32::MAX {
            start[c as usize + 1] += 1;
        }
    }
    for i in 0..cells {
        start[i + 1] += start[i];
    }
    let inside = start[cells];
    if inside == 0 {
        return Err(RasterError::NoPoints(format!(
            "{} points, lattice x {:.3}..{:.3}, y {:.3}..{:.3}",
            points.len(),
            lattice.bounds().x_min,
            lattice.bounds().x_max,
            lattice.bounds().y_min,
            lattice.bounds().y_max
        )));
    }
    let mut next = start.clone();
    let mut binned = vec![[0.0f64; 3]; inside];
    for (p, &c) in points.iter().zip(&cell_of) {
        if c != u32::MAX {
            let slot = &mut next[c as usize];
            binned[*slot] = *p;
            *slot += 1;
        }
    }
    Ok((start, binned))
}

fn validate(options: &DemOptions) -> Result<(), RasterError> {
    if let CellHeight::InverseDistance { radius, power } = options.height
        && !(radius > 0.0 && radius.is_finite() && power >= 0.0 && power.is_finite())
    {
        return Err(RasterError::InvalidOption(format!(
            "inverse-distance radius {radius} m and power {power}: the radius must be positive \
             and the power not negative"
        )));
    }
    if options.max_gap > 10_000 {
        return Err(RasterError::InvalidOption(format!(
            "max_gap {} cells is more than 10000",
            options.max_gap
        )));
    }
    Ok(())
}

/// Median height of a cell's points (mean of the two middle ones for an even count).
fn cell_median(points: &[[f64; 3]], scratch: &mut Vec<f64>) -> (f64, usize) {
    let n = points.len();
    if n == 0 {
        return (f64::NAN, 0);
    }
    scratch.clear();
    scratch.extend(points.iter().map(|p| p[2]));
    let mid = n / 2;
    let (lower, upper, _) = scratch.select_nth_unstable_by(mid, f64::total_cmp);
    let upper = *upper;
    if n % 2 == 1 {
        (upper, n)
    } else {
        let below = lower.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (0.5 * (below + upper), n)
    }
}

fn standard_deviation(points: &[[f64; 3]]) -> f32 {
    let n = points.len();
    if n < 2 {
        return f32::NAN;
    }
    let mean = points.iter().map(|p| p[2]).sum::<f64>() / n as f64;
    let var = points.iter().map(|p| (p[2] - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    var.sqrt() as f32
}

/// Inverse-distance mean of the points within `radius` of the centre of cell `(col, row)`.
fn inverse_distance(
    lattice: &Lattice,
    binned: &[[f64; 3]],
    start: &[usize],
    (col, row): (usize, usize),
    radius: f64,
    power: f64,
) -> (f64, usize) {
    let (cx, cy) = lattice.cell_center(col, row);
    let reach = (radius / lattice.cell_width().min(lattice.cell_height())).ceil() as usize;
    let (c0, c1) = (
        col.saturating_sub(reach),
        (col + reach).min(lattice.width() - 1),
    );
    let (r0, r1) = (
        row.saturating_sub(reach),
        (row + reach).min(lattice.height() - 1),
    );
    let r2 = radius * radius;
    // A point at the centre itself (closer than a millionth of a cell) decides the height.
    let exact = (1e-6 * lattice.cell()).powi(2);
    let (mut sum_w, mut sum_wz, mut n) = (0.0, 0.0, 0usize);
    for r in r0..=r1 {
        let base = r * lattice.width();
        for p in &binned[start[base + c0]..start[base + c1 + 1]] {
            let d2 = (p[0] - cx).powi(2) + (p[1] - cy).powi(2);
            if d2 > r2 {
                continue;
            }
            if d2 <= exact {
                return (p[2], 1);
            }
            let w = d2.powf(-0.5 * power);
            sum_w += w;
            sum_wz += w * p[2];
            n += 1;
        }
    }
    if n == 0 {
        (f64::NAN, 0)
    } else {
        (sum_wz / sum_w, n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lattice() -> Lattice {
        Lattice::new(100.0, 200.0, 0.5, 8, 6).unwrap()
    }

    #[test]
    fn median_max_count_and_spread_per_cell() {
        let l = lattice();
        let (x, y) = l.cell_center(2, 1);
        let pts = [
            [x - 0.1, y + 0.1, 10.0],
            [x + 0.2, y - 0.2, 13.0],
            [x, y, 11.0],
            [x + 0.1, y, 50.0], // an outlier the median ignores
            [1e9, 1e9, 0.0],    // outside
            [f64::NAN, y, 0.0], // not finite
        ];
        let options = DemOptions {
            max_gap: 0,
            ..DemOptions::default()
        };
        let dem = grid_cloud(&pts, &l, &options).unwrap();
        let cell = l.width() + 2;
        assert_eq!(dem.height[cell], 12.0); // (11 + 13) / 2
        assert_eq!(dem.count[cell], 4);
        let heights = [10.0f64, 13.0, 11.0, 50.0];
        let mean = heights.iter().sum::<f64>() / 4.0;
        let sd = (heights.iter().map(|h| (h - mean).powi(2)).sum::<f64>() / 3.0).sqrt();
        assert!((dem.spread[cell] as f64 - sd).abs() < 1e-5);
        assert_eq!(dem.valid_cells(), 1);
        let max = grid_cloud(
            &pts,
            &l,
            &DemOptions {
                height: CellHeight::Max,
                ..options
            },
        )
        .unwrap();
        assert_eq!(max.height[cell], 50.0);
        let strict = grid_cloud(
            &pts,
            &l,
            &DemOptions {
                min_points: 5,
                ..options
            },
        );
        assert_eq!(strict.unwrap().valid_cells(), 0);
    }

    #[test]
    fn inverse_distance_reproduces_a_plane_and_takes_exact_hits() {
        let l = lattice();
        let plane = |x: f64, y: f64| 3.0 + 0.2 * (x - 100.0) - 0.1 * (y - 200.0);
        // Points on a symmetric pattern around every cell centre: IDW of a plane is exact there.
        let mut pts = Vec::new();
        for r in 0..l.height() {
            for c in 0..l.width() {
                let (x, y) = l.cell_center(c, r);
                for (dx, dy) in [(0.2, 0.0), (-0.2, 0.0), (0.0, 0.2), (0.0, -0.2)] {
                    pts.push([x + dx, y + dy, plane(x + dx, y + dy)]);
                }
            }
        }
        let options = DemOptions {
            height: CellHeight::InverseDistance {
                radius: 0.21,
                power: 2.0,
            },
            min_points: 4,
            max_gap: 0,
        };
        let dem = grid_cloud(&pts, &l, &options).unwrap();
        for r in 0..l.height() {
            for c in 0..l.width() {
                let (x, y) = l.cell_center(c, r);
                let h = dem.height[r * l.width() + c] as f64;
                assert!((h - plane(x, y)).abs() < 1e-4, "{c} {r}: {h}");
            }
        }
        let (x, y) = l.cell_center(1, 1);
        let hit = grid_cloud(&[[x, y, 7.5], [x + 0.1, y, 100.0]], &l, &options).unwrap();
        // min_points 4 is not met by the hit alone; with 1 it is exact.
        assert!(hit.height[l.width() + 1].is_nan());
        let hit = grid_cloud(
            &[[x, y, 7.5], [x + 0.1, y, 100.0]],
            &l,
            &DemOptions {
                min_points: 1,
                ..options
            },
        )
        .unwrap();
        assert_eq!(hit.height[l.width() + 1], 7.5);
    }

    #[test]
    fn bad_input_is_an_error_not_nan() {
        let l = lattice();
        assert!(matches!(
            grid_cloud(&[], &l, &DemOptions::default()),
            Err(RasterError::NoPoints(_))
        ));
        assert!(matches!(
            grid_cloud(&[[0.0, 0.0, 1.0]], &l, &DemOptions::default()),
            Err(RasterError::NoPoints(_))
        ));
        let bad = DemOptions {
            height: CellHeight::InverseDistance {
                radius: -1.0,
                power: 2.0,
            },
            ..DemOptions::default()
        };
        assert!(matches!(
            grid_cloud(&[[101.0, 199.0, 1.0]], &l, &bad),
            Err(RasterError::InvalidOption(_))
        ));
    }
}
