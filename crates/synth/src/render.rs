//! Ray-cast rendering of textured triangle meshes through any `CameraModel`: every sample's ray
//! comes from the model's own `unproject`, so lens distortion is exact (no resampling of an
//! undistorted image), and a sample grid per pixel box-filters edges (supersampled anti-aliasing).
//! Rays are cast against a BVH of the mesh (parry3d); shading is Lambertian under a sun direction
//! plus ambient light; materials are procedural functions of the hit position, so texture detail
//! exists at every scale without texture images.

use nalgebra::{Vector2, Vector3};
use parry3d_f64::math::Vector as PVector;
use parry3d_f64::query::{Ray, RayCast};
use parry3d_f64::shape::{FeatureId, TriMesh};
use rayon::prelude::*;
use timesift_core::{CameraModel, Pose};

use crate::SynthError;

/// Longest ray (in units of the ray direction): finite, since BVH traversal does arithmetic on it.
const MAX_RAY_LENGTH: f64 = 1e9;

/// What a surface looks like: albedo (0–1) as a function of the world position.
#[derive(Debug, Clone, PartialEq)]
pub enum Material {
    /// Constant albedo.
    Flat(f64),
    /// A checkerboard of squares of side `size` on the plane through `origin` spanned by the unit
    /// vectors `u` and `v`; albedo `dark` and `light`.
    Checker {
        /// A corner of the board.
        origin: Vector3<f64>,
        /// First in-plane axis (unit).
        u: Vector3<f64>,
        /// Second in-plane axis (unit).
        v: Vector3<f64>,
        /// Square side, metres.
        size: f64,
        /// Albedo of dark squares.
        dark: f64,
        /// Albedo of light squares.
        light: f64,
    },
    /// Fractal noise texture: `mean + amplitude · fBm(position / scale)`, clamped to [0, 1].
    Noise {
        /// The noise (its seed).
        noise: Box<crate::noise::Noise>,
        /// Mean albedo.
        mean: f64,
        /// Amplitude of the variation.
        amplitude: f64,
        /// Longest wavelength, metres.
        scale: f64,
        /// Octaves (each halves the wavelength).
        octaves: u32,
    },
}

impl Material {
    /// Albedo at a world position.
    pub fn albedo(&self, x: &Vector3<f64>) -> f64 {
        match self {
            Material::Flat(a) => *a,
            Material::Checker {
                origin,
                u,
                v,
                size,
                dark,
                light,
            } => {
                let d = x - origin;
                let (i, j) = (
                    (d.dot(u) / size).floor() as i64,
                    (d.dot(v) / size).floor() as i64,
                );
                if (i + j).rem_euclid(2) == 0 {
                    *dark
                } else {
                    *light
                }
            }
            Material::Noise {
                noise,
                mean,
                amplitude,
                scale,
                octaves,
            } => (mean + amplitude * noise.fbm(x.x, x.y, x.z, *scale, *octaves, 0.55))
                .clamp(0.0, 1.0),
        }
    }
}

/// A scene: one triangle mesh with a material per triangle, and the light.
pub struct Scene {
    mesh: TriMesh,
    materials: Vec<Material>,
    triangle_material: Vec<usize>,
    /// Unit vector towards the sun.
    pub sun: Vector3<f64>,
    /// Ambient fraction of the light (0–1).
    pub ambient: f64,
    /// Value of rays that hit nothing.
    pub background: f64,
}

impl Scene {
    /// A scene from vertices, triangles (vertex indices) and each triangle's material index.
    pub fn new(
        vertices: &[Vector3<f64>],
        triangles: &[[u32; 3]],
        triangle_material: Vec<usize>,
        materials: Vec<Material>,
    ) -> Result<Scene, SynthError> {
        if triangle_material.len() != triangles.len() {
            return Err(SynthError::InvalidScene(format!(
                "{} materials for {} triangles",
                triangle_material.len(),
                triangles.len()
            )));
        }
        if let Some(m) = triangle_material.iter().find(|&&m| m >= materials.len()) {
            return Err(SynthError::InvalidScene(format!(
                "material {m} of {}",
                materials.len()
            )));
        }
        let mesh = TriMesh::new(
            vertices
                .iter()
                .map(|v| PVector::new(v.x, v.y, v.z))
                .collect(),
            triangles.to_vec(),
        )
        .map_err(|e| SynthError::InvalidScene(format!("triangle mesh: {e:?}")))?;
        Ok(Scene {
            mesh,
            materials,
            triangle_material,
            sun: Vector3::new(0.3, 0.2, 1.0).normalize(),
            ambient: 0.35,
            background: 0.0,
        })
    }

    /// The first surface point along a world ray, if any.
    pub fn hit(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<Vector3<f64>> {
        let ray = Ray::new(
            PVector::new(origin.x, origin.y, origin.z),
            PVector::new(dir.x, dir.y, dir.z),
        );
        self.mesh
            .cast_local_ray(&ray, MAX_RAY_LENGTH, false)
            .map(|t| origin + dir * t)
    }

    /// Radiance along a world ray (origin, direction): albedo × (ambient + (1 − ambient)·cos θ).
    pub fn trace(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> f64 {
        let ray = Ray::new(
            PVector::new(origin.x, origin.y, origin.z),
            PVector::new(dir.x, dir.y, dir.z),
        );
        let Some(hit) = self
            .mesh
            .cast_local_ray_and_get_normal(&ray, MAX_RAY_LENGTH, false)
        else {
            return self.background;
        };
        let n_tri = self.triangle_material.len() as u32;
        let tri = match hit.feature {
            FeatureId::Face(f) => (f % n_tri) as usize,
            _ => 0,
        };
        let x = origin + dir * hit.time_of_impact;
        let mut normal = Vector3::new(hit.normal.x, hit.normal.y, hit.normal.z);
        if normal.dot(dir) > 0.0 {
            normal = -normal;
        }
        let albedo = self.materials[self.triangle_material[tri]].albedo(&x);
        albedo * (self.ambient + (1.0 - self.ambient) * normal.dot(&self.sun).max(0.0))
    }
}

/// Rendering options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Samples per pixel along each axis (n × n per pixel, box filter).
    pub supersampling: u32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions { supersampling: 3 }
    }
}

/// A grey image, row-major, values 0–1 (before exposure and noise).
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Values.
    pub data: Vec<f32>,
}

impl GreyImage {
    /// Value at (col, row).
    pub fn get(&self, col: usize, row: usize) -> f32 {
        self.data[row * self.width + col]
    }
}

/// Renders `scene` as seen by `camera` at `pose` (`cam_from_world`). Pixel (i, j) covers
/// [i, i+1) × [j, j+1) (DESIGN.md); its samples sit at the centres of an n × n grid inside it.
pub fn render<C: CameraModel + Sync>(
    scene: &Scene,
    camera: &C,
    width: usize,
    height: usize,
    pose: &Pose,
    options: &RenderOptions,
) -> Result<GreyImage, SynthError> {
    let n = options.supersampling.max(1) as usize;
    let world_from_cam = pose.rotation.inverse();
    let centre = pose.center();
    let mut data = vec![0.0f32; width * height];
    data.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(row, line)| {
            for (col, out) in line.iter_mut().enumerate() {
                let mut sum = 0.0;
                for sy in 0..n {
                    for sx in 0..n {
                        let pixel = Vector2::new(
                            col as f64 + (sx as f64 + 0.5) / n as f64,
                            row as f64 + (sy as f64 + 0.5) / n as f64,
                        );
                        sum += match camera.unproject(&pixel) {
                            Ok(ray_cam) => scene.trace(&centre, &(world_from_cam * ray_cam)),
                            Err(_) => scene.background,
                        };
                    }
                }
                *out = (sum / (n * n) as f64) as f32;
            }
        });
    Ok(GreyImage {
        width,
        height,
        data,
    })
}
