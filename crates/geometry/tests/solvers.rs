//! Property tests of every solver: exact recovery on noise-free instances, error bounds under
//! 0.5 px noise, and errors (never NaN) on degenerate input.

mod common;

use common::*;
use nalgebra::{Matrix3, UnitQuaternion, Vector2, Vector3};
use proptest::prelude::*;
use timesift_core::{CameraModel, Pose, SeededRng};
use timesift_geometry::GeometryError;
use timesift_geometry::essential::{
    eight_point_essential, five_point, relative_pose_from_essential,
};
use timesift_geometry::fundamental::{eight_point, seven_point};
use timesift_geometry::homography::{homography_dlt, transfer};
use timesift_geometry::p3p::p3p;
use timesift_geometry::pnp::{RefineOptions, dlt_pnp, refine_pose};
use timesift_geometry::similarity::{TransformKind, umeyama};
use timesift_geometry::triangulation::{
    PixelObservation, TriangulationCheck, intersect_weighted, point_quality, triangulate_dlt,
    triangulate_two_view_midpoint,
};

fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x0715_31f7),
        ..ProptestConfig::default()
    }
}

/// Each pose with its exact ray to `point` (normalised camera coordinates).
fn exact_rays(poses: &[Pose], point: &Vector3<f64>) -> Vec<(Pose, Vector3<f64>)> {
    poses
        .iter()
        .map(|p| {
            let q = p.transform_point(point);
            (*p, q / q.z)
        })
        .collect()
}

/// Angular noise of 0.5 px at the synthetic focal length.
const SIGMA_PX: f64 = 0.5;

proptest! {
    #![proptest_config(config(200))]

    #[test]
    fn five_point_recovers_the_essential_matrix(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let s = two_view(&mut rng, 5, false);
        let sols = five_point(&s.x1, &s.x2).unwrap();
        prop_assert!(!sols.is_empty() && sols.len() <= 10);
        let truth = essential_of(&s.cam2_from_cam1);
        let best = sols.iter().map(|e| projective_distance(e, &truth)).fold(f64::INFINITY, f64::min);
        prop_assert!(best < 1e-8, "closest solution is {best:e} from the truth");
        // Every solution satisfies the five constraints.
        for e in &sols {
            for (a, b) in s.x1.iter().zip(&s.x2) {
                prop_assert!((b.normalize().transpose() * e * a.normalize())[0].abs() < 1e-9);
            }
        }
    }

    #[test]
    fn relative_pose_from_the_essential_matrix_passes_cheirality(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let s = two_view(&mut rng, 30, false);
        let (pose, count) = relative_pose_from_essential(&essential_of(&s.cam2_from_cam1), &s.x1, &s.x2).unwrap();
        prop_assert_eq!(count, 30);
        prop_assert!(pose.rotation.angle_to(&s.cam2_from_cam1.rotation) < 1e-8);
        let t = s.cam2_from_cam1.translation.normalize();
        prop_assert!((pose.translation - t).norm() < 1e-8);
    }

    #[test]
    fn eight_point_essential_exact_and_under_noise(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let n = 100;
        let s = two_view(&mut rng, n, false);
        let truth = essential_of(&s.cam2_from_cam1);
        let e = eight_point_essential(&s.x1, &s.x2, None).unwrap();
        prop_assert!(projective_distance(&e, &truth) < 1e-8);
        // Noise: the bound is derived from the Fisher information of the Sampson residuals at the
        // true pose (σ = 0.5 px / f per residual): the rotation standard deviation of an optimal
        // estimator. The linear fit is allowed 6 of them (measured: median 1.0, max 3.3 over 100
        // scenes), which absorbs its inefficiency and the tail of the distribution.
        let (a, b) = (noisy(&mut rng, &s.x1, SIGMA_PX), noisy(&mut rng, &s.x2, SIGMA_PX));
        let e = eight_point_essential(&a, &b, None).unwrap();
        let (pose, _) = relative_pose_from_essential(&e, &a, &b).unwrap();
        let bound = 6.0 * predicted_rotation_std(&s.cam2_from_cam1, &s.x1, &s.x2, SIGMA_PX / FOCAL);
        let err = pose.rotation.angle_to(&s.cam2_from_cam1.rotation);
        prop_assert!(err < bound, "rotation error {err:e} rad > bound {bound:e}");
    }

    #[test]
    fn seven_and_eight_point_fundamental(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let s = two_view(&mut rng, 60, false);
        let (p1, p2) = (pixels(&s.x1), pixels(&s.x2));
        // F = K⁻ᵀ E K⁻¹ for the pinhole of `pixels`.
        let k = Matrix3::new(FOCAL, 0.0, 800.0, 0.0, FOCAL, 600.0, 0.0, 0.0, 1.0);
        let kinv = k.try_inverse().unwrap();
        let truth = kinv.transpose() * essential_of(&s.cam2_from_cam1) * kinv;
        let sols = seven_point(&p1[..7], &p2[..7]).unwrap();
        prop_assert!(sols.len() == 1 || sols.len() == 3);
        let best = sols.iter().map(|f| projective_distance(f, &truth)).fold(f64::INFINITY, f64::min);
        prop_assert!(best < 1e-8, "seven-point: {best:e}");
        let f = eight_point(&p1, &p2, None).unwrap();
        prop_assert!(projective_distance(&f, &truth) < 1e-8);
        // Under noise the Sampson error of the fit stays at the noise level: mean squared
        // residual ≤ 2σ² (the expectation is below σ² for a consistent fit).
        let mut rng2 = SeededRng::new(seed ^ 1);
        let n1: Vec<_> = p1.iter().map(|p| p + Vector2::new(rng2.normal(), rng2.normal()) * SIGMA_PX).collect();
        let n2: Vec<_> = p2.iter().map(|p| p + Vector2::new(rng2.normal(), rng2.normal()) * SIGMA_PX).collect();
        let f = eight_point(&n1, &n2, None).unwrap();
        let mean: f64 = n1.iter().zip(&n2).map(|(a, b)| timesift_geometry::essential::sampson_distance_sq(&f, &a.push(1.0), &b.push(1.0))).sum::<f64>() / n1.len() as f64;
        prop_assert!(mean < 2.0 * SIGMA_PX * SIGMA_PX, "mean Sampson {mean}");
    }

    #[test]
    fn homography_exact_and_under_noise(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let s = two_view(&mut rng, 50, true);
        let (p1, p2) = (pixels(&s.x1), pixels(&s.x2));
        let h4 = homography_dlt(&p1[..4], &p2[..4], None).unwrap();
        for (a, b) in p1.iter().zip(&p2) {
            let err = (transfer(&h4, a).unwrap() - b).norm();
            prop_assert!(err < 1e-8 * 1000.0, "transfer error {err:e} px");
        }
        let mut rng2 = SeededRng::new(seed ^ 2);
        let n1: Vec<_> = p1.iter().map(|p| p + Vector2::new(rng2.normal(), rng2.normal()) * SIGMA_PX).collect();
        let n2: Vec<_> = p2.iter().map(|p| p + Vector2::new(rng2.normal(), rng2.normal()) * SIGMA_PX).collect();
        let h = homography_dlt(&n1, &n2, None).unwrap();
        // The fitted homography maps the noise-free points within 5σ·√(8/n)·3 of their partners
        // (8 parameters estimated from 2n measurements; factor 3 for the spread of the scenes).
        let bound = 5.0 * SIGMA_PX * (8.0 / 50.0f64).sqrt() * 3.0;
        for (a, b) in p1.iter().zip(&p2) {
            let err = (transfer(&h, a).unwrap() - b).norm();
            prop_assert!(err < bound, "transfer error {err} px > {bound}");
        }
    }

    #[test]
    fn p3p_recovers_the_pose(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let cam = camera();
        let s = absolute_scene(&mut rng, &cam, 3, false);
        let poses = p3p(&s.rays, &s.world).unwrap();
        prop_assert!(!poses.is_empty() && poses.len() <= 4);
        let best = poses.iter().map(|p| {
            let (r, c) = pose_error(p, &s.pose);
            r + c / 100.0
        }).fold(f64::INFINITY, f64::min);
        prop_assert!(best < 1e-8, "best P3P pose error {best:e}");
        for p in &poses {
            for (x, u) in s.world.iter().zip(&s.pixels) {
                let back = timesift_core::project_world(&cam, p, x).unwrap();
                prop_assert!((back - u).norm() < 1e-6);
            }
        }
    }

    #[test]
    fn dlt_pnp_and_refinement(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let cam = camera();
        let n = 40;
        let s = absolute_scene(&mut rng, &cam, n, false);
        let pose = dlt_pnp(&s.rays, &s.world).unwrap();
        let (r, c) = pose_error(&pose, &s.pose);
        prop_assert!(r < 1e-8 && c < 1e-8 * 100.0, "DLT error {r:e} rad {c:e} m");
        // Noise: refine from a perturbed start through the distorted camera.
        let noisy_px: Vec<_> = s.pixels.iter().map(|p| p + Vector2::new(rng.normal(), rng.normal()) * SIGMA_PX).collect();
        let start = Pose::new(UnitQuaternion::from_scaled_axis(Vector3::new(0.02, -0.01, 0.015)) * s.pose.rotation, s.pose.translation + Vector3::new(0.1, -0.1, 0.05));
        let refined = refine_pose(&cam, &start, &s.world, &noisy_px, None, &RefineOptions::default()).unwrap();
        // At the optimum the RMS residual is σ·√((2n − 6)/2n) in expectation; allow 30 %.
        let rms = (s.world.iter().zip(&noisy_px).map(|(x, u)| (timesift_core::project_world(&cam, &refined, x).unwrap() - u).norm_squared()).sum::<f64>() / (2 * n) as f64).sqrt();
        let expected = SIGMA_PX * ((2 * n - 6) as f64 / (2 * n) as f64).sqrt();
        prop_assert!(rms < 1.3 * expected, "rms {rms} vs expected {expected}");
        // Rotation error ≲ 5 σ/f · √(3/n) · (depth/extent ≈ 3).
        let (r, _) = pose_error(&refined, &s.pose);
        let bound = 5.0 * SIGMA_PX / FOCAL * (3.0 / n as f64).sqrt() * 3.0;
        prop_assert!(r < bound, "rotation error {r:e} > {bound:e}");
    }

    #[test]
    fn triangulation_exact_and_weighted_under_noise(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let cam = camera();
        let point = Vector3::new(rng.uniform_range(-5.0, 5.0), rng.uniform_range(-5.0, 5.0), rng.uniform_range(-2.0, 2.0));
        // Four cameras 30 m away looking at the point from different directions.
        let poses: Vec<Pose> = (0..4).map(|k| {
            let dir = Vector3::new((k as f64).cos(), (k as f64).sin(), 1.5).normalize();
            let center = point + dir * 30.0 + Vector3::new(rng.normal(), rng.normal(), rng.normal());
            Pose::look_at(&center, &point).unwrap()
        }).collect();
        let views = exact_rays(&poses, &point);
        let x = triangulate_dlt(&views).unwrap();
        prop_assert!((x - point).norm() < 1e-8 * 30.0);
        let m = triangulate_two_view_midpoint(&views[0].0, &views[0].1, &views[1].0, &views[1].1).unwrap();
        prop_assert!((m - point).norm() < 1e-8 * 30.0);
        let obs: Vec<PixelObservation> = poses.iter().map(|p| PixelObservation {
            camera: &cam,
            pose: *p,
            pixel: timesift_core::project_world(&cam, p, &point).unwrap() + Vector2::new(rng.normal(), rng.normal()) * SIGMA_PX,
            sigma_px: SIGMA_PX,
        }).collect();
        let q = point_quality(&point, &obs);
        prop_assert!(q.in_front && q.max_angle_deg > 20.0);
        prop_assert!(q.passes(&TriangulationCheck::default()));
        let r = intersect_weighted(&obs).unwrap();
        // The error is consistent with the returned covariance: Mahalanobis² below the 99.99 %
        // quantile of χ²(3) = 21.1.
        let d = r.position - point;
        let m2 = (d.transpose() * r.covariance.try_inverse().unwrap() * d)[0];
        prop_assert!(m2 < 21.1, "Mahalanobis² {m2}");
    }

    /// In projected coordinates (UTM: hundreds of thousands of metres east, millions north) a
    /// drone's nadir views of a ground point still intersect in it: the DLT is solved in a
    /// frame of the cameras' own (without it, these failed as "rays do not intersect").
    #[test]
    fn triangulation_in_projected_coordinates(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let cam = camera();
        let origin = Vector3::new(rng.uniform_range(2e5, 8e5), rng.uniform_range(1e6, 9e6), rng.uniform_range(0.0, 3e3));
        let point = origin + Vector3::new(rng.uniform_range(-50.0, 50.0), rng.uniform_range(-50.0, 50.0), rng.uniform_range(-5.0, 5.0));
        // Three nadir views 60 m up, 10-20 m apart.
        let poses: Vec<Pose> = (0..3).map(|k| {
            let center = point + Vector3::new(15.0 * k as f64 - 15.0 + rng.normal(), rng.uniform_range(-5.0, 5.0), 60.0);
            Pose::look_at(&center, &(point + Vector3::new(0.0, 1e-3, 0.0))).unwrap()
        }).collect();
        let views = exact_rays(&poses, &point);
        let x = triangulate_dlt(&views).unwrap();
        // Rounding of coordinates near 1e7 m is about 1e-9 m; the poses carry more.
        prop_assert!((x - point).norm() < 1e-5, "{:e} m off", (x - point).norm());
        let obs: Vec<PixelObservation> = poses.iter().map(|p| PixelObservation {
            camera: &cam,
            pose: *p,
            pixel: timesift_core::project_world(&cam, p, &point).unwrap(),
            sigma_px: SIGMA_PX,
        }).collect();
        let r = intersect_weighted(&obs).unwrap();
        prop_assert!((r.position - point).norm() < 1e-5, "{:e} m off", (r.position - point).norm());
    }

    #[test]
    fn umeyama_similarity_and_rigid(seed in any::<u64>()) {
        let mut rng = SeededRng::new(seed);
        let truth = timesift_geometry::similarity::Similarity {
            scale: rng.uniform_range(0.5, 2.0),
            rotation: random_rotation(&mut rng, 3.0),
            translation: Vector3::new(rng.uniform_range(-1e3, 1e3), rng.uniform_range(-1e3, 1e3), rng.uniform_range(-1e2, 1e2)),
        };
        let src: Vec<Vector3<f64>> = (0..20).map(|_| Vector3::new(rng.uniform_range(-50.0, 50.0), rng.uniform_range(-50.0, 50.0), rng.uniform_range(-5.0, 5.0))).collect();
        let dst: Vec<_> = src.iter().map(|p| truth.apply(p)).collect();
        let s = umeyama(&src, &dst, None, TransformKind::Similarity).unwrap();
        prop_assert!((s.scale - truth.scale).abs() < 1e-8 * truth.scale);
        prop_assert!(s.rotation.angle_to(&truth.rotation) < 1e-8);
        prop_assert!((s.translation - truth.translation).norm() < 1e-8 * 1e3);
        // 1 cm noise on 20 points spread over ~50 m: rotation error ≲ 5·0.01/(50·√20) rad.
        let noisy_dst: Vec<_> = dst.iter().map(|p| p + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.01 * truth.scale).collect();
        let s = umeyama(&src, &noisy_dst, None, TransformKind::Similarity).unwrap();
        prop_assert!(s.rotation.angle_to(&truth.rotation) < 5.0 * 0.01 / (30.0 * 20f64.sqrt()) * 3.0);
        let rigid_dst: Vec<_> = src.iter().map(|p| truth.rotation * p + truth.translation).collect();
        let r = umeyama(&src, &rigid_dst, Some(&[2.0; 20]), TransformKind::Rigid).unwrap();
        prop_assert_eq!(r.scale, 1.0);
        prop_assert!(r.rotation.angle_to(&truth.rotation) < 1e-8);
    }
}

/// Rotation standard deviation (rad) of an optimal relative-pose estimator: σ²(JᵀJ)⁻¹ for the
/// Sampson residuals, J by central differences over (rotation, translation direction).
fn predicted_rotation_std(
    truth: &Pose,
    x1: &[Vector3<f64>],
    x2: &[Vector3<f64>],
    sigma: f64,
) -> f64 {
    use nalgebra::{DMatrix, DVector};
    let t = truth.translation.normalize();
    let u = if t.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let (b1, b2) = (t.cross(&u).normalize(), t.cross(&t.cross(&u).normalize()));
    let residuals = |d: &[f64; 5]| {
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(d[0], d[1], d[2])) * truth.rotation;
        let tt = (t + b1 * d[3] + b2 * d[4]).normalize();
        let e = tt.cross_matrix() * r.to_rotation_matrix().into_inner();
        DVector::from_iterator(
            x1.len(),
            x1.iter().zip(x2).map(|(a, b)| {
                let (a, b) = (a / a.z, b / b.z);
                let (fa, fb) = (e * a, e.transpose() * b);
                b.dot(&fa) / (fa.x * fa.x + fa.y * fa.y + fb.x * fb.x + fb.y * fb.y).sqrt()
            }),
        )
    };
    let mut j = DMatrix::zeros(x1.len(), 5);
    for k in 0..5 {
        let h = 1e-6;
        let (mut p, mut m) = ([0.0; 5], [0.0; 5]);
        p[k] = h;
        m[k] = -h;
        j.set_column(k, &((residuals(&p) - residuals(&m)) / (2.0 * h)));
    }
    let cov = (j.transpose() * &j).try_inverse().unwrap() * (sigma * sigma);
    (cov[(0, 0)] + cov[(1, 1)] + cov[(2, 2)]).sqrt()
}

#[test]
fn degenerate_inputs_are_errors_not_nan() {
    let mut rng = SeededRng::new(11);
    let s = two_view(&mut rng, 30, true);
    let (p1, p2) = (pixels(&s.x1), pixels(&s.x2));
    // Planar scene: the eight-point solver cannot determine F.
    assert!(matches!(
        eight_point(&p1, &p2, None),
        Err(GeometryError::Degenerate { .. })
    ));
    // Fewer points than the minimal sample.
    assert!(matches!(
        five_point(&s.x1[..4], &s.x2[..4]),
        Err(GeometryError::NotEnoughData {
            needed: 5,
            got: 4,
            ..
        })
    ));
    assert!(matches!(
        seven_point(&p1[..6], &p2[..6]),
        Err(GeometryError::NotEnoughData { .. })
    ));
    assert!(matches!(
        homography_dlt(&p1[..3], &p2[..3], None),
        Err(GeometryError::NotEnoughData { .. })
    ));
    assert!(matches!(
        dlt_pnp(&s.x1[..5], &s.points[..5]),
        Err(GeometryError::NotEnoughData { .. })
    ));
    // Collinear points for P3P and the homography.
    let line: Vec<Vector3<f64>> = (0..3)
        .map(|i| Vector3::new(i as f64, 2.0 * i as f64, 5.0))
        .collect();
    assert!(matches!(
        p3p(&s.x1[..3], &line),
        Err(GeometryError::Degenerate { .. })
    ));
    let collinear: Vec<Vector2<f64>> = (0..4)
        .map(|i| {
            Vector2::new(
                i as f64 * 10.0,
                i as f64 * 5.0 + if i == 3 { 40.0 } else { 0.0 },
            )
        })
        .collect();
    assert!(matches!(
        homography_dlt(&collinear, &p2[..4], None),
        Err(GeometryError::Degenerate { .. })
    ));
    // Coplanar points for DLT PnP.
    let cam = camera();
    let planar = absolute_scene(&mut rng, &cam, 20, true);
    assert!(matches!(
        dlt_pnp(&planar.rays, &planar.world),
        Err(GeometryError::Degenerate { .. })
    ));
    // Zero baseline for triangulation.
    let p = Pose::identity();
    assert!(triangulate_two_view_midpoint(&p, &s.x1[0], &p, &s.x1[0]).is_err());
    assert!(triangulate_dlt(&[(p, s.x1[0]), (p, s.x1[0])]).is_err());
    let obs = [PixelObservation {
        camera: &cam,
        pose: p,
        pixel: Vector2::new(800.0, 600.0),
        sigma_px: 1.0,
    }; 2];
    assert!(intersect_weighted(&obs).is_err());
    assert!(intersect_weighted(&obs[..1]).is_err());
    // Collinear points for Umeyama.
    let dst: Vec<_> = line.iter().map(|v| v * 2.0).collect();
    assert!(matches!(
        umeyama(&line, &dst, None, TransformKind::Similarity),
        Err(GeometryError::Degenerate { .. })
    ));
    // NaN anywhere is reported, never propagated.
    let mut bad = s.x1.clone();
    bad[2].x = f64::NAN;
    assert!(matches!(
        five_point(&bad[..5], &s.x2[..5]),
        Err(GeometryError::NonFinite { .. })
    ));
    assert!(matches!(
        p3p(&bad[..3], &s.points[..3]),
        Err(GeometryError::NonFinite { .. })
    ));
    let mut badp = p1.clone();
    badp[0].y = f64::INFINITY;
    assert!(matches!(
        eight_point(&badp, &p2, None),
        Err(GeometryError::NonFinite { .. })
    ));
    assert!(matches!(
        homography_dlt(&badp[..4], &p2[..4], None),
        Err(GeometryError::NonFinite { .. })
    ));
    let _ = cam.width();
}
