//! Rigid poses `cam_from_world`: `X_cam = R X_world + t`, centre `C = -Rᵀ t`.

use nalgebra::{Matrix3, Rotation3, SMatrix, UnitQuaternion, Vector3, Vector6};

use crate::CoreError;

/// Tolerance on ‖RᵀR − I‖ (max abs entry) accepted when a rotation matrix is read from outside.
pub const ROTATION_TOLERANCE: f64 = 1e-9;

/// A rigid transform `cam_from_world`, with the rotation kept as a unit quaternion so that it stays
/// a rotation under repeated updates.
///
/// Compose left to right like the names say: `cam_from_model = cam_from_world * world_from_model`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Rotation part `R` of `X_cam = R X_world + t`.
    pub rotation: UnitQuaternion<f64>,
    /// Translation part `t` of `X_cam = R X_world + t` (not the centre).
    pub translation: Vector3<f64>,
}

impl Default for Pose {
    fn default() -> Self {
        Self::identity()
    }
}

impl Pose {
    /// The identity transform.
    pub fn identity() -> Self {
        Pose {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// From a unit quaternion and a translation.
    pub fn new(rotation: UnitQuaternion<f64>, translation: Vector3<f64>) -> Self {
        Pose {
            rotation,
            translation,
        }
    }

    /// From a rotation matrix `R` and translation `t`, checking that `R` is a proper rotation
    /// (orthonormal to [`ROTATION_TOLERANCE`], determinant +1) and every value is finite.
    pub fn from_rt(r: &Matrix3<f64>, t: &Vector3<f64>) -> Result<Self, CoreError> {
        if r.iter().chain(t.iter()).any(|v| !v.is_finite()) {
            return Err(CoreError::NonFinite {
                what: "pose (R, t)",
            });
        }
        let orthonormality_error = (r.transpose() * r - Matrix3::identity()).amax();
        let det = r.determinant();
        if orthonormality_error > ROTATION_TOLERANCE || det <= 0.0 {
            return Err(CoreError::NotARotation {
                orthonormality_error,
                det,
            });
        }
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r));
        Ok(Pose {
            rotation,
            translation: *t,
        })
    }

    /// From a rotation `cam_from_world` and the camera centre in world coordinates.
    pub fn from_rotation_and_center(rotation: UnitQuaternion<f64>, center: &Vector3<f64>) -> Self {
        Pose {
            rotation,
            translation: -(rotation * center),
        }
    }

    /// The camera at `center` looking at `target`, with image rows (y, down) as close as possible
    /// to world −Z: the usual oblique or nadir survey camera. `None` when the view direction is
    /// vertical or `center == target`, where the roll is undefined by this rule.
    pub fn look_at(center: &Vector3<f64>, target: &Vector3<f64>) -> Option<Self> {
        let z = (target - center).try_normalize(1e-12)?;
        // x = z × up points right when z is horizontal, so y = z × x points down.
        let x = z.cross(&Vector3::new(0.0, 0.0, 1.0)).try_normalize(1e-12)?;
        let y = z.cross(&x);
        // The rows of `cam_from_world` are the camera axes in world coordinates.
        let r = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
        Some(Pose::from_rotation_and_center(rotation, center))
    }

    /// The rotation matrix `R`.
    pub fn rotation_matrix(&self) -> Matrix3<f64> {
        self.rotation.to_rotation_matrix().into_inner()
    }

    /// The camera centre in world coordinates, `C = -Rᵀ t`.
    pub fn center(&self) -> Vector3<f64> {
        -(self.rotation.inverse() * self.translation)
    }

    /// Maps a world point into the camera frame.
    pub fn transform_point(&self, world_point: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * world_point + self.translation
    }

    /// The inverse transform (`world_from_cam` for a `cam_from_world` pose).
    pub fn inverse(&self) -> Pose {
        let inv = self.rotation.inverse();
        Pose {
            rotation: inv,
            translation: -(inv * self.translation),
        }
    }

    /// Applies a local update `delta = (δω, δt)`: `R ← exp([δω]×) R`, `t ← t + δt`.
    ///
    /// This is the parametrisation of the pose Jacobians in [`crate::camera`]: the derivative of the
    /// camera-frame point with respect to `δω` is `-[R X + t - t]× = -[R X]×` and to `δt` is `I`.
    pub fn retract(&self, delta: &Vector6<f64>) -> Pose {
        let omega = Vector3::new(delta[0], delta[1], delta[2]);
        let dt = Vector3::new(delta[3], delta[4], delta[5]);
        Pose {
            rotation: UnitQuaternion::from_scaled_axis(omega) * self.rotation,
            translation: self.translation + dt,
        }
    }

    /// Jacobian of `transform_point` with respect to the local pose update of [`Pose::retract`],
    /// evaluated at `world_point`: a 3×6 matrix `[-[R X]× | I]`.
    pub fn point_jacobian_wrt_pose(&self, world_point: &Vector3<f64>) -> SMatrix<f64, 3, 6> {
        let rx = self.rotation * world_point;
        let mut j = SMatrix::<f64, 3, 6>::zeros();
        // -[rx]× written out.
        j[(0, 1)] = rx.z;
        j[(0, 2)] = -rx.y;
        j[(1, 0)] = -rx.z;
        j[(1, 2)] = rx.x;
        j[(2, 0)] = rx.y;
        j[(2, 1)] = -rx.x;
        j[(0, 3)] = 1.0;
        j[(1, 4)] = 1.0;
        j[(2, 5)] = 1.0;
        j
    }
}

impl std::ops::Mul for Pose {
    type Output = Pose;

    /// `a_from_c = a_from_b * b_from_c`.
    fn mul(self, rhs: Pose) -> Pose {
        Pose {
            rotation: self.rotation * rhs.rotation,
            translation: self.rotation * rhs.translation + self.translation,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn sample() -> Pose {
        Pose::new(
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
            Vector3::new(1.0, -2.0, 3.0),
        )
    }

    #[test]
    fn center_is_mapped_to_camera_origin() {
        let p = sample();
        assert_relative_eq!(p.transform_point(&p.center()).norm(), 0.0, epsilon = 1e-12);
    }

    #[test]
    fn look_at_points_the_optical_axis_at_the_target() {
        let c = Vector3::new(30.0, -10.0, 25.0);
        let p = Pose::look_at(&c, &Vector3::zeros()).unwrap();
        let target_cam = p.transform_point(&Vector3::zeros());
        assert_relative_eq!(target_cam.x, 0.0, epsilon = 1e-12);
        assert_relative_eq!(target_cam.y, 0.0, epsilon = 1e-12);
        assert!(target_cam.z > 0.0);
        // Upright: a point above the target is imaged above it (negative y), and one to the
        // right of the view (looking from c towards the origin) at positive x.
        let above = p.transform_point(&Vector3::new(0.0, 0.0, 1.0));
        assert!(above.y < 0.0, "{above}");
        let forward = -c;
        let right = forward.cross(&Vector3::z());
        assert!(p.transform_point(&right).x > 0.0);
        assert!(Pose::look_at(&c, &c).is_none());
    }

    #[test]
    fn inverse_composes_to_identity() {
        let p = sample();
        let id = p * p.inverse();
        assert_relative_eq!(id.translation.norm(), 0.0, epsilon = 1e-12);
        assert_relative_eq!(id.rotation.angle(), 0.0, epsilon = 1e-12);
    }

    #[test]
    fn composition_order_is_left_to_right() {
        let a_from_b = sample();
        let b_from_c = Pose::new(
            UnitQuaternion::from_euler_angles(-0.5, 0.1, 0.2),
            Vector3::new(0.5, 0.0, -1.0),
        );
        let x = Vector3::new(0.3, 0.7, -0.2);
        let direct = a_from_b.transform_point(&b_from_c.transform_point(&x));
        assert_relative_eq!(
            (a_from_b * b_from_c).transform_point(&x),
            direct,
            epsilon = 1e-12
        );
    }

    #[test]
    fn from_rt_rejects_reflections_and_shears() {
        let reflection = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        assert!(matches!(
            Pose::from_rt(&reflection, &Vector3::zeros()),
            Err(CoreError::NotARotation { .. })
        ));
        let mut shear = Matrix3::identity();
        shear[(0, 1)] = 1e-3;
        assert!(Pose::from_rt(&shear, &Vector3::zeros()).is_err());
        let nan = Matrix3::from_element(f64::NAN);
        assert!(matches!(
            Pose::from_rt(&nan, &Vector3::zeros()),
            Err(CoreError::NonFinite { .. })
        ));
    }

    #[test]
    fn from_rt_round_trips_the_matrix() {
        let p = sample();
        let q = Pose::from_rt(&p.rotation_matrix(), &p.translation).unwrap();
        assert_relative_eq!(q.rotation_matrix(), p.rotation_matrix(), epsilon = 1e-15);
    }

    #[test]
    fn pose_jacobian_matches_central_differences() {
        let p = sample();
        let x = Vector3::new(0.4, -1.3, 5.0);
        let analytic = p.point_jacobian_wrt_pose(&x);
        let h = 1e-6;
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = h;
            let plus = p.retract(&d).transform_point(&x);
            d[k] = -h;
            let minus = p.retract(&d).transform_point(&x);
            let numeric = (plus - minus) / (2.0 * h);
            for r in 0..3 {
                assert_relative_eq!(analytic[(r, k)], numeric[r], epsilon = 1e-8);
            }
        }
    }
}
