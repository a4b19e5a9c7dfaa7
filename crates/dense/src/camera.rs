//! The ideal pinhole camera every view is resampled to before matching, and its pyramid.

use nalgebra::{Vector2, Vector3};

/// A distortion-free pinhole with square pixels and an absolute principal point (so that halving
/// an image with an odd size keeps `u_half = u / 2` exact):
/// `u = cx + f X/Z`, `v = cy + f Y/Z`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkingCamera {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Focal length, pixels.
    pub f: f64,
    /// Principal point, absolute pixel coordinates (docs/design.md convention).
    pub cx: f64,
    /// Principal point, absolute pixel coordinates.
    pub cy: f64,
}

impl WorkingCamera {
    /// The camera-frame ray through pixel coordinates (u, v), with z = 1.
    #[inline]
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.f, (v - self.cy) / self.f, 1.0)
    }

    /// The ray through the centre of pixel (i, j).
    #[inline]
    pub fn pixel_ray(&self, i: usize, j: usize) -> Vector3<f64> {
        self.ray(i as f64 + 0.5, j as f64 + 0.5)
    }

    /// Projection of a camera-frame point; `None` behind the camera.
    #[inline]
    pub fn project(&self, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        if !(p.z > 0.0) {
            return None;
        }
        Some(Vector2::new(
            self.cx + self.f * p.x / p.z,
            self.cy + self.f * p.y / p.z,
        ))
    }

    /// The camera of the image halved by [`crate::image::Plane::half`].
    pub fn half(&self) -> WorkingCamera {
        WorkingCamera {
            width: self.width / 2,
            height: self.height / 2,
            f: 0.5 * self.f,
            cx: 0.5 * self.cx,
            cy: 0.5 * self.cy,
        }
    }

    /// The camera at pyramid scale `scale` (halved `scale` times).
    pub fn at_scale(&self, scale: usize) -> WorkingCamera {
        (0..scale).fold(*self, |c, _| c.half())
    }

    /// Whether (u, v) lies inside the image.
    #[inline]
    pub fn contains(&self, u: f64, v: f64) -> bool {
        u >= 0.0 && v >= 0.0 && u < self.width as f64 && v < self.height as f64
    }
}
