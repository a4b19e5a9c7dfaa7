//! The geometry of a synthetic scene's epoch as it was rendered — the true surface, the true
//! cameras, which of them see a point —, and an orientation made from it (`out/cameras.json`
//! from `truth/cameras.json`, sparse points sampled on the true surface), so that the stages
//! after `align` can be run and judged on the true cameras. Used by `cargo xtask bench dense`
//! and `bench raster`, and the tests of the dense and raster stages.

use std::path::Path;

use nalgebra::{UnitQuaternion, Vector2, Vector3};
use timesift_core::{Camera, CameraModel, Pose, project_world};
use timesift_io::cameras_json::{Reconstruction, read_cameras_json, write_cameras_json};
use timesift_io::colmap::{ColmapPoint, from_reconstruction, write_colmap_text};
use timesift_synth::render::Scene;
use timesift_synth::scene::{Frame, SceneSpec};
use timesift_synth::terrain::Heightfield;

use timesift_io::layout::Layout;

use crate::EvalError;

fn synth_error(e: impl std::fmt::Display) -> EvalError {
    EvalError::Scene(e.to_string())
}

/// One epoch of a synthetic scene, in the scene's local frame (world minus `spec.origin`).
pub struct TrueEpoch<'a> {
    /// The scene.
    pub spec: &'a SceneSpec,
    /// Epoch index.
    pub epoch: usize,
    field: Heightfield,
    scene: Scene,
    /// Indices of the epoch's images in `truth/cameras.json`.
    pub images: Vec<usize>,
    /// Camera and `cam_from_local` of each of them.
    pub cameras: Vec<(Camera, Pose)>,
    /// Ground sampling distance, metres: the median over the images of the range of the
    /// central ray over the focal length.
    pub gsd: f64,
}

impl<'a> TrueEpoch<'a> {
    /// Epoch `epoch` (named `name`) of `spec`, with the true cameras of `truth`.
    pub fn new(
        spec: &'a SceneSpec,
        epoch: usize,
        truth: &Reconstruction,
        name: &str,
    ) -> Result<TrueEpoch<'a>, EvalError> {
        let field = spec.heightfield(epoch);
        let scene = spec.scene(&field, epoch).map_err(synth_error)?;
        let images: Vec<usize> = truth
            .images
            .iter()
            .enumerate()
            .filter(|(_, im)| im.epoch == name && im.pose.is_some())
            .map(|(k, _)| k)
            .collect();
        let world_from_local = Pose::new(UnitQuaternion::identity(), spec.origin);
        let mut cameras = Vec::with_capacity(images.len());
        for &k in &images {
            let im = &truth.images[k];
            let camera = truth
                .cameras
                .get(&im.camera)
                .ok_or_else(|| synth_error(format!("truth camera {} is not defined", im.camera)))?;
            cameras.push((
                camera.clone(),
                im.pose.unwrap_or_default() * world_from_local,
            ));
        }
        let mut ranges: Vec<f64> = cameras
            .iter()
            .filter_map(|(camera, pose)| {
                let centre = Vector2::new(camera.width() as f64, camera.height() as f64) * 0.5;
                let ray = camera.unproject(&centre).ok()?;
                let dir = (pose.rotation.inverse() * ray).normalize();
                let hit = scene.hit(&pose.center(), &dir)?;
                Some((hit - pose.center()).norm() / focal(camera))
            })
            .collect();
        if ranges.is_empty() {
            return Err(synth_error(format!(
                "no true image of epoch {name} sees the scene"
            )));
        }
        ranges.sort_by(f64::total_cmp);
        let gsd = ranges[ranges.len() / 2];
        Ok(TrueEpoch {
            spec,
            epoch,
            field,
            scene,
            images,
            cameras,
            gsd,
        })
    }

    /// (g₁, g₂, h) of a local point: grid position and height (for a wall, the depth).
    pub fn grid_of(&self, p: &Vector3<f64>) -> (f64, f64, f64) {
        match self.spec.frame {
            Frame::Ground => (p.x, p.y, p.z),
            Frame::Wall => (p.x, p.z, p.y),
        }
    }

    /// The true surface height at grid position (g₁, g₂).
    pub fn surface_height(&self, g1: f64, g2: f64) -> Option<f64> {
        self.spec.surface(&self.field, self.epoch, g1, g2)
    }

    /// The true surface point at grid position (g₁, g₂), local frame.
    pub fn surface_point(&self, g1: f64, g2: f64) -> Option<Vector3<f64>> {
        Some(
            self.spec
                .frame
                .to_local(g1, g2, self.surface_height(g1, g2)?),
        )
    }

    /// Where camera `k` sees local point `x`, at least 4 pixels inside its photograph (the
    /// image; for a film scan, the frame inside its dark film edge, where the marks sit);
    /// `None` behind it, outside, or beyond the fold of its distortion polynomial (where points
    /// far outside the field project back into the image).
    pub fn pixel(&self, k: usize, x: &Vector3<f64>) -> Option<Vector2<f64>> {
        let (camera, pose) = &self.cameras[k];
        let p = project_world(camera, pose, x).ok()?;
        let ray = pose.transform_point(x);
        let back = camera.unproject(&p).ok()?;
        if (back.x - ray.x / ray.z).abs() > 1e-6 || (back.y - ray.y / ray.z).abs() > 1e-6 {
            return None;
        }
        let margin = 4.0
            + self.spec.epochs[self.epoch]
                .film
                .as_ref()
                .map_or(0.0, |f| f.edge);
        (p.x > margin
            && p.y > margin
            && p.x < camera.width() as f64 - margin
            && p.y < camera.height() as f64 - margin)
            .then_some(p)
    }

    /// The cameras (indices into [`TrueEpoch::cameras`]) that see local point `x` unoccluded.
    pub fn seeing(&self, x: &Vector3<f64>) -> Vec<usize> {
        (0..self.cameras.len())
            .filter(|&k| {
                self.pixel(k, x).is_some()
                    && self
                        .scene
                        .sees(&self.cameras[k].1.center(), x, 2.0 * self.gsd)
            })
            .collect()
    }
}

/// The focal length of a camera, pixels.
pub fn focal(camera: &Camera) -> f64 {
    let mut p = vec![0.0; camera.num_params()];
    camera.params(&mut p);
    p[0]
}

/// Writes the orientation of a synthetic project from its truth: `out/cameras.json` as
/// `truth/cameras.json`, and `out/colmap/` with sparse points on each epoch's true surface
/// every `spacing_gsd` ground sampling distances, observed by the images that see them. Returns
/// the number of sparse points. Scans of film epochs need their interior orientations as the
/// pipeline gives them: the caller runs the fiducials step afterwards (the root's
/// `stages::fiducials_stage`), so that the stages after `align` see them in their cameras' frames.
pub fn write_true_orientation(
    dir: &Path,
    spec: &SceneSpec,
    spacing_gsd: f64,
) -> Result<usize, EvalError> {
    let layout = Layout::new(dir);
    let truth = read_cameras_json(&layout.truth_cameras())?;
    write_cameras_json(&layout.cameras_json(), &truth)?;
    // The COLMAP model carries the sparse points; its cameras are not read back (cameras.json
    // is the orientation), and COLMAP has no skew or r⁸ term (film scans have skew): drop them.
    let mut colmap_cameras = truth.clone();
    for camera in colmap_cameras.cameras.values_mut() {
        if let Camera::Brown(b) = camera {
            b.b2 = 0.0;
            b.k4 = 0.0;
        }
    }
    let mut model = from_reconstruction(&colmap_cameras).map_err(synth_error)?;
    let mut next = 1u64;
    for (e, epoch) in spec.epochs.iter().enumerate() {
        let t = TrueEpoch::new(spec, e, &truth, &epoch.name)?;
        let step = spacing_gsd * t.gsd;
        let (x0, y0, cell, nx, ny) = spec.grid;
        let (w, h) = ((nx - 1) as f64 * cell, (ny - 1) as f64 * cell);
        let mut g2 = y0 + 0.5 * step;
        while g2 < y0 + h {
            let mut g1 = x0 + 0.5 * step;
            while g1 < x0 + w {
                if let Some(x) = t.surface_point(g1, g2) {
                    let seen = t.seeing(&x);
                    if seen.len() >= 2 {
                        let mut track = Vec::with_capacity(seen.len());
                        for &k in &seen {
                            let id = t.images[k] as u32 + 1;
                            let pixel = t.pixel(k, &x).unwrap_or_default();
                            if let Some(im) = model.images.get_mut(&id) {
                                track.push((id, im.points2d.len() as u32));
                                im.points2d.push((pixel.x, pixel.y, next as i64));
                            }
                        }
                        model.points.insert(
                            next,
                            ColmapPoint {
                                xyz: x + spec.origin,
                                rgb: [128, 128, 128],
                                error: 0.0,
                                track,
                            },
                        );
                        next += 1;
                    }
                }
                g1 += step;
            }
            g2 += step;
        }
    }
    write_colmap_text(&layout.colmap_dir(), &model)?;
    Ok(next as usize - 1)
}

/// Writes, as each epoch's dense cloud (`out/epochs/<epoch>/dense.laz`), its true surface
/// sampled at random positions — on average one point per (`spacing_gsd` GSD)², with Gaussian
/// height noise of `noise_gsd` GSD —: a stand-in for the dense stage with a known error, for
/// the DEM and ortho stages' tests and benches (ground scenes). Returns each epoch's name and
/// GSD (metres).
pub fn write_sampled_clouds(
    dir: &Path,
    spec: &SceneSpec,
    spacing_gsd: f64,
    noise_gsd: f64,
    seed: u64,
) -> Result<Vec<(String, f64)>, EvalError> {
    let layout = Layout::new(dir);
    let truth = read_cameras_json(&layout.truth_cameras())?;
    let crs: timesift_io::coords::Crs = spec.crs.parse().map_err(synth_error)?;
    let mut rng = timesift_core::SeededRng::new(seed);
    let mut out = Vec::new();
    for (e, epoch) in spec.epochs.iter().enumerate() {
        let t = TrueEpoch::new(spec, e, &truth, &epoch.name)?;
        let (x0, y0, cell, nx, ny) = spec.grid;
        let (w, h) = ((nx - 1) as f64 * cell, (ny - 1) as f64 * cell);
        let spacing = spacing_gsd * t.gsd;
        let n = (w * h / (spacing * spacing)) as usize;
        let mut positions = Vec::with_capacity(n);
        for _ in 0..n {
            let g1 = rng.uniform_range(x0, x0 + w);
            let g2 = rng.uniform_range(y0, y0 + h);
            let noise = noise_gsd * t.gsd * rng.normal();
            if let Some(z) = t.surface_height(g1, g2) {
                let p = spec.frame.to_local(g1, g2, z + noise) + spec.origin;
                positions.push([p.x, p.y, p.z]);
            }
        }
        let path = layout.dense_cloud(&epoch.name);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|e| timesift_io::IoError::io(parent, e))?;
        }
        let cloud = timesift_io::pointcloud::PointCloud {
            positions,
            colors: None,
            attributes: Vec::new(),
            crs,
        };
        timesift_io::pointcloud::write_las(&path, &cloud, &Default::default())?;
        out.push((epoch.name.clone(), t.gsd));
    }
    Ok(out)
}
