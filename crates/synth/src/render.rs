//! Ray-cast rendering of textured triangle meshes through any `CameraModel`: every sample's ray
//! comes from the model's own `unproject`, so lens distortion is exact (no resampling of an
//! undistorted image), and a sample grid per pixel box-filters edges (supersampled anti-aliasing).
//! The first hit along a ray is the visible surface (a depth test by construction). Rays are cast
//! against a BVH of the mesh (parry3d); shading is Lambertian under a sun direction plus ambient
//! light, with optional cast shadows; materials are procedural functions of the hit position, so
//! texture detail exists at every scale without texture images.

use std::sync::Arc;

use nalgebra::{Vector2, Vector3};
use parry3d_f64::math::Vector as PVector;
use parry3d_f64::query::{Ray, RayCast};
use parry3d_f64::shape::TriMesh;
use rayon::prelude::*;
use timesift_core::{CameraModel, Pose};

use crate::SynthError;
use crate::noise::{Noise, speckles2, speckles3};
use crate::terrain::{FieldTracer, Heightfield};

/// Longest ray (in units of the ray direction): finite, since BVH traversal does arithmetic on it.
const MAX_RAY_LENGTH: f64 = 1e9;

/// Amplitude ratio between successive octaves of land-cover textures: a flat spectrum keeps
/// contrast at the pixel scale, where features are detected.
const COVER_GAIN: f64 = 0.8;

/// Linear RGB reflectance or radiance, each channel 0–1.
pub type Rgb = Vector3<f64>;

/// What a surface looks like: albedo as a function of the (texture) position.
#[derive(Debug, Clone, PartialEq)]
pub enum Material {
    /// Constant grey albedo.
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
    /// Grey fractal noise texture: `mean + amplitude · fBm(position / scale)`, clamped to [0, 1].
    Noise {
        /// The noise (its seed).
        noise: Box<Noise>,
        /// Mean albedo.
        mean: f64,
        /// Amplitude of the variation.
        amplitude: f64,
        /// Longest wavelength, metres.
        scale: f64,
        /// Octaves (each halves the wavelength).
        octaves: u32,
    },
    /// A land cover: colours mixed between `dark` and `light` by fractal noise with wavelengths
    /// from `scale` down to `scale / 2^(octaves−1)`, so that texture exists from the size of a
    /// field down to the ground sampling distance.
    Cover {
        /// The noise (its seed).
        noise: Box<Noise>,
        /// Colour where the noise is low.
        dark: Rgb,
        /// Colour where the noise is high.
        light: Rgb,
        /// Longest wavelength, metres.
        scale: f64,
        /// Octaves.
        octaves: u32,
        /// Contrast: how far the noise spreads the mix around its middle (about 1).
        contrast: f64,
        /// Strength of the speckles added to the mix (0: none): sparse spots of 0.6 to 6 ground
        /// pixels, in three sizes, for the small-scale structure real ground has.
        speckle: f64,
        /// Seed of the speckles.
        speckle_seed: u64,
    },
}

impl Material {
    /// Whether the albedo varies smoothly at the scale of a pixel (a checkerboard does not).
    pub fn is_smooth(&self) -> bool {
        !matches!(self, Material::Checker { .. })
    }

    /// Albedo at a texture position.
    pub fn albedo(&self, x: &Vector3<f64>) -> Rgb {
        self.shade(
            x,
            |n, scale, octaves, gain| n.fbm(x.x, x.y, x.z, scale, octaves, gain),
            |cell, seed| speckles3(x.x, x.y, x.z, cell, seed),
        )
    }

    /// Albedo of a texture mapped onto a plane, at plane coordinates (x, y): the same patterns
    /// with 2-D noise (half the work), for heightfields, seen from their normal side so that no
    /// stretching shows.
    pub fn albedo_planar(&self, x: f64, y: f64) -> Rgb {
        self.shade(
            &Vector3::new(x, y, 0.0),
            |n, scale, octaves, gain| n.fbm2(x, y, scale, octaves, gain),
            |cell, seed| speckles2(x, y, cell, seed),
        )
    }

    /// The albedo with `fbm(noise, scale, octaves, gain)` as the fractal noise at the point and
    /// `speckles(cell, seed)` as the speckles.
    fn shade(
        &self,
        x: &Vector3<f64>,
        fbm: impl Fn(&Noise, f64, u32, f64) -> f64,
        speckles: impl Fn(f64, u64) -> f64,
    ) -> Rgb {
        let grey = |a: f64| Rgb::new(a, a, a);
        match self {
            Material::Flat(a) => grey(*a),
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
                grey(if (i + j).rem_euclid(2) == 0 {
                    *dark
                } else {
                    *light
                })
            }
            Material::Noise {
                noise,
                mean,
                amplitude,
                scale,
                octaves,
            } => grey((mean + amplitude * fbm(noise, *scale, *octaves, 0.55)).clamp(0.0, 1.0)),
            Material::Cover {
                noise,
                dark,
                light,
                scale,
                octaves,
                contrast,
                speckle,
                speckle_seed,
            } => {
                let mut t = 0.5 + contrast * fbm(noise, *scale, *octaves, COVER_GAIN);
                if *speckle > 0.0 {
                    // Cells of 5, 10 and 20 ground pixels (the finest wavelength is half a pixel).
                    let finest = scale / 2f64.powi(*octaves as i32 - 1);
                    for (k, cell) in [10.0, 20.0, 40.0].iter().enumerate() {
                        t += speckle * speckles(cell * finest, speckle_seed.wrapping_add(k as u64));
                    }
                }
                dark + (light - dark) * t.clamp(0.0, 1.0)
            }
        }
    }
}

/// A surveying target painted on a surface: a disc of four quadrants, black and white
/// alternately, whose centre (the quadrants' common corner) is the marked point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// Centre, world coordinates (on the surface).
    pub centre: Vector3<f64>,
    /// First in-plane axis (unit).
    pub u: Vector3<f64>,
    /// Second in-plane axis (unit).
    pub v: Vector3<f64>,
    /// Radius, metres.
    pub radius: f64,
}

/// Maps a world position to the position at which materials are evaluated, so texture can move
/// with the ground (a landslide block carries its texture downhill).
pub type TextureWarp = Arc<dyn Fn(&Vector3<f64>) -> Vector3<f64> + Send + Sync>;

/// The material index of a world position (land cover evaluated where a ray lands, so cover
/// boundaries are sharp whatever the mesh resolution).
pub type CoverAt = Arc<dyn Fn(&Vector3<f64>) -> usize + Send + Sync>;

/// How the triangles of a heightfield layer get their material.
#[derive(Clone)]
pub enum FieldMaterial {
    /// One material for all.
    Uniform(usize),
    /// The scene's cover function at the hit point.
    Cover,
}

/// A heightfield in the scene, in a frame that may swap y and z (a vertical wall).
struct FieldLayer {
    tracer: FieldTracer,
    swap_yz: bool,
    material: FieldMaterial,
}

fn swap(v: &Vector3<f64>, swap_yz: bool) -> Vector3<f64> {
    if swap_yz {
        Vector3::new(v.x, v.z, v.y)
    } else {
        *v
    }
}

/// Accumulates meshes, heightfields and their materials into one [`Scene`].
#[derive(Default)]
pub struct SceneBuilder {
    vertices: Vec<Vector3<f64>>,
    triangles: Vec<[u32; 3]>,
    triangle_material: Vec<usize>,
    materials: Vec<Material>,
    fields: Vec<FieldLayer>,
    cover: Option<CoverAt>,
    targets: Vec<Target>,
    warp: Option<TextureWarp>,
}

impl SceneBuilder {
    /// An empty scene.
    pub fn new() -> SceneBuilder {
        SceneBuilder::default()
    }

    /// Adds a material; returns its index.
    pub fn material(&mut self, material: Material) -> usize {
        self.materials.push(material);
        self.materials.len() - 1
    }

    /// Adds a mesh whose triangle `k` has material `material_of(k)`.
    pub fn add_mesh(
        &mut self,
        vertices: &[Vector3<f64>],
        triangles: &[[u32; 3]],
        material_of: impl Fn(usize) -> usize,
    ) {
        let base = self.vertices.len() as u32;
        self.vertices.extend_from_slice(vertices);
        for (k, t) in triangles.iter().enumerate() {
            self.triangles.push([t[0] + base, t[1] + base, t[2] + base]);
            self.triangle_material.push(material_of(k));
        }
    }

    /// Adds a heightfield; with `swap_yz` its (x, y, height) is the world's (x, z, y).
    pub fn add_field(&mut self, field: Heightfield, swap_yz: bool, material: FieldMaterial) {
        self.fields.push(FieldLayer {
            tracer: FieldTracer::new(field),
            swap_yz,
            material,
        });
    }

    /// Sets the cover function used by [`FieldMaterial::Cover`] layers.
    pub fn cover(&mut self, cover: CoverAt) {
        self.cover = Some(cover);
    }

    /// Adds a painted target.
    pub fn target(&mut self, target: Target) {
        self.targets.push(target);
    }

    /// Sets the texture warp.
    pub fn warp(&mut self, warp: TextureWarp) {
        self.warp = Some(warp);
    }

    /// The scene.
    pub fn build(self) -> Result<Scene, SynthError> {
        if let Some(m) = self.fields.iter().find_map(|f| match f.material {
            FieldMaterial::Uniform(m) if m >= self.materials.len() => Some(m),
            _ => None,
        }) {
            return Err(SynthError::InvalidScene(format!(
                "material {m} of {}",
                self.materials.len()
            )));
        }
        if self.cover.is_none()
            && self
                .fields
                .iter()
                .any(|f| matches!(f.material, FieldMaterial::Cover))
        {
            return Err(SynthError::InvalidScene(
                "a heightfield takes its cover from a function that was not given".into(),
            ));
        }
        let mut scene = Scene::new(
            &self.vertices,
            &self.triangles,
            self.triangle_material,
            self.materials,
        )?;
        scene.fields = self.fields;
        scene.cover = self.cover;
        scene.targets = self.targets;
        scene.warp = self.warp;
        Ok(scene)
    }
}

/// What a ray hit: distance, unit normal, material.
struct Hit {
    t: f64,
    normal: Vector3<f64>,
    material: usize,
    /// For heightfield hits, whether the layer swaps y and z (its texture is planar).
    planar: Option<bool>,
}

/// A scene: triangle meshes and heightfields with materials, painted targets, and the light.
pub struct Scene {
    mesh: Option<TriMesh>,
    materials: Vec<Material>,
    triangle_material: Vec<usize>,
    fields: Vec<FieldLayer>,
    cover: Option<CoverAt>,
    targets: Vec<Target>,
    warp: Option<TextureWarp>,
    /// Unit vector towards the sun.
    pub sun: Vector3<f64>,
    /// Ambient fraction of the light (0–1).
    pub ambient: f64,
    /// Radiance of rays that hit nothing.
    pub background: Rgb,
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
        let mesh = if triangles.is_empty() {
            None
        } else {
            Some(
                TriMesh::new(
                    vertices
                        .iter()
                        .map(|v| PVector::new(v.x, v.y, v.z))
                        .collect(),
                    triangles.to_vec(),
                )
                .map_err(|e| SynthError::InvalidScene(format!("triangle mesh: {e:?}")))?,
            )
        };
        Ok(Scene {
            mesh,
            materials,
            triangle_material,
            fields: Vec::new(),
            cover: None,
            targets: Vec::new(),
            warp: None,
            sun: Vector3::new(0.3, 0.2, 1.0).normalize(),
            ambient: 0.35,
            background: Rgb::zeros(),
        })
    }

    fn ray(origin: &Vector3<f64>, dir: &Vector3<f64>) -> Ray {
        Ray::new(
            PVector::new(origin.x, origin.y, origin.z),
            PVector::new(dir.x, dir.y, dir.z),
        )
    }

    /// The nearest hit along a ray within `t_max`.
    fn nearest(&self, origin: &Vector3<f64>, dir: &Vector3<f64>, t_max: f64) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        if let Some(mesh) = &self.mesh {
            if let Some(hit) =
                mesh.cast_local_ray_and_get_normal(&Self::ray(origin, dir), t_max, false)
            {
                // The triangle hit, in the order given to `new` (parry's sub-shape id).
                let tri = (hit.subshape as usize).min(self.triangle_material.len() - 1);
                best = Some(Hit {
                    t: hit.time_of_impact,
                    normal: Vector3::new(hit.normal.x, hit.normal.y, hit.normal.z),
                    material: self.triangle_material[tri],
                    planar: None,
                });
            }
        }
        for layer in &self.fields {
            let limit = best.as_ref().map_or(t_max, |b| b.t);
            let (o, d) = (swap(origin, layer.swap_yz), swap(dir, layer.swap_yz));
            if let Some(hit) = layer.tracer.cast(&o, &d, limit) {
                if best.as_ref().is_none_or(|b| hit.t < b.t) {
                    let material = match &layer.material {
                        FieldMaterial::Uniform(m) => *m,
                        FieldMaterial::Cover => match &self.cover {
                            Some(cover) => cover(&(origin + dir * hit.t)),
                            None => 0,
                        },
                    };
                    best = Some(Hit {
                        t: hit.t,
                        normal: swap(&hit.normal, layer.swap_yz),
                        material,
                        planar: Some(layer.swap_yz),
                    });
                }
            }
        }
        best
    }

    /// The first surface point along a world ray, if any.
    pub fn hit(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<Vector3<f64>> {
        self.nearest(origin, dir, MAX_RAY_LENGTH)
            .map(|h| origin + dir * h.t)
    }

    /// Whether the segment from `a` to `b` is free of surfaces (ends excluded by `tolerance`
    /// metres): the line of sight of a camera to a point.
    pub fn sees(&self, a: &Vector3<f64>, b: &Vector3<f64>, tolerance: f64) -> bool {
        let d = b - a;
        let length = d.norm();
        if length <= tolerance {
            return true;
        }
        let dir = d / length;
        self.nearest(a, &dir, length - tolerance).is_none()
    }

    fn target_albedo(&self, x: &Vector3<f64>) -> Option<Rgb> {
        self.targets.iter().find_map(|t| {
            let d = x - t.centre;
            (d.norm_squared() <= t.radius * t.radius).then(|| {
                let a = if d.dot(&t.u) * d.dot(&t.v) >= 0.0 {
                    0.92
                } else {
                    0.04
                };
                Rgb::new(a, a, a)
            })
        })
    }

    /// Radiance along a world ray: albedo × (ambient + (1 − ambient)·cos θ), the direct part
    /// dropped where another surface shadows the point (when `shadows`).
    pub fn trace(&self, origin: &Vector3<f64>, dir: &Vector3<f64>, shadows: bool) -> Rgb {
        match self.nearest(origin, dir, MAX_RAY_LENGTH) {
            Some(hit) => self.shade(&(origin + dir * hit.t), &hit, dir, shadows),
            None => self.background,
        }
    }

    /// The radiance of surface point `x` hit along `dir`.
    fn shade(&self, x: &Vector3<f64>, hit: &Hit, dir: &Vector3<f64>, shadows: bool) -> Rgb {
        let mut normal = hit.normal;
        if normal.dot(dir) > 0.0 {
            normal = -normal;
        }
        let albedo = match self.target_albedo(x) {
            Some(a) => a,
            None => {
                let texture_x = match &self.warp {
                    Some(w) => w(x),
                    None => *x,
                };
                let material = &self.materials[hit.material];
                match hit.planar {
                    Some(swap_yz) => {
                        let g = swap(&texture_x, swap_yz);
                        material.albedo_planar(g.x, g.y)
                    }
                    None => material.albedo(&texture_x),
                }
            }
        };
        let mut direct = normal.dot(&self.sun).max(0.0);
        if shadows && direct > 0.0 {
            let lifted = x + normal * 1e-6 * (1.0 + hit.t);
            if self.nearest(&lifted, &self.sun, MAX_RAY_LENGTH).is_some() {
                direct = 0.0;
            }
        }
        albedo * (self.ambient + (1.0 - self.ambient) * direct)
    }

    /// Radiance of one pixel from the rays of its samples. Geometry is always sampled n × n
    /// times; when every sample lands on the same smooth material (band-limited texture, no
    /// painted target) at nearly the same depth, shading — texture and shadow — is done once at
    /// their mean point, since it would differ by less than the texture's finest detail. Edges of
    /// objects, of land covers and of targets keep every sample.
    fn pixel(&self, centre: &Vector3<f64>, dirs: &[Vector3<f64>], shadows: bool) -> Rgb {
        let mut hits: [Option<Hit>; MAX_SAMPLES] = std::array::from_fn(|_| None);
        let n = dirs.len().min(MAX_SAMPLES);
        for (slot, dir) in hits.iter_mut().zip(dirs) {
            *slot = self.nearest(centre, dir, MAX_RAY_LENGTH);
        }
        let first = &hits[0];
        let uniform = n > 1
            && first.as_ref().is_some_and(|f| {
                self.materials[f.material].is_smooth()
                    && hits[1..n].iter().all(|h| {
                        h.as_ref().is_some_and(|h| {
                            h.material == f.material
                                && h.planar == f.planar
                                && (h.t - f.t).abs() < 1e-3 * f.t
                        })
                    })
            });
        if uniform {
            let mut x = Vector3::zeros();
            let mut dir = Vector3::zeros();
            for (h, d) in hits[..n].iter().zip(dirs) {
                if let Some(h) = h {
                    x += centre + d * h.t;
                    dir += d;
                }
            }
            x /= n as f64;
            if self.target_albedo(&x).is_none()
                && hits[..n].iter().zip(dirs).all(|(h, d)| {
                    h.as_ref()
                        .is_some_and(|h| self.target_albedo(&(centre + d * h.t)).is_none())
                })
            {
                let mut hit = hits[0].take().unwrap_or(Hit {
                    t: 0.0,
                    normal: Vector3::z(),
                    material: 0,
                    planar: None,
                });
                hit.normal = hits[1..n]
                    .iter()
                    .flatten()
                    .fold(hit.normal, |s, h| s + h.normal)
                    .normalize();
                // Texture at the samples' mean point (the pixel centre's footprint); shadows
                // from each sample's own surface point, since the mean point may lie a hair
                // inside a curved surface and would shadow itself.
                let albedo_light = self.shade(&x, &hit, &dir, false);
                if !shadows {
                    return albedo_light;
                }
                let mut normal = hit.normal;
                if normal.dot(&dir) > 0.0 {
                    normal = -normal;
                }
                let cos = normal.dot(&self.sun).max(0.0);
                let full = self.ambient + (1.0 - self.ambient) * cos;
                if cos == 0.0 || full <= 0.0 {
                    return albedo_light;
                }
                let lit = hits[1..n]
                    .iter()
                    .flatten()
                    .chain(std::iter::once(&hit))
                    .zip(dirs[1..n].iter().chain(std::iter::once(&dirs[0])))
                    .filter(|(h, d)| {
                        let p = centre + *d * h.t + normal * 1e-6 * (1.0 + h.t);
                        self.nearest(&p, &self.sun, MAX_RAY_LENGTH).is_none()
                    })
                    .count();
                let fraction = lit as f64 / n as f64;
                let shaded = self.ambient + (1.0 - self.ambient) * cos * fraction;
                return albedo_light * (shaded / full);
            }
        }
        let mut sum = Rgb::zeros();
        for (h, d) in hits[..n].iter().zip(dirs) {
            sum += match h {
                Some(h) => self.shade(&(centre + d * h.t), h, d, shadows),
                None => self.background,
            };
        }
        sum / n as f64
    }
}

/// Most samples per pixel the renderer takes (8 × 8).
const MAX_SAMPLES: usize = 64;

/// Rendering options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Samples per pixel along each axis (n × n per pixel, box filter; at most 8).
    pub supersampling: u32,
    /// Whether surfaces cast shadows (one more ray per sample).
    pub shadows: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            supersampling: 2,
            shadows: false,
        }
    }
}

/// A linear RGB image, row-major, values 0–1 (before exposure and noise).
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Pixels.
    pub data: Vec<[f32; 3]>,
}

impl RgbImage {
    /// Pixel at (col, row).
    pub fn get(&self, col: usize, row: usize) -> [f32; 3] {
        self.data[row * self.width + col]
    }

    /// The luminance image (Rec. 601 weights): what panchromatic film records.
    pub fn to_grey(&self) -> GreyImage {
        GreyImage {
            width: self.width,
            height: self.height,
            data: self
                .data
                .iter()
                .map(|p| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2])
                .collect(),
        }
    }
}

/// A grey image, row-major, values 0–1.
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

/// The camera-frame ray of every sample of every pixel, computed once per camera (undistortion
/// is iterative, and every image of an epoch shares the camera). Stored as f32 unit-z rays:
/// 1e-7 rad, far below a pixel.
pub struct RayTable {
    width: usize,
    height: usize,
    samples: usize,
    rays: Vec<Option<[f32; 2]>>,
}

impl RayTable {
    /// The rays of `camera` for images of `width` × `height` with n × n samples per pixel.
    pub fn new<C: CameraModel + Sync>(
        camera: &C,
        width: usize,
        height: usize,
        supersampling: u32,
    ) -> RayTable {
        let n = supersampling.clamp(1, 8) as usize;
        let mut rays = vec![None; width * height * n * n];
        rays.par_chunks_mut((width * n * n).max(1))
            .enumerate()
            .for_each(|(row, line)| {
                for (k, out) in line.iter_mut().enumerate() {
                    let (col, s) = (k / (n * n), k % (n * n));
                    let pixel = Vector2::new(
                        col as f64 + ((s % n) as f64 + 0.5) / n as f64,
                        row as f64 + ((s / n) as f64 + 0.5) / n as f64,
                    );
                    *out = camera
                        .unproject(&pixel)
                        .ok()
                        .map(|r| [(r.x / r.z) as f32, (r.y / r.z) as f32]);
                }
            });
        RayTable {
            width,
            height,
            samples: n,
            rays,
        }
    }
}

/// Renders `scene` from `pose` (`cam_from_world`) with the rays of a [`RayTable`]. Pixel (i, j)
/// covers [i, i+1) × [j, j+1) (docs/design.md); its samples sit at the centres of an n × n grid inside
/// it and are averaged (box filter).
pub fn render_rays(scene: &Scene, rays: &RayTable, pose: &Pose, shadows: bool) -> RgbImage {
    let (width, n2) = (rays.width, rays.samples * rays.samples);
    let world_from_cam = pose.rotation.inverse();
    let centre = pose.center();
    let mut data = vec![[0.0f32; 3]; width * rays.height];
    data.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(row, line)| {
            for (col, out) in line.iter_mut().enumerate() {
                let first = (row * width + col) * n2;
                let mut dirs = [Vector3::zeros(); MAX_SAMPLES];
                let mut count = 0;
                let mut missed = 0;
                for ray in &rays.rays[first..first + n2] {
                    match ray {
                        Some([x, y]) if count < MAX_SAMPLES => {
                            dirs[count] = world_from_cam * Vector3::new(*x as f64, *y as f64, 1.0);
                            count += 1;
                        }
                        _ => missed += 1,
                    }
                }
                let lit = if count > 0 {
                    scene.pixel(&centre, &dirs[..count], shadows) * count as f64
                } else {
                    Rgb::zeros()
                };
                let mean = (lit + scene.background * missed as f64) / n2 as f64;
                *out = [mean.x as f32, mean.y as f32, mean.z as f32];
            }
        });
    RgbImage {
        width,
        height: rays.height,
        data,
    }
}

/// Renders `scene` as seen by `camera` at `pose` (`cam_from_world`): [`render_rays`] with the
/// camera's [`RayTable`].
pub fn render<C: CameraModel + Sync>(
    scene: &Scene,
    camera: &C,
    width: usize,
    height: usize,
    pose: &Pose,
    options: &RenderOptions,
) -> Result<RgbImage, SynthError> {
    if width == 0 || height == 0 {
        return Err(SynthError::InvalidScene(format!(
            "image of {width} × {height} pixels"
        )));
    }
    let rays = RayTable::new(camera, width, height, options.supersampling);
    Ok(render_rays(scene, &rays, pose, options.shadows))
}
