//! Slope and aspect of a DEM by Horn's (1981) 3 × 3 finite differences, on metric cell sizes.

use rayon::prelude::*;

use crate::grid::Dem;

/// Surface gradient of one cell, metres per metre, east and north components.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gradient {
    /// ∂z/∂east.
    pub east: f64,
    /// ∂z/∂north.
    pub north: f64,
}

impl Gradient {
    /// tan(slope) = |∇z|.
    pub fn tan_slope(&self) -> f64 {
        self.east.hypot(self.north)
    }

    /// Aspect, radians clockwise from north, of the downslope direction (0 = facing north).
    pub fn aspect(&self) -> f64 {
        (-self.east)
            .atan2(-self.north)
            .rem_euclid(std::f64::consts::TAU)
    }
}

/// Gradients of the interior cells from a stencil `(dem, col, row, dx, dy) → (∂z/∂east, ∂z/∂row)`
/// on metric cell sizes; `None` on the border and where the stencil meets nodata.
fn interior_gradients(
    dem: &Dem,
    stencil: impl Fn(usize, usize, f64, f64) -> (f64, f64) + Sync,
) -> Vec<Option<Gradient>> {
    let (w, h) = (dem.grid.width, dem.grid.height);
    let mut out = vec![None; w * h];
    if w < 3 || h < 3 {
        return out;
    }
    out.par_chunks_mut(w)
        .enumerate()
        .skip(1)
        .take(h - 2)
        .for_each(|(row, line)| {
            let (dx, dy) = dem.grid.metric_cell_size_at_row(row);
            for col in 1..w - 1 {
                let (east, dz_drow) = stencil(col, row, dx, dy);
                // Rows grow southwards: ∂z/∂north = −∂z/∂row.
                if east.is_finite() && dz_drow.is_finite() {
                    line[col] = Some(Gradient {
                        east,
                        north: -dz_drow,
                    });
                }
            }
        });
    out
}

/// Horn gradients for every cell; `None` on the border and where any of the 3 × 3 cells is nodata.
pub fn horn_gradients(dem: &Dem) -> Vec<Option<Gradient>> {
    interior_gradients(dem, |col, row, dx, dy| {
        let z = |dc: isize, dr: isize| {
            dem.get((col as isize + dc) as usize, (row as isize + dr) as usize) as f64
        };
        let (a, b, c) = (z(-1, -1), z(0, -1), z(1, -1));
        let (d, f) = (z(-1, 0), z(1, 0));
        let (g, hh, i) = (z(-1, 1), z(0, 1), z(1, 1));
        (
            ((c + 2.0 * f + i) - (a + 2.0 * d + g)) / (8.0 * dx),
            ((g + 2.0 * hh + i) - (a + 2.0 * b + c)) / (8.0 * dy),
        )
    })
}

/// How surface gradients are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GradientMethod {
    /// Horn (1981) 3 × 3 weighted differences (smooths noise; the usual slope/aspect of GIS).
    Horn,
    /// Central differences of the four direct neighbours (numpy's `gradient`, as xdem's Nuth &
    /// Kääb uses).
    Central,
}

/// Gradients by `method`.
pub fn gradients(dem: &Dem, method: GradientMethod) -> Vec<Option<Gradient>> {
    match method {
        GradientMethod::Horn => horn_gradients(dem),
        GradientMethod::Central => central_gradients(dem),
    }
}

/// Central-difference gradients; `None` on the border and where a neighbour is nodata.
pub fn central_gradients(dem: &Dem) -> Vec<Option<Gradient>> {
    interior_gradients(dem, |col, row, dx, dy| {
        (
            (dem.get(col + 1, row) as f64 - dem.get(col - 1, row) as f64) / (2.0 * dx),
            (dem.get(col, row + 1) as f64 - dem.get(col, row - 1) as f64) / (2.0 * dy),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use timesift_io::coords::Crs;
    use timesift_io::geotiff::GeoTransform;

    #[test]
    fn plane_gradient_and_aspect() {
        let grid = Grid {
            transform: GeoTransform {
                origin_x: 500.0,
                origin_y: 800.0,
                pixel_width: 2.0,
                pixel_height: -2.0,
            },
            width: 6,
            height: 5,
            crs: Crs::Epsg(32633),
        };
        // z rises to the north-east: the slope faces south-west (aspect 225°).
        let values = (0..grid.len())
            .map(|i| {
                let (x, y) = grid.cell_center(i % 6, i / 6);
                (0.3 * x + 0.3 * y) as f32
            })
            .collect();
        let dem = Dem { grid, values };
        for method in [GradientMethod::Horn, GradientMethod::Central] {
            let g = gradients(&dem, method);
            let inner = g[2 * 6 + 2].expect("interior");
            assert!((inner.east - 0.3).abs() < 1e-3 && (inner.north - 0.3).abs() < 1e-3);
            assert!((inner.aspect().to_degrees() - 225.0).abs() < 0.1);
            assert!(g[0].is_none() && g[5 * 6 - 1].is_none());
        }
    }
}
