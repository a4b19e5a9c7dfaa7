//! Property tests of the camera models: round trips and analytic Jacobians against central finite
//! differences, over random realistic parameters.

use nalgebra::{UnitQuaternion, Vector2, Vector3, Vector6};
use proptest::prelude::*;
use timesift_core::camera::MAX_INTRINSICS;
use timesift_core::{
    BrownCamera, Camera, CameraModel, CoreError, PinholeCamera, Pose, project_world,
    project_world_with_jacobians,
};

/// Realistic Brown parameters as the issue bounds them: |k1|, |k2| ≤ 0.3, |k3|, |k4| ≤ 0.1,
/// |p1|, |p2| ≤ 0.01, |b1|, |b2| ≤ 1e-3 f.
fn brown_camera() -> impl Strategy<Value = BrownCamera> {
    (
        (640u32..8000, 0.5f64..1.0, 0.8f64..3.0),
        (
            -0.05f64..0.05,
            -0.05f64..0.05,
            -1e-3f64..1e-3,
            -1e-3f64..1e-3,
        ),
        (-0.3f64..0.3, -0.3f64..0.3, -0.1f64..0.1, -0.1f64..0.1),
        (-0.01f64..0.01, -0.01f64..0.01),
    )
        .prop_map(
            |((w, aspect, f_rel), (cx, cy, b1, b2), (k1, k2, k3, k4), (p1, p2))| {
                let h = ((w as f64 * aspect) as u32).max(1);
                let f = f_rel * w.max(h) as f64;
                let mut cam = BrownCamera {
                    width: w,
                    height: h,
                    f,
                    cx: cx * w as f64,
                    cy: cy * h as f64,
                    b1: b1 * f,
                    b2: b2 * f,
                    k1,
                    k2,
                    k3,
                    k4,
                    p1,
                    p2,
                };
                // A real lens is invertible over its own image: widen the focal length until the
                // radial map r -> r·radial(r) is increasing well past the image corner.
                while !radial_map_invertible_over_image(&cam) {
                    cam.f *= 1.1;
                    cam.b1 *= 1.1;
                    cam.b2 *= 1.1;
                }
                cam
            },
        )
}

/// Independent check of the radial part: monotone with margin up to 1.5× the corner radius, and
/// reaching past the corner's distorted radius.
fn radial_map_invertible_over_image(cam: &BrownCamera) -> bool {
    let half_diag = 0.5 * ((cam.width as f64).powi(2) + (cam.height as f64).powi(2)).sqrt();
    let corner = (half_diag + cam.cx.abs().max(cam.cy.abs())) / cam.f;
    let g = |r: f64| {
        let r2 = r * r;
        r * (1.0 + cam.k1 * r2 + cam.k2 * r2 * r2 + cam.k3 * r2.powi(3) + cam.k4 * r2.powi(4))
    };
    let steps = 400;
    let r_max = 1.5 * corner;
    let mut prev = 0.0;
    for i in 1..=steps {
        let r = r_max * i as f64 / steps as f64;
        let v = g(r);
        if (v - prev) / (r_max / steps as f64) < 0.3 {
            return false;
        }
        prev = v;
    }
    prev > 1.2 * corner
}

fn pose() -> impl Strategy<Value = Pose> {
    (
        (-3.1f64..3.1, -1.5f64..1.5, -3.1f64..3.1),
        (-100.0f64..100.0, -100.0f64..100.0, -100.0f64..100.0),
    )
        .prop_map(|((r, p, y), (tx, ty, tz))| {
            Pose::new(
                UnitQuaternion::from_euler_angles(r, p, y),
                Vector3::new(tx, ty, tz),
            )
        })
}

/// Relative difference with a floor at 1e-3 of the block's largest entry, so that entries that are
/// analytically zero are judged on the block's scale.
fn rel_err(analytic: f64, numeric: f64, block_scale: f64) -> f64 {
    (analytic - numeric).abs() / analytic.abs().max(numeric.abs()).max(1e-3 * block_scale)
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 256,
        // Seeded, so every run explores the same cases (reproducible CI).
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x0715_31f7),
        ..ProptestConfig::default()
    })]

    #[test]
    fn brown_project_unproject_round_trip_covers_whole_image(
        cam in brown_camera(),
        samples in prop::collection::vec((0.0f64..=1.0, 0.0f64..=1.0), 32),
    ) {
        let (w, h) = (cam.width as f64, cam.height as f64);
        let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5)];
        for (a, b) in corners.into_iter().chain(samples) {
            let pixel = Vector2::new(a * w, b * h);
            let ray = cam.unproject(&pixel).map_err(|e| TestCaseError::fail(format!("{e}")))?;
            prop_assert!((ray.z - 1.0).abs() < 1e-15);
            for depth in [0.5, 7.0, 1000.0] {
                let back = cam.project(&(ray * depth)).unwrap();
                prop_assert!((back - pixel).norm() < 1e-9, "round trip error {} px at {:?}", (back - pixel).norm(), pixel);
            }
        }
    }

    #[test]
    fn brown_jacobians_match_central_differences(
        cam in brown_camera(),
        pose in pose(),
        (a, b, depth) in (0.0f64..=1.0, 0.0f64..=1.0, 1.0f64..500.0),
    ) {
        // A world point that projects inside the image at the given depth.
        let pixel = Vector2::new(a * cam.width as f64, b * cam.height as f64);
        let ray = cam.unproject(&pixel).unwrap();
        let world = pose.inverse().transform_point(&(ray * depth));
        check_all_jacobians(&Camera::Brown(cam), &pose, &world)?;
    }

    #[test]
    fn pinhole_jacobians_match_central_differences(
        (w, f_rel, cx, cy) in (100u32..5000, 0.3f64..3.0, -50.0f64..50.0, -50.0f64..50.0),
        pose in pose(),
        (a, b, depth) in (0.0f64..=1.0, 0.0f64..=1.0, 0.5f64..500.0),
    ) {
        let mut cam = PinholeCamera::new(w, w * 3 / 4 + 1, f_rel * w as f64).unwrap();
        cam.cx = cx;
        cam.cy = cy;
        let pixel = Vector2::new(a * cam.width as f64, b * cam.height as f64);
        let ray = cam.unproject(&pixel).unwrap();
        prop_assert!((cam.project(&(ray * depth)).unwrap() - pixel).norm() < 1e-9);
        let world = pose.inverse().transform_point(&(ray * depth));
        check_all_jacobians(&Camera::Pinhole(cam), &pose, &world)?;
    }
}

/// Central difference with one Richardson step (error O(h⁴)), robust to the large higher
/// derivatives of wide-angle projections.
fn derivative(g: impl Fn(f64) -> Vector2<f64>, h: f64) -> Vector2<f64> {
    let d = |h: f64| (g(h) - g(-h)) / (2.0 * h);
    (d(h * 0.5) * 4.0 - d(h)) / 3.0
}

fn check_all_jacobians(
    cam: &Camera,
    pose: &Pose,
    world: &Vector3<f64>,
) -> Result<(), TestCaseError> {
    let n = cam.num_params();
    let mut d_intr = [0.0; 2 * MAX_INTRINSICS];
    let j = project_world_with_jacobians(cam, pose, world, Some(&mut d_intr[..2 * n]))
        .map_err(|e| TestCaseError::fail(format!("{e}")))?;
    prop_assert!((j.pixel - project_world(cam, pose, world).unwrap()).norm() == 0.0);

    // World point.
    let scale = j.d_world_point.amax();
    for k in 0..3 {
        let h = 1e-5 * (1.0 + world.norm());
        let num = derivative(
            |step| {
                let mut x = *world;
                x[k] += step;
                project_world(cam, pose, &x).unwrap()
            },
            h,
        );
        for r in 0..2 {
            let e = rel_err(j.d_world_point[(r, k)], num[r], scale);
            prop_assert!(
                e < 1e-6,
                "d/dX[{r},{k}]: analytic {} numeric {} (rel {e:e})",
                j.d_world_point[(r, k)],
                num[r]
            );
        }
    }

    // Pose, through the local update of Pose::retract.
    let scale = j.d_pose.amax();
    for k in 0..6 {
        let h = if k < 3 {
            1e-4
        } else {
            1e-5 * (1.0 + pose.translation.norm())
        };
        let num = derivative(
            |step| {
                let mut d = Vector6::zeros();
                d[k] = step;
                project_world(cam, &pose.retract(&d), world).unwrap()
            },
            h,
        );
        for r in 0..2 {
            let e = rel_err(j.d_pose[(r, k)], num[r], scale);
            prop_assert!(
                e < 1e-6,
                "d/dpose[{r},{k}]: analytic {} numeric {} (rel {e:e})",
                j.d_pose[(r, k)],
                num[r]
            );
        }
    }

    // Every intrinsic.
    let mut params = [0.0; MAX_INTRINSICS];
    cam.params(&mut params[..n]);
    let scale = d_intr[..2 * n].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for k in 0..n {
        // The pixel is linear in each intrinsic taken alone, so a large step has no truncation error
        // and keeps round-off small.
        let h = 1e-3 * params[k].abs().max(1.0);
        let perturbed = |delta: f64| {
            let mut c = cam.clone();
            let mut p = params;
            p[k] += delta;
            c.set_params(&p[..n]).unwrap();
            project_world(&c, pose, world).unwrap()
        };
        let num = (perturbed(h) - perturbed(-h)) / (2.0 * h);
        for r in 0..2 {
            let a = d_intr[r * n + k];
            let e = rel_err(a, num[r], scale);
            prop_assert!(
                e < 1e-6,
                "d/d{}[{r}]: analytic {a} numeric {} (rel {e:e})",
                cam.param_names()[k],
                num[r]
            );
        }
    }
    Ok(())
}

#[test]
fn points_behind_the_camera_have_no_projection() {
    let cam = BrownCamera::new(4000, 3000, 2900.0).unwrap();
    for z in [0.0, -1.0, f64::NAN] {
        assert!(matches!(
            cam.project(&Vector3::new(0.1, 0.2, z)),
            Err(CoreError::BehindCamera { .. })
        ));
    }
}

#[test]
fn unproject_reports_divergence_beyond_the_fold() {
    // Strong barrel distortion: r·radial(r) peaks near r = 0.58 at about 0.38, so a pixel whose
    // distorted radius is 0.9 has no preimage.
    let mut cam = BrownCamera::new(2000, 2000, 1000.0).unwrap();
    cam.k1 = -1.0;
    let pixel = Vector2::new(1000.0 + 900.0, 1000.0);
    assert!(matches!(
        cam.unproject(&pixel),
        Err(CoreError::UndistortionDiverged { .. })
    ));
}

#[test]
fn invalid_parameters_are_rejected_by_name() {
    assert!(matches!(
        BrownCamera::new(100, 100, -5.0),
        Err(CoreError::InvalidCameraParameter { name: "f", .. })
    ));
    let mut cam = BrownCamera::new(100, 100, 50.0).unwrap();
    let mut p = cam.param_array();
    p[5] = f64::NAN;
    assert!(matches!(
        cam.set_params(&p),
        Err(CoreError::InvalidCameraParameter { name: "k1", .. })
    ));
    assert!(matches!(
        cam.set_params(&p[..3]),
        Err(CoreError::ParameterCount { .. })
    ));
    // A failed update leaves the camera as it was.
    assert_eq!(cam.k1, 0.0);
}

#[test]
fn brown_formula_matches_design_by_hand() {
    // One point worked through the docs/design.md formulas with every term non-zero.
    let cam = BrownCamera {
        width: 4000,
        height: 3000,
        f: 2900.0,
        cx: 12.0,
        cy: -7.0,
        b1: 1.5,
        b2: -0.8,
        k1: -0.1,
        k2: 0.02,
        k3: -0.003,
        k4: 0.0004,
        p1: 0.001,
        p2: -0.002,
    };
    let (x, y) = (0.2f64, -0.15f64);
    let r2 = x * x + y * y;
    let radial = 1.0 - 0.1 * r2 + 0.02 * r2.powi(2) - 0.003 * r2.powi(3) + 0.0004 * r2.powi(4);
    let xd = x * radial + 0.001 * (r2 + 2.0 * x * x) + 2.0 * -0.002 * x * y;
    let yd = y * radial - 0.002 * (r2 + 2.0 * y * y) + 2.0 * 0.001 * x * y;
    let u = 2000.0 + 12.0 + xd * (2900.0 + 1.5) + yd * -0.8;
    let v = 1500.0 - 7.0 + yd * 2900.0;
    let p = cam.project(&Vector3::new(x * 3.0, y * 3.0, 3.0)).unwrap();
    assert!((p - Vector2::new(u, v)).norm() < 1e-9);
}
