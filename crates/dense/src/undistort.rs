//! Resampling of an original (distorted) image to its working pinhole camera at a level of 1, 2,
//! 4 or 8 (full, half, quarter, eighth resolution, as Metashape's ultra-high … low).
//!
//! Every working pixel averages `level × level` sub-samples, each interpolated bilinearly in the
//! original image at the position the camera model projects its ray to: a box filter over the
//! working pixel's footprint, so that reduced levels are not aliased. The map from working
//! sub-samples to original positions depends only on the camera, so one [`UndistortMap`] serves
//! every image of a camera group.

use rayon::prelude::*;
use timesift_core::{Camera, CameraModel};

use crate::DenseError;
use crate::camera::WorkingCamera;
use crate::image::{ImageView, Mask, Plane, WorkingImage};

/// The working camera of `camera` at `level`: the original size divided by the level (rounded
/// down), the focal length divided by the level, the principal point at the centre.
pub fn working_camera(camera: &Camera, level: u32) -> Result<WorkingCamera, DenseError> {
    if !matches!(level, 1 | 2 | 4 | 8) {
        return Err(DenseError::InvalidOption(format!(
            "level = {level}: expected 1, 2, 4 or 8"
        )));
    }
    let f = match camera {
        Camera::Brown(c) => c.f,
        Camera::Pinhole(c) => c.f,
    };
    let width = camera.width() as usize / level as usize;
    let height = camera.height() as usize / level as usize;
    if width < 8 || height < 8 {
        return Err(DenseError::InvalidOption(format!(
            "level = {level} leaves a {width} × {height} image: too small to match"
        )));
    }
    Ok(WorkingCamera {
        width,
        height,
        f: f / level as f64,
        cx: 0.5 * width as f64,
        cy: 0.5 * height as f64,
    })
}

/// Where every sub-sample of every working pixel falls in the original image.
#[derive(Debug, Clone)]
pub struct UndistortMap {
    /// The working camera.
    pub camera: WorkingCamera,
    original: (usize, usize),
    level: usize,
    /// Per working pixel, `level²` original positions (u, v); NaN where the ray does not reach
    /// the original image.
    positions: Vec<[f32; 2]>,
}

impl UndistortMap {
    /// The map from `working` (see [`working_camera`]) to the original `camera`.
    pub fn new(camera: &Camera, working: WorkingCamera, level: u32) -> UndistortMap {
        let n = level as usize;
        let (ow, oh) = (camera.width() as usize, camera.height() as usize);
        let mut positions = vec![[f32::NAN; 2]; working.width * working.height * n * n];
        positions
            .par_chunks_mut(working.width * n * n)
            .enumerate()
            .for_each(|(j, row)| {
                for (k, out) in row.iter_mut().enumerate() {
                    let (i, s) = (k / (n * n), k % (n * n));
                    let u = i as f64 + ((s % n) as f64 + 0.5) / n as f64;
                    let v = j as f64 + ((s / n) as f64 + 0.5) / n as f64;
                    if let Ok(p) = camera.project(&working.ray(u, v)) {
                        // Inside the band of pixel centres, where bilinear needs no extrapolation.
                        if p.x >= 0.5 && p.y >= 0.5 && p.x <= ow as f64 - 0.5 && p.y <= oh as f64 - 0.5
                        {
                            *out = [p.x as f32, p.y as f32];
                        }
                    }
                }
            });
        UndistortMap {
            camera: working,
            original: (ow, oh),
            level: n,
            positions,
        }
    }

    /// Resamples `image` (the original pixels of a view of this camera). A working pixel is
    /// unusable when any of its sub-samples leaves the original image, touches a pixel that
    /// `mask` marks unusable, or touches a no-data pixel (exactly black in every channel) when
    /// `black_is_nodata`.
    pub fn apply(
        &self,
        image: &ImageView<'_>,
        mask: Option<&Mask>,
        black_is_nodata: bool,
    ) -> Result<WorkingImage, DenseError> {
        let (ow, oh) = self.original;
        if image.width != ow || image.height != oh {
            return Err(DenseError::ImageSize {
                expected: (ow, oh),
                found: (image.width, image.height),
            });
        }
        if !matches!(image.channels, 1 | 3) || image.data.len() != ow * oh * image.channels {
            return Err(DenseError::InvalidInput(format!(
                "an image of {ow} × {oh} pixels with {} channels holds {} values",
                image.channels,
                image.data.len()
            )));
        }
        if let Some(m) = mask
            && (m.width != ow || m.height != oh)
        {
            return Err(DenseError::ImageSize {
                expected: (ow, oh),
                found: (m.width, m.height),
            });
        }
        let cam = self.camera;
        let n2 = self.level * self.level;
        let c = image.channels;
        let pixel = |i: usize, j: usize| -> [f32; 3] {
            let k = (j * ow + i) * c;
            if c == 3 {
                [image.data[k], image.data[k + 1], image.data[k + 2]]
            } else {
                [image.data[k]; 3]
            }
        };
        let unusable = |i: usize, j: usize| -> bool {
            mask.is_some_and(|m| !m.at(i, j)) || (black_is_nodata && pixel(i, j) == [0.0; 3])
        };
        let rows: Vec<(Vec<[f32; 3]>, Vec<bool>)> = (0..cam.height)
            .into_par_iter()
            .map(|j| {
                let mut rgb = Vec::with_capacity(cam.width);
                let mut usable = Vec::with_capacity(cam.width);
                for i in 0..cam.width {
                    let first = (j * cam.width + i) * n2;
                    let mut sum = [0.0f32; 3];
                    let mut ok = true;
                    for &[u, v] in &self.positions[first..first + n2] {
                        if u.is_nan() {
                            ok = false;
                            break;
                        }
                        let (x, y) = (u - 0.5, v - 0.5);
                        let (i0, j0) = (x as usize, y as usize);
                        let (i1, j1) = ((i0 + 1).min(ow - 1), (j0 + 1).min(oh - 1));
                        let (fx, fy) = (x - i0 as f32, y - j0 as f32);
                        if unusable(i0, j0)
                            || unusable(i1, j0)
                            || unusable(i0, j1)
                            || unusable(i1, j1)
                        {
                            ok = false;
                            break;
                        }
                        let (a, b, cc, d) = (pixel(i0, j0), pixel(i1, j0), pixel(i0, j1), pixel(i1, j1));
                        for k in 0..3 {
                            let top = a[k] + (b[k] - a[k]) * fx;
                            let bottom = cc[k] + (d[k] - cc[k]) * fx;
                            sum[k] += top + (bottom - top) * fy;
                        }
                    }
                    let inv = 1.0 / n2 as f32;
                    rgb.push(if ok {
                        [sum[0] * inv, sum[1] * inv, sum[2] * inv]
                    } else {
                        [0.0; 3]
                    });
                    usable.push(ok);
                }
                (rgb, usable)
            })
            .collect();
        let mut rgb = Vec::with_capacity(cam.width * cam.height);
        let mut usable = Vec::with_capacity(cam.width * cam.height);
        for (r, u) in rows {
            rgb.extend(r);
            usable.extend(u);
        }
        let grey = rgb
            .iter()
            .map(|p| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2])
            .collect();
        Ok(WorkingImage {
            grey: Plane {
                width: cam.width,
                height: cam.height,
                data: grey,
            },
            rgb,
            mask: Mask {
                width: cam.width,
                height: cam.height,
                usable,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use timesift_core::BrownCamera;

    /// An image whose value is a smooth function of the viewing ray is resampled to the value of
    /// the same function at the working pixel's ray, whatever the distortion.
    #[test]
    fn resampling_follows_the_rays_through_distortion() {
        let mut brown = BrownCamera::new(160, 120, 150.0).unwrap();
        brown.k1 = -0.08;
        brown.k2 = 0.03;
        brown.p1 = 0.001;
        brown.cx = 2.0;
        brown.cy = -1.5;
        let camera = Camera::Brown(brown);
        let field = |r: &Vector3<f64>| (0.5 + 0.3 * r.x + 0.2 * r.y) as f32;
        let mut data = Vec::new();
        for j in 0..120 {
            for i in 0..160 {
                let ray = camera
                    .unproject(&nalgebra::Vector2::new(i as f64 + 0.5, j as f64 + 0.5))
                    .unwrap();
                data.push(field(&ray));
            }
        }
        let view = ImageView {
            width: 160,
            height: 120,
            channels: 1,
            data: &data,
        };
        for level in [1, 2] {
            let working = working_camera(&camera, level).unwrap();
            let map = UndistortMap::new(&camera, working, level);
            let out = map.apply(&view, None, false).unwrap();
            let mut checked = 0;
            for j in 0..working.height {
                for i in 0..working.width {
                    if !out.mask.at(i, j) {
                        continue;
                    }
                    let expected = field(&working.pixel_ray(i, j));
                    // The field is linear in the distorted image only to first order.
                    assert!(
                        (out.grey.at(i, j) - expected).abs() < 2e-3,
                        "level {level} pixel ({i}, {j}): {} vs {expected}",
                        out.grey.at(i, j)
                    );
                    checked += 1;
                }
            }
            assert!(checked > working.width * working.height * 8 / 10, "{checked}");
        }
    }

    #[test]
    fn masked_and_black_pixels_are_unusable() {
        let camera = Camera::Brown(BrownCamera::new(40, 30, 40.0).unwrap());
        let mut data = vec![0.5f32; 40 * 30];
        data[15 * 40 + 20] = 0.0;
        let view = ImageView {
            width: 40,
            height: 30,
            channels: 1,
            data: &data,
        };
        let working = working_camera(&camera, 1).unwrap();
        let map = UndistortMap::new(&camera, working, 1);
        let out = map.apply(&view, None, true).unwrap();
        assert!(!out.mask.at(20, 15));
        assert!(out.mask.at(10, 10));
        let mut mask = Mask::all(40, 30);
        mask.usable[5 * 40 + 5] = false;
        let out = map.apply(&view, Some(&mask), false).unwrap();
        assert!(out.mask.at(20, 15));
        assert!(!out.mask.at(5, 5));
        let wrong = ImageView {
            width: 30,
            height: 30,
            channels: 1,
            data: &data[..900],
        };
        assert!(map.apply(&wrong, None, true).is_err());
        assert!(working_camera(&camera, 3).is_err());
    }
}
