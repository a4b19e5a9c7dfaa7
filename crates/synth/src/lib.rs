//! Ground-truth multi-epoch scene generator: renders textured scenes through the `brown` camera
//! model and writes complete project directories plus `truth/`, so that every accuracy figure
//! timesift claims can be measured against a known answer.
//!
//! - `render`, `terrain`, `noise`, `effects`: ray casting through any camera model (exact lens
//!   distortion), heightfield ray walk, procedural land covers, camera and film-scan effects.
//! - `shapes`, `scene`, `flight`: what a scene is made of (changes with closed-form volumes,
//!   epochs, cameras placed as surveys are flown).
//! - `scenes`: the seven study cases at `small` and `full` scale; `writer`: the project + truth.
//!
//! Invariants: only ever writes the project format of docs/design.md (plus `scalebars.csv`), so that
//! what it makes is consumed exactly like user data; every random choice comes from a seed; the
//! truth describes exactly what was rendered.

#![warn(missing_docs, unnameable_types)]

pub mod effects;
pub mod film;
pub mod flight;
pub mod noise;
pub mod render;
pub mod scene;
pub mod scenes;
pub mod shapes;
pub mod terrain;
pub mod writer;

use thiserror::Error;

/// Why a scene could not be built or rendered.
#[derive(Debug, Error)]
pub enum SynthError {
    /// The scene description is inconsistent.
    #[error("invalid scene: {0}")]
    InvalidScene(String),
    /// A file of the project could not be written.
    #[error("cannot write the scene: {0}")]
    Write(String),
}
