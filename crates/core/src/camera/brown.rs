//! The `brown` frame-camera model of docs/design.md (Agisoft Metashape's):
//!
//! ```text
//! x = Xc/Zc, y = Yc/Zc, r2 = x² + y²
//! radial = 1 + k1 r2 + k2 r2² + k3 r2³ + k4 r2⁴
//! x' = x radial + p1 (r2 + 2x²) + 2 p2 x y
//! y' = y radial + p2 (r2 + 2y²) + 2 p1 x y
//! u  = w/2 + cx + x' (f + b1) + y' b2
//! v  = h/2 + cy + y' f
//! ```
//!
//! p1/p2 are swapped relative to OpenCV/COLMAP; conversions live in `timesift-io`.

use nalgebra::{Matrix2, Matrix2x3, Vector2, Vector3};

use super::{CameraModel, check_finite, normalise, normalise_jacobian};
use crate::CoreError;

/// Parameter order of [`BrownCamera`] as a flat vector.
pub const BROWN_PARAMS: [&str; 11] = [
    "f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2",
];

/// Most Newton iterations of the undistortion before it is declared diverged.
const UNDISTORT_MAX_ITERATIONS: usize = 50;

/// The Metashape frame camera: focal length, principal point offset from the image centre, affinity
/// and skew (b1, b2), four radial and two tangential terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BrownCamera {
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
    /// Affinity: the x focal length is `f + b1`.
    pub b1: f64,
    /// Skew: `u` gets `y' b2`.
    pub b2: f64,
    /// Radial distortion coefficients of r², r⁴, r⁶, r⁸.
    pub k1: f64,
    /// Radial coefficient of r⁴.
    pub k2: f64,
    /// Radial coefficient of r⁶.
    pub k3: f64,
    /// Radial coefficient of r⁸.
    pub k4: f64,
    /// Tangential (decentring) coefficients, Metashape convention.
    pub p1: f64,
    /// Tangential coefficient, Metashape convention (OpenCV's p1).
    pub p2: f64,
}

/// The lens part of the model at one normalised point: distorted coordinates and their Jacobian.
struct Distortion {
    xd: f64,
    yd: f64,
    /// d(x', y') / d(x, y).
    jacobian: Matrix2<f64>,
    r2: f64,
    radial: f64,
    /// d radial / d r2.
    d_radial: f64,
}

impl Distortion {
    /// Whether the point lies on the lens's invertible branch: the radial scale is positive and the
    /// radial map r -> r·radial(r) is still increasing there (before the fold of barrel distortion).
    fn on_invertible_branch(&self) -> bool {
        self.radial > 0.0
            && self.radial + 2.0 * self.r2 * self.d_radial > 0.0
            && self.jacobian.determinant() > 0.0
    }
}

impl BrownCamera {
    /// A distortion-free camera of the given size and focal length with a centred principal point.
    pub fn new(width: u32, height: u32, f: f64) -> Result<Self, CoreError> {
        let cam = BrownCamera {
            width,
            height,
            f,
            cx: 0.0,
            cy: 0.0,
            b1: 0.0,
            b2: 0.0,
            k1: 0.0,
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
            p1: 0.0,
            p2: 0.0,
        };
        cam.validate()?;
        Ok(cam)
    }

    /// The parameters in the order of [`CameraModel::param_names`](crate::CameraModel::param_names).
    pub fn param_array(&self) -> [f64; 11] {
        [
            self.f, self.cx, self.cy, self.b1, self.b2, self.k1, self.k2, self.k3, self.k4,
            self.p1, self.p2,
        ]
    }

    /// Checks every parameter's domain: all finite, `f > 0`, `f + b1 > 0`, positive image size.
    pub fn validate(&self) -> Result<(), CoreError> {
        for (name, value) in BROWN_PARAMS.iter().zip(self.param_array()) {
            check_finite(name, value)?;
        }
        if !(self.f > 0.0) {
            return Err(CoreError::InvalidCameraParameter {
                name: "f",
                value: self.f,
                expected: "a positive focal length in pixels",
            });
        }
        if !(self.f + self.b1 > 0.0) {
            return Err(CoreError::InvalidCameraParameter {
                name: "b1",
                value: self.b1,
                expected: "f + b1 > 0",
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

    fn distort(&self, x: f64, y: f64) -> Distortion {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * (self.k3 + r2 * self.k4)));
        // d radial / d r2
        let d_radial = self.k1 + r2 * (2.0 * self.k2 + r2 * (3.0 * self.k3 + r2 * 4.0 * self.k4));
        let xy = x * y;
        let xd = x * radial + self.p1 * (r2 + 2.0 * x * x) + 2.0 * self.p2 * xy;
        let yd = y * radial + self.p2 * (r2 + 2.0 * y * y) + 2.0 * self.p1 * xy;
        let dxd_dx = radial + 2.0 * x * x * d_radial + 6.0 * self.p1 * x + 2.0 * self.p2 * y;
        let dxd_dy = 2.0 * xy * d_radial + 2.0 * self.p1 * y + 2.0 * self.p2 * x;
        let dyd_dx = 2.0 * xy * d_radial + 2.0 * self.p2 * x + 2.0 * self.p1 * y;
        let dyd_dy = radial + 2.0 * y * y * d_radial + 6.0 * self.p2 * y + 2.0 * self.p1 * x;
        Distortion {
            xd,
            yd,
            jacobian: Matrix2::new(dxd_dx, dxd_dy, dyd_dx, dyd_dy),
            r2,
            radial,
            d_radial,
        }
    }

    fn affine(&self, xd: f64, yd: f64) -> Vector2<f64> {
        let (u0, v0) = self.principal_point();
        Vector2::new(
            u0 + xd * (self.f + self.b1) + yd * self.b2,
            v0 + yd * self.f,
        )
    }

    /// Solves `distort(x, y) = (xd, yd)` by Newton's method, starting at the distorted point.
    fn undistort(&self, xd: f64, yd: f64, pixel: &Vector2<f64>) -> Result<(f64, f64), CoreError> {
        let target = Vector2::new(xd, yd);
        let tolerance = 1e-15 * (1.0 + target.norm());
        let mut p = target;
        let mut residual = f64::INFINITY;
        for iteration in 0..UNDISTORT_MAX_ITERATIONS {
            let d = self.distort(p.x, p.y);
            let r = Vector2::new(d.xd, d.yd) - target;
            residual = r.norm();
            if !residual.is_finite() {
                break;
            }
            if residual <= tolerance {
                // A root beyond the fold of the polynomial is not the lens's inverse.
                if !d.on_invertible_branch() {
                    break;
                }
                return Ok((p.x, p.y));
            }
            let Some(inv) = d.jacobian.try_inverse() else {
                break;
            };
            let step = inv * r;
            p -= step;
            // Newton's step stalls at round-off: accept once the step no longer changes p.
            if iteration > 2
                && step.norm() <= 1e-16 * (1.0 + p.norm())
                && residual <= 1e3 * tolerance
                && d.on_invertible_branch()
            {
                return Ok((p.x, p.y));
            }
        }
        Err(CoreError::UndistortionDiverged {
            u: pixel.x,
            v: pixel.y,
            iterations: UNDISTORT_MAX_ITERATIONS,
            residual,
        })
    }
}

impl CameraModel for BrownCamera {
    fn model_name(&self) -> &'static str {
        "brown"
    }
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }
    fn param_names(&self) -> &'static [&'static str] {
        &BROWN_PARAMS
    }
    fn params(&self, out: &mut [f64]) {
        out[..11].copy_from_slice(&self.param_array());
    }
    fn set_params(&mut self, params: &[f64]) -> Result<(), CoreError> {
        let &[f, cx, cy, b1, b2, k1, k2, k3, k4, p1, p2] = params else {
            return Err(CoreError::ParameterCount {
                model: "brown",
                expected: 11,
                got: params.len(),
            });
        };
        let candidate = BrownCamera {
            width: self.width,
            height: self.height,
            f,
            cx,
            cy,
            b1,
            b2,
            k1,
            k2,
            k3,
            k4,
            p1,
            p2,
        };
        candidate.validate()?;
        *self = candidate;
        Ok(())
    }

    fn project(&self, p_cam: &Vector3<f64>) -> Result<Vector2<f64>, CoreError> {
        let (x, y, _) = normalise(p_cam)?;
        let d = self.distort(x, y);
        Ok(self.affine(d.xd, d.yd))
    }

    fn project_with_jacobians(
        &self,
        p_cam: &Vector3<f64>,
        d_intrinsics: Option<&mut [f64]>,
    ) -> Result<(Vector2<f64>, Matrix2x3<f64>), CoreError> {
        let (x, y, inv_z) = normalise(p_cam)?;
        let d = self.distort(x, y);
        let pixel = self.affine(d.xd, d.yd);
        // d(u, v) / d(x', y')
        let d_affine = Matrix2::new(self.f + self.b1, self.b2, 0.0, self.f);
        let d_point = d_affine * d.jacobian * normalise_jacobian(x, y, inv_z);
        if let Some(out) = d_intrinsics {
            let (xd, yd, r2) = (d.xd, d.yd, d.r2);
            let (r4, r6) = (r2 * r2, r2 * r2 * r2);
            let r8 = r4 * r4;
            // d(x', y') / d(k1..k4, p1, p2)
            let dxd = [
                x * r2,
                x * r4,
                x * r6,
                x * r8,
                r2 + 2.0 * x * x,
                2.0 * x * y,
            ];
            let dyd = [
                y * r2,
                y * r4,
                y * r6,
                y * r8,
                2.0 * x * y,
                r2 + 2.0 * y * y,
            ];
            let fx = self.f + self.b1;
            // Row u: f, cx, cy, b1, b2, then lens terms through (f + b1, b2).
            out[0] = xd;
            out[1] = 1.0;
            out[2] = 0.0;
            out[3] = xd;
            out[4] = yd;
            // Row v: f, cx, cy, b1, b2, then lens terms through f.
            out[11] = yd;
            out[12] = 0.0;
            out[13] = 1.0;
            out[14] = 0.0;
            out[15] = 0.0;
            for k in 0..6 {
                out[5 + k] = fx * dxd[k] + self.b2 * dyd[k];
                out[16 + k] = self.f * dyd[k];
            }
        }
        Ok((pixel, d_point))
    }

    fn unproject(&self, pixel: &Vector2<f64>) -> Result<Vector3<f64>, CoreError> {
        if !pixel.x.is_finite() || !pixel.y.is_finite() {
            return Err(CoreError::NonFinite { what: "pixel" });
        }
        let (u0, v0) = self.principal_point();
        let yd = (pixel.y - v0) / self.f;
        let xd = (pixel.x - u0 - yd * self.b2) / (self.f + self.b1);
        let (x, y) = self.undistort(xd, yd, pixel)?;
        Ok(Vector3::new(x, y, 1.0))
    }
}
