//! Where the ground is known not to have changed, in the block's frame: the caller's stable
//! areas (polygons or a mask) rasterised onto a horizontal grid.
//!
//! Why a grid and not polygons: the strategies ask one question per tie point ("may this point
//! tie the epochs?"), the answer must not depend on how the caller drew its areas, and a grid
//! is also what a stable-mask raster already is. The caller chooses the cell (a fraction of
//! the ground sampling distance is plenty: a tie point's position is known to about that).

use nalgebra::Vector3;

use crate::AlignError;

/// A horizontal grid of the block's frame (x east, y north, in the frame of the priors and
/// control points), each cell stable or not. Outside the grid nothing is known to be stable.
#[derive(Debug, Clone, PartialEq)]
pub struct StableGround {
    /// Lower-left corner (x, y) of cell (0, 0).
    origin: [f64; 2],
    /// Cell size, in the frame's units.
    cell: f64,
    /// Cells along x.
    width: usize,
    /// Cells along y.
    height: usize,
    /// Row-major from the lower-left corner (row 0 at the smallest y).
    stable: Vec<bool>,
}

impl StableGround {
    /// The grid of `width × height` cells of size `cell` from `origin`, with
    /// `is_stable(x, y)` asked at every cell centre.
    pub fn rasterise(
        origin: [f64; 2],
        cell: f64,
        width: usize,
        height: usize,
        is_stable: impl Fn(f64, f64) -> bool + Sync,
    ) -> Result<StableGround, AlignError> {
        if !(cell > 0.0) || !cell.is_finite() || !origin.iter().all(|v| v.is_finite()) {
            return Err(AlignError::InvalidOption {
                name: "stable_ground.cell",
                value: cell,
                expected: "a positive cell size and a finite origin",
            });
        }
        if width == 0 || height == 0 {
            return Err(AlignError::InvalidOption {
                name: "stable_ground.size",
                value: (width * height) as f64,
                expected: "a grid of at least one cell",
            });
        }
        let stable = (0..height)
            .flat_map(|row| (0..width).map(move |col| (row, col)))
            .map(|(row, col)| {
                is_stable(
                    origin[0] + (col as f64 + 0.5) * cell,
                    origin[1] + (row as f64 + 0.5) * cell,
                )
            })
            .collect();
        Ok(StableGround {
            origin,
            cell,
            width,
            height,
            stable,
        })
    }

    /// Whether the ground under `position` (its horizontal coordinates) is stable.
    pub fn contains(&self, position: &Vector3<f64>) -> bool {
        let col = ((position.x - self.origin[0]) / self.cell).floor();
        let row = ((position.y - self.origin[1]) / self.cell).floor();
        if !(col >= 0.0 && row >= 0.0 && col < self.width as f64 && row < self.height as f64) {
            return false;
        }
        self.stable[row as usize * self.width + col as usize]
    }

    /// Share of the grid's cells that are stable.
    pub fn stable_fraction(&self) -> f64 {
        self.stable.iter().filter(|s| **s).count() as f64 / self.stable.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_disc_is_stable_inside_and_nothing_is_outside_the_grid() {
        let disc = |x: f64, y: f64| (x - 5.0).powi(2) + (y + 2.0).powi(2) < 9.0;
        let g = StableGround::rasterise([0.0, -6.0], 0.1, 100, 80, disc).unwrap();
        assert!(g.contains(&Vector3::new(5.0, -2.0, 7.0)));
        assert!(g.contains(&Vector3::new(7.5, -2.0, 0.0)));
        assert!(!g.contains(&Vector3::new(8.5, -2.0, 0.0)));
        assert!(!g.contains(&Vector3::new(-0.01, -2.0, 0.0)));
        assert!(!g.contains(&Vector3::new(5.0, 2.01, 0.0)));
        assert!(!g.contains(&Vector3::new(f64::NAN, 0.0, 0.0)));
        // π r² over the grid's area.
        let expected = std::f64::consts::PI * 9.0 / 80.0;
        assert!((g.stable_fraction() - expected).abs() < 0.005);
    }

    #[test]
    fn degenerate_grids_are_errors() {
        assert!(StableGround::rasterise([0.0, 0.0], 0.0, 10, 10, |_, _| true).is_err());
        assert!(StableGround::rasterise([0.0, f64::NAN], 1.0, 10, 10, |_, _| true).is_err());
        assert!(StableGround::rasterise([0.0, 0.0], 1.0, 0, 10, |_, _| true).is_err());
    }
}
