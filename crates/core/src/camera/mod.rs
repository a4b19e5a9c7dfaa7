//! Camera models behind one trait, and projection of world points through a pose.
//!
//! A model maps a point in the camera frame (x right, y down, z forward) to a pixel with the
//! docs/design.md convention (centre of the top-left pixel at (0.5, 0.5)). Intrinsic parameters are a flat
//! list whose order is fixed per model ([`CameraModel::param_names`]), so solvers can hold them in one
//! vector per camera group and mask any subset as fixed.

mod brown;
mod pinhole;

pub use brown::BrownCamera;
pub use pinhole::PinholeCamera;

/// The most pixels a camera's image may have: 2³¹ (a 46,000-pixel square), what every buffer
/// made from a camera's size (dense maps, undistortion tables) can hold. A camera file claiming
/// more is corrupt, whatever the memory.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 31;

/// A positive image size of at most [`MAX_IMAGE_PIXELS`] pixels.
fn check_image_size(width: u32, height: u32) -> Result<(), crate::CoreError> {
    let pixels = u64::from(width) * u64::from(height);
    if width == 0 || height == 0 || pixels > MAX_IMAGE_PIXELS {
        return Err(crate::CoreError::InvalidCameraParameter {
            name: "width/height",
            value: pixels as f64,
            expected: "a positive image size of at most 2^31 pixels",
        });
    }
    Ok(())
}

use nalgebra::{Matrix2x3, SMatrix, Vector2, Vector3};

use crate::{CoreError, Pose};

/// Most parameters any model has; lets callers keep intrinsics Jacobians on the stack.
pub const MAX_INTRINSICS: usize = 11;

/// A camera model: projection, unprojection and analytic Jacobians.
pub trait CameraModel {
    /// Name written to files (`"brown"`, `"pinhole"`).
    fn model_name(&self) -> &'static str;
    /// Image width in pixels.
    fn width(&self) -> u32;
    /// Image height in pixels.
    fn height(&self) -> u32;
    /// Names of the intrinsic parameters, in the order of [`CameraModel::params`].
    fn param_names(&self) -> &'static [&'static str];
    /// Number of intrinsic parameters.
    fn num_params(&self) -> usize {
        self.param_names().len()
    }
    /// Writes the intrinsic parameters into `out` (length [`CameraModel::num_params`]).
    fn params(&self, out: &mut [f64]);
    /// Sets the intrinsic parameters from `params`, validating them.
    fn set_params(&mut self, params: &[f64]) -> Result<(), CoreError>;
    /// Projects a camera-frame point to a pixel.
    fn project(&self, p_cam: &Vector3<f64>) -> Result<Vector2<f64>, CoreError>;
    /// Projects a camera-frame point and returns the 2×3 Jacobian of the pixel with respect to the
    /// camera-frame point. When `d_intrinsics` is given (length `2 * num_params`), the Jacobian with
    /// respect to the intrinsics is written into it row-major: `du/dθ` first, then `dv/dθ`.
    fn project_with_jacobians(
        &self,
        p_cam: &Vector3<f64>,
        d_intrinsics: Option<&mut [f64]>,
    ) -> Result<(Vector2<f64>, Matrix2x3<f64>), CoreError>;
    /// The viewing ray of a pixel, scaled so that its z component is 1. Fails when the lens model
    /// cannot be inverted there (iterative undistortion diverges or lands beyond a fold).
    fn unproject(&self, pixel: &Vector2<f64>) -> Result<Vector3<f64>, CoreError>;
}

/// A camera of any supported model; what camera groups store.
#[derive(Debug, Clone, PartialEq)]
pub enum Camera {
    /// The Metashape frame-camera model of docs/design.md.
    Brown(BrownCamera),
    /// Distortion-free pinhole.
    Pinhole(PinholeCamera),
}

macro_rules! dispatch {
    ($self:ident, $cam:ident => $e:expr) => {
        match $self {
            Camera::Brown($cam) => $e,
            Camera::Pinhole($cam) => $e,
        }
    };
}

impl CameraModel for Camera {
    fn model_name(&self) -> &'static str {
        dispatch!(self, c => c.model_name())
    }
    fn width(&self) -> u32 {
        dispatch!(self, c => c.width())
    }
    fn height(&self) -> u32 {
        dispatch!(self, c => c.height())
    }
    fn param_names(&self) -> &'static [&'static str] {
        dispatch!(self, c => c.param_names())
    }
    fn params(&self, out: &mut [f64]) {
        dispatch!(self, c => c.params(out))
    }
    fn set_params(&mut self, params: &[f64]) -> Result<(), CoreError> {
        dispatch!(self, c => c.set_params(params))
    }
    fn project(&self, p_cam: &Vector3<f64>) -> Result<Vector2<f64>, CoreError> {
        dispatch!(self, c => c.project(p_cam))
    }
    fn project_with_jacobians(
        &self,
        p_cam: &Vector3<f64>,
        d_intrinsics: Option<&mut [f64]>,
    ) -> Result<(Vector2<f64>, Matrix2x3<f64>), CoreError> {
        dispatch!(self, c => c.project_with_jacobians(p_cam, d_intrinsics))
    }
    fn unproject(&self, pixel: &Vector2<f64>) -> Result<Vector3<f64>, CoreError> {
        dispatch!(self, c => c.unproject(pixel))
    }
}

/// Jacobians of the projection of a world point through a pose and a camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProjectionJacobians {
    /// The projected pixel.
    pub pixel: Vector2<f64>,
    /// d pixel / d world point (2×3).
    pub d_world_point: Matrix2x3<f64>,
    /// d pixel / d local pose update `(δω, δt)` of [`Pose::retract`] (2×6).
    pub d_pose: SMatrix<f64, 2, 6>,
}

/// Projects a world point through `cam_from_world` and the camera.
pub fn project_world<C: CameraModel + ?Sized>(
    camera: &C,
    cam_from_world: &Pose,
    world_point: &Vector3<f64>,
) -> Result<Vector2<f64>, CoreError> {
    camera.project(&cam_from_world.transform_point(world_point))
}

/// Projects a world point and returns the Jacobians with respect to the point and the pose; the
/// Jacobian with respect to the intrinsics goes into `d_intrinsics` when given (row-major 2×n).
pub fn project_world_with_jacobians<C: CameraModel + ?Sized>(
    camera: &C,
    cam_from_world: &Pose,
    world_point: &Vector3<f64>,
    d_intrinsics: Option<&mut [f64]>,
) -> Result<ProjectionJacobians, CoreError> {
    let p_cam = cam_from_world.transform_point(world_point);
    let (pixel, d_pcam) = camera.project_with_jacobians(&p_cam, d_intrinsics)?;
    let d_world_point = d_pcam * cam_from_world.rotation_matrix();
    let d_pose = d_pcam * cam_from_world.point_jacobian_wrt_pose(world_point);
    Ok(ProjectionJacobians {
        pixel,
        d_world_point,
        d_pose,
    })
}

/// Checks that a parameter is finite, naming it otherwise.
pub(crate) fn check_finite(name: &'static str, value: f64) -> Result<(), CoreError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(CoreError::InvalidCameraParameter {
            name,
            value,
            expected: "a finite number",
        })
    }
}

/// Normalised image coordinates of a camera-frame point, failing for points not in front.
pub(crate) fn normalise(p_cam: &Vector3<f64>) -> Result<(f64, f64, f64), CoreError> {
    let z = p_cam.z;
    if !(z > 0.0) || !p_cam.x.is_finite() || !p_cam.y.is_finite() || !z.is_finite() {
        return Err(CoreError::BehindCamera { z });
    }
    let inv_z = 1.0 / z;
    Ok((p_cam.x * inv_z, p_cam.y * inv_z, inv_z))
}

/// Jacobian of `(x, y) = (X/Z, Y/Z)` with respect to `(X, Y, Z)`.
pub(crate) fn normalise_jacobian(x: f64, y: f64, inv_z: f64) -> Matrix2x3<f64> {
    Matrix2x3::new(inv_z, 0.0, -x * inv_z, 0.0, inv_z, -y * inv_z)
}
