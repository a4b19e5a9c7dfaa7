//! Sparse Levenberg–Marquardt bundle adjustment with a Schur complement over the points,
//! self-calibration per camera group, control points, GNSS priors and scale bars (issue "Bundle
//! adjustment").
//!
//! Invariants (once built): a solver of a problem expressed in `timesift-core` types; knows nothing
//! of how the observations were obtained. Not implemented yet: this crate holds only its charter.
