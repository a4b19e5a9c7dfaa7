//! Shared vocabulary of timesift: identifiers, poses, camera models, keypoints, observations and
//! tracks, and the errors they can raise.
//!
//! Every stage crate depends on this one and the stages meet only through its types, so that any
//! stage can be swapped or benchmarked alone.
//!
//! Invariants:
//! - Conventions of `docs/design.md` hold everywhere: f64 geometry in metres and radians, pixel
//!   centres at `i + 0.5`, camera frame x right / y down / z forward, poses are `cam_from_world`.
//! - This crate does no I/O and knows nothing of files, projects or epochs' meaning; it has no
//!   dependency beyond `nalgebra` and `thiserror`.

#![warn(missing_docs, unnameable_types)]

pub mod camera;
pub mod error;
pub mod features;
pub mod ids;
pub mod pose;
pub mod rng;
pub mod tracks;

pub use camera::{
    BrownCamera, Camera, CameraModel, PinholeCamera, ProjectionJacobians, project_world,
    project_world_with_jacobians,
};
pub use error::CoreError;
pub use features::{Descriptors, Keypoint};
pub use ids::{CameraGroupId, EpochId, FeatureIndex, ImageId, TrackId};
pub use pose::Pose;
pub use rng::SeededRng;
pub use tracks::{Observation, Track, TrackElement};

/// Re-exported so downstream crates name the same nalgebra version.
pub use nalgebra;
