//! Descriptor matching, pair selection, geometric verification and track building.
//!
//! Map: [`matcher`] (nearest neighbours of float descriptors by blocked matrix products, binary
//! ones by popcount; ratio test, mutual check, maximum distance), [`verify`] (fundamental,
//! essential and homography RANSAC from `timesift-geometry`, two-view type), [`guided`] (more
//! matches for a verified pair, searched along its epipolar lines), [`staged`] (a pair matched
//! coarse to fine: the largest-scale keypoints verified, then guided matching), [`pairs`] (which
//! image pairs to match: exhaustive, sequential, spatial, epoch-aware),
//! [`preselect`](mod@preselect) (pairs worth matching in full, from matching the largest-scale
//! keypoints), [`tracks`]
//! (conflict-free union-find over verified matches, statistics per epoch pair), [`storage`]
//! (versioned binary feature and match files with checksums), [`stp`] (stable tie points between
//! two separately oriented epochs).
//!
//! Invariants: consumes keypoints and descriptors typed in `timesift-core` and uses
//! `timesift-geometry` for verification; never reads images; results do not depend on the
//! thread count.
//!
//! # Example
//!
//! Matching the SIFT features of two views of one textured plane, the second shifted 7 px to
//! the right: the mutual, ratio-tested matches join keypoints 7 px apart.
//!
//! ```
//! use timesift_features::{FeatureExtractor, GreyImage, SiftExtractor, doc_example::blobs};
//! use timesift_matching::{MatchOptions, match_descriptors};
//!
//! let (width, height) = (160, 120);
//! let extract = |shift: f64| {
//!     let pixels = blobs(width, height, shift);
//!     SiftExtractor::default().extract(&GreyImage::new(width, height, &pixels)?, None)
//! };
//! let (a, b) = (extract(0.0)?, extract(7.0)?);
//! let matches = match_descriptors(&a.descriptors, &b.descriptors, &MatchOptions::default())?;
//! assert!(matches.len() >= 10);
//! let shifted = matches.iter().filter(|m| {
//!     let (p, q) = (&a.keypoints[m.query as usize], &b.keypoints[m.train as usize]);
//!     (q.x - p.x - 7.0).abs() < 0.5 && (q.y - p.y).abs() < 0.5
//! });
//! assert!(shifted.count() * 10 >= matches.len() * 9);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs, unnameable_types)]

mod error;
pub mod guided;
pub mod matcher;
pub mod pairs;
pub mod preselect;
pub mod staged;
pub mod storage;
pub mod stp;
pub mod tracks;
pub mod verify;

pub use error::MatchingError;
pub use guided::{GuidedOptions, grow_verified};
pub use matcher::{FloatDistance, Match, MatchOptions, match_descriptors};
pub use pairs::PairPolicy;
pub use preselect::{PreselectOptions, preselect};
pub use staged::{MatchedBy, StagedMatches, StagedOptions, staged_matches};
pub use stp::{StablePair, StpOptions, StpResult, TiePoint, stable_tie_points};
pub use tracks::{PairMatches, TrackSet, build_tracks};
pub use verify::{EpipolarModel, VerifiedPair, VerifyOptions, verify_pair};
