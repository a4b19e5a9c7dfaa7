//! DEM gridding of dense clouds and orthomosaics on the DEM grid.
//!
//! Invariants (once built): works in the project's projected frame relative to the recorded origin
//! offset; knows nothing of cameras beyond their poses and models. Not implemented yet: this crate
//! holds only its charter.
