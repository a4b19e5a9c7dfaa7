//! File formats of timesift: images and EXIF, the CSV inputs of a project, `cameras.json`, the COLMAP
//! text model, GeoTIFF and EXR rasters, LAS/LAZ point clouds, and WGS84 ↔ projected coordinates.
//!
//! Invariants:
//! - Every error names the file, and the line or key where there is one ([`IoError`]).
//! - Conventions of docs/design.md are enforced at this boundary: whatever a foreign format stores
//!   (COLMAP's OpenCV distortion with swapped p1/p2, absolute principal points, GeoTIFF tie points),
//!   values leave this crate in timesift's conventions.
//! - Writers are atomic: they write a temporary file beside the target and rename it, so a failure
//!   never leaves a half-written output.
//! - Nothing here knows about stages, epochs' meaning or algorithms.

#![warn(missing_docs, unnameable_types)]

pub mod bal;
pub mod budget;
pub mod cameras_json;
pub mod colmap;
pub mod coords;
pub mod csv_inputs;
pub mod decoder_guard;
mod error;
pub mod exif;
pub mod exr;
mod faults;
pub mod fingerprint;
pub mod fsutil;
pub mod geotiff;
pub mod image;
mod las_checks;
mod las_sink;
pub mod layout;
mod laz_positions;
pub mod libmv;
pub mod metashape;
pub mod opensfm;
pub mod ply;
pub mod pointcloud;
pub mod qgis;
pub mod tiled_tiff;
pub mod topocentric;
pub mod truth_csv;
pub mod wkt;

pub use error::IoError;
