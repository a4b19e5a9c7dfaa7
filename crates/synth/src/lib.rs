//! Ground-truth multi-epoch scene generator: renders textured scenes through the `brown` camera
//! model and writes complete project directories plus `truth/` (issue "Ground-truth multi-epoch
//! scene generator").
//!
//! Invariants (once built): only ever writes the project format of DESIGN.md, so that what it makes
//! is consumed exactly like user data. Not implemented yet: this crate holds only its charter.
