//! Robust estimation with 50 % outliers: for each model, 1000 seeded trials of 100
//! correspondences (50 inliers with 0.5 px noise, 50 uniform outliers) must find the truth in at
//! least 99 % of them.

mod common;

use common::*;
use nalgebra::{Vector2, Vector3};
use timesift_core::{CameraModel, SeededRng};
use timesift_geometry::essential::{
    EssentialEstimator, relative_pose_from_essential, relative_pose_residuals,
};
use timesift_geometry::fundamental::FundamentalEstimator;
use timesift_geometry::homography::{HomographyEstimator, transfer};
use timesift_geometry::pnp::AbsolutePoseEstimator;
use timesift_geometry::ransac::{RansacOptions, Scoring, ransac};
use timesift_geometry::similarity::{Similarity, SimilarityEstimator, TransformKind};

const TRIALS: u64 = 1000;
const INLIERS: usize = 50;
const OUTLIERS: usize = 50;

fn options(seed: u64, max_error: f64, scoring: Scoring) -> RansacOptions {
    RansacOptions {
        max_error,
        seed,
        scoring,
        confidence: 0.999,
        ..RansacOptions::default()
    }
}

/// Runs `trial` for every seed and asserts at least 99 % successes.
fn success_rate(name: &str, trial: impl Fn(u64) -> bool + Sync) {
    let successes: usize = std::thread::scope(|s| {
        let handles: Vec<_> = (0..2u64)
            .map(|half| {
                let trial = &trial;
                s.spawn(move || {
                    (half..TRIALS)
                        .step_by(2)
                        .filter(|&seed| trial(seed))
                        .count()
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).sum()
    });
    println!("{name}: {successes}/{TRIALS}");
    assert!(
        successes as f64 >= 0.99 * TRIALS as f64,
        "{name}: only {successes}/{TRIALS} trials found the truth"
    );
}

/// Outlier pixels anywhere in a 1600 × 1200 image, as z = 1 rays of the pinhole in `pixels`.
fn outlier_ray(rng: &mut SeededRng) -> Vector3<f64> {
    Vector3::new(
        (rng.uniform_range(0.0, 1600.0) - 800.0) / FOCAL,
        (rng.uniform_range(0.0, 1200.0) - 600.0) / FOCAL,
        1.0,
    )
}

fn contaminated_two_view(
    seed: u64,
    planar: bool,
) -> (TwoView, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let mut rng = SeededRng::new(seed);
    let s = two_view(&mut rng, INLIERS, planar);
    let mut a = noisy(&mut rng, &s.x1, 0.5);
    let mut b = noisy(&mut rng, &s.x2, 0.5);
    for _ in 0..OUTLIERS {
        a.push(outlier_ray(&mut rng));
        b.push(outlier_ray(&mut rng));
    }
    (s, a, b)
}

#[test]
fn essential_ransac_with_half_outliers() {
    for scoring in [Scoring::Msac, Scoring::Marginalized] {
        success_rate(&format!("essential {scoring:?}"), |seed| {
            let started = std::time::Instant::now();
            if std::env::var_os("TRACE_TRIALS").is_some() {
                println!("start seed {seed}");
            }
            let _guard = SlowTrial { seed, started };
            let (s, a, b) = contaminated_two_view(seed, false);
            let est = EssentialEstimator {
                x1: &a,
                x2: &b,
                focal_px: FOCAL,
            };
            let Ok(r) = ransac(&est, &options(seed, 2.0, scoring)) else {
                return false;
            };
            let inl: Vec<usize> = (0..a.len()).filter(|&i| r.inliers[i]).collect();
            let (ia, ib): (Vec<_>, Vec<_>) = inl.iter().map(|&i| (a[i], b[i])).unzip();
            let Ok((pose, _)) = relative_pose_from_essential(&r.model, &ia, &ib) else {
                return false;
            };
            let rot = pose
                .rotation
                .angle_to(&s.cam2_from_cam1.rotation)
                .to_degrees();
            let dir = pose
                .translation
                .normalize()
                .angle(&s.cam2_from_cam1.translation.normalize())
                .to_degrees();
            // Within noise: 6 standard deviations of an optimal estimator on the true inliers
            // (Fisher information of their Sampson residuals), and the right inliers.
            let truth = timesift_core::Pose::new(
                s.cam2_from_cam1.rotation,
                s.cam2_from_cam1.translation.normalize(),
            );
            let rows = relative_pose_residuals(&truth, &s.x1, &s.x2);
            let mut info = nalgebra::SMatrix::<f64, 5, 5>::zeros();
            for (_, j) in &rows {
                let j = nalgebra::SVector::<f64, 5>::from_row_slice(j);
                info += j * j.transpose();
            }
            let cov = info.try_inverse().unwrap() * (0.5 / FOCAL) * (0.5 / FOCAL);
            let rot_std = (cov[(0, 0)] + cov[(1, 1)] + cov[(2, 2)])
                .sqrt()
                .to_degrees();
            let dir_std = (cov[(3, 3)] + cov[(4, 4)]).sqrt().to_degrees();
            let outliers_in = (INLIERS..a.len()).filter(|&i| r.inliers[i]).count();
            let ok = rot < 6.0 * rot_std
                && dir < 6.0 * dir_std
                && (0..INLIERS).filter(|&i| r.inliers[i]).count() >= 45
                && outliers_in <= 5;
            if !ok {
                println!(
                    "E fail seed {seed}: rot {rot} ({rot_std}) dir {dir} ({dir_std}) inl {} true-inl {} iters {}",
                    r.num_inliers,
                    (0..INLIERS).filter(|&i| r.inliers[i]).count(),
                    r.iterations
                );
            }
            ok
        });
    }
}

#[test]
fn fundamental_ransac_with_half_outliers() {
    success_rate("fundamental", |seed| {
        let (s, a, b) = contaminated_two_view(seed, false);
        let (p1, p2) = (pixels(&a), pixels(&b));
        let (t1, t2) = (pixels(&s.x1), pixels(&s.x2));
        let est = FundamentalEstimator { p1: &p1, p2: &p2 };
        let Ok(r) = ransac(&est, &options(seed, 2.0, Scoring::Msac)) else {
            return false;
        };
        // The noise-free correspondences satisfy the estimated F to within a pixel.
        let worst = (t1
            .iter()
            .zip(&t2)
            .map(|(x, y)| {
                timesift_geometry::essential::sampson_distance_sq(
                    &r.model,
                    &x.push(1.0),
                    &y.push(1.0),
                )
            })
            .sum::<f64>()
            / t1.len() as f64)
            .sqrt();
        let ok = worst < 1.5 && (0..INLIERS).filter(|&i| r.inliers[i]).count() >= 45;
        if !ok {
            println!(
                "F fail seed {seed}: worst {} inl {} true-inl {} iters {}",
                worst.sqrt(),
                r.num_inliers,
                (0..INLIERS).filter(|&i| r.inliers[i]).count(),
                r.iterations
            );
        }
        ok
    });
}

#[test]
fn homography_ransac_with_half_outliers() {
    success_rate("homography", |seed| {
        let (s, a, b) = contaminated_two_view(seed, true);
        let (p1, p2) = (pixels(&a), pixels(&b));
        let (t1, t2) = (pixels(&s.x1), pixels(&s.x2));
        let est = HomographyEstimator { p1: &p1, p2: &p2 };
        let Ok(r) = ransac(&est, &options(seed, 2.0, Scoring::Msac)) else {
            return false;
        };
        let rms = (t1
            .iter()
            .zip(&t2)
            .map(|(x, y)| transfer(&r.model.h, x).map_or(f64::INFINITY, |q| (q - y).norm_squared()))
            .sum::<f64>()
            / t1.len() as f64)
            .sqrt();
        let found = (0..INLIERS).filter(|&i| r.inliers[i]).count();
        let ok = rms < 1.0 && found >= 45;
        if !ok {
            println!(
                "H fail seed {seed}: rms {rms} inl {} true-inl {found} iters {}",
                r.num_inliers, r.iterations
            );
        }
        ok
    });
}

#[test]
fn absolute_pose_ransac_with_half_outliers() {
    let cam = camera();
    success_rate("absolute pose", |seed| {
        let mut rng = SeededRng::new(seed);
        let s = absolute_scene(&mut rng, &cam, INLIERS + OUTLIERS, false);
        let mut px: Vec<Vector2<f64>> = s
            .pixels
            .iter()
            .map(|p| p + Vector2::new(rng.normal(), rng.normal()) * 0.5)
            .collect();
        for p in px.iter_mut().skip(INLIERS) {
            *p = Vector2::new(
                rng.uniform_range(0.0, 1600.0),
                rng.uniform_range(0.0, 1200.0),
            );
        }
        let rays: Vec<_> = px.iter().map(|p| cam.unproject(p).unwrap()).collect();
        let est = AbsolutePoseEstimator {
            camera: &cam,
            pixels: &px,
            rays: &rays,
            world: &s.world,
        };
        let Ok(r) = ransac(&est, &options(seed, 2.0, Scoring::Msac)) else {
            return false;
        };
        let (rot, centre) = pose_error(&r.model, &s.pose);
        rot.to_degrees() < 0.5 && centre < 0.1
    });
}

#[test]
fn similarity_ransac_with_half_outliers() {
    success_rate("similarity", |seed| {
        let mut rng = SeededRng::new(seed);
        let truth = Similarity {
            scale: rng.uniform_range(0.8, 1.2),
            rotation: random_rotation(&mut rng, 3.0),
            translation: Vector3::new(
                rng.uniform_range(-1e3, 1e3),
                rng.uniform_range(-1e3, 1e3),
                rng.uniform_range(-50.0, 50.0),
            ),
        };
        let src: Vec<Vector3<f64>> = (0..INLIERS + OUTLIERS)
            .map(|_| {
                Vector3::new(
                    rng.uniform_range(-100.0, 100.0),
                    rng.uniform_range(-100.0, 100.0),
                    rng.uniform_range(-10.0, 10.0),
                )
            })
            .collect();
        let dst: Vec<Vector3<f64>> = src
            .iter()
            .enumerate()
            .map(|(i, p)| {
                if i < INLIERS {
                    truth.apply(p) + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.01
                } else {
                    truth.apply(p)
                        + Vector3::new(
                            rng.uniform_range(-30.0, 30.0),
                            rng.uniform_range(-30.0, 30.0),
                            rng.uniform_range(-30.0, 30.0),
                        )
                }
            })
            .collect();
        let est = SimilarityEstimator {
            src: &src,
            dst: &dst,
            kind: TransformKind::Similarity,
        };
        let Ok(r) = ransac(&est, &options(seed, 0.05, Scoring::Msac)) else {
            return false;
        };
        r.model.rotation.angle_to(&truth.rotation).to_degrees() < 0.01
            && (r.model.scale / truth.scale - 1.0).abs() < 1e-4
    });
}

/// Reports trials that take unusually long (diagnostics for the sampler's termination).
struct SlowTrial {
    seed: u64,
    started: std::time::Instant,
}

impl Drop for SlowTrial {
    fn drop(&mut self) {
        let t = self.started.elapsed().as_secs_f64();
        if t > 0.5 {
            println!("slow trial seed {}: {t:.2} s", self.seed);
        }
    }
}

#[test]
fn homography_explained_pairs_are_flagged() {
    use timesift_geometry::homography::{TwoViewType, classify_two_view};
    for (planar, expected) in [
        (true, TwoViewType::HomographyExplained),
        (false, TwoViewType::General),
    ] {
        let mut flagged = 0;
        for seed in 0..20 {
            let (_, a, b) = contaminated_two_view(seed, planar);
            let (p1, p2) = (pixels(&a), pixels(&b));
            let e = ransac(
                &EssentialEstimator {
                    x1: &a,
                    x2: &b,
                    focal_px: FOCAL,
                },
                &options(seed, 2.0, Scoring::Msac),
            )
            .unwrap();
            let h = ransac(
                &HomographyEstimator { p1: &p1, p2: &p2 },
                &options(seed, 2.0, Scoring::Msac),
            )
            .unwrap();
            if classify_two_view(e.num_inliers, h.num_inliers, 0.8) == expected {
                flagged += 1;
            }
        }
        assert!(
            flagged >= 19,
            "planar = {planar}: {flagged}/20 classified {expected:?}"
        );
    }
}

#[test]
fn helmert_report_is_in_surveyors_units() {
    let truth = Similarity {
        scale: 1.0 + 25e-6,
        rotation: nalgebra::UnitQuaternion::from_euler_angles(
            0.001f64.to_radians(),
            -0.002f64.to_radians(),
            0.5f64.to_radians(),
        ),
        translation: Vector3::new(12.5, -3.0, 0.75),
    };
    let r = truth.helmert_report();
    assert!((r.scale_ppm - 25.0).abs() < 1e-6);
    assert!(
        (r.rotation_deg[0] - 0.001).abs() < 1e-9
            && (r.rotation_deg[1] + 0.002).abs() < 1e-9
            && (r.rotation_deg[2] - 0.5).abs() < 1e-9
    );
    assert_eq!(r.translation, truth.translation);
    let back = truth.inverse();
    let p = Vector3::new(100.0, 200.0, 30.0);
    assert!((back.apply(&truth.apply(&p)) - p).norm() < 1e-9);
}
