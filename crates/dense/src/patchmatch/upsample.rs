//! Joint bilateral upsampling of a coarse depth map to the next finer scale (ACMM): every fine
//! pixel averages the planes of the 5 × 5 coarse pixels around it, each evaluated on the fine
//! pixel's own ray (so slanted planes stay slanted), weighted by the distance to the coarse
//! pixel and by the intensity difference between the fine pixel and the coarse pixel.

use super::cost::{RefCamera, plane_depth};
use crate::depth_map::DepthMap;
use crate::image::Plane;

/// Spatial σ in coarse pixels and intensity σ (0–1) of the upsampling kernel.
const SIGMA_SPATIAL: f32 = 0.5;
const SIGMA_INTENSITY: f32 = 0.1;

/// The coarse map's planes on the fine grid: `(depth, normal)` per fine pixel, depth 0 where no
/// coarse neighbour has a depth. `coarse_camera` is the camera of `coarse`, `fine_camera` that
/// of `fine_grey`; normals are in the (scale-independent) camera frame.
pub fn upsample(
    coarse: &DepthMap,
    coarse_grey: &Plane,
    coarse_camera: &RefCamera,
    fine_grey: &Plane,
    fine_camera: &RefCamera,
) -> (Vec<f32>, Vec<[f32; 3]>) {
    let (fw, fh) = (fine_grey.width, fine_grey.height);
    let mut depth = vec![0.0f32; fw * fh];
    let mut normal = vec![[0.0f32; 3]; fw * fh];
    let inv_two_ss = 1.0 / (2.0 * SIGMA_SPATIAL * SIGMA_SPATIAL);
    let inv_two_si = 1.0 / (2.0 * SIGMA_INTENSITY * SIGMA_INTENSITY);
    for y in 0..fh {
        for x in 0..fw {
            let (u, v) = (x as f32 + 0.5, y as f32 + 0.5);
            let ray = fine_camera.ray(u, v);
            // Continuous coarse coordinates of this pixel centre, and its coarse pixel index.
            let (cu, cv) = (
                coarse_camera.cx + (u - fine_camera.cx) * coarse_camera.f / fine_camera.f,
                coarse_camera.cy + (v - fine_camera.cy) * coarse_camera.f / fine_camera.f,
            );
            let (ci, cj) = ((cu - 0.5).round() as i64, (cv - 0.5).round() as i64);
            let guide = fine_grey.at(x, y);
            let (mut sw, mut sd) = (0.0f32, 0.0f32);
            let mut sn = [0.0f32; 3];
            for dj in -2..=2 {
                for di in -2..=2 {
                    let (i, j) = (ci + di, cj + dj);
                    if i < 0 || j < 0 || i >= coarse.width as i64 || j >= coarse.height as i64 {
                        continue;
                    }
                    let k = j as usize * coarse.width + i as usize;
                    if !(coarse.depth[k] > 0.0) {
                        continue;
                    }
                    let n = coarse.normal[k];
                    let cray = coarse_camera.ray(i as f32 + 0.5, j as f32 + 0.5);
                    let w_plane =
                        -(n[0] * cray[0] + n[1] * cray[1] + n[2] * cray[2]) * coarse.depth[k];
                    let d = plane_depth(&n, w_plane, &ray);
                    if !(d > 0.0) {
                        continue;
                    }
                    let (ddx, ddy) = (i as f32 + 0.5 - cu, j as f32 + 0.5 - cv);
                    let di_ = guide - coarse_grey.at(i as usize, j as usize);
                    let w = (-(ddx * ddx + ddy * ddy) * inv_two_ss - di_ * di_ * inv_two_si).exp();
                    sw += w;
                    sd += w * d;
                    for c in 0..3 {
                        sn[c] += w * n[c];
                    }
                }
            }
            if sw > 1e-12 {
                let len = (sn[0] * sn[0] + sn[1] * sn[1] + sn[2] * sn[2]).sqrt();
                if len > 1e-6 {
                    let k = y * fw + x;
                    depth[k] = sd / sw;
                    normal[k] = [sn[0] / len, sn[1] / len, sn[2] / len];
                }
            }
        }
    }
    (depth, normal)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A slanted plane upsampled from half resolution keeps its exact depth on every fine ray.
    #[test]
    fn slanted_planes_upsample_exactly() {
        let fine_cam = RefCamera {
            f: 80.0,
            cx: 40.0,
            cy: 30.0,
        };
        let coarse_cam = RefCamera {
            f: 40.0,
            cx: 20.0,
            cy: 15.0,
        };
        let n = {
            let v = [0.3f32, -0.2, -1.0];
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            [v[0] / l, v[1] / l, v[2] / l]
        };
        let w = 12.0f32 * n[2].abs();
        let mut coarse = DepthMap::empty(40, 30);
        for j in 0..30 {
            for i in 0..40 {
                let ray = coarse_cam.ray(i as f32 + 0.5, j as f32 + 0.5);
                coarse.depth[j * 40 + i] = plane_depth(&n, w, &ray);
                coarse.normal[j * 40 + i] = n;
            }
        }
        let grey_c = Plane::filled(40, 30, 0.5);
        let grey_f = Plane::filled(80, 60, 0.5);
        let (depth, normal) = upsample(&coarse, &grey_c, &coarse_cam, &grey_f, &fine_cam);
        for j in 0..60 {
            for i in 0..80 {
                let ray = fine_cam.ray(i as f32 + 0.5, j as f32 + 0.5);
                let expected = plane_depth(&n, w, &ray);
                let got = depth[j * 80 + i];
                assert!(
                    (got - expected).abs() < 1e-3 * expected,
                    "{i} {j}: {got} {expected}"
                );
                assert!((normal[j * 80 + i][2] - n[2]).abs() < 1e-5);
            }
        }
    }
}
