//! Feature extraction: Gaussian scale space, SIFT (with RootSIFT) and binary LDB descriptors behind
//! one `FeatureExtractor` trait (issue "Features").
//!
//! This stage decides whether epochs years apart can be joined at all, so it is built for
//! repeatability across illumination and sensor changes rather than for speed alone.
//!
//! Invariants (once built): depends only on `timesift-core` (and `timesift-io` for images); knows
//! nothing of epochs, matching or geometry. Not implemented yet: this crate holds only its charter.
