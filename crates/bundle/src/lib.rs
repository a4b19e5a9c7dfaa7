//! Bundle adjustment: Levenberg–Marquardt on the reduced camera system (Schur complement over the
//! points), camera groups with shared intrinsics and a fixed/free mask per parameter, robust losses,
//! fixed poses and points (issue "Bundle adjustment").
//!
//! Built so far: reprojection residuals through any `CameraModel` with per-observation sigmas,
//! camera-centre (GNSS) and control-point priors with horizontal/vertical sigmas, offsets shared by
//! centre priors (a GNSS bias per flight) estimated with their own prior,
//! Huber/Cauchy/soft-L1 losses, dense and sparse (faer, symbolic analysis once per solve) Schur
//! paths, Ceres-like trust-region control and
//! termination, the BAL problem conversion, and `precision`: residual statistics per kind, group
//! and image, the posterior variance factor, outlier flags, covariances of camera centres and
//! intrinsics; scale bars (distances between two points), whose end points stay in the reduced
//! system since they couple two points; libmv problems; Schur elimination of points or poses
//! (whichever leaves the smaller system); an iterative (PCG, Schur–Jacobi) path that never forms
//! the reduced system. Still to come (see the issue): parallel assembly.
//!
//! Invariants: a solver of problems expressed in `timesift-core` types; it knows nothing of how the
//! observations were obtained, of epochs or of files (BAL conversion aside, for benchmarks).

#![warn(missing_docs, unnameable_types)]

pub mod bal;
mod error;
pub mod libmv;
pub mod loss;
pub mod precision;
pub mod problem;
mod reduced;
pub mod solver;

pub use error::BundleError;
pub use loss::Loss;
pub use problem::{
    BundleImage, BundlePoint, BundleProblem, CameraGroup, CenterPrior, Observation, PointPrior, PriorOffset, ScaleBar,
};
pub use solver::{
    BundleOptions, BundleReport, Elimination, LinearSolver, Termination, cost, gradient,
    num_parameters, perturbed, solve,
};
