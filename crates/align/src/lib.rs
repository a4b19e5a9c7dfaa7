//! Orientation of the multi-epoch block: incremental SfM, georeferencing and the five
//! co-registration strategies (`timesift`, `msfm`, `chunk`, `stp`, `independent`) of DESIGN.md
//! (issue "Orientation of the multi-epoch block").
//!
//! Invariants (once built): meets the other stages only through `timesift-core` types. Not
//! implemented yet: this crate holds only its charter.
