//! Rasters of an epoch on the project's one lattice: the lattice itself ([`plan_grid`]: cell size
//! from the epochs' ground sample distances, extent from their footprints, edges on cell
//! multiples), DEM gridding of any point cloud ([`grid_cloud`]: median, max or inverse distance
//! per cell, counts and spread beside the heights, small holes filled and marked), true
//! orthomosaics sampled from the original images through the camera model ([`orthomosaic`]), and
//! hillshade previews.
//!
//! Invariants: works in the world frame in f64 and stores heights as f32; reads and writes no
//! file (the root does, through `timesift-io`) and knows no file format; never changes an
//! orientation; knows nothing of epochs, projects or stages — one call grids one cloud or mosaics
//! one set of views; every bad input is a [`RasterError`], never NaN in a valid cell.
//!
//! # Example
//!
//! A DEM of 1 m cells from a cloud sampled on the plane `z = 100 + 0.1 x`, with one hole of two
//! cells that the gap filling closes (and marks):
//!
//! ```
//! use timesift_raster::{DemOptions, Lattice, grid_cloud};
//!
//! // 20 × 10 cells from (0, 10) at the north-west corner.
//! let lattice = Lattice::new(0.0, 10.0, 1.0, 20, 10)?;
//! let mut points = Vec::new();
//! for j in 0..40 {
//!     for i in 0..80 {
//!         let (x, y) = (0.125 + 0.25 * i as f64, 0.125 + 0.25 * j as f64);
//!         let in_hole = (5.0..7.0).contains(&x) && (4.0..5.0).contains(&y);
//!         if !in_hole {
//!             points.push([x, y, 100.0 + 0.1 * x]);
//!         }
//!     }
//! }
//! let dem = grid_cloud(&points, &lattice, &DemOptions::default())?;
//! assert_eq!(dem.valid_cells(), 200);
//! assert_eq!(dem.filled.iter().filter(|&&f| f).count(), 2);
//! for row in 0..10 {
//!     for col in 0..20 {
//!         let (x, _) = lattice.cell_center(col, row);
//!         let h = dem.height[row * 20 + col] as f64;
//!         assert!((h - (100.0 + 0.1 * x)).abs() < 1e-4);
//!     }
//! }
//! # Ok::<(), timesift_raster::RasterError>(())
//! ```

#![warn(missing_docs, unnameable_types)]

mod dem;
mod error;
mod fill;
mod hillshade;
mod lattice;
mod ortho;

pub use dem::{CellHeight, Dem, DemOptions, grid_cloud};
pub use error::RasterError;
pub use hillshade::{Downscaler, downscale, hillshade};
pub use lattice::{
    Bounds, EpochFootprint, ExtentRule, GridOptions, Lattice, ProjectGrid, plan_grid, tidy_cell,
};
pub use ortho::{
    Ortho, OrthoMosaic, OrthoOptions, OrthoStats, OrthoSummary, OrthoView, RgbImage, RowSink,
    TileRowFigures, ViewImages, ortho_stats, orthomosaic, orthomosaic_by_rows,
};
