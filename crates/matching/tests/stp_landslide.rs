//! Stable tie points on the rendered `landslide` scene: two epochs triangulated separately (the
//! second in a frame shifted by a known similarity, as an independent orientation would leave
//! it), then `stp` finds the pairs of tie points that did not move. None of the accepted pairs
//! joins two points whose true positions differ (moving ground: the slide moved 3 m between the
//! epochs), and the similarity fitted on them undoes the known one within a ground sampling
//! distance over the scene.

mod common;

use nalgebra::{UnitQuaternion, Vector2, Vector3};
use rayon::prelude::*;
use timesift_core::{CameraModel, Descriptors, ImageId, project_world};
use timesift_features::FeatureExtractor;
use timesift_geometry::similarity::Similarity;
use timesift_geometry::triangulation::triangulate_two_view_midpoint;
use timesift_matching::pairs::{PairPolicy, select};
use timesift_matching::stp::{StpOptions, TiePoint, stable_tie_points};
use timesift_matching::tracks::{PairMatches, build_tracks};
use timesift_matching::verify::{VerifyOptions, verify_pair};
use timesift_matching::{FloatDistance, MatchOptions, match_descriptors};

#[test]
fn stable_tie_points_avoid_the_slide_and_recover_the_frame() {
    let common::Rendered { dir, truth, epochs } = common::landslide();
    let stable =
        timesift_io::csv_inputs::read_stable_areas(&dir.path().join("stable.csv")).unwrap();
    let is_stable = |x: f64, y: f64| {
        stable
            .iter()
            .flat_map(|a| &a.polygons)
            .any(|p| p.contains(x, y))
    };
    let extractor = common::rootsift(4000);
    // Tie points of one epoch, triangulated with the true cameras.
    let epoch_points = |epoch: &str| -> (Vec<TiePoint>, f64) {
        let images: Vec<usize> = (0..truth.images.len())
            .filter(|&i| truth.images[i].epoch == epoch)
            .collect();
        let features: Vec<_> = images
            .par_iter()
            .map(|&i| {
                timesift_features::files::extract_file(
                    &dir.path().join(&truth.images[i].name),
                    &extractor as &dyn FeatureExtractor,
                )
                .unwrap()
            })
            .collect();
        let n = images.len();
        let options = MatchOptions {
            ratio_on: FloatDistance::Angle,
            ..MatchOptions::default()
        };
        let pairs = select(
            &(0..n).collect::<Vec<_>>(),
            &vec![None; n],
            PairPolicy::Exhaustive,
        );
        let verified: Vec<PairMatches> = pairs
            .par_iter()
            .filter_map(|&(a, b)| {
                let m =
                    match_descriptors(&features[a].descriptors, &features[b].descriptors, &options)
                        .unwrap();
                let v = verify_pair(
                    &features[a].keypoints,
                    &features[b].keypoints,
                    &m,
                    None,
                    &VerifyOptions {
                        max_error_px: 2.0,
                        ..VerifyOptions::default()
                    },
                )
                .unwrap()?;
                Some(PairMatches {
                    a: ImageId::from(a),
                    b: ImageId::from(b),
                    matches: v.inliers,
                })
            })
            .collect();
        let counts: Vec<usize> = features.iter().map(|f| f.keypoints.len()).collect();
        let tracks = build_tracks(&counts, &verified).unwrap();
        let mut gsd = Vec::new();
        let points = tracks
            .tracks
            .iter()
            .filter(|t| t.len() >= 3)
            .filter_map(|t| {
                let obs: Vec<(usize, usize)> = t
                    .elements
                    .iter()
                    .map(|e| (e.image.index(), e.feature.index()))
                    .collect();
                let pixel = |(k, f): (usize, usize)| {
                    let kp = &features[k].keypoints[f];
                    Vector2::new(kp.x, kp.y)
                };
                let cam = |k: usize| &truth.cameras[&truth.images[images[k]].camera];
                let pose = |k: usize| truth.images[images[k]].pose.unwrap();
                let (first, last) = (obs[0], obs[obs.len() - 1]);
                let x = triangulate_two_view_midpoint(
                    &pose(first.0),
                    &cam(first.0).unproject(&pixel(first)).ok()?,
                    &pose(last.0),
                    &cam(last.0).unproject(&pixel(last)).ok()?,
                )
                .ok()?;
                for &o in &obs {
                    let p = project_world(cam(o.0), &pose(o.0), &x).ok()?;
                    if (p - pixel(o)).norm() > 2.0 {
                        return None;
                    }
                }
                let f = {
                    let mut v = [0.0; 12];
                    cam(first.0).params(&mut v[..cam(first.0).num_params()]);
                    v[0]
                };
                gsd.push((pose(first.0).center() - x).norm() / f);
                let mut descriptors = Vec::new();
                for &(k, f) in &obs {
                    if let Descriptors::Float { dim, data } = &features[k].descriptors {
                        descriptors.extend_from_slice(&data[f * dim..(f + 1) * dim]);
                    }
                }
                Some(TiePoint {
                    position: x,
                    descriptors,
                })
            })
            .collect();
        gsd.sort_by(f64::total_cmp);
        (points, gsd[gsd.len() / 2])
    };
    let (reference, gsd) = epoch_points(&epochs[0]);
    let (second, _) = epoch_points(&epochs[1]);
    // The second epoch's frame: 0.3° about the vertical, (1.5, −1.0, 0.4) m, scale 1.002, about
    // the scene's centre.
    let centre =
        reference.iter().map(|t| t.position).sum::<Vector3<f64>>() / reference.len() as f64;
    let rotation = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3f64.to_radians());
    let other_from_true = Similarity {
        scale: 1.002,
        rotation,
        translation: centre + Vector3::new(1.5, -1.0, 0.4) - rotation * centre * 1.002,
    };
    let other: Vec<TiePoint> = second
        .iter()
        .map(|t| TiePoint {
            position: other_from_true.apply(&t.position),
            descriptors: t.descriptors.clone(),
        })
        .collect();
    let result = stable_tie_points(&reference, &other, 128, &StpOptions::default()).unwrap();
    // Moving ground: the holes of the stable polygon (the slide's body, the boulder field, the
    // unstable band). Tie points beyond the polygon's outer ring are outside the modelled area.
    let holes: Vec<&Vec<[f64; 2]>> = stable
        .iter()
        .flat_map(|a| &a.polygons)
        .flat_map(|p| &p.holes)
        .collect();
    let in_hole = |x: f64, y: f64| {
        holes
            .iter()
            .position(|h| timesift_io::wkt::ring_contains(h, x, y))
    };
    let mut per_hole = vec![0usize; holes.len()];
    for p in &result.pairs {
        let q = reference[p.reference].position;
        if let Some(h) = in_hole(q.x, q.y) {
            per_hole[h] += 1;
        }
    }
    let outside = result
        .pairs
        .iter()
        .filter(|p| {
            let q = reference[p.reference].position;
            !is_stable(q.x, q.y) && in_hole(q.x, q.y).is_none()
        })
        .count();
    println!(
        "accepted pairs per unstable hole of stable.csv: {per_hole:?}; beyond the modelled area: {outside}"
    );
    // A pair on moving ground joins two points whose true positions differ (the slide moved
    // 3 m between these epochs); stable pairs agree within the triangulation noise.
    let true_from_other = other_from_true.inverse();
    let moving: Vec<_> = result
        .pairs
        .iter()
        .filter(|p| {
            let a = reference[p.reference].position;
            let b = true_from_other.apply(&other[p.other].position);
            (a - b).norm() > 1.0
        })
        .map(|p| reference[p.reference].position)
        .collect();
    let moved_candidates = moving.len();
    // The candidates the similarity removed: mostly ground that truly moved.
    let removed_and_moved = result
        .moved
        .iter()
        .filter(|p| {
            let a = reference[p.reference].position;
            let b = true_from_other.apply(&other[p.other].position);
            (a - b).norm() > 1.0
        })
        .count();
    println!(
        "the similarity removed {} candidate pairs, {removed_and_moved} of which truly moved",
        result.moved.len()
    );
    // The fitted transform against the truth, at the tie points' extent.
    let worst = reference
        .iter()
        .map(|t| {
            (result
                .reference_from_other
                .apply(&other_from_true.apply(&t.position))
                - t.position)
                .norm()
        })
        .fold(0.0f64, f64::max);
    println!(
        "{} and {} tie points; {} candidate pairs, {} stable; {moved_candidates} accepted pairs \
         moved; worst frame error {worst:.3} m over the scene, GSD {gsd:.3} m",
        reference.len(),
        other.len(),
        result.candidates,
        result.pairs.len(),
    );
    assert!(result.pairs.len() >= 20);
    assert!(
        moving.is_empty(),
        "accepted pairs on moving ground: {moving:?}"
    );
    assert!(worst <= gsd, "frame error {worst} m > GSD {gsd} m");
}
