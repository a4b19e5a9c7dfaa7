//! Ground-truth multi-epoch scene generator: renders textured scenes through the `brown` camera
//! model and writes complete project directories plus `truth/` (issue "Ground-truth multi-epoch
//! scene generator").
//!
//! Built so far: the renderer (`render`): ray casting of triangle meshes through any camera model,
//! exact lens distortion, supersampling, sun and ambient shading, procedural materials. Still to
//! come (see the issue): terrain and object generators, textures by land cover, image effects,
//! the seven study-case scenes and the project writer.
//!
//! Invariants: only ever writes the project format of DESIGN.md, so that what it makes is
//! consumed exactly like user data; every random choice comes from a seed.

pub mod effects;
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
