//! libmv problems as bundle problems, the problem Ceres's `libmv_bundle_adjuster` solves: one
//! shared camera (the libmv polynomial model is the brown model with p1 and p2 swapped and no k4),
//! every camera pose and point free except the camera of the first usable marker, markers whose
//! camera or point does not exist left out, and — for markers in pixels — f, k1 and k2 refined.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Vector2, Vector3};
use timesift_core::{BrownCamera, Camera, Pose};
use timesift_io::libmv::LibmvProblem;

use crate::BundleError;
use crate::problem::{BundleImage, BundlePoint, BundleProblem, CameraGroup, Observation};

/// Converts a libmv problem. The file's f32 rotations are projected onto the nearest rotation.
pub fn from_libmv(libmv: &LibmvProblem) -> Result<BundleProblem, BundleError> {
    let mut problem = BundleProblem {
        groups: vec![camera_group(libmv)?],
        ..BundleProblem::default()
    };
    let image_index = add_cameras(&mut problem, libmv)?;
    let point_index = add_points(&mut problem, libmv);
    add_markers(&mut problem, libmv, &image_index, &point_index);
    // Cameras and points no marker refers to are not part of the problem (Ceres never sees
    // them); fixing them keeps them out of the normal equations.
    let mut seen_image = vec![false; problem.images.len()];
    let mut seen_point = vec![false; problem.points.len()];
    for o in &problem.observations {
        seen_image[o.image] = true;
        seen_point[o.point] = true;
    }
    for (im, seen) in problem.images.iter_mut().zip(seen_image) {
        im.fixed |= !seen;
    }
    for (pt, seen) in problem.points.iter_mut().zip(seen_point) {
        pt.fixed |= !seen;
    }
    if problem.observations.is_empty() {
        return Err(BundleError::InvalidProblem(
            "no marker refers to an existing camera and point".into(),
        ));
    }
    Ok(problem)
}

/// The problem's one camera group: the libmv intrinsics as a brown camera (p1 and p2 swapped),
/// with f, k1 and k2 free for markers in pixels and everything fixed otherwise.
fn camera_group(libmv: &LibmvProblem) -> Result<CameraGroup, BundleError> {
    let [f, cx, cy, k1, k2, k3, p1, p2] = libmv.intrinsics;
    // The brown model's principal point is an offset from the image centre: any width works as
    // long as the offset compensates; take the one that makes it nearly zero.
    let width = (2.0 * cx).round().max(1.0) as u32;
    let height = (2.0 * cy).round().max(1.0) as u32;
    let mut camera = BrownCamera::new(width, height, f)
        .map_err(|e| BundleError::InvalidProblem(format!("intrinsics: {e}")))?;
    camera.cx = cx - 0.5 * width as f64;
    camera.cy = cy - 0.5 * height as f64;
    camera.k1 = k1;
    camera.k2 = k2;
    camera.k3 = k3;
    camera.p1 = p2;
    camera.p2 = p1;
    if libmv.pixel_space {
        CameraGroup::with_free(Camera::Brown(camera), &["f", "k1", "k2"])
    } else {
        Ok(CameraGroup::fixed(Camera::Brown(camera)))
    }
}

/// Adds the libmv cameras as free images of group 0; returns the problem image of each libmv
/// image number.
fn add_cameras(
    problem: &mut BundleProblem,
    libmv: &LibmvProblem,
) -> Result<BTreeMap<usize, usize>, BundleError> {
    let mut image_index = BTreeMap::new();
    for c in &libmv.cameras {
        let m = Matrix3::from_fn(|r, k| c.rotation[r][k]);
        let rotation = nearest_rotation(&m).ok_or_else(|| {
            BundleError::InvalidProblem(format!(
                "camera of image {}: the rotation is degenerate",
                c.image
            ))
        })?;
        let pose = Pose::from_rt(&rotation, &Vector3::from(c.translation)).map_err(|e| {
            BundleError::InvalidProblem(format!("camera of image {}: {e}", c.image))
        })?;
        // A later camera of the same image replaces an earlier one, as in libmv.
        match image_index.get(&c.image) {
            Some(&i) => {
                problem.images[i] = BundleImage {
                    pose,
                    group: 0,
                    fixed: false,
                }
            }
            None => {
                image_index.insert(c.image, problem.images.len());
                problem.images.push(BundleImage {
                    pose,
                    group: 0,
                    fixed: false,
                });
            }
        }
    }
    Ok(image_index)
}

/// Adds the libmv points as free points; returns the problem point of each track. A later point
/// of the same track replaces an earlier one.
fn add_points(problem: &mut BundleProblem, libmv: &LibmvProblem) -> BTreeMap<usize, usize> {
    let mut point_index = BTreeMap::new();
    for p in &libmv.points {
        let point = BundlePoint {
            position: Vector3::from(p.position),
            fixed: false,
        };
        match point_index.get(&p.track) {
            Some(&i) => problem.points[i] = point,
            None => {
                point_index.insert(p.track, problem.points.len());
                problem.points.push(point);
            }
        }
    }
    point_index
}

/// Adds the markers whose camera and point exist as observations (σ 1), and fixes the camera of
/// the first of them (the gauge Ceres's libmv adjuster fixes).
fn add_markers(
    problem: &mut BundleProblem,
    libmv: &LibmvProblem,
    image_index: &BTreeMap<usize, usize>,
    point_index: &BTreeMap<usize, usize>,
) {
    let mut fixed_first = false;
    for m in &libmv.markers {
        let (Some(&image), Some(&point)) = (image_index.get(&m.image), point_index.get(&m.track))
        else {
            continue;
        };
        if !fixed_first {
            problem.images[image].fixed = true;
            fixed_first = true;
        }
        problem.observations.push(Observation {
            image,
            point,
            pixel: Vector2::new(m.xy[0], m.xy[1]),
            sigma_px: 1.0,
        });
    }
}

/// The rotation nearest to `m` (Frobenius norm): `U Vᵀ` of its SVD, with the sign fixed so that the
/// determinant is +1; `None` when `m` is far from a rotation (a singular value off by 1 %).
fn nearest_rotation(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let svd = m.try_svd(true, true, 1e-15, 200)?;
    if svd.singular_values.iter().any(|s| (s - 1.0).abs() > 0.01) {
        return None;
    }
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut r = u * v_t;
    if r.determinant() < 0.0 {
        let mut d = Matrix3::identity();
        d[(2, 2)] = -1.0;
        r = u * d * v_t;
    }
    Some(r)
}
