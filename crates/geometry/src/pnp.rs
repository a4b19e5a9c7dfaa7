//! Absolute pose from n ≥ 6 points by DLT, iterative refinement of a pose on the reprojection error
//! through any camera model (Levenberg–Marquardt), and the RANSAC estimator (P3P minimal,
//! refinement as local optimisation).

use nalgebra::{Matrix6, SMatrix, Vector2, Vector3, Vector6};
use timesift_core::{CameraModel, Pose, project_world, project_world_with_jacobians};

use crate::GeometryError;
use crate::error::{check_finite, check_pairs};
use crate::p3p::{nearest_rotation, p3p};
use crate::ransac::Estimator;

/// DLT absolute pose from six or more non-coplanar points and their viewing rays.
pub fn dlt_pnp(rays: &[Vector3<f64>], world: &[Vector3<f64>]) -> Result<Pose, GeometryError> {
    let solver = "DLT PnP";
    check_pairs(solver, rays.len(), world.len(), 6)?;
    check_finite(solver, rays.iter().chain(world).flat_map(|v| v.iter()))?;
    let n = world.len() as f64;
    let centroid = world.iter().fold(Vector3::zeros(), |a, p| a + p) / n;
    let spread = world.iter().map(|p| (p - centroid).norm()).sum::<f64>() / n;
    if !(spread > 0.0) {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "all world points coincide",
        });
    }
    let k = 3f64.sqrt() / spread;
    let mut ata = SMatrix::<f64, 12, 12>::zeros();
    for (r, x) in rays.iter().zip(world) {
        if !(r.z.abs() > 0.0) {
            return Err(GeometryError::Degenerate {
                solver,
                reason: "a ray is parallel to the image plane",
            });
        }
        let (u, v) = (r.x / r.z, r.y / r.z);
        let xn = (x - centroid) * k;
        let h = [xn.x, xn.y, xn.z, 1.0];
        let mut r1 = SMatrix::<f64, 12, 1>::zeros();
        let mut r2 = SMatrix::<f64, 12, 1>::zeros();
        for c in 0..4 {
            r1[c] = -h[c];
            r1[8 + c] = u * h[c];
            r2[4 + c] = -h[c];
            r2[8 + c] = v * h[c];
        }
        ata += r1 * r1.transpose() + r2 * r2.transpose();
    }
    let eig = ata.symmetric_eigen();
    let mut order: Vec<usize> = (0..12).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    if !(eig.eigenvalues[order[1]] > 1e-14 * eig.eigenvalues[order[11]]) {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "points are coplanar or too few are distinct (use P3P + refinement)",
        });
    }
    let p = eig.eigenvectors.column(order[0]);
    let mut m = nalgebra::Matrix3::new(p[0], p[1], p[2], p[4], p[5], p[6], p[8], p[9], p[10]);
    let mut col = Vector3::new(p[3], p[7], p[11]);
    // Points must have positive depth: fix the overall sign by the majority.
    let in_front = world
        .iter()
        .filter(|x| (m.row(2) * ((*x - centroid) * k)).x + col.z > 0.0)
        .count();
    if 2 * in_front < world.len() {
        m = -m;
        col = -col;
    }
    let svd = m.svd(false, false);
    let s = svd.singular_values.mean();
    if !(s > 0.0) {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "rank-deficient projection",
        });
    }
    let r = nearest_rotation(&m);
    if m.determinant() < 0.0 {
        return Err(GeometryError::NoSolution {
            solver,
            reason: "the projection is a reflection",
        });
    }
    let t = -(r * centroid) + col / (s * k);
    Ok(Pose::new(
        nalgebra::UnitQuaternion::from_rotation_matrix(&r),
        t,
    ))
}

/// Options of [`refine_pose`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineOptions {
    /// Most Levenberg–Marquardt iterations.
    pub max_iterations: usize,
    /// Stop when the relative cost decrease falls below this.
    pub function_tolerance: f64,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            max_iterations: 50,
            function_tolerance: 1e-12,
        }
    }
}

/// Refines `cam_from_world` by Levenberg–Marquardt on the (optionally weighted) squared reprojection
/// error of world points through the camera model. Points that do not project are ignored.
pub fn refine_pose(
    camera: &dyn CameraModel,
    start: &Pose,
    world: &[Vector3<f64>],
    pixels: &[Vector2<f64>],
    weights: Option<&[f64]>,
    options: &RefineOptions,
) -> Result<Pose, GeometryError> {
    let solver = "pose refinement";
    check_pairs(solver, world.len(), pixels.len(), 3)?;
    if let Some(w) = weights {
        check_pairs(solver, world.len(), w.len(), 3)?;
    }
    let cost = |pose: &Pose| -> f64 {
        world
            .iter()
            .zip(pixels)
            .enumerate()
            .map(|(i, (x, u))| {
                let w = weights.map_or(1.0, |w| w[i]);
                project_world(camera, pose, x)
                    // A point that stops projecting costs as much as a huge residual, so no
                    // step can lower the cost by pushing points behind the camera.
                    .map_or(w * 1e12, |p| w * (p - u).norm_squared())
            })
            .sum()
    };
    let mut pose = *start;
    let mut current = cost(&pose);
    let mut mu = 1e-4;
    for _ in 0..options.max_iterations {
        let mut h = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        let mut used = 0;
        for (i, (x, u)) in world.iter().zip(pixels).enumerate() {
            let Ok(j) = project_world_with_jacobians(camera, &pose, x, None) else {
                continue;
            };
            let w = weights.map_or(1.0, |w| w[i]);
            let r = j.pixel - u;
            h += j.d_pose.transpose() * j.d_pose * w;
            g += j.d_pose.transpose() * r * w;
            used += 1;
        }
        if used < 3 {
            return Err(GeometryError::NoSolution {
                solver,
                reason: "fewer than three points project into the camera",
            });
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = h;
            for k in 0..6 {
                damped[(k, k)] += mu * h[(k, k)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|c| -c.solve(&g)) else {
                mu *= 10.0;
                continue;
            };
            let candidate = pose.retract(&step);
            let c = cost(&candidate);
            if c < current {
                let decrease = (current - c) / current.max(1e-300);
                pose = candidate;
                current = c;
                mu = (mu * 0.3).max(1e-12);
                improved = decrease > options.function_tolerance;
                break;
            }
            mu *= 10.0;
        }
        if !improved {
            break;
        }
    }
    Ok(pose)
}

/// RANSAC estimator of an absolute pose from 2-D/3-D correspondences: P3P on the unprojected rays,
/// refinement through the camera model as local optimisation; residuals in pixels².
pub struct AbsolutePoseEstimator<'a> {
    /// The camera of the image.
    pub camera: &'a dyn CameraModel,
    /// Measured pixels.
    pub pixels: &'a [Vector2<f64>],
    /// Their viewing rays (`camera.unproject`).
    pub rays: &'a [Vector3<f64>],
    /// World points.
    pub world: &'a [Vector3<f64>],
}

impl Estimator for AbsolutePoseEstimator<'_> {
    type Model = Pose;
    const NAME: &'static str = "absolute pose RANSAC";
    fn min_samples(&self) -> usize {
        3
    }
    fn num_data(&self) -> usize {
        self.world.len().min(self.pixels.len()).min(self.rays.len())
    }
    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Pose>) {
        let r: Vec<_> = sample.iter().map(|&i| self.rays[i]).collect();
        let w: Vec<_> = sample.iter().map(|&i| self.world[i]).collect();
        if let Ok(poses) = p3p(&r, &w) {
            models.extend(poses);
        }
    }
    fn fit_nonminimal(&self, idx: &[usize], weights: Option<&[f64]>, start: &Pose) -> Option<Pose> {
        let w: Vec<_> = idx.iter().map(|&i| self.world[i]).collect();
        let p: Vec<_> = idx.iter().map(|&i| self.pixels[i]).collect();
        refine_pose(
            self.camera,
            start,
            &w,
            &p,
            weights,
            &RefineOptions::default(),
        )
        .ok()
    }
    fn residual_sq(&self, pose: &Pose, i: usize) -> f64 {
        project_world(self.camera, pose, &self.world[i])
            .map_or(f64::INFINITY, |p| (p - self.pixels[i]).norm_squared())
    }
}
