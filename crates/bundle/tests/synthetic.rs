//! Random synthetic blocks with 0.5 px noise converge from perturbed starts to a cost consistent
//! with the noise (χ² test), as free networks with self-calibration, without singular failure.

use nalgebra::{Vector2, Vector3};
use proptest::prelude::*;
use timesift_bundle::problem::{BundleImage, BundlePoint};
use timesift_bundle::{BundleOptions, BundleProblem, CameraGroup, Observation, Termination, solve};
use timesift_core::{BrownCamera, Camera, Pose, SeededRng, project_world};

const SIGMA: f64 = 0.5;

/// Eight oblique views on a ring around 150 points in a 20 m box; noisy observations; the start
/// perturbed (poses, points, focal length and k1).
fn block(seed: u64) -> (BundleProblem, usize) {
    let mut rng = SeededRng::new(seed);
    let mut cam = BrownCamera::new(2000, 1500, 1800.0).unwrap();
    cam.k1 = -0.06;
    let points: Vec<Vector3<f64>> = (0..150)
        .map(|_| {
            Vector3::new(
                rng.uniform_range(-10.0, 10.0),
                rng.uniform_range(-10.0, 10.0),
                rng.uniform_range(-3.0, 3.0),
            )
        })
        .collect();
    let poses: Vec<Pose> = (0..8)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 8.0 + rng.uniform_range(-0.1, 0.1);
            Pose::look_at(
                &Vector3::new(
                    35.0 * a.cos(),
                    35.0 * a.sin(),
                    25.0 + rng.uniform_range(-2.0, 2.0),
                ),
                &Vector3::zeros(),
            )
            .unwrap()
        })
        .collect();
    let mut observations = Vec::new();
    for (i, pose) in poses.iter().enumerate() {
        for (j, x) in points.iter().enumerate() {
            if let Ok(px) = project_world(&cam, pose, x) {
                if px.x > 0.0 && px.y > 0.0 && px.x < 2000.0 && px.y < 1500.0 {
                    let noisy = px + Vector2::new(rng.normal(), rng.normal()) * SIGMA;
                    observations.push(Observation {
                        image: i,
                        point: j,
                        pixel: noisy,
                        sigma_px: SIGMA,
                    });
                }
            }
        }
    }
    let mut start = cam;
    start.f *= 1.01;
    start.k1 *= 0.8;
    let images = poses
        .iter()
        .map(|p| {
            let d =
                nalgebra::Vector6::from_fn(|k, _| if k < 3 { 0.005 } else { 0.1 } * rng.normal());
            BundleImage {
                pose: p.retract(&d),
                group: 0,
                fixed: false,
            }
        })
        .collect();
    let pts = points
        .iter()
        .map(|x| BundlePoint {
            position: x + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.05,
            fixed: false,
        })
        .collect();
    let n_params = 8 * 6 + 2 + 3 * 150;
    let dof = 2 * observations.len() - n_params + 7;
    (
        BundleProblem {
            groups: vec![CameraGroup::with_free(Camera::Brown(start), &["f", "k1"]).unwrap()],
            images,
            points: pts,
            observations,
            ..BundleProblem::default()
        },
        dof,
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, rng_seed: proptest::test_runner::RngSeed::Fixed(0x0715_31f7), ..ProptestConfig::default() })]

    #[test]
    fn free_network_with_self_calibration_reaches_the_noise_floor(seed in any::<u64>()) {
        let (mut problem, dof) = block(seed);
        let options = BundleOptions { function_tolerance: 1e-10, ..BundleOptions::default() };
        let report = solve(&mut problem, &options).unwrap();
        prop_assert!(report.termination != Termination::NoProgress && report.termination != Termination::MaxIterations, "{:?}", report.termination);
        // cost = ½ χ²; χ² ~ χ²(dof): mean dof, standard deviation √(2 dof); allow 5 of them.
        let chi2 = 2.0 * report.final_cost;
        let tol = 5.0 * (2.0 * dof as f64).sqrt();
        prop_assert!((chi2 - dof as f64).abs() < tol, "χ² = {chi2}, dof = {dof}");
        // Per-observation RMS: E‖r‖² = 2σ² · dof / (2 n_obs) at the optimum.
        prop_assert!((report.rms_px - SIGMA * (dof as f64 / problem.observations.len() as f64).sqrt()).abs() < 0.07);
        prop_assert_eq!(report.unprojected, 0);
    }
}

#[test]
fn bad_problems_are_errors() {
    let (mut p, _) = block(1);
    p.observations[3].point = 10_000;
    assert!(solve(&mut p, &BundleOptions::default()).is_err());
    let (mut p, _) = block(1);
    p.observations[0].sigma_px = 0.0;
    assert!(solve(&mut p, &BundleOptions::default()).is_err());
    let (mut p, _) = block(1);
    for im in &mut p.images {
        im.fixed = true;
    }
    for pt in &mut p.points {
        pt.fixed = true;
    }
    p.groups[0] = CameraGroup::fixed(p.groups[0].camera.clone());
    assert!(solve(&mut p, &BundleOptions::default()).is_err());
    assert!(CameraGroup::with_free(p.groups[0].camera.clone(), &["focal"]).is_err());
    let (mut p, _) = block(1);
    let bad = BundleOptions {
        loss: timesift_bundle::Loss::Cauchy(0.0),
        ..BundleOptions::default()
    };
    assert!(solve(&mut p, &bad).is_err());
}

/// The block of [`block`] with GNSS priors on every camera centre (2 cm / 5 cm, noisy) and surveyed
/// coordinates for ten points, all intrinsics but the image size free.
fn georeferenced_block(seed: u64) -> (BundleProblem, Vec<Vector3<f64>>) {
    let (mut p, _) = block(seed);
    let mut rng = SeededRng::new(seed ^ 0xABCD);
    // Truth: recover it from the noise-free generator by re-running with the same seed.
    let truth_centres: Vec<Vector3<f64>> = {
        let mut rng2 = SeededRng::new(seed);
        let _cam_points: Vec<Vector3<f64>> = (0..150)
            .map(|_| {
                Vector3::new(
                    rng2.uniform_range(-10.0, 10.0),
                    rng2.uniform_range(-10.0, 10.0),
                    rng2.uniform_range(-3.0, 3.0),
                )
            })
            .collect();
        (0..8)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 8.0 + rng2.uniform_range(-0.1, 0.1);
                Vector3::new(
                    35.0 * a.cos(),
                    35.0 * a.sin(),
                    25.0 + rng2.uniform_range(-2.0, 2.0),
                )
            })
            .collect()
    };
    p.center_priors = truth_centres
        .iter()
        .enumerate()
        .map(|(i, c)| timesift_bundle::CenterPrior {
            image: i,
            position: c + Vector3::new(
                rng.normal() * 0.02,
                rng.normal() * 0.02,
                rng.normal() * 0.05,
            ),
            sigma_xy: 0.02,
            sigma_z: 0.05,
            offset: None,
        })
        .collect();
    (p, truth_centres)
}

/// The true points of `block(seed)`: its generator draws them first, so the same seed gives them
/// again.
fn block_points(seed: u64) -> Vec<Vector3<f64>> {
    let mut rng = SeededRng::new(seed);
    (0..150)
        .map(|_| {
            Vector3::new(
                rng.uniform_range(-10.0, 10.0),
                rng.uniform_range(-10.0, 10.0),
                rng.uniform_range(-3.0, 3.0),
            )
        })
        .collect()
}

#[test]
fn a_scale_bar_fixes_the_scale_of_a_free_network() {
    // Truth from the noise-free generator: the same seed gives the same geometry.
    let (mut p, _) = block(21);
    let truth = block_points(21);
    // Start 10 % too large (points and camera centres scaled about the origin).
    for pt in &mut p.points {
        pt.position *= 1.1;
    }
    for im in &mut p.images {
        let c = im.pose.center() * 1.1;
        im.pose = Pose::from_rotation_and_center(im.pose.rotation, &c);
    }
    p.scale_bars = vec![timesift_bundle::ScaleBar {
        a: 0,
        b: 1,
        length: (truth[0] - truth[1]).norm(),
        sigma: 0.001,
    }];
    let report = solve(&mut p, &BundleOptions::default()).unwrap();
    assert!(matches!(
        report.termination,
        Termination::FunctionTolerance
            | Termination::ParameterTolerance
            | Termination::GradientTolerance
    ));
    // Every other distance is right to the noise level: compare the spread of all pairwise ratios.
    let mut worst = 0.0f64;
    for (a, b) in [(2usize, 50usize), (10, 120), (33, 77), (5, 140)] {
        let est = (p.points[a].position - p.points[b].position).norm();
        let tru = (truth[a] - truth[b]).norm();
        worst = worst.max((est / tru - 1.0).abs());
    }
    assert!(worst < 2e-3, "relative distance error {worst}");
    let stats = timesift_bundle::precision::residual_statistics(&p, 4.0);
    assert_eq!(stats.scale_bars.map(|s| s.1), Some(1));
}

#[test]
fn analytic_gradient_matches_finite_differences_for_every_residual_type() {
    let (mut p, _) = georeferenced_block(5);
    // Every intrinsic free, control-point priors on ten points, a robust loss.
    p.groups[0].free = vec![true; 11];
    p.point_priors = (0..10)
        .map(|j| timesift_bundle::PointPrior {
            point: j,
            position: p.points[j].position + Vector3::new(0.01, -0.02, 0.03),
            // Half of them heights on a sloped surface (a reference DEM's), without horizontal
            // weight.
            sigma_xy: if j < 5 { 0.01 } else { f64::INFINITY },
            sigma_z: 0.02,
            slope: if j < 5 { [0.0; 2] } else { [0.3, -0.2] },
        })
        .collect();
    // Two scale bars (one sharing an end with a control point), slightly off the current lengths.
    p.scale_bars = [(3usize, 40usize), (60, 90)]
        .iter()
        .map(|&(a, b)| timesift_bundle::ScaleBar {
            a,
            b,
            length: (p.points[a].position - p.points[b].position).norm() + 0.02,
            sigma: 0.005,
        })
        .collect();
    // Two GNSS offsets away from zero, each carried by half of the centre priors.
    p.prior_offsets = [Vector3::new(0.3, -0.2, 0.5), Vector3::new(-0.1, 0.4, -0.6)]
        .iter()
        .map(|&value| timesift_bundle::PriorOffset {
            value,
            sigma_xy: 2.0,
            sigma_z: 3.0,
            fixed: false,
        })
        .collect();
    for (i, c) in p.center_priors.iter_mut().enumerate() {
        c.offset = Some(i / 4);
    }
    for loss in [
        timesift_bundle::Loss::Trivial,
        timesift_bundle::Loss::Cauchy(2.0),
    ] {
        let g = timesift_bundle::gradient(&p, &loss);
        let n = timesift_bundle::num_parameters(&p);
        assert_eq!(g.len(), n);
        let scale = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut worst = 0.0f64;
        for k in 0..n {
            // Central differences with one Richardson step; steps sized per parameter kind.
            // Poses, intrinsics, then offsets and points.
            let h = if k < 48 {
                1e-6
            } else if k < 59 {
                1e-4
            } else {
                1e-5
            };
            let f = |d: f64| {
                let mut delta = vec![0.0; n];
                delta[k] = d;
                timesift_bundle::cost(&timesift_bundle::perturbed(&p, &delta).unwrap(), &loss)
            };
            let d = |h: f64| (f(h) - f(-h)) / (2.0 * h);
            let numeric = (4.0 * d(h / 2.0) - d(h)) / 3.0;
            let rel = (g[k] - numeric).abs() / g[k].abs().max(numeric.abs()).max(1e-4 * scale);
            worst = worst.max(rel);
            assert!(
                rel < 1e-6,
                "{loss:?} parameter {k}: analytic {} numeric {numeric} (rel {rel:e})",
                g[k]
            );
        }
        println!("{loss:?}: worst relative gradient error {worst:e} over {n} parameters");
    }
}

#[test]
fn gnss_priors_georeference_the_block() {
    let (mut p, truth) = georeferenced_block(9);
    let n_obs = p.observations.len();
    let report = solve(
        &mut p,
        &BundleOptions {
            function_tolerance: 1e-12,
            ..BundleOptions::default()
        },
    )
    .unwrap();
    // No gauge freedom left: χ² has 2·n_obs + 3·8 − (48 + 2 + 450) degrees of freedom.
    let dof = (2 * n_obs + 24) as f64 - 500.0;
    let chi2 = 2.0 * report.final_cost;
    assert!(
        (chi2 - dof).abs() < 5.0 * (2.0 * dof).sqrt(),
        "χ² = {chi2}, dof = {dof}"
    );
    // Centres within 4 prior sigmas of the truth (the block adds its own precision).
    for (im, c) in p.images.iter().zip(&truth) {
        let d = im.pose.center() - c;
        assert!(
            d.xy().norm() < 4.0 * 0.02 * 2f64.sqrt() && d.z.abs() < 4.0 * 0.05,
            "centre off by {d:?}"
        );
    }
}

/// The block of `georeferenced_block` with its camera centres known only to metres and shifted
/// by `bias` (a photo index), and every point given a height on a surface through it (a
/// reference DEM) sampled 1.8 m away from the truth (where a shifted block would ask), σ 1 mm;
/// with its tangent plane's slope (points facing every way) or without.
fn held_to_a_surface(
    seed: u64,
    bias: Vector3<f64>,
    sloped: bool,
) -> (BundleProblem, Vec<Vector3<f64>>) {
    let (mut p, truth) = georeferenced_block(seed);
    for (c, t) in p.center_priors.iter_mut().zip(&truth) {
        c.position = t + bias;
        c.sigma_xy = 10.0;
        c.sigma_z = 10.0;
    }
    let sampled_at = Vector3::new(1.5, -1.0, 0.0);
    p.point_priors = block_points(seed)
        .iter()
        .enumerate()
        .map(|(j, t)| {
            let angle = 2.4 * j as f64;
            let slope = [0.5 * angle.cos(), 0.5 * angle.sin()];
            let at = t + sampled_at;
            // The surface's height there: on the plane through the true point.
            let height = t.z + slope[0] * sampled_at.x + slope[1] * sampled_at.y;
            timesift_bundle::PointPrior {
                point: j,
                position: Vector3::new(at.x, at.y, if sloped { height } else { t.z }),
                sigma_xy: f64::INFINITY,
                sigma_z: 0.001,
                slope: if sloped { slope } else { [0.0; 2] },
            }
        })
        .collect();
    (p, truth)
}

#[test]
fn heights_on_a_sloped_surface_fix_a_blocks_horizontal_shift_and_flat_heights_cannot() {
    let bias = Vector3::new(3.0, -2.0, 1.0);
    let options = BundleOptions {
        function_tolerance: 1e-14,
        ..BundleOptions::default()
    };
    let worst = |p: &BundleProblem, truth: &[Vector3<f64>]| {
        p.images
            .iter()
            .zip(truth)
            .map(|(im, c)| (im.pose.center() - c).norm())
            .fold(0.0f64, f64::max)
    };
    let (mut sloped, truth) = held_to_a_surface(41, bias, true);
    solve(&mut sloped, &options).unwrap();
    let (mut flat, _) = held_to_a_surface(41, bias, false);
    solve(&mut flat, &options).unwrap();
    // The tangent planes put the block back to what its pixel noise allows (the 20 m block's
    // centres from 0.5 px of noise: centimetres); heights alone fix its height and tilt but
    // leave it where the biased centres put it sideways.
    let (sloped, flat) = (worst(&sloped, &truth), worst(&flat, &truth));
    assert!(sloped < 0.05, "sloped: centres off by {sloped} m");
    assert!(
        (flat - bias.xy().norm()).abs() < 0.05,
        "flat: centres off by {flat} m, the bias's horizontal part is {} m",
        bias.xy().norm()
    );
}

/// The block of `georeferenced_block` with control points on ten points, where the last four
/// images' GNSS carries a common bias `bias`.
fn biased_flight(seed: u64, bias: Vector3<f64>) -> (BundleProblem, Vec<Vector3<f64>>) {
    let (mut p, truth) = georeferenced_block(seed);
    let truth_points = block_points(seed);
    p.point_priors = (0..10)
        .map(|j| timesift_bundle::PointPrior {
            point: j * 15,
            position: truth_points[j * 15],
            sigma_xy: 0.005,
            sigma_z: 0.005,
            slope: [0.0; 2],
        })
        .collect();
    for c in p.center_priors.iter_mut().skip(4) {
        c.position += bias;
    }
    (p, truth)
}

#[test]
fn a_gnss_bias_per_flight_is_estimated_within_its_precision() {
    let bias = Vector3::new(1.2, -0.7, 2.5);
    let options = BundleOptions {
        function_tolerance: 1e-12,
        ..BundleOptions::default()
    };
    // Without an offset the biased flight drags the block: centres metres off.
    let (mut plain, truth) = biased_flight(31, bias);
    solve(&mut plain, &options).unwrap();
    let worst_plain = plain
        .images
        .iter()
        .zip(&truth)
        .map(|(im, c)| (im.pose.center() - c).norm())
        .fold(0.0f64, f64::max);
    // With one offset for the biased flight (prior σ 10 m around zero), estimated in the block.
    let (mut p, truth) = biased_flight(31, bias);
    p.prior_offsets = vec![timesift_bundle::PriorOffset {
        value: Vector3::zeros(),
        sigma_xy: 10.0,
        sigma_z: 10.0,
        fixed: false,
    }];
    for c in p.center_priors.iter_mut().skip(4) {
        c.offset = Some(0);
    }
    solve(&mut p, &options).unwrap();
    let precision = timesift_bundle::precision::precision(
        &p,
        timesift_bundle::precision::CovarianceScale::Posterior,
    )
    .unwrap();
    let std = precision
        .offset_std(0)
        .expect("free offset has a covariance");
    let estimate = p.prior_offsets[0].value;
    for k in 0..3 {
        assert!(
            (estimate[k] - bias[k]).abs() < 3.0 * std[k] && std[k] < 0.05,
            "axis {k}: estimated {} ± {} for a bias of {}",
            estimate[k],
            std[k],
            bias[k]
        );
    }
    let worst = p
        .images
        .iter()
        .zip(&truth)
        .map(|(im, c)| (im.pose.center() - c).norm())
        .fold(0.0f64, f64::max);
    assert!(
        worst < 0.05 && worst_plain > 10.0 * worst,
        "centre errors: {worst} m with the offset, {worst_plain} m without"
    );
    // The prior RMS now measures the GNSS noise, not the bias.
    let stats = timesift_bundle::precision::residual_statistics(&p, 4.0);
    let (rms, n) = stats.center_priors.unwrap();
    assert_eq!(n, 8);
    assert!(rms[0] < 0.05 && rms[2] < 0.15, "{rms:?}");
}

#[test]
fn a_fixed_offset_is_applied_and_bad_offsets_are_errors() {
    let bias = Vector3::new(0.0, 0.0, 1.5);
    let (mut p, truth) = biased_flight(32, bias);
    p.prior_offsets = vec![timesift_bundle::PriorOffset {
        value: bias,
        sigma_xy: 1.0,
        sigma_z: 1.0,
        fixed: true,
    }];
    for c in p.center_priors.iter_mut().skip(4) {
        c.offset = Some(0);
    }
    let mut bad = p.clone();
    solve(&mut p, &BundleOptions::default()).unwrap();
    assert_eq!(
        p.prior_offsets[0].value, bias,
        "a fixed offset does not move"
    );
    for (im, c) in p.images.iter().zip(&truth) {
        assert!((im.pose.center() - c).norm() < 0.05);
    }
    bad.center_priors[5].offset = Some(1);
    let err = solve(&mut bad.clone(), &BundleOptions::default()).unwrap_err();
    assert!(err.to_string().contains("offset"), "{err}");
    bad.center_priors[5].offset = Some(0);
    bad.prior_offsets[0].sigma_z = 0.0;
    let err = solve(&mut bad, &BundleOptions::default()).unwrap_err();
    assert!(err.to_string().contains("prior offset 0"), "{err}");
}

/// The correlation of an offset with an intrinsic obeys the Gaussian conditioning identity:
/// fixing the intrinsic shrinks the offset's variance by the factor 1 − ρ². Both variances come
/// from the (separately tested) diagonal blocks, so this checks the cross terms exactly.
#[test]
fn offset_intrinsic_correlations_match_the_conditional_variances() {
    let p = adjusted_flight_with_offset(33, Vector3::new(0.0, 0.0, 2.0));
    let scale = timesift_bundle::precision::CovarianceScale::Prior;
    let free = timesift_bundle::precision::precision(&p, scale).unwrap();
    let correlations = &free.offset_intrinsic_correlations[0];
    assert_eq!(correlations.len(), 3, "{correlations:?}");
    let std = free.offset_std(0).unwrap();
    for c in correlations {
        let (param, rho) = (c.param, c.rho);
        assert_eq!(c.group, 0);
        let mut fixed = p.clone();
        fixed.groups[0].free[param] = false;
        let conditional = timesift_bundle::precision::precision(&fixed, scale)
            .unwrap()
            .offset_std(0)
            .unwrap();
        for c in 0..3 {
            let shrink = 1.0 - (conditional[c] / std[c]).powi(2);
            assert!(
                (rho[c] * rho[c] - shrink).abs() < 1e-6,
                "param {param} axis {c}: ρ = {}, 1 − σ²|fixed / σ² = {shrink}",
                rho[c]
            );
        }
    }
    // An offset without a free intrinsic to correlate with has none.
    let mut calibrated = p.clone();
    calibrated.groups[0].free.fill(false);
    let none = timesift_bundle::precision::precision(&calibrated, scale).unwrap();
    assert!(none.offset_intrinsic_correlations[0].is_empty());
}

/// [`biased_flight`] with one free offset (σ 1 m) for its biased images, focal length and
/// principal point free, adjusted.
fn adjusted_flight_with_offset(seed: u64, bias: Vector3<f64>) -> BundleProblem {
    let (mut p, _) = biased_flight(seed, bias);
    p.prior_offsets = vec![timesift_bundle::PriorOffset {
        value: Vector3::zeros(),
        sigma_xy: 1.0,
        sigma_z: 1.0,
        fixed: false,
    }];
    for c in p.center_priors.iter_mut().skip(4) {
        c.offset = Some(0);
    }
    p.groups[0].free = (0..p.groups[0].free.len()).map(|k| k < 3).collect();
    solve(&mut p, &BundleOptions::default()).unwrap();
    p
}

/// The a-posteriori covariances are the a-priori ones times the variance factor, so one
/// factorisation gives both (`Precision::rescaled`); the precision without the poses has every
/// other entry of the full one.
#[test]
fn a_posteriori_precision_is_the_a_priori_one_rescaled_and_poses_can_be_left_out() {
    let p = adjusted_flight_with_offset(35, Vector3::new(0.5, -0.3, 2.0));
    use timesift_bundle::precision::{CovarianceScale, intrinsic_and_offset_precision, precision};
    let prior = precision(&p, CovarianceScale::Prior).unwrap();
    let posterior = precision(&p, CovarianceScale::Posterior).unwrap();
    let factor = CovarianceScale::Posterior.factor(&p);
    assert!(
        factor > 0.0 && (factor - 1.0).abs() > 1e-3,
        "σ0² = {factor}"
    );
    let rescaled = prior.rescaled(factor);
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1e-12);
    assert!(close(rescaled.scale, posterior.scale));
    for (a, b) in rescaled.poses.iter().zip(&posterior.poses) {
        let (a, b) = (a.unwrap(), b.unwrap());
        assert!(
            a.iter().zip(b.iter()).all(|(x, y)| close(*x, *y)),
            "{a} != {b}"
        );
    }
    for (a, b) in rescaled.intrinsics.iter().zip(&posterior.intrinsics) {
        assert_eq!(a.len(), b.len());
        assert!(a.iter().zip(b).all(|(x, y)| x.0 == y.0 && close(x.1, y.1)));
    }
    let (a, b) = (rescaled.offsets[0].unwrap(), posterior.offsets[0].unwrap());
    assert!(a.iter().zip(b.iter()).all(|(x, y)| close(*x, *y)));
    assert_eq!(
        rescaled.offset_intrinsic_correlations,
        posterior.offset_intrinsic_correlations
    );
    let partial = intrinsic_and_offset_precision(&p, CovarianceScale::Posterior).unwrap();
    assert!(partial.poses.iter().all(Option::is_none));
    assert!(partial.centers.iter().all(Option::is_none));
    assert_eq!(partial.intrinsics, posterior.intrinsics);
    assert_eq!(partial.offsets, posterior.offsets);
    assert_eq!(
        partial.offset_intrinsic_correlations,
        posterior.offset_intrinsic_correlations
    );
}
