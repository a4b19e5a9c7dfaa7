//! The two-view geometry of every image pair that shares enough tracks: relative rotation,
//! direction of the baseline, inliers and the median triangulation angle. What the matching
//! stage verified by a fundamental matrix is estimated again here as an essential matrix at the
//! camera groups' current intrinsics: the global mapper needs the rotations and directions, not
//! only the inlier sets.

use nalgebra::{UnitQuaternion, Vector3};
use rayon::prelude::*;
use timesift_core::{CameraModel, Pose};
use timesift_geometry::essential::{EssentialEstimator, relative_pose_from_essential};
use timesift_geometry::ransac::{RansacOptions, ransac};
use timesift_geometry::triangulation::{triangulate_two_view_midpoint, triangulation_angle};

use crate::init::focal_px;
use crate::model::SfmInput;
use crate::options::SfmOptions;

/// Fewest shared tracks for a pair to be estimated, and fewest essential inliers to be kept
/// (GLOMAP keeps two-view geometries from 30 inliers).
pub(crate) const MIN_PAIR_INLIERS: usize = 30;
/// Smallest inlier share of a pair's shared tracks: below, the essential matrix explains a
/// minority of what the matcher verified and is more likely a wrong model than a right one.
const MIN_INLIER_SHARE: f64 = 0.5;
/// Below this median triangulation angle the baseline's direction is noise (the same waypoint
/// flown at two epochs): the pair gives its rotation only.
pub(crate) const MIN_DIRECTION_ANGLE_DEG: f64 = 1.5;
/// Most correspondences per pair given to RANSAC: more add time, not accuracy, to a rotation
/// and a direction.
const MAX_CORRESPONDENCES: usize = 400;
/// Partners each image keeps within its own flight and, as many again, from other flights: the
/// pairs that share most tracks. Tracks join images transitively, so an 800-image block of 8
/// epochs has about 190 partners per image sharing 30 tracks; the averaging needs a
/// well-connected graph, not all of them, and the pairs estimated stay linear in the images.
/// Kept apart for the other flights so that the epochs stay tied to each other when the
/// images of one flight share more tracks among themselves.
pub(crate) const MAX_PARTNERS: usize = 20;

/// One pair's relative geometry.
#[derive(Debug, Clone, Copy)]
pub(crate) struct TwoView {
    /// First image (the lower index).
    pub a: usize,
    /// Second image.
    pub b: usize,
    /// Rotation `cam_b_from_cam_a`.
    pub rotation: UnitQuaternion<f64>,
    /// Unit translation of `cam_b_from_cam_a`, when the baseline is long enough to give it.
    pub translation: Option<Vector3<f64>>,
    /// Essential-matrix inliers.
    pub inliers: usize,
}

/// Shared keypoints per image pair: for every track, every pair of its elements, sorted by
/// pair. Each entry is (a, b, feature in a, feature in b) with a < b.
fn correspondences(input: &SfmInput) -> Vec<(u32, u32, u32, u32)> {
    let mut all = Vec::new();
    for track in &input.tracks {
        for (k, ea) in track.elements.iter().enumerate() {
            for eb in &track.elements[k + 1..] {
                let (x, y) = if ea.image < eb.image {
                    (ea, eb)
                } else {
                    (eb, ea)
                };
                if x.image == y.image {
                    continue;
                }
                all.push((
                    x.image.index() as u32,
                    y.image.index() as u32,
                    x.feature.index() as u32,
                    y.feature.index() as u32,
                ));
            }
        }
    }
    all.par_sort_unstable();
    all
}

/// The relative geometry of the pairs with at least [`MIN_PAIR_INLIERS`] shared tracks whose
/// essential matrix explains most of them, at most [`MAX_PARTNERS`] per image within its flight
/// and as many across (`flight_of`: each image's flight, `None` for images without one, which
/// count as one flight). Pairs come sorted by (a, b); the result does not depend on the thread
/// count (each pair's RANSAC is seeded by the pair).
pub(crate) fn relative_poses(
    input: &SfmInput,
    options: &SfmOptions,
    flight_of: &[Option<usize>],
) -> Vec<TwoView> {
    let all = correspondences(input);
    let mut groups: Vec<&[(u32, u32, u32, u32)]> = Vec::new();
    let mut start = 0;
    for k in 1..=all.len() {
        if k == all.len() || all[k].0 != all[start].0 || all[k].1 != all[start].1 {
            if k - start >= MIN_PAIR_INLIERS {
                groups.push(&all[start..k]);
            }
            start = k;
        }
    }
    let groups = strongest_partners(groups, input.images.len(), flight_of);
    groups
        .par_iter()
        .filter_map(|group| estimate(input, options, group))
        .collect()
}

/// The pairs (groups of one pair's correspondences, sorted by pair) among the [`MAX_PARTNERS`]
/// that share most tracks with either of their images, counted apart within the image's flight
/// and across; ties go to the lower image index, so the choice is deterministic.
fn strongest_partners<'a>(
    groups: Vec<&'a [(u32, u32, u32, u32)]>,
    images: usize,
    flight_of: &[Option<usize>],
) -> Vec<&'a [(u32, u32, u32, u32)]> {
    let flight = |i: u32| flight_of.get(i as usize).copied().flatten();
    // Per image and kind (0 within, 1 across): (shared tracks, partner, pair index).
    let mut partners: Vec<[Vec<(usize, u32, usize)>; 2]> = vec![[Vec::new(), Vec::new()]; images];
    for (k, group) in groups.iter().enumerate() {
        let (a, b) = (group[0].0, group[0].1);
        let kind = usize::from(flight(a) != flight(b));
        partners[a as usize][kind].push((group.len(), b, k));
        partners[b as usize][kind].push((group.len(), a, k));
    }
    let mut keep = vec![false; groups.len()];
    for list in partners.iter_mut().flat_map(|kinds| kinds.iter_mut()) {
        list.sort_unstable_by(|x, y| y.0.cmp(&x.0).then(x.1.cmp(&y.1)));
        for &(_, _, k) in list.iter().take(MAX_PARTNERS) {
            keep[k] = true;
        }
    }
    groups
        .into_iter()
        .zip(keep)
        .filter_map(|(group, kept)| kept.then_some(group))
        .collect()
}

/// One pair's essential matrix, pose and median angle.
fn estimate(
    input: &SfmInput,
    options: &SfmOptions,
    group: &[(u32, u32, u32, u32)],
) -> Option<TwoView> {
    let (a, b) = (group[0].0 as usize, group[0].1 as usize);
    let camera_a = &input.cameras[input.images[a].group];
    let camera_b = &input.cameras[input.images[b].group];
    // An even subsample of the largest pairs, deterministic.
    let step = group.len().div_ceil(MAX_CORRESPONDENCES);
    let mut rays_a = Vec::with_capacity(group.len() / step + 1);
    let mut rays_b = Vec::with_capacity(group.len() / step + 1);
    for &(_, _, fa, fb) in group.iter().step_by(step) {
        let pa = input.images[a].keypoints[fa as usize];
        let pb = input.images[b].keypoints[fb as usize];
        let (Ok(ra), Ok(rb)) = (camera_a.unproject(&pa), camera_b.unproject(&pb)) else {
            continue;
        };
        if ra.z <= 0.0 || rb.z <= 0.0 {
            continue;
        }
        rays_a.push(ra / ra.z);
        rays_b.push(rb / rb.z);
    }
    if rays_a.len() < MIN_PAIR_INLIERS {
        return None;
    }
    let estimator = EssentialEstimator {
        x1: &rays_a,
        x2: &rays_b,
        focal_px: 0.5 * (focal_px(camera_a) + focal_px(camera_b)),
    };
    let seed = options.seed ^ ((a as u64) << 32 | b as u64);
    let result = ransac(
        &estimator,
        &RansacOptions {
            max_error: options.init_max_error_px,
            seed,
            ..RansacOptions::default()
        },
    )
    .ok()?;
    if result.num_inliers < MIN_PAIR_INLIERS
        || (result.num_inliers as f64) < MIN_INLIER_SHARE * rays_a.len() as f64
    {
        return None;
    }
    let (x1, x2): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = result
        .inliers
        .iter()
        .zip(rays_a.iter().zip(&rays_b))
        .filter(|(ok, _)| **ok)
        .map(|(_, (r1, r2))| (*r1, *r2))
        .unzip();
    let (pose, _) = relative_pose_from_essential(&result.model, &x1, &x2).ok()?;
    let angle = median_angle_deg(&pose, &x1, &x2)?;
    Some(TwoView {
        a,
        b,
        rotation: pose.rotation,
        translation: (angle >= MIN_DIRECTION_ANGLE_DEG).then(|| pose.translation.normalize()),
        inliers: result.num_inliers,
    })
}

/// Median triangulation angle of the correspondences in front of both cameras, degrees; `None`
/// when fewer than half are.
fn median_angle_deg(pose: &Pose, x1: &[Vector3<f64>], x2: &[Vector3<f64>]) -> Option<f64> {
    let identity = Pose::identity();
    let mut angles: Vec<f64> = x1
        .iter()
        .zip(x2)
        .filter_map(|(r1, r2)| {
            let p = triangulate_two_view_midpoint(&identity, r1, pose, r2).ok()?;
            (p.z > 0.0 && pose.transform_point(&p).z > 0.0)
                .then(|| triangulation_angle(&identity.center(), &pose.center(), &p).to_degrees())
        })
        .collect();
    if angles.len() * 2 < x1.len() {
        return None;
    }
    let mid = angles.len() / 2;
    let (_, median, _) = angles.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*median)
}

#[cfg(test)]
mod tests {
    use super::{MAX_PARTNERS, strongest_partners};

    /// `n` correspondences of pair (a, b).
    fn pair(a: u32, b: u32, n: usize) -> Vec<(u32, u32, u32, u32)> {
        (0..n as u32).map(|k| (a, b, k, k)).collect()
    }

    /// Two flights of 100 images each, every pair within a flight sharing more tracks than any
    /// pair across: each image keeps its strongest partners within its flight and still its
    /// strongest across, and no image more than twice [`MAX_PARTNERS`] of its own choosing.
    #[test]
    fn each_image_keeps_its_strongest_partners_within_and_across_its_flight() {
        let images = 200u32;
        let flight_of: Vec<Option<usize>> = (0..images).map(|i| Some(i as usize / 100)).collect();
        let mut all = Vec::new();
        for a in 0..images {
            for b in a + 1..images {
                let same = a / 100 == b / 100;
                // Within: more shared the nearer; across: fewer, also by distance.
                let n = if same {
                    400 - (b - a) as usize
                } else {
                    200 - (b - a) as usize / 2
                };
                all.push(pair(a, b, n));
            }
        }
        let groups: Vec<&[(u32, u32, u32, u32)]> = all.iter().map(|g| g.as_slice()).collect();
        let total = groups.len();
        let kept = strongest_partners(groups, images as usize, &flight_of);
        assert!(
            kept.len() < total / 2,
            "{} of {total} pairs kept",
            kept.len()
        );
        assert!(kept.len() <= 2 * MAX_PARTNERS * images as usize);
        let is_kept = |a: u32, b: u32| kept.iter().any(|g| g[0].0 == a && g[0].1 == b);
        // Image 0's nearest partner within and its strongest across (image 100), not its
        // weakest within (image 99).
        assert!(is_kept(0, 1));
        assert!(is_kept(0, 100));
        assert!(!is_kept(0, 99));
        for image in 0..images {
            let across = kept
                .iter()
                .filter(|g| (g[0].0 == image || g[0].1 == image) && g[0].0 / 100 != g[0].1 / 100)
                .count();
            assert!(
                across >= MAX_PARTNERS,
                "image {image}: {across} pairs across"
            );
        }
        // The pairs stay sorted by pair, as `estimate`'s callers expect.
        assert!(
            kept.windows(2)
                .all(|w| (w[0][0].0, w[0][0].1) < (w[1][0].0, w[1][0].1))
        );
    }
}
