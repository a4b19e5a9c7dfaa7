//! DEM of difference: `b − a` on `a`'s grid, cropped to the overlap; `b` is resampled bilinearly
//! when the grids differ, and a cell is nodata when either DEM has none there.

use rayon::prelude::*;

use crate::ChangeError;
use crate::grid::{Dem, check_same_crs};

/// `later − earlier` on the earlier DEM's grid, restricted to the cells whose centres fall inside the
/// later DEM's extent.
pub fn dem_of_difference(earlier: &Dem, later: &Dem) -> Result<Dem, ChangeError> {
    check_same_crs(earlier.grid.crs, later.grid.crs)?;
    let dod = if earlier.grid.same_cells(&later.grid) {
        Dem {
            grid: earlier.grid,
            values: earlier
                .values
                .par_iter()
                .zip(later.values.par_iter())
                .map(|(&a, &b)| b - a)
                .collect(),
        }
    } else {
        let (grid, c0, r0) = earlier.grid.crop_to(&later.grid).ok_or_else(|| {
            ChangeError::NoOverlap(format!(
                "extents {:?} and {:?} do not intersect",
                earlier.grid.extent(),
                later.grid.extent()
            ))
        })?;
        let mut values = vec![f32::NAN; grid.len()];
        values
            .par_chunks_mut(grid.width)
            .enumerate()
            .for_each(|(row, out)| {
                for (col, v) in out.iter_mut().enumerate() {
                    let a = earlier.get(c0 + col, r0 + row);
                    if a.is_nan() {
                        continue;
                    }
                    let (x, y) = grid.cell_center(col, row);
                    *v = (later.bilinear(x, y) - a as f64) as f32;
                }
            });
        Dem { grid, values }
    };
    if dod.valid_count() == 0 {
        return Err(ChangeError::NoOverlap(
            "no cell holds a height in both DEMs".into(),
        ));
    }
    Ok(dod)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use timesift_io::coords::Crs;
    use timesift_io::geotiff::GeoTransform;

    fn dem(ox: f64, oy: f64, w: usize, h: usize, f: impl Fn(f64, f64) -> f32) -> Dem {
        let grid = Grid {
            transform: GeoTransform {
                origin_x: ox,
                origin_y: oy,
                pixel_width: 1.0,
                pixel_height: -1.0,
            },
            width: w,
            height: h,
            crs: Crs::Epsg(32632),
        };
        let values = (0..grid.len())
            .map(|i| {
                let (x, y) = grid.cell_center(i % w, i / w);
                f(x, y)
            })
            .collect();
        Dem { grid, values }
    }

    #[test]
    fn difference_of_planes_on_shifted_grids() {
        let a = dem(0.0, 20.0, 20, 20, |x, y| (0.1 * x + 0.2 * y) as f32);
        let b = dem(5.3, 17.6, 20, 20, |x, y| (0.1 * x + 0.2 * y + 1.5) as f32);
        let d = dem_of_difference(&a, &b).expect("overlap");
        assert!(d.valid_count() > 150);
        for v in d.values.iter().filter(|v| !v.is_nan()) {
            assert!((v - 1.5).abs() < 1e-5);
        }
        // Nodata in either input propagates.
        let mut a2 = a.clone();
        a2.values[15 * 20 + 10] = f32::NAN;
        let d = dem_of_difference(&a2, &b).expect("overlap");
        // The crop starts at a's cell (5, 2): centres strictly inside b's extent.
        assert!(d.get(10 - 5, 15 - 2).is_nan());
        assert!(!d.get(11 - 5, 15 - 2).is_nan());
    }

    #[test]
    fn bad_pairs_are_refused() {
        let a = dem(0.0, 20.0, 10, 10, |_, _| 1.0);
        let far = dem(1000.0, 20.0, 10, 10, |_, _| 1.0);
        assert!(matches!(
            dem_of_difference(&a, &far),
            Err(ChangeError::NoOverlap(_))
        ));
        let mut other_crs = a.clone();
        other_crs.grid.crs = Crs::Epsg(4326);
        assert!(matches!(
            dem_of_difference(&a, &other_crs),
            Err(ChangeError::CrsMismatch { .. })
        ));
        let empty = dem(0.0, 20.0, 10, 10, |_, _| f32::NAN);
        assert!(matches!(
            dem_of_difference(&a, &empty),
            Err(ChangeError::NoOverlap(_))
        ));
    }
}
