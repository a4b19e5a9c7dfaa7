//! Bundle adjustment: Levenberg–Marquardt on the reduced camera system (Schur complement over the
//! points), camera groups with shared intrinsics and a fixed/free mask per parameter, robust losses,
//! fixed poses and points.
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
//! the reduced system.
//!
//! Invariants: a solver of problems expressed in `timesift-core` types; it knows nothing of how the
//! observations were obtained, of epochs or of files (BAL conversion aside, for benchmarks).
//!
//! # Example
//!
//! A BAL problem (the format of Ceres's `bundle_adjuster`; `timesift_io::bal::read_bal` reads
//! one from a file) made here of four cameras and 60 exactly projected points, then perturbed:
//! 5 cm on every point and 1 % on every focal length. The adjustment brings the reprojection
//! error back to zero.
//!
//! ```
//! use timesift_bundle::{BundleOptions, bal::from_bal, solve};
//! use timesift_io::bal::{BalObservation, BalProblem};
//!
//! let f = 800.0;
//! // BAL cameras: angle-axis, translation, f, k1, k2; they look down −z.
//! let cameras: Vec<[f64; 9]> =
//!     (0..4).map(|c| [0.0, 0.02 * c as f64, 0.0, -1.5 * c as f64, 0.0, 0.0, f, 0.0, 0.0]).collect();
//! let points: Vec<[f64; 3]> = (0..60)
//!     .map(|k| [-3.0 + (k % 10) as f64, -2.0 + (k / 10) as f64 * 0.8, -12.0 + (k % 4) as f64])
//!     .collect();
//! let mut observations = Vec::new();
//! for (c, cam) in cameras.iter().enumerate() {
//!     let r = timesift_core::nalgebra::Rotation3::new(timesift_core::nalgebra::Vector3::new(
//!         cam[0], cam[1], cam[2],
//!     ));
//!     for (p, x) in points.iter().enumerate() {
//!         let q = r * timesift_core::nalgebra::Vector3::new(x[0], x[1], x[2])
//!             + timesift_core::nalgebra::Vector3::new(cam[3], cam[4], cam[5]);
//!         let xy = [-f * q.x / q.z, -f * q.y / q.z];
//!         observations.push(BalObservation { camera: c, point: p, xy });
//!     }
//! }
//! let mut perturbed = BalProblem { cameras, points, observations };
//! for (k, x) in perturbed.points.iter_mut().enumerate() {
//!     x[k % 3] += 0.05;
//! }
//! for cam in &mut perturbed.cameras {
//!     cam[6] *= 1.01;
//! }
//! // Principal points at the centre of 1000 × 800 images.
//! let mut problem = from_bal(&perturbed, &[(500.0, 400.0); 4], (1000, 800))?;
//! let report = solve(&mut problem, &BundleOptions::default())?;
//! assert!(report.initial_cost > 1.0);
//! assert!(report.rms_px < 1e-6, "{}", report.rms_px);
//! # Ok::<(), timesift_bundle::BundleError>(())
//! ```

#![warn(missing_docs, unnameable_types)]

pub mod bal;
mod coarse;
mod error;
mod layout;
pub mod libmv;
pub mod loss;
pub mod precision;
pub mod problem;
mod reduced;
pub mod rigid;
mod schur;
pub mod solver;

pub use error::BundleError;
pub use loss::Loss;
pub use problem::{
    BundleImage, BundlePoint, BundleProblem, CameraGroup, CenterPrior, Observation, PointPrior,
    PriorOffset, ScaleBar,
};
pub use solver::{
    BundleOptions, BundleReport, Elimination, LinearSolver, Termination, cost, gradient,
    num_parameters, perturbed, solve,
};
