//! cameras.json → COLMAP text → cameras.json preserves poses and projections.

use std::collections::BTreeMap;

use nalgebra::{UnitQuaternion, Vector3};
use proptest::prelude::*;
use timesift_core::{BrownCamera, Camera, PinholeCamera, Pose, project_world};
use timesift_io::cameras_json::{
    OrientedImage, Reconstruction, read_cameras_json, write_cameras_json,
};
use timesift_io::colmap::{
    from_reconstruction, read_colmap_text, to_reconstruction, write_colmap_text,
};

fn reconstruction(translation: f64) -> impl Strategy<Value = Reconstruction> {
    let brown = (
        (
            500u32..6000,
            0.8f64..2.5,
            -30.0f64..30.0,
            -30.0f64..30.0,
            -2.0f64..2.0,
        ),
        (
            -0.3f64..0.3,
            -0.3f64..0.3,
            prop_oneof![Just(0.0), -0.1f64..0.1],
        ),
        (-0.01f64..0.01, -0.01f64..0.01),
    )
        .prop_map(|((w, f, cx, cy, b1), (k1, k2, k3), (p1, p2))| {
            let h = w * 2 / 3;
            let mut c = BrownCamera::new(w, h, f * w as f64).unwrap();
            (c.cx, c.cy, c.b1, c.k1, c.k2, c.k3, c.p1, c.p2) = (cx, cy, b1, k1, k2, k3, p1, p2);
            Camera::Brown(c)
        });
    let pose = (
        (-3.1f64..3.1, -1.5f64..1.5, -3.1f64..3.1),
        (
            -translation..translation,
            -translation..translation,
            -translation..translation,
        ),
    )
        .prop_map(|((r, p, y), (x, yy, z))| {
            Pose::new(
                UnitQuaternion::from_euler_angles(r, p, y),
                Vector3::new(x, yy, z),
            )
        });
    (
        prop::collection::vec(brown, 1..4),
        prop::collection::vec((pose, 0usize..8), 1..12),
    )
        .prop_map(|(cams, poses)| {
            let mut cameras: BTreeMap<String, Camera> = cams
                .into_iter()
                .enumerate()
                .map(|(i, c)| (format!("epoch-{i}"), c))
                .collect();
            cameras.insert(
                "pin".into(),
                Camera::Pinhole(PinholeCamera::new(800, 600, 700.0).unwrap()),
            );
            let names: Vec<String> = cameras.keys().cloned().collect();
            let images = poses
                .into_iter()
                .enumerate()
                .map(|(i, (pose, c))| {
                    let camera = names[c % names.len()].clone();
                    OrientedImage {
                        name: format!("images/{camera}/IMG {i:04}.jpg"),
                        epoch: camera.clone(),
                        camera,
                        pose: Some(pose),
                    }
                })
                .collect();
            Reconstruction {
                crs: "EPSG:32633".into(),
                cameras,
                images,
            }
        })
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 32,
        // Seeded, so every run explores the same cases (reproducible CI).
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x0715_31f7),
        ..ProptestConfig::default()
    })]
    #[test]
    fn round_trip_preserves_utm_sized_poses(r in reconstruction(6e6)) {
        let back = round_trip(&r);
        for (a, b) in r.images.iter().zip(&back.images) {
            let (pa, pb) = (a.pose.unwrap(), b.pose.unwrap());
            prop_assert!((pa.rotation_matrix() - pb.rotation_matrix()).amax() < 1e-12);
            prop_assert_eq!(pa.translation, pb.translation);
        }
    }

    /// Projections are compared in a local frame: with UTM-sized world coordinates, f64 itself cannot
    /// place a point 2 m in front of a camera to 1e-9 px, whatever the file format.
    #[test]
    fn cameras_json_colmap_cameras_json_preserves_geometry(r in reconstruction(100.0), seeds in prop::collection::vec((0.0f64..1.0, 0.0f64..1.0, 2.0f64..300.0), 20)) {
        let original = r;
        let back = round_trip(&original);

        prop_assert_eq!(back.images.len(), original.images.len());
        for (a, b) in original.images.iter().zip(&back.images) {
            prop_assert_eq!(&a.name, &b.name);
            prop_assert_eq!(&a.epoch, &b.epoch);
            prop_assert_eq!(&a.camera, &b.camera);
            let (pa, pb) = (a.pose.unwrap(), b.pose.unwrap());
            prop_assert!((pa.rotation_matrix() - pb.rotation_matrix()).amax() < 1e-12);
            prop_assert!((pa.translation - pb.translation).amax() <= 1e-12 * pa.translation.amax().max(1.0));
            let (ca, cb) = (&original.cameras[&a.camera], &back.cameras[&b.camera]);
            // Random points in front of the camera, through each camera model.
            for (u, v, depth) in &seeds {
                let pc = Vector3::new((u - 0.5) * 0.8 * depth, (v - 0.5) * 0.6 * depth, *depth);
                let world = pa.inverse().transform_point(&pc);
                let xa = project_world(ca, &pa, &world).unwrap();
                let xb = project_world(cb, &pb, &world).unwrap();
                prop_assert!((xa - xb).norm() < 1e-9, "projection differs by {} px", (xa - xb).norm());
            }
        }
    }
}

/// cameras.json -> COLMAP text -> cameras.json through files.
fn round_trip(r: &Reconstruction) -> Reconstruction {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("cameras.json");
    write_cameras_json(&json, r).unwrap();
    let original = read_cameras_json(&json).unwrap();
    write_colmap_text(
        &dir.path().join("colmap"),
        &from_reconstruction(&original).unwrap(),
    )
    .unwrap();
    let back = to_reconstruction(
        &read_colmap_text(&dir.path().join("colmap")).unwrap(),
        &original.crs,
    )
    .unwrap();
    let json2 = dir.path().join("cameras2.json");
    write_cameras_json(&json2, &back).unwrap();
    read_cameras_json(&json2).unwrap()
}

#[test]
fn unrepresentable_brown_terms_are_refused() {
    let mut c = BrownCamera::new(100, 100, 90.0).unwrap();
    c.b2 = 0.5;
    assert!(
        timesift_io::colmap::camera_to_colmap(&Camera::Brown(c))
            .unwrap_err()
            .contains("b2")
    );
    c.b2 = 0.0;
    c.k4 = 0.01;
    assert!(
        timesift_io::colmap::camera_to_colmap(&Camera::Brown(c))
            .unwrap_err()
            .contains("k4")
    );
}

#[test]
fn the_nearest_colmap_camera_drops_only_the_terms_colmap_lacks_and_says_which() {
    let mut c = BrownCamera::new(100, 100, 90.0).unwrap();
    (c.b1, c.b2, c.k1, c.k4, c.cx) = (0.2, 0.5, -0.01, 0.003, 1.5);
    let (nearest, dropped) = timesift_io::colmap::nearest_colmap_camera("film", &Camera::Brown(c));
    assert_eq!(dropped.len(), 2, "{dropped:?}");
    assert!(dropped[0].contains("\"film\"") && dropped[0].contains("b2 = 0.5"));
    assert!(dropped[1].contains("k4 = 0.003"));
    let Camera::Brown(n) = nearest else {
        panic!("{nearest:?}")
    };
    assert_eq!((n.b1, n.b2, n.k1, n.k4, n.cx), (0.2, 0.0, -0.01, 0.0, 1.5));
    // An exact camera loses nothing.
    let (same, dropped) = timesift_io::colmap::nearest_colmap_camera("drone", &Camera::Brown(n));
    assert!(dropped.is_empty());
    assert_eq!(same, Camera::Brown(n));
}

#[test]
fn opencv_tangential_terms_are_swapped() {
    let mut c = BrownCamera::new(1000, 800, 900.0).unwrap();
    c.p1 = 0.001;
    c.p2 = -0.002;
    let (model, params) = timesift_io::colmap::camera_to_colmap(&Camera::Brown(c)).unwrap();
    assert_eq!(model, "OPENCV");
    // OpenCV p1 is our p2; principal point absolute.
    assert_eq!(
        (params[2], params[3], params[6], params[7]),
        (500.0, 400.0, -0.002, 0.001)
    );
}

#[test]
fn non_finite_values_and_duplicate_ids_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cameras.txt"), "1 PINHOLE 100 80 90 90 50 40\n").unwrap();
    std::fs::write(d.join("images.txt"), "1 1 0 0 0 nan 0 0 1 a.jpg\n\n").unwrap();
    let e = read_colmap_text(d).unwrap_err().to_string();
    assert!(e.contains("images.txt: line 1") && e.contains("TX"), "{e}");
    std::fs::write(
        d.join("images.txt"),
        "1 1 0 0 0 0 0 0 1 a.jpg\n\n1 1 0 0 0 0 0 0 1 b.jpg\n\n",
    )
    .unwrap();
    let e = read_colmap_text(d).unwrap_err().to_string();
    assert!(e.contains("image id 1 is defined twice"), "{e}");
}
