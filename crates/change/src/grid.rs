//! North-up grids and DEMs with nodata as NaN: bilinear sampling, resampling onto another grid,
//! overlap, and the metric size of a cell (also for geographic grids, where a cell is measured in
//! degrees).

use rayon::prelude::*;
use timesift_io::coords::Crs;
use timesift_io::geotiff::{GeoRaster, GeoReference, GeoTransform};

use crate::ChangeError;

/// WGS84 semi-major axis and first eccentricity squared, for the metric size of geographic cells.
const WGS84_A: f64 = 6_378_137.0;
const WGS84_E2: f64 = 0.006_694_379_990_14;

/// A north-up grid of `width` × `height` cells.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Corner-based geotransform (GDAL style).
    pub transform: GeoTransform,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// CRS of the coordinates.
    pub crs: Crs,
}

impl Grid {
    /// Number of cells.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// Whether the grid has no cell.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// World coordinates of the centre of cell (col, row).
    pub fn cell_center(&self, col: usize, row: usize) -> (f64, f64) {
        self.transform
            .pixel_to_world(col as f64 + 0.5, row as f64 + 0.5)
    }

    /// Continuous cell index of a world position: cell (i, j)'s centre maps to (i, j).
    pub fn continuous_index(&self, x: f64, y: f64) -> (f64, f64) {
        let (c, r) = self.transform.world_to_pixel(x, y);
        (c - 0.5, r - 0.5)
    }

    /// (xmin, ymin, xmax, ymax) of the grid's outer edges.
    pub fn extent(&self) -> (f64, f64, f64, f64) {
        let (x0, y0) = self.transform.pixel_to_world(0.0, 0.0);
        let (x1, y1) = self
            .transform
            .pixel_to_world(self.width as f64, self.height as f64);
        (x0.min(x1), y0.min(y1), x0.max(x1), y0.max(y1))
    }

    /// Metric size (east, north) of one cell in metres. For a geographic CRS the cell is measured on
    /// the WGS84 ellipsoid at the latitude of `row`'s centre.
    pub fn metric_cell_size_at_row(&self, row: usize) -> (f64, f64) {
        let t = &self.transform;
        if !self.crs.is_geographic() {
            return (t.pixel_width.abs(), t.pixel_height.abs());
        }
        let (_, lat) = self.cell_center(0, row);
        let phi = lat.to_radians();
        let w = 1.0 - WGS84_E2 * phi.sin().powi(2);
        let meridional = WGS84_A * (1.0 - WGS84_E2) / w.powf(1.5);
        let prime_vertical = WGS84_A / w.sqrt();
        (
            prime_vertical * phi.cos() * t.pixel_width.abs().to_radians(),
            meridional * t.pixel_height.abs().to_radians(),
        )
    }

    /// Metric size of one cell at the grid's middle row.
    pub fn metric_cell_size(&self) -> (f64, f64) {
        self.metric_cell_size_at_row(self.height / 2)
    }

    /// Whether `other` has the same cells (same CRS, size and geotransform to 1e-6 of a cell).
    pub fn same_cells(&self, other: &Grid) -> bool {
        let (a, b) = (&self.transform, &other.transform);
        let tol = 1e-6 * a.pixel_width.abs().min(a.pixel_height.abs());
        self.crs == other.crs
            && self.width == other.width
            && self.height == other.height
            && (a.origin_x - b.origin_x).abs() <= tol
            && (a.origin_y - b.origin_y).abs() <= tol
            && (a.pixel_width - b.pixel_width).abs() <= tol
            && (a.pixel_height - b.pixel_height).abs() <= tol
    }

    /// The sub-grid of `self` whose cell centres fall inside `other`'s extent, with the offset (col,
    /// row) of its first cell in `self`; `None` when no centre does.
    pub fn crop_to(&self, other: &Grid) -> Option<(Grid, usize, usize)> {
        let (xmin, ymin, xmax, ymax) = other.extent();
        let inside_cols: Vec<usize> = (0..self.width)
            .filter(|&c| {
                let (x, _) = self.cell_center(c, 0);
                x > xmin && x < xmax
            })
            .collect();
        let inside_rows: Vec<usize> = (0..self.height)
            .filter(|&r| {
                let (_, y) = self.cell_center(0, r);
                y > ymin && y < ymax
            })
            .collect();
        let (&c0, &c1) = (inside_cols.first()?, inside_cols.last()?);
        let (&r0, &r1) = (inside_rows.first()?, inside_rows.last()?);
        let (ox, oy) = self.transform.pixel_to_world(c0 as f64, r0 as f64);
        Some((
            Grid {
                transform: GeoTransform {
                    origin_x: ox,
                    origin_y: oy,
                    ..self.transform
                },
                width: c1 - c0 + 1,
                height: r1 - r0 + 1,
                crs: self.crs,
            },
            c0,
            r0,
        ))
    }
}

/// A digital elevation model: one f32 height per cell, NaN where there is no data.
#[derive(Debug, Clone, PartialEq)]
pub struct Dem {
    /// The grid.
    pub grid: Grid,
    /// Row-major heights, NaN for nodata.
    pub values: Vec<f32>,
}

/// Nodata value written into DEM GeoTIFFs (DESIGN: `dem.tif`, nodata −32767).
pub const DEM_NODATA: f32 = -32767.0;

impl Dem {
    /// A DEM from a single-band raster. Cells equal to the raster's declared nodata, to
    /// `extra_nodata` (for files with an undeclared sentinel such as −10000) or not finite become NaN.
    pub fn from_raster(
        raster: GeoRaster<f32>,
        extra_nodata: Option<f64>,
    ) -> Result<Dem, ChangeError> {
        if raster.bands != 1 {
            return Err(ChangeError::InvalidInput(format!(
                "a DEM has one band; this raster has {}",
                raster.bands
            )));
        }
        if raster.width == 0 || raster.height == 0 {
            return Err(ChangeError::InvalidInput("the DEM has no cell".into()));
        }
        let t = raster.georef.transform;
        if !(t.pixel_width.is_finite()
            && t.pixel_width > 0.0
            && t.pixel_height.is_finite()
            && t.pixel_height < 0.0)
        {
            return Err(ChangeError::InvalidInput(format!(
                "pixel size ({}, {}); a north-up grid (width > 0, height < 0) was expected",
                t.pixel_width, t.pixel_height
            )));
        }
        let declared = raster.georef.nodata;
        let is_nodata = |v: f32| {
            !v.is_finite()
                || declared.is_some_and(|n| v == n as f32)
                || extra_nodata.is_some_and(|n| v == n as f32)
        };
        let values = raster
            .data
            .into_iter()
            .map(|v| if is_nodata(v) { f32::NAN } else { v })
            .collect();
        Ok(Dem {
            grid: Grid {
                transform: raster.georef.transform,
                width: raster.width,
                height: raster.height,
                crs: raster.georef.crs,
            },
            values,
        })
    }

    /// The DEM as a float32 raster with nodata [`DEM_NODATA`].
    pub fn to_raster(&self) -> GeoRaster<f32> {
        GeoRaster {
            width: self.grid.width,
            height: self.grid.height,
            bands: 1,
            data: self
                .values
                .iter()
                .map(|&v| if v.is_nan() { DEM_NODATA } else { v })
                .collect(),
            georef: GeoReference {
                transform: self.grid.transform,
                crs: self.grid.crs,
                nodata: Some(DEM_NODATA as f64),
                pixel_is_point: false,
            },
        }
    }

    /// Height of cell (col, row), NaN for nodata.
    pub fn get(&self, col: usize, row: usize) -> f32 {
        self.values[row * self.grid.width + col]
    }

    /// Number of cells holding a height.
    pub fn valid_count(&self) -> usize {
        self.values.iter().filter(|v| !v.is_nan()).count()
    }

    /// Bilinear interpolation between cell centres at continuous index (fc, fr) (see
    /// [`Grid::continuous_index`]). NaN outside the centres' hull or when a cell that carries weight
    /// is nodata: nodata propagates, it is never filled in.
    pub fn bilinear_at_index(&self, fc: f64, fr: f64) -> f64 {
        let (w, h) = (self.grid.width, self.grid.height);
        let eps = 1e-9;
        if !(fc >= -eps && fr >= -eps && fc <= (w - 1) as f64 + eps && fr <= (h - 1) as f64 + eps) {
            return f64::NAN;
        }
        let c0 = (fc.max(0.0).floor() as usize).min(w.saturating_sub(2));
        let r0 = (fr.max(0.0).floor() as usize).min(h.saturating_sub(2));
        let tx = (fc - c0 as f64).clamp(0.0, 1.0);
        let ty = (fr - r0 as f64).clamp(0.0, 1.0);
        let mut sum = 0.0;
        for (dc, wx) in [(0usize, 1.0 - tx), (1, tx)] {
            for (dr, wy) in [(0usize, 1.0 - ty), (1, ty)] {
                let weight = wx * wy;
                if weight <= 0.0 {
                    continue;
                }
                let (c, r) = (c0 + dc, r0 + dr);
                if c >= w || r >= h {
                    return f64::NAN;
                }
                let v = self.get(c, r);
                if v.is_nan() {
                    return f64::NAN;
                }
                sum += weight * v as f64;
            }
        }
        sum
    }

    /// Bilinear interpolation at a world position.
    pub fn bilinear(&self, x: f64, y: f64) -> f64 {
        let (fc, fr) = self.grid.continuous_index(x, y);
        self.bilinear_at_index(fc, fr)
    }

    /// This DEM sampled (bilinearly) at the cell centres of `grid`. The CRSs must agree.
    pub fn resample_onto(&self, grid: &Grid) -> Result<Dem, ChangeError> {
        check_same_crs(self.grid.crs, grid.crs)?;
        if self.grid.same_cells(grid) {
            return Ok(self.clone());
        }
        let mut values = vec![f32::NAN; grid.len()];
        values
            .par_chunks_mut(grid.width.max(1))
            .enumerate()
            .for_each(|(row, out)| {
                for (col, v) in out.iter_mut().enumerate() {
                    let (x, y) = grid.cell_center(col, row);
                    *v = self.bilinear(x, y) as f32;
                }
            });
        Ok(Dem {
            grid: *grid,
            values,
        })
    }

    /// The DEM translated by (dx, dy) in world units and dz in height units: the grid moves, the cells
    /// keep their values (no resampling), so `translated(dx, dy, dz)` at world p equals the original at
    /// p − (dx, dy), plus dz.
    pub fn translated(&self, dx: f64, dy: f64, dz: f64) -> Dem {
        let mut grid = self.grid;
        grid.transform.origin_x += dx;
        grid.transform.origin_y += dy;
        Dem {
            grid,
            values: self
                .values
                .iter()
                .map(|&v| (v as f64 + dz) as f32)
                .collect(),
        }
    }
}

impl Dem {
    /// One point per valid cell, at the cell centre: the cloud a DEM stands for.
    pub fn to_points(&self) -> Vec<[f64; 3]> {
        let w = self.grid.width;
        self.values
            .iter()
            .enumerate()
            .filter(|(_, v)| !v.is_nan())
            .map(|(i, &v)| {
                let (x, y) = self.grid.cell_center(i % w, i / w);
                [x, y, v as f64]
            })
            .collect()
    }

    /// Values at scattered points averaged on a north-up grid of `cell` units whose cell
    /// centres lie on the lattice through the westmost and northmost finite points (core points
    /// subsampled at `cell` land one per cell): the map of a per-point quantity such as an M3C2
    /// distance. Points with a non-finite value are left out; cells without a point are nodata.
    ///
    /// `None` when no value is finite, or the grid would exceed 50 million cells (a spacing far
    /// too small for the points' extent).
    pub fn mean_of_points(points: &[[f64; 3]], values: &[f64], cell: f64, crs: Crs) -> Option<Dem> {
        if !(cell.is_finite() && cell > 0.0) {
            return None;
        }
        let finite = || {
            points
                .iter()
                .zip(values)
                .filter(|(_, v)| v.is_finite())
                .map(|(p, &v)| (p[0], p[1], v))
        };
        let (mut xmin, mut ymin, mut xmax, mut ymax) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for (x, y, _) in finite() {
            xmin = xmin.min(x);
            ymin = ymin.min(y);
            xmax = xmax.max(x);
            ymax = ymax.max(y);
        }
        if xmin > xmax {
            return None;
        }
        let width = ((xmax - xmin) / cell).round() + 1.0;
        let height = ((ymax - ymin) / cell).round() + 1.0;
        if !(width * height <= 5e7) {
            return None;
        }
        let (width, height) = (width as usize, height as usize);
        let grid = Grid {
            transform: GeoTransform {
                origin_x: xmin - 0.5 * cell,
                origin_y: ymax + 0.5 * cell,
                pixel_width: cell,
                pixel_height: -cell,
            },
            width,
            height,
            crs,
        };
        let mut sum = vec![0.0f64; grid.len()];
        let mut count = vec![0u32; grid.len()];
        for (x, y, v) in finite() {
            let (c, r) = grid.transform.world_to_pixel(x, y);
            let c = (c.floor().max(0.0) as usize).min(width - 1);
            let r = (r.floor().max(0.0) as usize).min(height - 1);
            sum[r * width + c] += v;
            count[r * width + c] += 1;
        }
        let values = sum
            .iter()
            .zip(&count)
            .map(|(&s, &n)| {
                if n > 0 {
                    (s / n as f64) as f32
                } else {
                    f32::NAN
                }
            })
            .collect();
        Some(Dem { grid, values })
    }
}

/// Fails unless the two CRSs are the same.
pub fn check_same_crs(a: Crs, b: Crs) -> Result<(), ChangeError> {
    if a == b {
        Ok(())
    } else {
        Err(ChangeError::CrsMismatch {
            a: a.to_string(),
            b: b.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(w: usize, h: usize) -> Grid {
        Grid {
            transform: GeoTransform {
                origin_x: 100.0,
                origin_y: 200.0,
                pixel_width: 2.0,
                pixel_height: -2.0,
            },
            width: w,
            height: h,
            crs: Crs::Epsg(32633),
        }
    }

    #[test]
    fn bilinear_reproduces_a_plane_and_propagates_nodata() {
        let g = grid(5, 4);
        let plane = |x: f64, y: f64| 3.0 + 0.25 * x - 0.5 * y;
        let mut values: Vec<f32> = (0..g.len())
            .map(|i| {
                let (x, y) = g.cell_center(i % 5, i / 5);
                plane(x, y) as f32
            })
            .collect();
        let dem = Dem {
            grid: g,
            values: values.clone(),
        };
        for (x, y) in [
            (101.0, 199.0),
            (104.3, 194.1),
            (109.0, 193.0),
            (105.0, 197.0),
        ] {
            assert!((dem.bilinear(x, y) - plane(x, y)).abs() < 1e-4, "{x} {y}");
        }
        assert!(
            dem.bilinear(100.5, 199.0).is_nan(),
            "outside the centres' hull"
        );
        values[5 + 1] = f32::NAN;
        let dem = Dem { grid: g, values };
        assert!(dem.bilinear(103.5, 196.5).is_nan());
        assert!(!dem.bilinear(107.0, 193.5).is_nan());
    }

    #[test]
    fn geographic_cells_have_metric_sizes() {
        let g = Grid {
            transform: GeoTransform {
                origin_x: 40.0,
                origin_y: 40.0,
                pixel_width: 1.0 / 1200.0,
                pixel_height: -1.0 / 1200.0,
            },
            width: 1,
            height: 1,
            crs: Crs::Epsg(4326),
        };
        let (dx, dy) = g.metric_cell_size();
        // 3 arc-seconds at 40° N: 71.1 m east, 92.5 m north (standard geodetic tables).
        assert!((dx - 71.15).abs() < 0.1, "{dx}");
        assert!((dy - 92.53).abs() < 0.1, "{dy}");
    }

    #[test]
    fn crop_keeps_cells_whose_centres_are_inside() {
        let a = grid(10, 10);
        let mut b = grid(4, 3);
        b.transform.origin_x = 105.5;
        b.transform.origin_y = 195.5;
        let (c, c0, r0) = a.crop_to(&b).expect("overlap");
        assert_eq!((c0, r0, c.width, c.height), (3, 2, 4, 3));
        b.transform.origin_x = 500.0;
        assert!(a.crop_to(&b).is_none());
    }

    #[test]
    fn points_averaged_one_cell_each_north_row_first() {
        // A 3 × 2 lattice of points 10 m apart: six cells, one value each, north row first.
        let points: Vec<[f64; 3]> = [
            (0.0, 0.0),
            (10.0, 0.0),
            (20.0, 0.0),
            (0.0, 10.0),
            (10.0, 10.0),
            (20.0, 10.0),
        ]
        .iter()
        .map(|&(x, y)| [x, y, 0.0])
        .collect();
        let values = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let dem = Dem::mean_of_points(&points, &values, 10.0, Crs::Local).expect("grid");
        assert_eq!((dem.grid.width, dem.grid.height), (3, 2));
        assert_eq!(dem.values, vec![4.0, 5.0, 6.0, 1.0, 2.0, 3.0]);
        assert_eq!(dem.grid.cell_center(0, 0), (0.0, 10.0));
        // Two points in one cell average; a NaN value is left out.
        let two = [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 2.0, 0.0]];
        let dem = Dem::mean_of_points(&two, &[1.0, 3.0, f64::NAN], 10.0, Crs::Local).expect("grid");
        assert_eq!(dem.values, vec![2.0]);
        assert!(
            Dem::mean_of_points(&points, &values, 1e-9, Crs::Local).is_none(),
            "absurd sizes refused"
        );
        assert!(Dem::mean_of_points(&points, &[f64::NAN; 6], 10.0, Crs::Local).is_none());
        assert!(Dem::mean_of_points(&points, &values, 0.0, Crs::Local).is_none());
    }
}
