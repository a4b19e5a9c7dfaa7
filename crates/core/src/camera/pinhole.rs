//! Distortion-free pinhole: `u = w/2 + cx + f x`, `v = h/2 + cy + f y`.

use nalgebra::{Matrix2x3, Vector2, Vector3};

use super::{CameraModel, check_finite, normalise, normalise_jacobian};
use crate::CoreError;

/// A pinhole camera with the principal point given as an offset from the image centre, like
/// [`super::BrownCamera`] with all distortion terms zero.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeCamera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length in pixels.
    pub f: f64,
    /// Principal point offset from the image centre, pixels.
    pub cx: f64,
    /// Principal point offset from the image centre, pixels.
    pub cy: f64,
}

const PINHOLE_PARAMS: [&str; 3] = ["f", "cx", "cy"];

impl PinholeCamera {
    /// A pinhole camera of the given size and focal length with a centred principal point.
    pub fn new(width: u32, height: u32, f: f64) -> Result<Self, CoreError> {
        let cam = PinholeCamera {
            width,
            height,
            f,
            cx: 0.0,
            cy: 0.0,
        };
        cam.validate()?;
        Ok(cam)
    }

    /// Checks every parameter's domain.
    pub fn validate(&self) -> Result<(), CoreError> {
        for (name, value) in [("f", self.f), ("cx", self.cx), ("cy", self.cy)] {
            check_finite(name, value)?;
        }
        if !(self.f > 0.0) {
            return Err(CoreError::InvalidCameraParameter {
                name: "f",
                value: self.f,
                expected: "a positive focal length in pixels",
            });
        }
        super::check_image_size(self.width, self.height)
    }

    fn principal_point(&self) -> (f64, f64) {
        (
            0.5 * self.width as f64 + self.cx,
            0.5 * self.height as f64 + self.cy,
        )
    }
}

impl CameraModel for PinholeCamera {
    fn model_name(&self) -> &'static str {
        "pinhole"
    }
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }
    fn param_names(&self) -> &'static [&'static str] {
        &PINHOLE_PARAMS
    }
    fn params(&self, out: &mut [f64]) {
        out[..3].copy_from_slice(&[self.f, self.cx, self.cy]);
    }
    fn set_params(&mut self, params: &[f64]) -> Result<(), CoreError> {
        if params.len() != 3 {
            return Err(CoreError::ParameterCount {
                model: "pinhole",
                expected: 3,
                got: params.len(),
            });
        }
        let candidate = PinholeCamera {
            f: params[0],
            cx: params[1],
            cy: params[2],
            ..*self
        };
        candidate.validate()?;
        *self = candidate;
        Ok(())
    }
    fn project(&self, p_cam: &Vector3<f64>) -> Result<Vector2<f64>, CoreError> {
        let (x, y, _) = normalise(p_cam)?;
        let (u0, v0) = self.principal_point();
        Ok(Vector2::new(u0 + self.f * x, v0 + self.f * y))
    }
    fn project_with_jacobians(
        &self,
        p_cam: &Vector3<f64>,
        d_intrinsics: Option<&mut [f64]>,
    ) -> Result<(Vector2<f64>, Matrix2x3<f64>), CoreError> {
        let (x, y, inv_z) = normalise(p_cam)?;
        let (u0, v0) = self.principal_point();
        if let Some(d) = d_intrinsics {
            d[..6].copy_from_slice(&[x, 1.0, 0.0, y, 0.0, 1.0]);
        }
        let d_point = normalise_jacobian(x, y, inv_z) * self.f;
        Ok((Vector2::new(u0 + self.f * x, v0 + self.f * y), d_point))
    }
    fn unproject(&self, pixel: &Vector2<f64>) -> Result<Vector3<f64>, CoreError> {
        let (u0, v0) = self.principal_point();
        Ok(Vector3::new(
            (pixel.x - u0) / self.f,
            (pixel.y - v0) / self.f,
            1.0,
        ))
    }
}
