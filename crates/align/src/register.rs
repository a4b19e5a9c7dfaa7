//! Orienting one more image: candidates ranked by how many and how well spread triangulated
//! points they see, then absolute-pose RANSAC (P3P) and refinement through the camera model.

use nalgebra::{Vector2, Vector3};
use timesift_core::{CameraModel, Pose};
use timesift_geometry::pnp::AbsolutePoseEstimator;
use timesift_geometry::ransac::{RansacOptions, ransac};

use crate::state::{NONE, State};

/// Levels of the visibility pyramid (grids of 2×2 up to 2^LEVELS × 2^LEVELS cells).
const LEVELS: u32 = 6;

/// 2-D/3-D correspondences of an image: its keypoints whose track has a point.
pub(crate) fn correspondences(
    state: &State<'_>,
    image: usize,
) -> (Vec<Vector2<f64>>, Vec<Vector3<f64>>) {
    let keypoints = &state.input.images[image].keypoints;
    let mut pixels = Vec::new();
    let mut world = Vec::new();
    for (f, &t) in state.track_of[image].iter().enumerate() {
        if t == NONE {
            continue;
        }
        let p = state.point_of_track[t as usize];
        if p != NONE {
            pixels.push(keypoints[f]);
            world.push(state.rec.points[p as usize].position);
        }
    }
    (pixels, world)
}

/// Visibility score (COLMAP's visibility pyramid): at each level, the occupied cells of a grid
/// over the image, weighted by the level's resolution, so many well-spread points score highest.
fn visibility_score(camera: &dyn CameraModel, pixels: &[Vector2<f64>]) -> usize {
    let (w, h) = (camera.width() as f64, camera.height() as f64);
    let mut score = 0;
    let mut occupied = Vec::new();
    for level in 1..=LEVELS {
        let n = 1usize << level;
        occupied.clear();
        occupied.resize(n * n, false);
        for p in pixels {
            let cx = ((p.x / w * n as f64) as usize).min(n - 1);
            let cy = ((p.y / h * n as f64) as usize).min(n - 1);
            occupied[cy * n + cx] = true;
        }
        score += occupied.iter().filter(|o| **o).count() * n;
    }
    score
}

/// Unoriented available images with enough correspondences, best first.
pub(crate) fn candidates(state: &State<'_>) -> Vec<usize> {
    let mut scored: Vec<(usize, usize)> = (0..state.input.images.len())
        .filter(|&i| {
            state.available[i]
                && state.rec.poses[i].is_none()
                && state.failed_trials[i] < state.options.max_register_trials
        })
        .filter_map(|i| {
            let (pixels, _) = correspondences(state, i);
            (pixels.len() >= state.options.abs_pose_min_inliers).then(|| {
                (
                    i,
                    visibility_score(state.rec.camera_of(state.input, i), &pixels),
                )
            })
        })
        .collect();
    scored.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    scored.into_iter().map(|(i, _)| i).collect()
}

/// Estimates the pose of an image from its correspondences; `None` when too few inliers.
pub(crate) fn estimate_pose(state: &State<'_>, image: usize) -> Option<(Pose, usize)> {
    let options = state.options;
    let (pixels, world) = correspondences(state, image);
    let camera = state.rec.camera_of(state.input, image);
    let mut rays = Vec::with_capacity(pixels.len());
    let mut kept_pixels = Vec::with_capacity(pixels.len());
    let mut kept_world = Vec::with_capacity(pixels.len());
    for (u, x) in pixels.iter().zip(&world) {
        if let Ok(r) = camera.unproject(u) {
            rays.push(r.normalize());
            kept_pixels.push(*u);
            kept_world.push(*x);
        }
    }
    if kept_pixels.len() < options.abs_pose_min_inliers {
        return None;
    }
    let estimator = AbsolutePoseEstimator {
        camera,
        pixels: &kept_pixels,
        rays: &rays,
        world: &kept_world,
    };
    let result = ransac(
        &estimator,
        &RansacOptions {
            max_error: options.abs_pose_max_error_px,
            seed: options.seed ^ (image as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
            ..RansacOptions::default()
        },
    )
    .ok()?;
    let ratio = result.num_inliers as f64 / kept_pixels.len() as f64;
    (result.num_inliers >= options.abs_pose_min_inliers
        && ratio >= options.abs_pose_min_inlier_ratio)
        .then_some((result.model, result.num_inliers))
}
