//! Change detection between two epochs: DEM of difference, DEM co-registration (Nuth & Kääb),
//! stable-area statistics, level of detection and volumes, point-cloud ICP and M3C2, and the maps
//! that go into a report.
//!
//! Invariants: works on any two DEMs or point clouds, including ones made by other software; knows
//! nothing of images, cameras or orientation, and reads or writes no file (the caller does, through
//! `timesift-io`). Nodata is NaN everywhere inside the crate and is propagated, never filled in.
//!
//! # Example
//!
//! Two DEMs of the same 1 m grid, the later one 2 cm higher everywhere (a bias of its
//! orientation) and 1.5 m higher on a 10 × 10 m mound; with the first rows marked stable, the
//! pair's analysis finds the bias on the stable ground and the mound's volume:
//!
//! ```
//! use timesift_change::{Crs, Dem, GeoTransform, Grid, Mask, PairOptions, analyse_pair};
//!
//! let transform =
//!     GeoTransform { origin_x: 0.0, origin_y: 40.0, pixel_width: 1.0, pixel_height: -1.0 };
//! let grid = Grid { transform, width: 40, height: 40, crs: Crs::Local };
//! let ground = |col: usize, row: usize| 50.0 + 0.01 * col as f32 + 0.02 * row as f32;
//! let earlier = Dem { grid, values: (0..1600).map(|k| ground(k % 40, k / 40)).collect() };
//! let later = Dem {
//!     grid,
//!     values: (0..1600)
//!         .map(|k| {
//!             let (col, row) = (k % 40, k / 40);
//!             let mound = (20..30).contains(&col) && (20..30).contains(&row);
//!             ground(col, row) + 0.02 + if mound { 1.5 } else { 0.0 }
//!         })
//!         .collect(),
//! };
//! let stable = Mask { grid, cells: (0..1600).map(|k| k / 40 < 10).collect() };
//! let pair = analyse_pair(&earlier, &later, Some(&stable), None, &PairOptions::default())?;
//! let bias = pair.stable.expect("stable cells").median;
//! assert!((bias - 0.02).abs() < 1e-4);
//! // 100 cells of 1 m² raised by 1.5 m, the 2 cm bias over the other 1500 cells.
//! assert!((pair.volumes.net - (150.0 + 0.02 * 1600.0)).abs() < 0.1);
//! # Ok::<(), timesift_change::ChangeError>(())
//! ```

#![warn(missing_docs, unnameable_types)]

pub mod checkpoints;
pub mod cloud;
pub mod correlation;
pub mod dod;
mod error;
pub mod grid;
pub mod icp;
pub mod m3c2;
pub mod maps;
pub mod mask;
pub mod nuth_kaab;
pub mod pair;
pub mod stats;
pub mod terrain;
pub mod trend;
pub mod volume;

pub use correlation::{Variogram, variogram};
pub use dod::dem_of_difference;
pub use error::ChangeError;
pub use grid::{DEM_NODATA, Dem, Grid};
pub use icp::{IcpModel, IcpOptions, IcpResult, icp};
pub use m3c2::{M3c2Params, M3c2Point, m3c2};
pub use mask::Mask;
pub use nuth_kaab::{NuthKaabOptions, NuthKaabResult, nuth_kaab};
pub use pair::{LodSource, PairAnalysis, PairOptions, analyse_pair};
pub use stats::{Statistics, statistics};
/// The CRS and geotransform of a [`Grid`], from `timesift-io`: re-exported so that a caller
/// builds grids without naming another crate.
pub use timesift_io::{coords::Crs, geotiff::GeoTransform};
pub use trend::{PlaneTrend, plane_trend};
pub use volume::{VolumeOptions, Volumes, volumes};
