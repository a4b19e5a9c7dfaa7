//! Minimal and non-minimal geometric solvers and robust estimation: the five-point essential
//! matrix, seven- and eight-point fundamental matrices, homographies, P3P (Lambda Twist) and DLT
//! absolute pose with refinement through any camera model, triangulation (DLT, midpoint, weighted
//! intersection with covariance), similarity transforms (Umeyama, Helmert report), and one generic
//! RANSAC (LO-RANSAC, adaptive termination, seeded, MSAC or marginalised threshold-free scoring).
//!
//! Conventions: image measurements given to calibrated solvers are viewing rays in the camera
//! frame (`CameraModel::unproject`, z = 1 or unit length); uncalibrated solvers take pixels. A
//! relative pose is `cam2_from_cam1` and its essential matrix satisfies `x2ᵀ E x1 = 0`.
//!
//! Invariants: pure functions of their inputs (no I/O, no global state); degenerate or
//! insufficient input returns [`GeometryError`], never NaN; all randomness comes from a seed.
//!
//! # Example
//!
//! A similarity (Helmert) between two point sets, a quarter of whose correspondences are wrong:
//! RANSAC over [`SimilarityEstimator`](similarity::SimilarityEstimator) finds the transform and
//! flags the wrong pairs.
//!
//! ```
//! use timesift_core::nalgebra::{UnitQuaternion, Vector3};
//! use timesift_geometry::{RansacOptions, TransformKind, ransac, similarity::SimilarityEstimator};
//!
//! let rotation = UnitQuaternion::from_euler_angles(0.02, -0.01, 0.7);
//! let (scale, shift) = (1.3, Vector3::new(500.0, -20.0, 3.0));
//! let src: Vec<Vector3<f64>> = (0..40)
//!     .map(|k| Vector3::new((k % 7) as f64 * 3.0, (k / 7) as f64 * 2.5, (k % 3) as f64))
//!     .collect();
//! let mut dst: Vec<Vector3<f64>> = src.iter().map(|p| rotation * p * scale + shift).collect();
//! for k in (0..40).step_by(4) {
//!     dst[k].z += 5.0; // a wrong correspondence
//! }
//! let estimator = SimilarityEstimator { src: &src, dst: &dst, kind: TransformKind::Similarity };
//! let options = RansacOptions { max_error: 0.01, ..RansacOptions::default() };
//! let found = ransac(&estimator, &options)?;
//! assert_eq!(found.num_inliers, 30);
//! assert!((found.model.scale - scale).abs() < 1e-9);
//! assert!((found.model.apply(&src[1]) - dst[1]).norm() < 1e-9);
//! # Ok::<(), timesift_geometry::GeometryError>(())
//! ```

#![warn(missing_docs, unnameable_types)]

mod error;
pub mod essential;
pub mod fundamental;
pub mod homography;
mod normalize;
pub mod p3p;
pub mod pnp;
pub mod poly;
pub mod ransac;
pub mod similarity;
pub mod triangulation;

pub use error::GeometryError;
pub use essential::{five_point, relative_pose_from_essential};
pub use fundamental::{eight_point, seven_point};
pub use homography::{TwoViewType, homography_dlt};
pub use p3p::p3p;
pub use pnp::{dlt_pnp, refine_pose};
pub use ransac::{Estimator, RansacOptions, RansacResult, Scoring, ransac};
pub use similarity::{HelmertReport, Similarity, TransformKind, umeyama};
pub use triangulation::{IntersectedPoint, PixelObservation, intersect_weighted, triangulate_dlt};
