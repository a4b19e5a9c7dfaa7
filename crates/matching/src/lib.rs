//! Descriptor matching, pair selection, geometric verification and track building (issue
//! "Matching").
//!
//! Map: [`matcher`] (nearest neighbours of float descriptors by blocked matrix products, binary
//! ones by popcount; ratio test, mutual check, maximum distance), [`verify`] (fundamental,
//! essential and homography RANSAC from `timesift-geometry`, two-view type), [`guided`] (more
//! matches for a verified pair, searched along its epipolar lines), [`pairs`] (which
//! image pairs to match: exhaustive, sequential, spatial, epoch-aware), [`preselect`] (pairs
//! worth matching in full, from matching the largest-scale keypoints), [`tracks`]
//! (conflict-free union-find over verified matches, statistics per epoch pair), [`storage`]
//! (versioned binary feature and match files with checksums), [`stp`] (stable tie points between
//! two separately oriented epochs).
//!
//! Invariants: consumes keypoints and descriptors typed in `timesift-core` and uses
//! `timesift-geometry` for verification; never reads images; results do not depend on the
//! thread count.

#![warn(missing_docs, unnameable_types)]

mod error;
pub mod guided;
pub mod matcher;
pub mod pairs;
pub mod preselect;
pub mod storage;
pub mod stp;
pub mod tracks;
pub mod verify;

pub use error::MatchingError;
pub use matcher::{FloatDistance, Match, MatchOptions, match_descriptors};
