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

/// Largest working image relative to the original divided by the level: a lens whose border
/// unprojects further out (strong fisheye) is cropped to this.
const MAX_GROWTH: f64 = 1.5;

/// The working camera of `camera` at `level`: focal length divided by the level, and an image
/// just large enough to hold every original pixel (as COLMAP's undistorter does with
/// `blank_pixels = 1`): barrel distortion shows more than a pinhole of the original size would,
/// and cropping it would lose the periphery, where the images of a block overlap least. Working
/// pixels outside the original image are masked, not matched.
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
    let fw = f / level as f64;
    let (ow, oh) = (camera.width() as f64, camera.height() as f64);
    // Normalised coordinates of the original border (pixel edges, every pixel).
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    let mut border = Vec::new();
    for i in 0..=camera.width() {
        border.push((i as f64, 0.0));
        border.push((i as f64, oh));
    }
    for j in 0..=camera.height() {
        border.push((0.0, j as f64));
        border.push((ow, j as f64));
    }
    for (u, v) in border {
        if let Ok(r) = camera.unproject(&nalgebra::Vector2::new(u, v)) {
            x0 = x0.min(r.x);
            x1 = x1.max(r.x);
            y0 = y0.min(r.y);
            y1 = y1.max(r.y);
        }
    }
    let (max_w, max_h) = (
        MAX_GROWTH * ow / level as f64,
        MAX_GROWTH * oh / level as f64,
    );
    let (width, cx) = extent(x0, x1, fw, max_w, ow / level as f64);
    let (height, cy) = extent(y0, y1, fw, max_h, oh / level as f64);
    if width < 8 || height < 8 {
        return Err(DenseError::InvalidOption(format!(
            "level = {level} leaves a {width} × {height} image: too small to match"
        )));
    }
    Ok(WorkingCamera {
        width,
        height,
        f: fw,
        cx,
        cy,
    })
}

/// Size and principal point along one axis covering normalised coordinates [lo, hi] at focal
/// length `f`, at most `max` pixels (centred crop beyond); `fallback` pixels when the border
/// could not be unprojected.
fn extent(lo: f64, hi: f64, f: f64, max: f64, fallback: f64) -> (usize, f64) {
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        let n = fallback.floor().max(1.0);
        return (n as usize, 0.5 * n);
    }
    let size = ((hi - lo) * f).ceil();
    if size <= max {
        (size as usize, -lo * f)
    } else {
        let n = max.floor();
        // Keep the optical axis where it was relative to the covered range's centre.
        let centre = -0.5 * (lo + hi) * f;
        (n as usize, 0.5 * n + centre)
    }
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
                    let ray = working.ray(u, v);
                    if let Ok(p) = camera.project(&ray) {
                        // Inside the band of pixel centres, where bilinear needs no extrapolation,
                        // and on the lens's invertible branch: beyond the fold of a distortion
                        // polynomial, rays far outside the field project back into the image.
                        let inside = p.x >= 0.5
                            && p.y >= 0.5
                            && p.x <= ow as f64 - 0.5
                            && p.y <= oh as f64 - 0.5;
                        let same_ray = camera.unproject(&p).is_ok_and(|back| {
                            (back.x - ray.x).abs() < 1e-6 && (back.y - ray.y).abs() < 1e-6
                        });
                        if inside && same_ray {
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

    /// An image (and mask) of the original size, with one or three channels.
    fn check_input(&self, image: &ImageView<'_>, mask: Option<&Mask>) -> Result<(), DenseError> {
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
        Ok(())
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
        self.check_input(image, mask)?;
        let (ow, oh) = self.original;
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
                        let (a, b, cc, d) =
                            (pixel(i0, j0), pixel(i1, j0), pixel(i0, j1), pixel(i1, j1));
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
            assert!(
                checked > working.width * working.height * 8 / 10,
                "{checked}"
            );
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

    /// Barrel distortion shows more than a pinhole of the same size: the working image grows to
    /// keep every original pixel, so each original border pixel has a working pixel.
    #[test]
    fn the_working_image_keeps_the_periphery_of_barrel_distortion() {
        let mut brown = BrownCamera::new(200, 150, 160.0).unwrap();
        brown.k1 = -0.15;
        brown.cx = 3.0;
        let camera = Camera::Brown(brown);
        let working = working_camera(&camera, 1).unwrap();
        assert!(working.width > 200 && working.height > 150, "{working:?}");
        for (u, v) in [
            (0.5, 0.5),
            (199.5, 0.5),
            (0.5, 149.5),
            (199.5, 149.5),
            (100.0, 0.5),
        ] {
            let ray = camera.unproject(&nalgebra::Vector2::new(u, v)).unwrap();
            let p = working.project(&ray).unwrap();
            assert!(working.contains(p.x, p.y), "({u}, {v}) -> {p:?}");
        }
        let pinhole = Camera::Pinhole(timesift_core::PinholeCamera::new(200, 150, 160.0).unwrap());
        let w = working_camera(&pinhole, 2).unwrap();
        assert_eq!((w.width, w.height), (100, 75));
        assert!((w.cx - 50.0).abs() < 1e-9 && (w.cy - 37.5).abs() < 1e-9);
    }
}
