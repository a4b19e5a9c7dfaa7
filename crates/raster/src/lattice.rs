//! The project's one raster lattice: north-up square cells whose edges sit on multiples of the
//! cell size, so that every epoch's DEM (and, subdivided, every ortho) lands on the same cells.

use crate::RasterError;

/// Most cells a lattice may hold (a 46 000 × 46 000 grid); beyond this an explicit extent or a
/// cell size is almost certainly a unit mistake, and the error says so before any allocation.
const MAX_CELLS: usize = 1 << 31;

/// An axis-aligned rectangle in the world frame (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// West edge.
    pub x_min: f64,
    /// South edge.
    pub y_min: f64,
    /// East edge.
    pub x_max: f64,
    /// North edge.
    pub y_max: f64,
}

impl Bounds {
    /// The bounds from two corners, validated (finite, non-empty).
    pub fn new(x_min: f64, y_min: f64, x_max: f64, y_max: f64) -> Result<Bounds, RasterError> {
        let b = Bounds {
            x_min,
            y_min,
            x_max,
            y_max,
        };
        let finite = [x_min, y_min, x_max, y_max].iter().all(|v| v.is_finite());
        if !(finite && x_max > x_min && y_max > y_min) {
            return Err(RasterError::InvalidGrid(format!(
                "extent [{x_min}, {y_min}, {x_max}, {y_max}] is not [xmin, ymin, xmax, ymax] with \
                 xmin < xmax and ymin < ymax"
            )));
        }
        Ok(b)
    }

    /// The smallest rectangle holding both.
    pub fn union(&self, other: &Bounds) -> Bounds {
        Bounds {
            x_min: self.x_min.min(other.x_min),
            y_min: self.y_min.min(other.y_min),
            x_max: self.x_max.max(other.x_max),
            y_max: self.y_max.max(other.y_max),
        }
    }

    /// The common part, `None` when the two do not overlap.
    pub fn intersection(&self, other: &Bounds) -> Option<Bounds> {
        Bounds::new(
            self.x_min.max(other.x_min),
            self.y_min.max(other.y_min),
            self.x_max.min(other.x_max),
            self.y_max.min(other.y_max),
        )
        .ok()
    }
}

/// A north-up lattice: cell (col, row) spans `[west + col·cw, west + (col+1)·cw] ×
/// [north − (row+1)·ch, north − row·ch]`. The project's lattices have square cells (cw = ch);
/// rasters made elsewhere may not.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lattice {
    west: f64,
    north: f64,
    cell_width: f64,
    cell_height: f64,
    width: usize,
    height: usize,
}

impl Lattice {
    /// A lattice of square cells from its north-west corner, cell size and size in cells.
    pub fn new(
        west: f64,
        north: f64,
        cell: f64,
        width: usize,
        height: usize,
    ) -> Result<Lattice, RasterError> {
        Lattice::with_cells(west, north, cell, cell, width, height)
    }

    /// A lattice of `cell_width` × `cell_height` cells (the grid of a raster made elsewhere).
    pub fn with_cells(
        west: f64,
        north: f64,
        cell_width: f64,
        cell_height: f64,
        width: usize,
        height: usize,
    ) -> Result<Lattice, RasterError> {
        let positive = |c: f64| c > 0.0 && c.is_finite();
        if !(positive(cell_width) && positive(cell_height) && west.is_finite() && north.is_finite())
        {
            return Err(RasterError::InvalidGrid(format!(
                "cell size {cell_width} × {cell_height} and corner ({west}, {north}) must be \
                 finite with positive cells"
            )));
        }
        let cell = cell_width;
        if width == 0 || height == 0 || width.saturating_mul(height) > MAX_CELLS {
            return Err(RasterError::InvalidGrid(format!(
                "{width} × {height} cells of {cell} m: a lattice holds 1 to {MAX_CELLS} cells \
                 (check the extent and the cell size's unit)"
            )));
        }
        Ok(Lattice {
            west,
            north,
            cell_width,
            cell_height,
            width,
            height,
        })
    }

    /// The lattice of `cell` whose edges are multiples of `cell` and which covers `bounds`.
    pub fn covering(bounds: &Bounds, cell: f64) -> Result<Lattice, RasterError> {
        if !(cell > 0.0 && cell.is_finite()) {
            return Err(RasterError::InvalidGrid(format!(
                "cell size {cell} must be positive"
            )));
        }
        // Edges snapped outward to the cell multiples; the tolerance keeps an extent that is
        // already on the lattice (up to rounding of the division) from growing by a cell.
        let snap_down = |v: f64| {
            let q = v / cell;
            let r = q.round();
            if (q - r).abs() < 1e-9 { r } else { q.floor() }
        };
        let snap_up = |v: f64| {
            let q = v / cell;
            let r = q.round();
            if (q - r).abs() < 1e-9 { r } else { q.ceil() }
        };
        let (c0, c1) = (snap_down(bounds.x_min), snap_up(bounds.x_max));
        let (r0, r1) = (snap_down(bounds.y_min), snap_up(bounds.y_max));
        let width = ((c1 - c0).max(1.0)) as usize;
        let height = ((r1 - r0).max(1.0)) as usize;
        if (c1 - c0) > MAX_CELLS as f64 || (r1 - r0) > MAX_CELLS as f64 {
            return Err(RasterError::InvalidGrid(format!(
                "an extent of {:.1} × {:.1} m in cells of {cell} m is too many cells",
                bounds.x_max - bounds.x_min,
                bounds.y_max - bounds.y_min
            )));
        }
        Lattice::new(c0 * cell, r1 * cell, cell, width, height)
    }

    /// West edge (x of the north-west corner).
    pub fn west(&self) -> f64 {
        self.west
    }
    /// North edge (y of the north-west corner).
    pub fn north(&self) -> f64 {
        self.north
    }
    /// Cell size in metres: the larger side of a cell (the side of the project's square cells).
    pub fn cell(&self) -> f64 {
        self.cell_width.max(self.cell_height)
    }
    /// East–west size of a cell, metres.
    pub fn cell_width(&self) -> f64 {
        self.cell_width
    }
    /// North–south size of a cell, metres.
    pub fn cell_height(&self) -> f64 {
        self.cell_height
    }
    /// Columns.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Rows.
    pub fn height(&self) -> usize {
        self.height
    }
    /// Number of cells.
    pub fn len(&self) -> usize {
        self.width * self.height
    }
    /// Always false: a lattice has at least one cell.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The rectangle the lattice covers.
    pub fn bounds(&self) -> Bounds {
        Bounds {
            x_min: self.west,
            y_min: self.north - self.height as f64 * self.cell_height,
            x_max: self.west + self.width as f64 * self.cell_width,
            y_max: self.north,
        }
    }

    /// World (x, y) of the centre of cell (col, row).
    pub fn cell_center(&self, col: usize, row: usize) -> (f64, f64) {
        (
            self.west + (col as f64 + 0.5) * self.cell_width,
            self.north - (row as f64 + 0.5) * self.cell_height,
        )
    }

    /// Continuous cell coordinates of a world position: the centre of cell (i, j) maps to (i, j).
    pub fn continuous_index(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (x - self.west) / self.cell_width - 0.5,
            (self.north - y) / self.cell_height - 0.5,
        )
    }

    /// The cell holding a world position; positions on a shared edge go to the cell east or
    /// south of it. `None` outside.
    pub fn cell_of(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let c = ((x - self.west) / self.cell_width).floor();
        let r = ((self.north - y) / self.cell_height).floor();
        if c >= 0.0 && r >= 0.0 && c < self.width as f64 && r < self.height as f64 {
            Some((c as usize, r as usize))
        } else {
            None
        }
    }

    /// The same area in cells `factor` times smaller (the ortho lattice of a DEM lattice).
    pub fn subdivided(&self, factor: usize) -> Result<Lattice, RasterError> {
        if factor == 0 {
            return Err(RasterError::InvalidGrid("subdivision factor 0".into()));
        }
        Lattice::with_cells(
            self.west,
            self.north,
            self.cell_width / factor as f64,
            self.cell_height / factor as f64,
            self.width * factor,
            self.height * factor,
        )
    }
}

/// The cell size nearest to `raw` among 1, 2, 2.5 and 5 times a power of ten (nearest on a log
/// scale), so that lattices of different projects of one site tend to share their cell edges.
pub fn tidy_cell(raw: f64) -> Result<f64, RasterError> {
    if !(raw > 0.0 && raw.is_finite()) {
        return Err(RasterError::InvalidGrid(format!(
            "cannot derive a cell size from {raw} m"
        )));
    }
    let decade = 10f64.powf(raw.log10().floor());
    let best = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * decade)
        .min_by(|a, b| {
            let da = (a / raw).ln().abs();
            let db = (b / raw).ln().abs();
            da.total_cmp(&db)
        })
        .unwrap_or(decade);
    // Remove the rounding noise of `powf` so that 0.05 prints as 0.05.
    let digits = (-best.log10().floor()).max(0.0) as i32 + 2;
    let scale = 10f64.powi(digits);
    Ok((best * scale).round() / scale)
}

/// How the project's extent is chosen from the epochs' footprints.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ExtentRule {
    /// Everything any epoch covers (default).
    Union,
    /// Only what every epoch covers.
    Intersection,
    /// Fixed bounds.
    Explicit(Bounds),
}

/// What the project's lattice is derived from.
#[derive(Debug, Clone, PartialEq)]
pub struct GridOptions {
    /// DEM cell in metres; `None` = 2 × the coarsest epoch's GSD, tidied.
    pub dem_cell: Option<f64>,
    /// Ortho cell in metres; `None` = the finest epoch's GSD, as an integer fraction of the DEM
    /// cell. An explicit value must divide the DEM cell.
    pub ortho_cell: Option<f64>,
    /// Extent rule.
    pub extent: ExtentRule,
}

impl Default for GridOptions {
    fn default() -> Self {
        GridOptions {
            dem_cell: None,
            ortho_cell: None,
            extent: ExtentRule::Union,
        }
    }
}

/// The one lattice of a project: the DEM lattice and its subdivision for orthomosaics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProjectGrid {
    /// Where every epoch's DEM lies.
    pub dem: Lattice,
    /// Ortho cells per DEM cell along each axis (≥ 1).
    pub ortho_factor: usize,
}

impl ProjectGrid {
    /// Where every epoch's orthomosaic lies.
    pub fn ortho(&self) -> Lattice {
        // `subdivided` only fails for factor 0 or an oversized lattice; `plan_grid` checked both.
        self.dem.subdivided(self.ortho_factor).unwrap_or(self.dem)
    }
}

/// One epoch's contribution to the lattice: where it has data and its ground sample distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpochFootprint {
    /// Where the epoch has data (its dense cloud's extent).
    pub bounds: Bounds,
    /// Median ground sample distance of its images, metres.
    pub gsd: f64,
}

/// The project's lattice from the epochs' footprints and the options.
pub fn plan_grid(
    epochs: &[EpochFootprint],
    options: &GridOptions,
) -> Result<ProjectGrid, RasterError> {
    if epochs.is_empty() {
        return Err(RasterError::InvalidGrid("no epoch to grid".into()));
    }
    for e in epochs {
        if !(e.gsd > 0.0 && e.gsd.is_finite()) {
            return Err(RasterError::InvalidGrid(format!(
                "ground sample distance {} m of an epoch is not positive",
                e.gsd
            )));
        }
    }
    let coarsest = epochs.iter().map(|e| e.gsd).fold(0.0, f64::max);
    let finest = epochs.iter().map(|e| e.gsd).fold(f64::INFINITY, f64::min);
    let dem_cell = match options.dem_cell {
        Some(c) if !(c > 0.0 && c.is_finite()) => {
            return Err(RasterError::InvalidOption(format!(
                "dem_cell {c} must be a positive number of metres"
            )));
        }
        Some(c) => c,
        None => tidy_cell(2.0 * coarsest)?,
    };
    let ortho_factor = match options.ortho_cell {
        Some(c) => {
            let k = dem_cell / c;
            if !(c > 0.0 && k.is_finite()) || k.round() < 1.0 || (k - k.round()).abs() > 1e-6 * k {
                return Err(RasterError::InvalidOption(format!(
                    "ortho_cell {c} must divide dem_cell {dem_cell} an integer number of times"
                )));
            }
            k.round() as usize
        }
        None => ((dem_cell / finest).round() as usize).max(1),
    };
    let bounds = match options.extent {
        ExtentRule::Explicit(b) => b,
        ExtentRule::Union => epochs[1..]
            .iter()
            .fold(epochs[0].bounds, |acc, e| acc.union(&e.bounds)),
        ExtentRule::Intersection => {
            let mut acc = epochs[0].bounds;
            for e in &epochs[1..] {
                acc = acc.intersection(&e.bounds).ok_or_else(|| {
                    RasterError::InvalidGrid(
                        "the epochs' footprints have no common part (extent = \"intersection\")"
                            .into(),
                    )
                })?;
            }
            acc
        }
    };
    let dem = Lattice::covering(&bounds, dem_cell)?;
    // The ortho lattice must also stay within bounds.
    dem.subdivided(ortho_factor)?;
    Ok(ProjectGrid { dem, ortho_factor })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tidy_cells_are_round_numbers_near_the_input() {
        for (raw, tidy) in [
            (0.047, 0.05),
            (0.021, 0.02),
            (0.024, 0.025),
            (1.3, 1.0),
            (3.3, 2.5),
            (3.8, 5.0),
            (8.0, 10.0),
            (0.0031, 0.0025),
        ] {
            assert_eq!(tidy_cell(raw).unwrap(), tidy, "{raw}");
        }
        assert!(tidy_cell(0.0).is_err());
        assert!(tidy_cell(f64::NAN).is_err());
    }

    #[test]
    fn covering_lattice_snaps_edges_to_cell_multiples() {
        let b = Bounds::new(500_000.13, 6_000_000.07, 500_010.0, 6_000_004.96).unwrap();
        let l = Lattice::covering(&b, 0.5).unwrap();
        assert_eq!(l.west(), 500_000.0);
        assert_eq!(l.north(), 6_000_005.0);
        assert_eq!((l.width(), l.height()), (20, 10));
        let lb = l.bounds();
        assert!(lb.x_min <= b.x_min && lb.x_max >= b.x_max);
        assert!(lb.y_min <= b.y_min && lb.y_max >= b.y_max);
        // A cell centre maps back to its own cell and index.
        let (x, y) = l.cell_center(7, 3);
        assert_eq!(l.cell_of(x, y), Some((7, 3)));
        let (c, r) = l.continuous_index(x, y);
        assert!((c - 7.0).abs() < 1e-9 && (r - 3.0).abs() < 1e-9);
        assert_eq!(l.cell_of(l.west() - 0.01, y), None);
    }

    #[test]
    fn every_epoch_gets_the_same_lattice_and_the_ortho_subdivides_it() {
        let a = EpochFootprint {
            bounds: Bounds::new(0.3, 0.2, 40.0, 30.0).unwrap(),
            gsd: 0.021,
        };
        let b = EpochFootprint {
            bounds: Bounds::new(10.0, -5.0, 55.5, 25.0).unwrap(),
            gsd: 0.012,
        };
        let g = plan_grid(&[a, b], &GridOptions::default()).unwrap();
        // 2 × 0.021 → 0.05; the finest GSD 0.012 → 4 ortho cells per DEM cell (0.0125).
        assert_eq!(g.dem.cell(), 0.05);
        assert_eq!(g.ortho_factor, 4);
        let u = g.dem.bounds();
        let eps = 1e-9;
        assert!(u.x_min <= 0.3 + eps && u.x_max >= 55.5 - eps);
        assert!(u.y_min <= -5.0 + eps && u.y_max >= 30.0 - eps);
        let o = g.ortho();
        assert_eq!(o.bounds(), g.dem.bounds());
        assert_eq!(o.width(), 4 * g.dem.width());

        let inter = GridOptions {
            extent: ExtentRule::Intersection,
            ..GridOptions::default()
        };
        let gi = plan_grid(&[a, b], &inter).unwrap();
        let ib = gi.dem.bounds();
        assert!(ib.x_min <= 10.0 && ib.x_min > 9.9 && ib.x_max >= 40.0 && ib.x_max < 40.1);

        let bad = GridOptions {
            dem_cell: Some(0.05),
            ortho_cell: Some(0.03),
            ..GridOptions::default()
        };
        assert!(
            plan_grid(&[a, b], &bad)
                .unwrap_err()
                .to_string()
                .contains("ortho_cell 0.03")
        );
        let far = EpochFootprint {
            bounds: Bounds::new(100.0, 100.0, 110.0, 110.0).unwrap(),
            gsd: 0.02,
        };
        assert!(plan_grid(&[a, far], &inter).is_err());
        let huge = GridOptions {
            dem_cell: Some(1e-6),
            ..GridOptions::default()
        };
        assert!(
            plan_grid(&[a], &huge)
                .unwrap_err()
                .to_string()
                .contains("cell")
        );
    }
}
