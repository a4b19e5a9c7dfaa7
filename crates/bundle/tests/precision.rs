//! Precision output: the posterior variance factor matches the noise, reported standard deviations
//! of camera centres and self-calibrated intrinsics agree with their spread over 50 seeded noise
//! realisations, gross errors are flagged, and a free network is refused.

mod common;

use nalgebra::{Vector2, Vector3};
use timesift_bundle::precision::{CovarianceScale, precision, residual_statistics};
use timesift_bundle::problem::{BundleImage, BundlePoint};
use timesift_bundle::{
    BundleError, BundleOptions, BundleProblem, CameraGroup, CenterPrior, Loss, Observation, solve,
};
use timesift_core::{BrownCamera, Camera, Pose, SeededRng, project_world};

const SIGMA_PX: f64 = 0.5;
const F: usize = 0;
const K1: usize = 5;

struct Truth {
    camera: BrownCamera,
    poses: Vec<Pose>,
    points: Vec<Vector3<f64>>,
}

/// Ten views (eight oblique on a ring, two nadir) of 200 points on rough terrain.
fn truth() -> Truth {
    let mut rng = SeededRng::new(1);
    let mut camera = BrownCamera::new(2000, 1500, 1800.0).expect("camera");
    camera.k1 = -0.06;
    let points = (0..200)
        .map(|_| {
            Vector3::new(
                rng.uniform_range(-12.0, 12.0),
                rng.uniform_range(-12.0, 12.0),
                rng.uniform_range(-3.0, 3.0),
            )
        })
        .collect();
    let mut poses: Vec<Pose> = (0..8)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 8.0;
            Pose::look_at(
                &Vector3::new(35.0 * a.cos(), 35.0 * a.sin(), 25.0),
                &Vector3::zeros(),
            )
            .expect("pose")
        })
        .collect();
    for x in [-4.0, 4.0] {
        poses.push(
            Pose::look_at(&Vector3::new(x, 0.5, 40.0), &Vector3::new(x, 0.0, 0.0)).expect("pose"),
        );
    }
    Truth {
        camera,
        poses,
        points,
    }
}

/// One noise realisation: observations (0.5 px), GNSS centres (2 cm / 5 cm), ten control points
/// (1 cm / 2 cm), a perturbed start; f and k1 free.
fn realisation(t: &Truth, seed: u64) -> BundleProblem {
    let mut rng = SeededRng::new(seed);
    let mut observations = Vec::new();
    for (i, pose) in t.poses.iter().enumerate() {
        for (j, x) in t.points.iter().enumerate() {
            if let Ok(px) = project_world(&t.camera, pose, x) {
                if px.x > 0.0 && px.y > 0.0 && px.x < 2000.0 && px.y < 1500.0 {
                    observations.push(Observation {
                        image: i,
                        point: j,
                        pixel: px + Vector2::new(rng.normal(), rng.normal()) * SIGMA_PX,
                        sigma_px: SIGMA_PX,
                    });
                }
            }
        }
    }
    let center_priors = t
        .poses
        .iter()
        .enumerate()
        .map(|(i, pose)| CenterPrior {
            image: i,
            position: pose.center()
                + Vector3::new(
                    rng.normal() * 0.02,
                    rng.normal() * 0.02,
                    rng.normal() * 0.05,
                ),
            sigma_xy: 0.02,
            sigma_z: 0.05,
            offset: None,
        })
        .collect();
    let point_priors = (0..10)
        .map(|j| common::surveyed(j, &t.points[j], 0.01, 0.02, &mut rng))
        .collect();
    let mut start = t.camera;
    start.f *= 1.005;
    start.k1 *= 0.9;
    BundleProblem {
        groups: vec![CameraGroup::with_free(Camera::Brown(start), &["f", "k1"]).expect("group")],
        images: t
            .poses
            .iter()
            .map(|p| BundleImage {
                pose: p.retract(&nalgebra::Vector6::from_fn(|k, _| {
                    (if k < 3 { 0.002 } else { 0.05 }) * rng.normal()
                })),
                group: 0,
                fixed: false,
            })
            .collect(),
        points: t
            .points
            .iter()
            .map(|x| BundlePoint {
                position: x + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.03,
                fixed: false,
            })
            .collect(),
        observations,
        center_priors,
        prior_offsets: Vec::new(),
        point_priors,
        scale_bars: Vec::new(),
    }
}

fn options() -> BundleOptions {
    BundleOptions {
        function_tolerance: 1e-12,
        parameter_tolerance: 1e-12,
        ..BundleOptions::default()
    }
}

#[test]
fn reported_standard_deviations_match_the_spread_over_50_runs() {
    let t = truth();
    let runs = 50;
    let (mut f, mut k1) = (Vec::new(), Vec::new());
    let mut centres: Vec<Vec<Vector3<f64>>> = Vec::new();
    let (mut pred_f, mut pred_k1) = (0.0, 0.0);
    let mut pred_centre_var = 0.0;
    let mut factors = Vec::new();
    for run in 0..runs {
        let mut p = realisation(&t, 1000 + run);
        solve(&mut p, &options()).expect("solve");
        let stats = residual_statistics(&p, 4.0);
        factors.push(stats.variance_factor);
        // A-priori covariances: the sigmas are right by construction, so σ0² only adds noise.
        let prec = precision(&p, CovarianceScale::Prior).expect("precision");
        pred_f += prec.intrinsic_std(0, F).expect("f free").powi(2) / runs as f64;
        pred_k1 += prec.intrinsic_std(0, K1).expect("k1 free").powi(2) / runs as f64;
        for i in 0..t.poses.len() {
            let s = prec.center_std(i).expect("free");
            pred_centre_var +=
                s.iter().map(|v| v * v).sum::<f64>() / (runs as f64 * 3.0 * t.poses.len() as f64);
        }
        f.push(common::intrinsic(&p, F));
        k1.push(common::intrinsic(&p, K1));
        centres.push(p.images.iter().map(|im| im.pose.center()).collect());
    }
    let ratio_f = common::spread(&f) / pred_f.sqrt();
    let ratio_k1 = common::spread(&k1) / pred_k1.sqrt();
    // Camera centres: empirical variance pooled over all images and axes.
    let mut pooled = 0.0;
    for i in 0..t.poses.len() {
        for c in 0..3 {
            let v: Vec<f64> = centres.iter().map(|run| run[i][c]).collect();
            pooled += common::spread(&v).powi(2) / (3.0 * t.poses.len() as f64);
        }
    }
    let ratio_centres = (pooled / pred_centre_var).sqrt();
    let mean_factor = factors.iter().sum::<f64>() / factors.len() as f64;
    println!(
        "spread / reported σ over {runs} runs: f {ratio_f:.3} (σ {:.4} px), k1 {ratio_k1:.3} (σ {:.2e}), centres {ratio_centres:.3} (σ {:.4} m); mean σ0² {mean_factor:.3}",
        pred_f.sqrt(),
        pred_k1.sqrt(),
        pred_centre_var.sqrt()
    );
    for (name, r) in [("f", ratio_f), ("k1", ratio_k1), ("centres", ratio_centres)] {
        assert!((r - 1.0).abs() < 0.2, "{name}: spread/reported = {r}");
    }
    assert!((mean_factor - 1.0).abs() < 0.05, "{mean_factor}");
    // f and k1 recovered: mean within 0.1 % and 5 %.
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!((mean(&f) / t.camera.f - 1.0).abs() < 1e-3);
    assert!((mean(&k1) / t.camera.k1 - 1.0).abs() < 0.05);
}

#[test]
fn gross_errors_are_flagged() {
    let t = truth();
    let mut p = realisation(&t, 7);
    let bad = [3usize, 250, 611, 900, 1333];
    for &k in &bad {
        p.observations[k].pixel += Vector2::new(15.0, -12.0);
    }
    let o = BundleOptions {
        loss: Loss::Huber(2.0),
        ..options()
    };
    solve(&mut p, &o).expect("solve");
    let stats = residual_statistics(&p, 4.0);
    assert_eq!(
        stats.outliers,
        bad.to_vec(),
        "σ0² = {}",
        stats.variance_factor
    );
    assert!(stats.reprojection.count == p.observations.len());
    assert_eq!(stats.per_image.len(), 10);
    let (rms, n) = stats.center_priors.expect("centre priors");
    assert_eq!(n, 10);
    assert!(rms[0] < 0.05 && rms[2] < 0.1, "{rms:?}");
}

#[test]
fn a_free_network_has_no_covariance() {
    let t = truth();
    let mut p = realisation(&t, 3);
    p.center_priors.clear();
    p.point_priors.clear();
    solve(&mut p, &options()).expect("solve");
    let e = precision(&p, CovarianceScale::Posterior).unwrap_err();
    assert!(matches!(e, BundleError::Singular(_)), "{e}");
}

/// The rigid motions of two sets of cameras (each half of the ring with one nadir view) and
/// their difference, against their spread over 50 noise realisations: the covariance of
/// `rigid_motion_covariance`, cross terms included, is what the adjustment's errors do.
#[test]
fn rigid_motion_covariance_matches_the_spread_of_two_sets_over_50_runs() {
    use timesift_bundle::rigid::{rigid_motion, rigid_motion_covariance};
    let t = truth();
    let sets = [vec![0, 1, 2, 3, 8], vec![4, 5, 6, 7, 9]];
    let lever = 35.0;
    let runs = 50;
    let mut predicted = [0.0f64; 3]; // rotation of set 0, of set 1, of their difference
    let mut motions: Vec<[nalgebra::Vector6<f64>; 2]> = Vec::new();
    for run in 0..runs {
        let mut p = realisation(&t, 2000 + run);
        solve(&mut p, &options()).expect("solve");
        let c =
            rigid_motion_covariance(&p, &sets, lever, CovarianceScale::Prior).expect("covariance");
        for k in 0..3 {
            predicted[0] += c[(k, k)] / (3 * runs) as f64;
            predicted[1] += c[(6 + k, 6 + k)] / (3 * runs) as f64;
            predicted[2] +=
                (c[(k, k)] + c[(6 + k, 6 + k)] - 2.0 * c[(k, 6 + k)]) / (3 * runs) as f64;
        }
        let motion = |set: &[usize]| {
            let truth: Vec<Pose> = set.iter().map(|&i| t.poses[i]).collect();
            let adjusted: Vec<Pose> = set.iter().map(|&i| p.images[i].pose).collect();
            rigid_motion(&truth, &adjusted, lever).expect("motion")
        };
        motions.push([motion(&sets[0]), motion(&sets[1])]);
    }
    let pooled = |value: &dyn Fn(&[nalgebra::Vector6<f64>; 2], usize) -> f64| {
        (0..3)
            .map(|k| {
                let v: Vec<f64> = motions.iter().map(|m| value(m, k)).collect();
                common::spread(&v).powi(2) / 3.0
            })
            .sum::<f64>()
    };
    let measured = [
        pooled(&|m, k| m[0][k]),
        pooled(&|m, k| m[1][k]),
        pooled(&|m, k| m[1][k] - m[0][k]),
    ];
    for (name, (m, p)) in ["set 0", "set 1", "difference"]
        .iter()
        .zip(measured.iter().zip(&predicted))
    {
        let ratio = (m / p).sqrt();
        println!(
            "{name}: rotation spread {:.2e} rad, predicted σ {:.2e} rad, ratio {ratio:.3}",
            m.sqrt(),
            p.sqrt()
        );
        assert!(
            (ratio - 1.0).abs() < 0.2,
            "{name}: spread/predicted = {ratio}"
        );
    }
}

#[test]
fn a_rigid_motion_of_the_cameras_is_recovered_exactly_and_one_camera_is_refused() {
    use timesift_bundle::rigid::rigid_motion;
    let t = truth();
    let theta = nalgebra::Vector3::new(2e-4, -3e-4, 1e-4);
    let tau = nalgebra::Vector3::new(0.05, -0.02, 0.1);
    let centroid = t.poses.iter().fold(Vector3::zeros(), |a, p| a + p.center()) / 10.0;
    let q = nalgebra::UnitQuaternion::from_scaled_axis(theta);
    // The world turned by Q about the centroid and shifted: cameras that see it alike.
    let moved: Vec<Pose> = t
        .poses
        .iter()
        .map(|p| {
            let centre = q * (p.center() - centroid) + centroid + tau;
            let rotation = p.rotation * q.inverse();
            Pose::new(rotation, -(rotation * centre))
        })
        .collect();
    let motion = rigid_motion(&t.poses, &moved, 35.0).expect("motion");
    for k in 0..3 {
        // First order in θ: the recovered motion is exact to O(θ²).
        assert!((motion[k] - theta[k]).abs() < 1e-7, "{motion:?}");
        assert!((motion[3 + k] - tau[k]).abs() < 1e-4, "{motion:?}");
    }
    assert!(rigid_motion(&t.poses[..1], &moved[..1], 35.0).is_err());
    assert!(rigid_motion(&t.poses, &moved[..3], 35.0).is_err());
    assert!(rigid_motion(&t.poses, &moved, f64::NAN).is_err());
}
