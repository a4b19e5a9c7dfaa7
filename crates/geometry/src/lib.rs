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
