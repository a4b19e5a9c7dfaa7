//! How firmly an adjusted block holds sets of its images as rigid bodies: the covariance of a
//! small rotation and translation of each set of cameras, from the block's own covariance.
//!
//! Why: a surface intersected from a set of cameras moves with them. If every camera of the set
//! turns by `δθ` about the set's centroid and shifts by `δτ` (centres `C ← C + δθ × (C − C̄) +
//! δτ`, rotations `R ← R·exp(−[δθ]×)`), every point it intersects moves the same way, and the
//! horizontal components of `δθ` are the tilt of its DEM (radians). A set's actual pose errors
//! are not rigid, but their least-squares rigid part is what tilts and shifts the surface as a
//! whole. That part is a linear function of the pose updates, so its covariance is `G S⁻¹ Gᵀ`,
//! with `S` the reduced camera system (the points eliminated): what every observation, prior
//! and control point of the block allows, including how weakly tie points hold one set to
//! another. Two sets' covariance block says how their relative motion is known: the tilt of a
//! DoD between two epochs.
//!
//! The fit weighs a camera's rotation by the squared lever arm (its distance to the ground), so
//! that a rotation and a shift that move the ground alike count alike.

use nalgebra::{DMatrix, Matrix3, SMatrix, Vector3, Vector6};
use timesift_core::Pose;

use crate::BundleError;
use crate::layout::Layout;
use crate::precision::CovarianceScale;
use crate::problem::BundleProblem;
use crate::solver::{center_jacobian, reduced_system};

/// The covariance (6k × 6k, k = `sets.len()`) of the rigid motions `(δθ, δτ)` of `sets` of
/// images (indices into `p.images`; fixed images and unknown indices are left out of a set):
/// set `s` at rows `6s..6s + 3` (rotation, radians, world axes) and `6s + 3..6s + 6`
/// (translation, metres). `lever_m` weighs rotations against shifts (the distance from the
/// cameras to the ground). A set with fewer than two free images is an error: one camera's
/// rigid motion is its pose, not a body's.
pub fn rigid_motion_covariance(
    p: &BundleProblem,
    sets: &[Vec<usize>],
    lever_m: f64,
    scale: CovarianceScale,
) -> Result<DMatrix<f64>, BundleError> {
    p.validate()?;
    let layout = Layout::new(p);
    let n = layout.num_camera_params;
    // Rows of G: 6 per set.
    let mut g = DMatrix::<f64>::zeros(6 * sets.len(), n);
    for (s, set) in sets.iter().enumerate() {
        let free: Vec<(usize, usize)> = set
            .iter()
            .filter_map(|&i| Some((i, layout.pose_offset.get(i).copied().flatten()?)))
            .collect();
        let poses: Vec<Pose> = free.iter().map(|&(i, _)| p.images[i].pose).collect();
        let rows = rigid_fit(&poses, lever_m)
            .map_err(|message| BundleError::InvalidProblem(format!("set {s}: {message}")))?;
        for (k, &(_, offset)) in free.iter().enumerate() {
            for r in 0..6 {
                for c in 0..6 {
                    g[(6 * s + r, offset + c)] = rows[k][(r, c)];
                }
            }
        }
    }
    let singular = || {
        BundleError::Singular(
            "the reduced camera system is not positive definite: the datum is not fixed"
                .to_string(),
        )
    };
    let system = reduced_system(p, &layout)?.ok_or_else(singular)?;
    let system = system.factor().ok_or_else(singular)?;
    let factor = scale.factor(p);
    // S⁻¹ Gᵀ, every row of G solved against the one factorisation.
    let mut solved = faer::Mat::<f64>::from_fn(n, g.nrows(), |c, r| g[(r, c)]);
    system.solve_in_place(&mut solved).ok_or_else(singular)?;
    let mut covariance = DMatrix::<f64>::zeros(g.nrows(), g.nrows());
    for r in 0..g.nrows() {
        for q in 0..g.nrows() {
            covariance[(q, r)] = factor * (0..n).map(|c| g[(q, c)] * solved[(c, r)]).sum::<f64>();
        }
    }
    Ok(covariance)
}

/// The rigid motion `(δθ, δτ)` (rotation in radians, world axes; translation in metres) that
/// best explains how `adjusted` differs from `reference`, pose for pose (the least-squares
/// rigid part of the differences, rotations weighed by `lever_m`², as in
/// [`rigid_motion_covariance`]): how far a set of oriented cameras, and the surface they
/// intersect, is turned and shifted from the truth. An error for fewer than two poses or
/// lists of unequal length.
pub fn rigid_motion(
    reference: &[Pose],
    adjusted: &[Pose],
    lever_m: f64,
) -> Result<Vector6<f64>, BundleError> {
    if reference.len() != adjusted.len() {
        return Err(BundleError::InvalidProblem(format!(
            "{} reference poses for {} adjusted ones",
            reference.len(),
            adjusted.len()
        )));
    }
    let rows = rigid_fit(reference, lever_m).map_err(BundleError::InvalidProblem)?;
    let mut motion = Vector6::zeros();
    for ((rows, r), a) in rows.iter().zip(reference).zip(adjusted) {
        // The local update that takes `r` to `a`: R_a = exp(δω) R_r, t_a = t_r + δt.
        let delta = a.rotation * r.rotation.inverse();
        let omega = delta.scaled_axis();
        let update = Vector6::new(
            omega.x,
            omega.y,
            omega.z,
            a.translation.x - r.translation.x,
            a.translation.y - r.translation.y,
            a.translation.z - r.translation.z,
        );
        motion += rows * update;
    }
    Ok(motion)
}

/// Per pose, the 6 × 6 block of the linear map from its update `(δω, δt)` to the least-squares
/// rigid motion `(δθ, δτ)` of all of them about their centroid.
fn rigid_fit(poses: &[Pose], lever_m: f64) -> Result<Vec<SMatrix<f64, 6, 6>>, String> {
    if poses.len() < 2 {
        return Err(format!(
            "{} free images; a rigid motion needs two at least",
            poses.len()
        ));
    }
    if !(lever_m > 0.0 && lever_m.is_finite()) {
        return Err(format!(
            "lever arm {lever_m} m: a positive distance was expected"
        ));
    }
    let centroid = poses
        .iter()
        .fold(Vector3::zeros(), |a, pose| a + pose.center())
        / poses.len() as f64;
    // A_i maps (δθ, δτ) to (δω_i, δC_i); M_i maps the pose update (δω, δt) to the same.
    let mut w = SMatrix::<f64, 6, 6>::identity();
    for k in 0..3 {
        w[(k, k)] = lever_m * lever_m;
    }
    let mut normal = SMatrix::<f64, 6, 6>::zeros();
    let mut parts = Vec::with_capacity(poses.len());
    for pose in poses {
        let a = rigid_jacobian(&pose.rotation_matrix(), &(pose.center() - centroid));
        let mut m = SMatrix::<f64, 6, 6>::zeros();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        m.fixed_view_mut::<3, 6>(3, 0)
            .copy_from(&center_jacobian(pose));
        normal += a.transpose() * w * a;
        parts.push(a.transpose() * w * m);
    }
    let inverse = normal
        .try_inverse()
        .ok_or_else(|| "the cameras fix no rigid motion".to_string())?;
    Ok(parts.into_iter().map(|part| inverse * part).collect())
}

/// `(δω, δC)` of a camera with rotation `r` at `lever` from the set's centroid when the set
/// turns by `δθ` and shifts by `δτ`: `δω = −R δθ`, `δC = δθ × lever + δτ`.
fn rigid_jacobian(r: &Matrix3<f64>, lever: &Vector3<f64>) -> SMatrix<f64, 6, 6> {
    let mut a = SMatrix::<f64, 6, 6>::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-r));
    a.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(-lever.cross_matrix()));
    a.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&Matrix3::identity());
    a
}
