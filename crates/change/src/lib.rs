//! Change detection: DEM of difference, DEM co-registration (Nuth & Kääb), ICP, M3C2, stable-area
//! statistics and volumes (issue "Change detection").
//!
//! Invariants (once built): works on any two DEMs or point clouds, including ones made by other
//! software; knows nothing of images or orientation. Not implemented yet: this crate holds only its
//! charter.
