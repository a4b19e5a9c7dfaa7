//! Orientation of the multi-epoch block: incremental structure from motion over verified tracks,
//! georeferencing, and the co-registration strategies of DESIGN.md behind one trait (`timesift`,
//! `independent`, `chunk`, `msfm`, `stp`).
//!
//! Inside: `model` (input: camera groups, keypoint positions per image, tracks; output:
//! [`Reconstruction`]), `options`, `state` (one reconstruction in progress: track → point table,
//! triangulation of tracks, extension of points to newly oriented images, filtering), `init`
//! (initial pair), `register` (next image and absolute pose), `adjust` (bundle adjustment through
//! `timesift-bundle`), `incremental` (the loop and components), `georef` (similarity to GNSS
//! priors and control points per component, merge, adjustment with the priors, control and
//! check point residuals), `strategy` (the strategies over a multi-epoch `Block`), `moved`
//! (inter-epoch tie points on surfaces that moved or off the stable ground, split by epoch),
//! `stable_ground` (the caller's stable areas as a grid), `stable` (the `stp`
//! strategy over a caller-given descriptor matcher).
//!
//! Invariants: meets the other stages only through `timesift-core` types (tracks, cameras, poses);
//! reads no file and knows nothing of descriptors (`stp` asks a [`StableMatcher`]); an epoch is a partition of the images and a
//! reference index, nothing more; every random choice is
//! seeded, so a run is reproducible; the frame of a reconstruction is arbitrary (first image at
//! the origin) until georeferencing.

#![warn(missing_docs, unnameable_types)]

mod adjust;
mod error;
mod georef;
mod incremental;
mod init;
mod model;
mod moved;
mod options;
mod register;
mod stable;
mod stable_ground;
mod state;
mod strategy;

pub use adjust::{CentrePrior, OffsetPrior};
pub use error::AlignError;
pub use georef::{
    Datum, EstimatedOffset, GeoreferenceInput, Georeferenced, GroundPoint, Marker, PointResidual,
    georeference, ground_point_residuals,
};
pub use incremental::reconstruct;
pub use model::{FocalSource, Reconstruction, SfmImage, SfmInput, SparsePoint};
pub use options::{SelfCalibration, SfmOptions};
pub use stable::{OfferedTiePoint, StableMatch, StableMatcher, StableSearch, StableTiePoints};
pub use stable_ground::StableGround;
pub use strategy::{
    AVAILABLE, Block, ChunkAlignment, Independent, ProgressiveMerge, SingleBlock, Strategy,
    strategy,
};
