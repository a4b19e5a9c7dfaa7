//! Multi-view stereo per epoch with frozen orientations and depth-map fusion into a dense cloud.
//!
//! Invariants (once built): sees one epoch at a time; never changes an orientation. Not implemented
//! yet: this crate holds only its charter.
