//! Descriptor matching, pair selection, geometric verification, track building and the
//! inter-epoch stable-tie-point matcher (issue "Matching").
//!
//! Invariants (once built): consumes keypoints and descriptors typed in `timesift-core`, uses
//! `timesift-geometry` for verification, never reads images itself. Not implemented yet: this crate
//! holds only its charter.
