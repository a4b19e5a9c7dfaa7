//! The initial pair of a reconstruction: among the pairs sharing the most tracks, the first whose
//! essential matrix has enough inliers and whose triangulated inliers see each other under a
//! large enough median angle (a rotation about the centre or a tiny baseline fails that test).

use std::collections::HashMap;

use nalgebra::Vector3;
use timesift_core::{CameraModel, Pose};
use timesift_geometry::essential::{EssentialEstimator, relative_pose_from_essential};
use timesift_geometry::ransac::{RansacOptions, ransac};
use timesift_geometry::triangulation::{triangulate_two_view_midpoint, triangulation_angle};

use crate::AlignError;
use crate::state::State;

/// Shared tracks per image pair among the available images, most first (ties by index).
pub(crate) fn pair_counts(state: &State<'_>) -> Vec<((usize, usize), usize)> {
    let mut counts: HashMap<(usize, usize), usize> = HashMap::new();
    for track in &state.input.tracks {
        let images: Vec<usize> = track
            .elements
            .iter()
            .map(|e| e.image.index())
            .filter(|&i| state.available[i])
            .collect();
        for (k, &a) in images.iter().enumerate() {
            for &b in &images[k + 1..] {
                *counts.entry((a, b)).or_insert(0) += 1;
            }
        }
    }
    let mut pairs: Vec<_> = counts.into_iter().collect();
    pairs.sort_by(|x, y| y.1.cmp(&x.1).then(x.0.cmp(&y.0)));
    pairs
}

/// What a candidate pair gave.
struct Candidate {
    cam_b_from_cam_a: Pose,
    inliers: usize,
    median_angle_deg: f64,
}

/// Below this median displacement of their shared tracks (pixels, after undistortion, in the
/// cameras' own frames) two images show the same view: identical files, or photos taken from one
/// spot in one direction. No essential matrix or triangulation is defined for them.
const SAME_VIEW_PX: f64 = 0.5;

/// Why a pair cannot start the reconstruction.
enum Rejection {
    /// The pair's tracks are the same pixels in both images (median displacement, pixels).
    SameView(f64),
    /// Too few shared tracks or essential inliers, or no relative pose.
    Weak,
}

/// The median distance, in pixels at `focal`, between corresponding normalised rays.
fn median_displacement_px(rays_a: &[Vector3<f64>], rays_b: &[Vector3<f64>], focal: f64) -> f64 {
    let mut d: Vec<f64> = rays_a
        .iter()
        .zip(rays_b)
        .map(|(a, b)| (a.xy() - b.xy()).norm() * focal)
        .collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().unwrap_or(f64::INFINITY)
}

/// Relative pose of a pair from their shared tracks.
fn evaluate(
    state: &State<'_>,
    a: usize,
    b: usize,
    seed: u64,
    min_inliers: usize,
) -> Result<Candidate, Rejection> {
    let input = state.input;
    let camera_a = state.rec.camera_of(input, a);
    let camera_b = state.rec.camera_of(input, b);
    let mut rays_a = Vec::new();
    let mut rays_b = Vec::new();
    for track in &input.tracks {
        let ea = track.elements.iter().find(|e| e.image.index() == a);
        let eb = track.elements.iter().find(|e| e.image.index() == b);
        if let (Some(ea), Some(eb)) = (ea, eb) {
            let (Ok(ra), Ok(rb)) = (
                camera_a.unproject(&input.pixel(ea)),
                camera_b.unproject(&input.pixel(eb)),
            ) else {
                continue;
            };
            rays_a.push(ra / ra.z);
            rays_b.push(rb / rb.z);
        }
    }
    if rays_a.len() < min_inliers {
        return Err(Rejection::Weak);
    }
    let focal = 0.5 * (focal_px(camera_a) + focal_px(camera_b));
    let displacement = median_displacement_px(&rays_a, &rays_b, focal);
    if displacement < SAME_VIEW_PX {
        return Err(Rejection::SameView(displacement));
    }
    let estimator = EssentialEstimator {
        x1: &rays_a,
        x2: &rays_b,
        focal_px: focal,
    };
    let result = ransac(
        &estimator,
        &RansacOptions {
            max_error: state.options.init_max_error_px,
            seed,
            ..RansacOptions::default()
        },
    )
    .map_err(|_| Rejection::Weak)?;
    if result.num_inliers < min_inliers {
        return Err(Rejection::Weak);
    }
    let (x1, x2): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = result
        .inliers
        .iter()
        .enumerate()
        .filter(|(_, ok)| **ok)
        .map(|(k, _)| (rays_a[k], rays_b[k]))
        .unzip();
    let (pose, _) =
        relative_pose_from_essential(&result.model, &x1, &x2).map_err(|_| Rejection::Weak)?;
    let identity = Pose::identity();
    let mut angles: Vec<f64> = x1
        .iter()
        .zip(&x2)
        .filter_map(|(r1, r2)| {
            let p = triangulate_two_view_midpoint(&identity, r1, &pose, r2).ok()?;
            (p.z > 0.0 && pose.transform_point(&p).z > 0.0)
                .then(|| triangulation_angle(&identity.center(), &pose.center(), &p).to_degrees())
        })
        .collect();
    if angles.len() < min_inliers {
        return Err(Rejection::Weak);
    }
    angles.sort_by(f64::total_cmp);
    Ok(Candidate {
        cam_b_from_cam_a: pose,
        inliers: result.num_inliers,
        median_angle_deg: angles[angles.len() / 2],
    })
}

/// A camera's focal length in pixels, for expressing ray residuals in pixels: the mean of the
/// unprojection's scales at the image centre.
pub(crate) fn focal_px(camera: &dyn CameraModel) -> f64 {
    let c = nalgebra::Vector2::new(camera.width() as f64 / 2.0, camera.height() as f64 / 2.0);
    let d = nalgebra::Vector2::new(1.0, 0.0);
    match (camera.unproject(&c), camera.unproject(&(c + d))) {
        (Ok(a), Ok(b)) => 1.0 / ((b / b.z) - (a / a.z)).norm().max(1e-12),
        _ => camera.width().max(camera.height()) as f64,
    }
}

/// Halvings of the initial-pair thresholds tried when no pair passes (COLMAP relaxes its
/// initialisation the same way): sequences of close-range photos rarely see 4° at first.
const RELAXATIONS: u32 = 3;

/// Batches of `init_max_trials` pairs evaluated after the first when none has passed the full
/// thresholds yet.
const EXTRA_BATCHES: usize = 7;

/// Chooses and orients the initial pair, triangulates its tracks and adjusts the two images.
/// The most connected pairs are evaluated once, in batches of `init_max_trials` until one passes
/// the full thresholds; the one with the most inliers among those that pass starts, the
/// thresholds halving up to [`RELAXATIONS`] times when none does.
/// Returns the pair.
pub(crate) fn initialise(state: &mut State<'_>) -> Result<(usize, usize), AlignError> {
    let options = state.options;
    let pairs = pair_counts(state);
    let min_shared = (options.init_min_inliers >> RELAXATIONS).max(15);
    // The most connected pairs are often the worst starts: in a repeated survey the same
    // waypoint flown at two epochs shares the most tracks and almost no baseline. So pairs are
    // evaluated in batches, most connected first, until one passes the full thresholds (or
    // EXTRA_BATCHES more batches found none); the relaxations below then choose among all
    // evaluated.
    let mut evaluated: Vec<((usize, usize), Candidate)> = Vec::new();
    let (mut tried, mut same_view) = (0usize, Vec::new());
    let connected: Vec<(usize, usize)> = pairs
        .iter()
        .take_while(|(_, shared)| *shared >= min_shared)
        .map(|&(pair, _)| pair)
        .collect();
    let batch = options.init_max_trials.max(1);
    for chunk in connected.chunks(batch).take(1 + EXTRA_BATCHES) {
        for &(a, b) in chunk {
            let seed = options.seed ^ ((a as u64) << 32 | b as u64);
            tried += 1;
            match evaluate(state, a, b, seed, min_shared) {
                Ok(c) => evaluated.push(((a, b), c)),
                Err(Rejection::SameView(px)) => same_view.push(((a, b), px)),
                Err(Rejection::Weak) => {
                    tracing::debug!(a, b, "initial pair: too few essential inliers")
                }
            }
        }
        let passes_in_full = evaluated.iter().any(|(_, c)| {
            c.inliers >= options.init_min_inliers
                && c.median_angle_deg >= options.init_min_angle_deg
        });
        if passes_in_full {
            break;
        }
    }
    for level in 0..=RELAXATIONS {
        let min_inliers = (options.init_min_inliers >> level).max(15);
        let min_angle = options.init_min_angle_deg / f64::from(1u32 << level);
        let mut passing: Vec<&((usize, usize), Candidate)> = evaluated
            .iter()
            .filter(|(_, c)| c.inliers >= min_inliers && c.median_angle_deg >= min_angle)
            .collect();
        passing.sort_by(|x, y| y.1.inliers.cmp(&x.1.inliers).then(x.0.cmp(&y.0)));
        for &&((a, b), ref candidate) in &passing {
            tracing::info!(
                a,
                b,
                inliers = candidate.inliers,
                median_angle_deg = candidate.median_angle_deg,
                "initial pair"
            );
            state.rec.poses[a] = Some(Pose::identity());
            state.rec.poses[b] = Some(candidate.cam_b_from_cam_a);
            state.gauge = a;
            state.complete_tracks_of_image(a);
            if state.rec.points.len() >= min_inliers / 2 {
                return Ok((a, b));
            }
            state.rec.poses[a] = None;
            state.rec.poses[b] = None;
            state.rec.points.clear();
            state.point_of_track.fill(crate::state::NONE);
        }
    }
    if tried > 0 && same_view.len() == tried {
        let ((a, b), px) = same_view[0];
        return Err(AlignError::NoBaseline {
            pairs: tried,
            first: a,
            second: b,
            displacement_px: px,
        });
    }
    Err(AlignError::NoInitialPair {
        tried,
        min_inliers: options.init_min_inliers,
        min_angle_deg: options.init_min_angle_deg,
    })
}
