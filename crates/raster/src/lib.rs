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

#![warn(missing_docs, unnameable_types)]

mod dem;
mod error;
mod fill;
mod hillshade;
mod lattice;
mod ortho;

pub use dem::{CellHeight, Dem, DemOptions, grid_cloud};
pub use error::RasterError;
pub use hillshade::{downscale, hillshade};
pub use lattice::{
    Bounds, EpochFootprint, ExtentRule, GridOptions, Lattice, ProjectGrid, plan_grid, tidy_cell,
};
pub use ortho::{Ortho, OrthoOptions, OrthoStats, OrthoView, RgbImage, ViewImages, orthomosaic};
