//! The timesift orchestrator: the project directory (`project.toml` and its inputs), the stage
//! pipeline of `timesift run`, and the commands of the CLI. The binary in `main.rs` only parses
//! arguments and reports errors; everything it does is here so it can be tested and scripted.
//!
//! Invariants:
//! - The user's inputs are never modified; outputs go under `out/` and work files under `work/`.
//! - Every user-facing failure is a [`ProjectError`] (or an `IoError` inside one) whose message is
//!   one line naming the file and the line or key.
//! - Stage crates are called only through the types of `timesift-core`.

#![warn(missing_docs, unnameable_types)]

pub mod commands;
pub mod config;
mod error;
pub mod eval;
pub mod film;
pub mod html;
pub mod progress;
pub mod project;
pub mod report;
pub mod stable_matcher;
pub mod stages;
pub mod tasks;

pub use error::ProjectError;
pub use project::Project;
/// The paths of a project directory (`timesift_io::layout`), under the name the stages use.
pub use timesift_io::layout;
