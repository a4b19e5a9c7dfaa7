//! Triangulation: two-view midpoint, multi-view DLT, quality checks (angle, depth, reprojection),
//! and the weighted intersection of control or check points measured in several images, with the
//! covariance of the result.

use nalgebra::{Matrix3, Matrix4, Vector2, Vector3};
use timesift_core::{CameraModel, Pose, project_world, project_world_with_jacobians};

use crate::GeometryError;
use crate::error::check_finite;

/// The world point halfway between the closest points of two viewing rays.
/// `ray1` and `ray2` are directions in the frames of `cam1_from_world` and `cam2_from_world`.
pub fn triangulate_two_view_midpoint(
    cam1_from_world: &Pose,
    ray1: &Vector3<f64>,
    cam2_from_world: &Pose,
    ray2: &Vector3<f64>,
) -> Result<Vector3<f64>, GeometryError> {
    let solver = "midpoint triangulation";
    check_finite(solver, ray1.iter().chain(ray2.iter()))?;
    let c1 = cam1_from_world.center();
    let c2 = cam2_from_world.center();
    let d1 = (cam1_from_world.rotation.inverse() * ray1).normalize();
    let d2 = (cam2_from_world.rotation.inverse() * ray2).normalize();
    let b = c2 - c1;
    let cos = d1.dot(&d2);
    let denom = 1.0 - cos * cos;
    if !(denom > 1e-14) || b.norm() == 0.0 {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "parallel rays or zero baseline",
        });
    }
    // Minimise |c1 + s d1 − c2 − u d2|².
    let (bd1, bd2) = (b.dot(&d1), b.dot(&d2));
    let s = (bd1 - cos * bd2) / denom;
    let u = (cos * bd1 - bd2) / denom;
    Ok(0.5 * ((c1 + d1 * s) + (c2 + d2 * u)))
}

/// Multi-view linear (DLT) triangulation from `(cam_from_world, ray)` pairs, minimising the
/// algebraic error `Σ |[r]× (R X + t)|²` over homogeneous X.
///
/// Solved in a frame centred on the cameras and scaled to their spread (Hartley's
/// normalisation): in projected coordinates (hundreds of thousands of metres) the translation
/// column would otherwise dwarf the rotation's and the smallest eigenvector would drown in
/// rounding, failing as "rays do not intersect".
pub fn triangulate_dlt(views: &[(Pose, Vector3<f64>)]) -> Result<Vector3<f64>, GeometryError> {
    let solver = "DLT triangulation";
    if views.len() < 2 {
        return Err(GeometryError::NotEnoughData {
            solver,
            needed: 2,
            got: views.len(),
        });
    }
    for (pose, _) in views {
        check_finite(solver, pose.translation.iter())?;
    }
    let n = views.len() as f64;
    let origin = views
        .iter()
        .fold(Vector3::zeros(), |sum, (pose, _)| sum + pose.center())
        / n;
    let spread = (views
        .iter()
        .map(|(pose, _)| (pose.center() - origin).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt();
    // Centres that coincide to rounding keep the unit scale: blown up to one, their rounding
    // would pass for a baseline. (Distinct rays from one centre intersect there.)
    let scale = if spread > 1e-12 * (origin.norm() + 1.0) {
        spread
    } else {
        1.0
    };
    let mut ata = Matrix4::<f64>::zeros();
    for (pose, ray) in views {
        check_finite(solver, ray.iter())?;
        let r = ray.normalize();
        let rot = pose.rotation_matrix();
        let skew = r.cross_matrix();
        // Rows of [r]× [R | t'] for the normalised point X' = (X − origin) / scale:
        // R X + t = scale · (R X' + t'), t' = (R origin + t) / scale.
        let m = skew * rot;
        let mt = skew * ((rot * origin + pose.translation) / scale);
        for row in 0..3 {
            let a = nalgebra::Vector4::new(m[(row, 0)], m[(row, 1)], m[(row, 2)], mt[row]);
            ata += a * a.transpose();
        }
    }
    let eig = ata.symmetric_eigen();
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .fold(
            (0, f64::INFINITY),
            |acc, (i, &v)| if v < acc.1 { (i, v) } else { acc },
        );
    let mut sorted: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    sorted.sort_by(f64::total_cmp);
    if !(sorted[1] > 1e-14 * sorted[3]) {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "rays do not intersect in one point (zero baseline?)",
        });
    }
    let h = eig.eigenvectors.column(imin);
    if h[3].abs() < 1e-12 * h.norm() {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "point at infinity",
        });
    }
    Ok(origin + Vector3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]) * scale)
}

/// Angle (radians) at `point` between the rays to two camera centres.
pub fn triangulation_angle(
    center1: &Vector3<f64>,
    center2: &Vector3<f64>,
    point: &Vector3<f64>,
) -> f64 {
    let a = (center1 - point).normalize();
    let b = (center2 - point).normalize();
    a.dot(&b).clamp(-1.0, 1.0).acos()
}

/// One image measurement for triangulation checks and weighted intersection.
#[derive(Clone, Copy)]
pub struct PixelObservation<'a> {
    /// The camera model of the image.
    pub camera: &'a dyn CameraModel,
    /// `cam_from_world` of the image.
    pub pose: Pose,
    /// Measured pixel.
    pub pixel: Vector2<f64>,
    /// Standard deviation of the measurement, pixels.
    pub sigma_px: f64,
}

/// Thresholds a triangulated point must pass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangulationCheck {
    /// Smallest accepted largest triangulation angle, degrees.
    pub min_angle_deg: f64,
    /// Largest accepted reprojection error, pixels.
    pub max_reprojection_px: f64,
}

impl Default for TriangulationCheck {
    fn default() -> Self {
        TriangulationCheck {
            min_angle_deg: 1.5,
            max_reprojection_px: 4.0,
        }
    }
}

/// What the checks measured on a point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointQuality {
    /// Largest angle between any two rays, degrees.
    pub max_angle_deg: f64,
    /// Largest reprojection error, pixels (infinite when behind a camera).
    pub max_reprojection_px: f64,
    /// Whether the point is in front of every camera.
    pub in_front: bool,
}

impl PointQuality {
    /// Whether the point passes the thresholds.
    pub fn passes(&self, check: &TriangulationCheck) -> bool {
        self.in_front
            && self.max_angle_deg >= check.min_angle_deg
            && self.max_reprojection_px <= check.max_reprojection_px
    }
}

/// Measures triangulation angle, depth sign and reprojection error of a point.
pub fn point_quality(point: &Vector3<f64>, observations: &[PixelObservation<'_>]) -> PointQuality {
    let mut q = PointQuality {
        max_angle_deg: 0.0,
        max_reprojection_px: 0.0,
        in_front: true,
    };
    for (i, a) in observations.iter().enumerate() {
        if a.pose.transform_point(point).z <= 0.0 {
            q.in_front = false;
        }
        let err = project_world(a.camera, &a.pose, point)
            .map(|p| (p - a.pixel).norm())
            .unwrap_or(f64::INFINITY);
        q.max_reprojection_px = q.max_reprojection_px.max(err);
        for b in &observations[i + 1..] {
            let ang = triangulation_angle(&a.pose.center(), &b.pose.center(), point).to_degrees();
            q.max_angle_deg = q.max_angle_deg.max(ang);
        }
    }
    q
}

/// A point intersected from weighted image measurements.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntersectedPoint {
    /// World position.
    pub position: Vector3<f64>,
    /// Covariance of the position from the measurement sigmas (a priori), m².
    pub covariance: Matrix3<f64>,
    /// Posterior variance factor (χ² / redundancy); 1 when the sigmas are right.
    pub variance_factor: f64,
    /// RMS reprojection error, pixels.
    pub rms_px: f64,
}

/// Weighted least-squares intersection of a point measured in several oriented images (markers
/// of GCPs and check points): DLT start, then Gauss–Newton on the sigma-weighted reprojection
/// error through each camera model. Fails with fewer than two measurements, a zero baseline, or
/// a point that ends behind a camera.
pub fn intersect_weighted(
    observations: &[PixelObservation<'_>],
) -> Result<IntersectedPoint, GeometryError> {
    let solver = "weighted intersection";
    if observations.len() < 2 {
        return Err(GeometryError::NotEnoughData {
            solver,
            needed: 2,
            got: observations.len(),
        });
    }
    let mut views = Vec::with_capacity(observations.len());
    for o in observations {
        if !(o.sigma_px > 0.0) {
            return Err(GeometryError::Degenerate {
                solver,
                reason: "measurement sigma must be positive",
            });
        }
        let ray = o
            .camera
            .unproject(&o.pixel)
            .map_err(|_| GeometryError::NoSolution {
                solver,
                reason: "a pixel cannot be unprojected through its camera",
            })?;
        views.push((o.pose, ray));
    }
    let mut x = triangulate_dlt(&views)?;
    // Normal equations and χ² at a point.
    let normal_at = |x: &Vector3<f64>| -> Result<(Matrix3<f64>, Vector3<f64>, f64), GeometryError> {
        let mut normal = Matrix3::zeros();
        let mut rhs = Vector3::zeros();
        let mut chi2 = 0.0;
        for o in observations {
            let j = project_world_with_jacobians(o.camera, &o.pose, x, None).map_err(|_| {
                GeometryError::NoSolution {
                    solver,
                    reason: "point behind a camera",
                }
            })?;
            let w = 1.0 / (o.sigma_px * o.sigma_px);
            let r = o.pixel - j.pixel;
            chi2 += r.norm_squared() * w;
            normal += j.d_world_point.transpose() * j.d_world_point * w;
            rhs += j.d_world_point.transpose() * r * w;
        }
        Ok((normal, rhs, chi2))
    };
    let mut converged = false;
    for _ in 0..50 {
        let (normal, rhs, _) = normal_at(&x)?;
        let Some(step) = normal.cholesky().map(|c| c.solve(&rhs)) else {
            return Err(GeometryError::Degenerate {
                solver,
                reason: "normal equations singular (zero baseline)",
            });
        };
        x += step;
        if step.norm() <= 1e-12 * (1.0 + x.norm()) {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(GeometryError::NoSolution {
            solver,
            reason: "Gauss–Newton did not converge in 50 iterations",
        });
    }
    // Covariance and χ² at the final point.
    let (normal, _, chi2) = normal_at(&x)?;
    let covariance = normal.try_inverse().ok_or(GeometryError::Degenerate {
        solver,
        reason: "normal equations singular (zero baseline)",
    })?;
    let redundancy = 2 * observations.len() as i64 - 3;
    let mut sq = 0.0;
    for o in observations {
        let p = project_world(o.camera, &o.pose, &x).map_err(|_| GeometryError::NoSolution {
            solver,
            reason: "point behind a camera",
        })?;
        sq += (p - o.pixel).norm_squared();
    }
    Ok(IntersectedPoint {
        position: x,
        covariance,
        // At least two measurements: the redundancy is at least 1.
        variance_factor: chi2 / redundancy.max(1) as f64,
        rms_px: (sq / observations.len() as f64).sqrt(),
    })
}
