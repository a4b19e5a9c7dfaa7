//! Real data: relative poses between the three OpenSfM `berlin` photos, estimated from the tracks
//! shipped with the data (`tracks_example.csv`) by essential-matrix RANSAC, agree with OpenSfM's
//! `reconstruction_example.json` within 0.5°. As in incremental SfM, the strongest pair (01–02) is
//! oriented by essential-matrix RANSAC, its tracks triangulated, 03 registered by P3P RANSAC (the
//! two-view geometries 01–03 and 02–03 alone are too weak: 266 and 629 tracks on a facade), and the
//! three views bundle-adjusted.

use std::collections::BTreeMap;
use std::path::PathBuf;

use nalgebra::{UnitQuaternion, Vector3};
use timesift_bundle::problem::{BundleImage, BundlePoint};
use timesift_bundle::{BundleOptions, BundleProblem, CameraGroup, Loss, Observation, solve};
use timesift_core::{CameraModel, PinholeCamera, Pose};
use timesift_geometry::essential::{EssentialEstimator, relative_pose_from_essential};

use timesift_geometry::pnp::AbsolutePoseEstimator;
use timesift_geometry::ransac::{RansacOptions, ransac};
use timesift_geometry::triangulation::triangulate_dlt;

fn berlin() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/opensfm/berlin")
}

struct Camera {
    focal: f64,
    k1: f64,
    k2: f64,
    max_side: f64,
}

impl Camera {
    /// OpenSfM normalised coordinates (pixels / max(w, h), centred) to a z = 1 ray, inverting
    /// OpenSfM's radial model x_n = f · x · (1 + k1 r² + k2 r⁴) by Newton's method.
    fn ray(&self, xn: f64, yn: f64) -> Vector3<f64> {
        let (xd, yd) = (xn / self.focal, yn / self.focal);
        let rd = (xd * xd + yd * yd).sqrt();
        let mut r = rd;
        for _ in 0..20 {
            let f = r * (1.0 + self.k1 * r * r + self.k2 * r.powi(4)) - rd;
            let df = 1.0 + 3.0 * self.k1 * r * r + 5.0 * self.k2 * r.powi(4);
            r -= f / df;
        }
        let s = if rd > 0.0 { r / rd } else { 1.0 };
        Vector3::new(xd * s, yd * s, 1.0)
    }
}

#[test]
fn berlin_relative_poses_match_opensfm_within_half_a_degree() {
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(berlin().join("reconstruction_example.json")).unwrap(),
    )
    .unwrap();
    let rec = &json[0];
    let (_, cam) = rec["cameras"].as_object().unwrap().iter().next().unwrap();
    let camera = Camera {
        focal: cam["focal"].as_f64().unwrap(),
        k1: cam["k1"].as_f64().unwrap(),
        k2: cam["k2"].as_f64().unwrap(),
        max_side: cam["width"]
            .as_f64()
            .unwrap()
            .max(cam["height"].as_f64().unwrap()),
    };
    let mut poses: BTreeMap<String, Pose> = BTreeMap::new();
    for (name, shot) in rec["shots"].as_object().unwrap() {
        let v = |k: &str, i: usize| shot[k][i].as_f64().unwrap();
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(
            v("rotation", 0),
            v("rotation", 1),
            v("rotation", 2),
        ));
        poses.insert(
            name.clone(),
            Pose::new(
                r,
                Vector3::new(
                    v("translation", 0),
                    v("translation", 1),
                    v("translation", 2),
                ),
            ),
        );
    }

    // image -> track -> ray
    let mut tracks: BTreeMap<String, BTreeMap<u64, Vector3<f64>>> = BTreeMap::new();
    for line in std::fs::read_to_string(berlin().join("tracks_example.csv"))
        .unwrap()
        .lines()
        .skip(1)
    {
        let f: Vec<&str> = line.split('\t').collect();
        let (x, y) = (f[3].parse::<f64>().unwrap(), f[4].parse::<f64>().unwrap());
        tracks
            .entry(f[0].to_string())
            .or_default()
            .insert(f[1].parse().unwrap(), camera.ray(x, y));
    }

    let focal_px = camera.focal * camera.max_side;
    let pair = |a: &str, b: &str| -> (Vec<u64>, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let (ta, tb) = (&tracks[a], &tracks[b]);
        let mut common: Vec<u64> = ta.keys().filter(|k| tb.contains_key(k)).copied().collect();
        common.sort();
        let x1 = common.iter().map(|k| ta[k]).collect();
        let x2 = common.iter().map(|k| tb[k]).collect();
        (common, x1, x2)
    };
    let options = RansacOptions {
        max_error: 2.0,
        seed: 1,
        ..RansacOptions::default()
    };

    // Initial pair: the two-view geometry of 01–02 (1,076 common tracks).
    let (ids, x1, x2) = pair("01.jpg", "02.jpg");
    let r = ransac(
        &EssentialEstimator {
            x1: &x1,
            x2: &x2,
            focal_px,
        },
        &options,
    )
    .unwrap();
    let inl: Vec<usize> = (0..x1.len()).filter(|&i| r.inliers[i]).collect();
    let (ia, ib): (Vec<_>, Vec<_>) = inl.iter().map(|&i| (x1[i], x2[i])).unzip();
    let (cam2, _) = relative_pose_from_essential(&r.model, &ia, &ib).unwrap();
    let cam1 = Pose::identity();

    // Triangulate its inlier tracks, then register 03 by P3P RANSAC and refinement on the
    // 2-D/3-D correspondences, as incremental SfM does.
    let mut points: BTreeMap<u64, Vector3<f64>> = BTreeMap::new();
    for &i in &inl {
        if let Ok(p) = triangulate_dlt(&[(cam1, x1[i]), (cam2, x2[i])])
            && p.z > 0.0
            && cam2.transform_point(&p).z > 0.0
        {
            points.insert(ids[i], p);
        }
    }
    let pinhole = PinholeCamera::new(3264, 2448, focal_px).unwrap();
    let t3 = &tracks["03.jpg"];
    let (world, rays): (Vec<_>, Vec<_>) = points
        .iter()
        .filter_map(|(id, p)| t3.get(id).map(|r| (*p, *r)))
        .unzip();
    let pixels: Vec<_> = rays.iter().map(|r| pinhole.project(r).unwrap()).collect();
    let est = AbsolutePoseEstimator {
        camera: &pinhole,
        pixels: &pixels,
        rays: &rays,
        world: &world,
    };
    // Points triangulated from a short baseline are noisy in depth: register with COLMAP's
    // looser absolute-pose threshold (12 px) rather than the two-view one.
    let r3 = ransac(
        &est,
        &RansacOptions {
            max_error: 12.0,
            ..options
        },
    )
    .unwrap();
    let cam3 = r3.model;
    println!(
        "registered 03.jpg from {} of {} 2-D/3-D correspondences",
        r3.num_inliers,
        world.len()
    );

    // Bundle adjustment of the three views (01 fixed, Huber loss against remaining mismatches) on
    // every track seen at least twice, triangulated with the current poses.
    let names = ["01.jpg", "02.jpg", "03.jpg"];
    let cams = [cam1, cam2, cam3];
    let mut all_ids: Vec<u64> = names
        .iter()
        .flat_map(|n| tracks[*n].keys().copied())
        .collect();
    all_ids.sort();
    all_ids.dedup();
    let mut problem = BundleProblem {
        groups: vec![CameraGroup::fixed(timesift_core::Camera::Pinhole(pinhole))],
        images: cams
            .iter()
            .enumerate()
            .map(|(k, c)| BundleImage {
                pose: *c,
                group: 0,
                fixed: k == 0,
            })
            .collect(),
        points: Vec::new(),
        observations: Vec::new(),
        ..BundleProblem::default()
    };
    for id in &all_ids {
        let views: Vec<(usize, Vector3<f64>)> = (0..3)
            .filter_map(|k| tracks[names[k]].get(id).map(|r| (k, *r)))
            .collect();
        if views.len() < 2 {
            continue;
        }
        let rays: Vec<(Pose, Vector3<f64>)> = views.iter().map(|(k, r)| (cams[*k], *r)).collect();
        let Ok(p) = triangulate_dlt(&rays) else {
            continue;
        };
        // Keep tracks consistent with the initial poses within 8 px.
        let consistent = views.iter().all(|(k, r)| {
            pinhole
                .project(&cams[*k].transform_point(&p))
                .is_ok_and(|px| (px - pinhole.project(r).unwrap()).norm() < 8.0)
        });
        if !consistent {
            continue;
        }
        let point = problem.points.len();
        problem.points.push(BundlePoint {
            position: p,
            fixed: false,
        });
        for (k, r) in &views {
            problem.observations.push(Observation {
                image: *k,
                point,
                pixel: pinhole.project(r).unwrap(),
                sigma_px: 1.0,
            });
        }
    }
    let report = solve(
        &mut problem,
        &BundleOptions {
            loss: Loss::Huber(2.0),
            ..BundleOptions::default()
        },
    )
    .unwrap();
    println!(
        "bundle adjustment: {} points, {} observations, RMS {:.2} px, {:?}",
        problem.points.len(),
        problem.observations.len(),
        report.rms_px,
        report.termination
    );
    let (cam2, cam3) = (problem.images[1].pose, problem.images[2].pose);

    let ours = [("01.jpg", cam1), ("02.jpg", cam2), ("03.jpg", cam3)];
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        let (a, pa) = ours[i];
        let (b, pb) = ours[j];
        let estimated = pb * pa.inverse();
        let truth = poses[b] * poses[a].inverse();
        let rot = estimated.rotation.angle_to(&truth.rotation).to_degrees();
        let dir = estimated
            .translation
            .normalize()
            .angle(&truth.translation.normalize())
            .to_degrees();
        println!("{a}-{b}: rotation {rot:.3}°, translation direction {dir:.3}°");
        assert!(rot < 0.5, "{a}-{b}: rotation differs by {rot}°");
        assert!(
            dir < 0.5,
            "{a}-{b}: translation direction differs by {dir}°"
        );
    }
}
