//! Change detection between two epochs: DEM of difference, DEM co-registration (Nuth & Kääb),
//! stable-area statistics, level of detection and volumes, point-cloud ICP and M3C2, and the maps
//! that go into a report.
//!
//! Invariants: works on any two DEMs or point clouds, including ones made by other software; knows
//! nothing of images, cameras or orientation, and reads or writes no file (the caller does, through
//! `timesift-io`). Nodata is NaN everywhere inside the crate and is propagated, never filled in.

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

pub use error::ChangeError;
