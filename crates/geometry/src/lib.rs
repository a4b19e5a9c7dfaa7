//! Minimal solvers (five-point essential, seven/eight-point fundamental, homography, P3P, EPnP),
//! generic RANSAC with local optimisation, triangulation and similarity transforms (issue
//! "Geometry").
//!
//! Invariants (once built): pure functions of correspondences and cameras from `timesift-core`; no
//! I/O, no knowledge of epochs or projects. Not implemented yet: this crate holds only its charter.
