//! A reference DEM in the block's frame: a modern lidar or photogrammetric surface that the
//! epochs' tie points on stable ground are held to (ASP's heights-from-DEM), so that a film
//! archive without a single control point lands on it and its bending is removed where the
//! reference sees stable ground.
//!
//! Why a grid of its own and not the GeoTIFF: this crate knows no file format nor CRS; the
//! caller puts the DEM in the block's frame (north-up, metres) and states its σ.

use crate::AlignError;

/// A north-up height grid in the block's frame, with the σ of one height.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceDem {
    /// x of the west edge of column 0.
    west: f64,
    /// y of the north edge of row 0.
    north: f64,
    /// Cell size, metres.
    cell: f64,
    width: usize,
    height: usize,
    /// Row-major from the north-west cell; NaN where the DEM has no height.
    heights: Vec<f32>,
    /// Standard deviation of one height, metres.
    sigma: f64,
}

impl ReferenceDem {
    /// The DEM of `width × height` cells of size `cell` whose north-west corner is at
    /// (`west`, `north`); `heights` row-major from there, NaN for none.
    pub fn new(
        [west, north]: [f64; 2],
        cell: f64,
        [width, height]: [usize; 2],
        heights: Vec<f32>,
        sigma: f64,
    ) -> Result<ReferenceDem, AlignError> {
        if !(cell > 0.0 && cell.is_finite() && west.is_finite() && north.is_finite()) {
            return Err(AlignError::InvalidOption {
                name: "reference_dem.cell",
                value: cell,
                expected: "a positive cell size and a finite corner",
            });
        }
        if width < 2 || height < 2 || heights.len() != width * height {
            return Err(AlignError::InvalidOption {
                name: "reference_dem.size",
                value: heights.len() as f64,
                expected: "width × height heights, at least 2 × 2",
            });
        }
        if !(sigma > 0.0 && sigma.is_finite()) {
            return Err(AlignError::InvalidOption {
                name: "reference_dem_sigma",
                value: sigma,
                expected: "a positive standard deviation in metres",
            });
        }
        Ok(ReferenceDem {
            west,
            north,
            cell,
            width,
            height,
            heights,
            sigma,
        })
    }

    /// Standard deviation of one height, metres.
    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    /// Cell size, metres.
    pub fn cell(&self) -> f64 {
        self.cell
    }

    /// Cells with a height.
    pub fn valid_cells(&self) -> usize {
        self.heights.iter().filter(|h| h.is_finite()).count()
    }

    /// The height at (x, y), bilinear between the four nearest cell centres; `None` outside the
    /// grid or next to a cell without a height.
    pub fn height_at(&self, x: f64, y: f64) -> Option<f64> {
        let col = (x - self.west) / self.cell - 0.5;
        let row = (self.north - y) / self.cell - 0.5;
        if !(col >= 0.0 && row >= 0.0) {
            return None;
        }
        let (c, r) = (col.floor() as usize, row.floor() as usize);
        if c + 1 >= self.width || r + 1 >= self.height {
            return None;
        }
        let (fc, fr) = (col - c as f64, row - r as f64);
        let at = |c: usize, r: usize| f64::from(self.heights[r * self.width + c]);
        let h = (1.0 - fr) * ((1.0 - fc) * at(c, r) + fc * at(c + 1, r))
            + fr * ((1.0 - fc) * at(c, r + 1) + fc * at(c + 1, r + 1));
        h.is_finite().then_some(h)
    }

    /// The height at (x, y) and the surface's slope there (dz/dx, dz/dy), when known: the slope
    /// of the plane fitted to the cells within 4 cells of the nearest (9 × 9; at least
    /// half of them with a height).
    pub fn sample(&self, x: f64, y: f64) -> Option<(f64, [f64; 2])> {
        let h = self.height_at(x, y)?;
        Some((h, self.slope_at(x, y)?))
    }

    /// The slope of the plane through the window's heights (least squares about its centre).
    fn slope_at(&self, x: f64, y: f64) -> Option<[f64; 2]> {
        let col = ((x - self.west) / self.cell).floor();
        let row = ((self.north - y) / self.cell).floor();
        let r = SLOPE_RADIUS_CELLS as isize;
        // Sums over the window's cells with a height, offsets in cells (east, north).
        let (mut n, mut sx, mut sy, mut sz) = (0.0, 0.0, 0.0, 0.0);
        let (mut sxx, mut syy, mut sxy, mut sxz, mut syz) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for dr in -r..=r {
            for dc in -r..=r {
                let (c, rr) = (col as isize + dc, row as isize + dr);
                if c < 0 || rr < 0 || c as usize >= self.width || rr as usize >= self.height {
                    continue;
                }
                let z = f64::from(self.heights[rr as usize * self.width + c as usize]);
                if !z.is_finite() {
                    continue;
                }
                let (u, v) = (dc as f64, -dr as f64);
                n += 1.0;
                sx += u;
                sy += v;
                sz += z;
                sxx += u * u;
                syy += v * v;
                sxy += u * v;
                sxz += u * z;
                syz += v * z;
            }
        }
        let window = ((2 * r + 1) * (2 * r + 1)) as f64;
        if n < 0.5 * window {
            return None;
        }
        // Centred sums: the normal equations of the two slopes.
        let (cxx, cyy, cxy) = (sxx - sx * sx / n, syy - sy * sy / n, sxy - sx * sy / n);
        let (cxz, cyz) = (sxz - sx * sz / n, syz - sy * sz / n);
        let det = cxx * cyy - cxy * cxy;
        if !(det > 1e-9 * cxx * cyy) {
            return None;
        }
        let gx = (cyy * cxz - cxy * cyz) / det / self.cell;
        let gy = (cxx * cyz - cxy * cxz) / det / self.cell;
        (gx.is_finite() && gy.is_finite()).then_some([gx, gy])
    }
}

/// Half-width of the window whose plane gives a reference DEM's slope at a point, cells: the
/// slope holds a block sideways, and from one cell either way a DEM's noise swamps it (0.8 m
/// of noise on 2 m cells, `cargo xtask bench-methods --ties refdem`: a slope σ of 0.29, more
/// than the terrain's); over 9 × 9 cells it is 0.018.
const SLOPE_RADIUS_CELLS: usize = 4;

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1 m grid over x 100–140, y 200–230 of a tilted plane, its north-east quarter empty.
    fn dem() -> ReferenceDem {
        let (width, height) = (40, 30);
        let heights = (0..height)
            .flat_map(|r| (0..width).map(move |c| (r, c)))
            .map(|(r, c)| {
                let (x, y) = (100.5 + c as f64, 229.5 - r as f64);
                if x > 130.0 && y > 222.0 {
                    f32::NAN
                } else {
                    (50.0 + 0.25 * (x - 100.0) - 0.125 * (y - 200.0)) as f32
                }
            })
            .collect();
        ReferenceDem::new([100.0, 230.0], 1.0, [width, height], heights, 0.5).unwrap()
    }

    #[test]
    fn a_plane_is_sampled_exactly_with_its_slope_and_nothing_outside_or_beside_a_hole() {
        let dem = dem();
        let (h, slope) = dem.sample(113.37, 211.9).unwrap();
        assert!(
            (h - (50.0 + 0.25 * 13.37 - 0.125 * 11.9)).abs() < 1e-4,
            "{h}"
        );
        assert!((slope[0] - 0.25).abs() < 1e-6 && (slope[1] + 0.125).abs() < 1e-6);
        // Outside the cell centres, and in or next to the empty quarter.
        assert_eq!(dem.height_at(100.2, 215.0), None);
        assert_eq!(dem.height_at(120.0, 229.9), None);
        assert_eq!(dem.height_at(135.0, 225.0), None);
        // Beside the hole, the slope from the cells around it with a height; near the edge
        // (fewer than half the window's cells), none.
        let (_, beside) = dem.sample(129.2, 221.0).unwrap();
        assert!((beside[0] - 0.25).abs() < 1e-6 && (beside[1] + 0.125).abs() < 1e-6);
        assert_eq!(dem.sample(100.6, 229.4), None);
        assert_eq!(dem.valid_cells(), 40 * 30 - 10 * 8);
    }

    #[test]
    fn a_noisy_dems_slope_is_found_to_the_windows_precision() {
        // 0.8 m of noise on 2 m cells over a 5 % and −3 % plane: the 9 × 9 window's slope σ is
        // 0.8 / (2 √540) = 0.017.
        let mut rng = timesift_core::SeededRng::new(9);
        let (width, height) = (60, 60);
        let heights = (0..width * height)
            .map(|k| {
                let (c, r) = ((k % width) as f64, (k / width) as f64);
                (0.05 * 2.0 * c + 0.03 * 2.0 * r + 0.8 * rng.normal()) as f32
            })
            .collect();
        let dem = ReferenceDem::new([0.0, 120.0], 2.0, [width, height], heights, 0.8).unwrap();
        let mut worst: f64 = 0.0;
        for k in 0..50 {
            let (x, y) = (20.0 + 1.6 * k as f64, 30.0 + 1.1 * k as f64 % 60.0);
            let (_, g) = dem.sample(x, y).unwrap();
            worst = worst.max((g[0] - 0.05).abs()).max((g[1] + 0.03).abs());
        }
        assert!(worst < 4.0 * 0.017, "worst slope error {worst}");
    }

    #[test]
    fn a_grid_that_is_empty_mis_sized_or_without_a_positive_sigma_is_refused() {
        let h = vec![0.0f32; 6];
        assert!(ReferenceDem::new([0.0, 0.0], 1.0, [3, 2], h.clone(), 0.1).is_ok());
        assert!(ReferenceDem::new([0.0, 0.0], 1.0, [2, 2], h.clone(), 0.1).is_err());
        assert!(ReferenceDem::new([0.0, 0.0], 0.0, [3, 2], h.clone(), 0.1).is_err());
        assert!(ReferenceDem::new([0.0, 0.0], 1.0, [3, 2], h.clone(), 0.0).is_err());
        assert!(ReferenceDem::new([f64::NAN, 0.0], 1.0, [3, 2], h, 0.1).is_err());
    }
}
