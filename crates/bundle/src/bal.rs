//! BAL problems as bundle problems: every BAL camera becomes an image with its own camera group
//! whose `f`, `k1`, `k2` are free, principal point fixed at the given position, in timesift's
//! conventions (camera frame x right, y down, z forward; pixels from the top-left corner).
//! `R = D R_bal`, `t = D t_bal` with `D = diag(1, −1, −1)`; `u = cx + x`, `v = cy − y`.

use nalgebra::{Matrix3, UnitQuaternion, Vector2, Vector3};
use timesift_core::{BrownCamera, Camera, Pose};
use timesift_io::bal::BalProblem;

use crate::BundleError;
use crate::problem::{BundleImage, BundlePoint, BundleProblem, CameraGroup, Observation};

/// Converts a BAL problem. `principal_points[c]` is `(cx, cy)` in pixels for camera `c`, and
/// `(width, height)` the image size (the brown model's principal point is an offset from the
/// image centre).
pub fn from_bal(
    bal: &BalProblem,
    principal_points: &[(f64, f64)],
    size: (u32, u32),
) -> Result<BundleProblem, BundleError> {
    if principal_points.len() != bal.cameras.len() {
        return Err(BundleError::InvalidProblem(format!(
            "{} principal points for {} cameras",
            principal_points.len(),
            bal.cameras.len()
        )));
    }
    let d = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let mut problem = BundleProblem::default();
    for (c, cam) in bal.cameras.iter().enumerate() {
        let r_bal = UnitQuaternion::from_scaled_axis(Vector3::new(cam[0], cam[1], cam[2]));
        let r = d * r_bal.to_rotation_matrix().into_inner();
        let t = d * Vector3::new(cam[3], cam[4], cam[5]);
        let pose = Pose::from_rt(&r, &t)
            .map_err(|e| BundleError::InvalidProblem(format!("camera {c}: {e}")))?;
        let mut brown = BrownCamera::new(size.0, size.1, cam[6])
            .map_err(|e| BundleError::InvalidProblem(format!("camera {c}: {e}")))?;
        brown.cx = principal_points[c].0 - 0.5 * size.0 as f64;
        brown.cy = principal_points[c].1 - 0.5 * size.1 as f64;
        brown.k1 = cam[7];
        brown.k2 = cam[8];
        problem.groups.push(CameraGroup::with_free(
            Camera::Brown(brown),
            &["f", "k1", "k2"],
        )?);
        problem.images.push(BundleImage {
            pose,
            group: c,
            fixed: false,
        });
    }
    problem.points = bal
        .points
        .iter()
        .map(|p| BundlePoint {
            position: Vector3::new(p[0], p[1], p[2]),
            fixed: false,
        })
        .collect();
    problem.observations = bal
        .observations
        .iter()
        .map(|o| {
            let (cx, cy) = principal_points[o.camera];
            Observation {
                image: o.camera,
                point: o.point,
                pixel: Vector2::new(cx + o.xy[0], cy - o.xy[1]),
                sigma_px: 1.0,
            }
        })
        .collect();
    Ok(problem)
}
