//! Cell masks (stable areas, regions of interest) on a [`Grid`]: from WKT polygons (cell-centre
//! rule, even–odd so holes are honoured) or from a mask raster (non-zero cells).

use timesift_io::wkt::Polygon;

use crate::ChangeError;
use crate::grid::{Dem, Grid, check_same_crs};

/// One flag per cell of a grid, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Mask {
    /// The grid the flags belong to.
    pub grid: Grid,
    /// `true` for selected cells.
    pub cells: Vec<bool>,
}

impl Mask {
    /// Every cell selected.
    pub fn all(grid: Grid) -> Mask {
        Mask {
            grid,
            cells: vec![true; grid.len()],
        }
    }

    /// Fails unless `mask` (when given) has one flag per cell of `grid`: functions that take a
    /// mask for a grid they also take call this first.
    pub fn check_fits(mask: Option<&Mask>, grid: &Grid) -> Result<(), ChangeError> {
        match mask {
            Some(m) if m.cells.len() != grid.len() => Err(ChangeError::InvalidInput(format!(
                "mask of {} cells for a grid of {}",
                m.cells.len(),
                grid.len()
            ))),
            _ => Ok(()),
        }
    }

    /// Number of selected cells.
    pub fn count(&self) -> usize {
        self.cells.iter().filter(|&&c| c).count()
    }

    /// Cells whose centre lies inside any of the polygons (polygon coordinates in the grid's CRS).
    /// Scan-line fill: each row crosses every ring edge once at most, so the cost is
    /// rows × edges + cells.
    pub fn from_polygons(grid: Grid, polygons: &[Polygon]) -> Mask {
        let mut cells = vec![false; grid.len()];
        let mut crossings: Vec<f64> = Vec::new();
        for row in 0..grid.height {
            let (_, y) = grid.cell_center(0, row);
            for polygon in polygons {
                crossings.clear();
                for ring in std::iter::once(&polygon.exterior).chain(polygon.holes.iter()) {
                    ring_crossings(ring, y, &mut crossings);
                }
                crossings.sort_unstable_by(f64::total_cmp);
                for pair in crossings.chunks_exact(2) {
                    let (c0, _) = grid.continuous_index(pair[0], y);
                    let (c1, _) = grid.continuous_index(pair[1], y);
                    // Cell centres (continuous index = col) in [lo, hi], clipped to the grid.
                    let (lo, hi) = (c0.min(c1), c0.max(c1));
                    if hi < 0.0 || grid.width == 0 {
                        continue;
                    }
                    let first = lo.ceil().max(0.0) as usize;
                    let last = (hi.floor() as usize).min(grid.width - 1);
                    for col in first..=last {
                        cells[row * grid.width + col] = true;
                    }
                }
            }
        }
        Mask { grid, cells }
    }

    /// Cells of `grid` whose centre falls on a non-zero, valid cell of `raster` (nearest cell).
    pub fn from_raster(grid: Grid, raster: &Dem) -> Result<Mask, ChangeError> {
        check_same_crs(grid.crs, raster.grid.crs)?;
        let mut cells = vec![false; grid.len()];
        for row in 0..grid.height {
            for col in 0..grid.width {
                let (x, y) = grid.cell_center(col, row);
                let (fc, fr) = raster.grid.continuous_index(x, y);
                let (c, r) = (fc.round(), fr.round());
                if c >= 0.0 && r >= 0.0 {
                    let (c, r) = (c as usize, r as usize);
                    if c < raster.grid.width && r < raster.grid.height {
                        let v = raster.get(c, r);
                        cells[row * grid.width + col] = !v.is_nan() && v != 0.0;
                    }
                }
            }
        }
        Ok(Mask { grid, cells })
    }

    /// The mask carried to another grid (nearest cell); cells outside become unselected.
    pub fn onto(&self, grid: &Grid) -> Result<Mask, ChangeError> {
        if self.grid.same_cells(grid) {
            return Ok(self.clone());
        }
        let as_dem = Dem {
            grid: self.grid,
            values: self.cells.iter().map(|&c| c as u8 as f32).collect(),
        };
        Mask::from_raster(*grid, &as_dem)
    }
}

/// X coordinates where a closed ring crosses the horizontal line at `y` (half-open rule on the
/// edge's y range, so a vertex on the line is counted once).
fn ring_crossings(ring: &[[f64; 2]], y: f64, out: &mut Vec<f64>) {
    let n = ring.len();
    if n < 3 {
        return;
    }
    for i in 0..n {
        let a = ring[i];
        let b = ring[(i + 1) % n];
        if a == b {
            continue;
        }
        if (a[1] <= y) != (b[1] <= y) {
            let t = (y - a[1]) / (b[1] - a[1]);
            out.push(a[0] + t * (b[0] - a[0]));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use timesift_io::coords::Crs;
    use timesift_io::geotiff::GeoTransform;
    use timesift_io::wkt::parse_polygons;

    #[test]
    fn polygon_with_hole_matches_point_in_polygon() {
        let grid = Grid {
            transform: GeoTransform {
                origin_x: 0.0,
                origin_y: 50.0,
                pixel_width: 1.0,
                pixel_height: -1.0,
            },
            width: 60,
            height: 50,
            crs: Crs::Local,
        };
        let polygons = parse_polygons(
            "POLYGON ((3.2 4.1, 51.7 9.3, 44.0 47.5, 7.9 38.2, 3.2 4.1), (20.3 20.1, 30.6 20.4, 25.2 31.8, 20.3 20.1))",
        )
        .expect("wkt");
        let mask = Mask::from_polygons(grid, &polygons);
        let mut selected = 0;
        for row in 0..grid.height {
            for col in 0..grid.width {
                let (x, y) = grid.cell_center(col, row);
                let inside = polygons.iter().any(|p| p.contains(x, y));
                assert_eq!(mask.cells[row * grid.width + col], inside, "{col} {row}");
                selected += inside as usize;
            }
        }
        assert!(selected > 1000 && mask.count() == selected);
    }
}
