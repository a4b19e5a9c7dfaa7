//! `timesift run --to align` on a rendered two-epoch project (soil-pit: a vertical wall at close
//! range, GCPs marked in the reference epoch only, check points in both): every image oriented,
//! reprojection RMS within 0.5 px, check points within 1 GSD horizontally and 1.5 GSD vertically
//! in every epoch, camera centres close to the truth; the output files are readable. Then the
//! same with `align.method = "stp"`.

use crate::common::timesift;
use nalgebra::Vector3;
use timesift_io::cameras_json::read_cameras_json;
use timesift_synth::scenes::{Scale, build};
use timesift_synth::writer::{WriteOptions, write_scene};

#[test]
fn align_stage_orients_every_epoch_within_the_ground_sampling_distance() {
    let dir = tempfile::tempdir().expect("tempdir");
    let spec = build("soil-pit", Scale::Small, 1).expect("scene");
    write_scene(&spec, dir.path(), &WriteOptions::default()).expect("write");
    let path = dir.path().to_str().expect("utf-8 path");
    let (ok, _, err) = timesift(&["run", path, "--to", "align"]);
    assert!(ok, "{err}");
    let out = dir.path().join("out");
    let ours = read_cameras_json(&out.join("cameras.json")).expect("cameras.json");
    let truth = read_cameras_json(&dir.path().join("truth/cameras.json")).expect("truth");
    assert_eq!(ours.crs, truth.crs);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    println!("{report:#}");
    // Ground sampling distance at the check points: mean camera distance over the focal length.
    let checks: Vec<Vector3<f64>> = std::fs::read_to_string(dir.path().join("checkpoints.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').skip(1).map(|x| x.parse().unwrap()).collect();
            Vector3::new(v[0], v[1], v[2])
        })
        .collect();
    let centroid = checks.iter().sum::<Vector3<f64>>() / checks.len() as f64;
    let mut distance = 0.0;
    let mut centre_sq = 0.0;
    for (o, t) in ours.images.iter().zip(&truth.images) {
        assert_eq!(o.name, t.name);
        let (o, t) = (o.pose.expect("oriented"), t.pose.unwrap());
        distance += (t.center() - centroid).norm();
        centre_sq += (o.center() - t.center()).norm_squared();
    }
    let n = ours.images.len() as f64;
    let camera = truth.cameras.values().next().unwrap();
    let mut f = vec![0.0; 11];
    timesift_core::CameraModel::params(camera, &mut f);
    let gsd = distance / n / f[0];
    let centre_rmse = (centre_sq / n).sqrt();
    println!("GSD {gsd:.4} m, camera centre RMSE {centre_rmse:.4} m");
    check_epochs(&report, gsd);
    // The outlier bound comes from the block's noise: within [0.5, 4] px by construction, and
    // 4 σ of an RMS within 0.5 px is under 2 px.
    let bound = report["observation_bound_px"].as_f64().unwrap();
    assert!((0.5..2.0).contains(&bound), "observation bound {bound} px");
    // Each camera group is judged by its own noise, within the same limits.
    let groups = report["group_noise"].as_array().unwrap();
    assert_eq!(groups.len(), report["cameras"].as_array().unwrap().len());
    for g in groups {
        let (sigma, bound) = (
            g["sigma_px"].as_f64().unwrap(),
            g["bound_px"].as_f64().unwrap(),
        );
        assert!(sigma < 0.5 && (0.5..2.0).contains(&bound), "{g}");
    }
    for (name, epoch) in report["epochs"].as_object().unwrap() {
        assert!(
            epoch["inter_epoch_tie_points"].as_u64().unwrap() > 100,
            "{name}"
        );
    }
    // Without stable areas, no spread of the tie points on them; the points held to the
    // reference epoch's surface, where any are, widen the ties.
    let held_in = |name: &serde_json::Value| {
        let epoch = &report["epochs"][name.as_str().expect("epoch name")];
        epoch["surface_fit"]["points_held"].as_u64().unwrap_or(0)
    };
    for pair in report["epoch_pairs"].as_array().unwrap() {
        assert!(pair["stable_across_std_m"].is_null(), "{pair}");
        let epochs = pair["epochs"].as_array().expect("the pair's epochs");
        let held = epochs.iter().map(held_in).sum::<u64>();
        match pair["held_across_std_m"].as_f64() {
            Some(across) => assert!(held > 0 && across.is_finite() && across > 0.0, "{pair}"),
            None => assert_eq!(held, 0, "{pair}"),
        }
    }
    // One block: every epoch rests on all of its control, so the tilt σ that control allows
    // is one figure.
    let tilts: Vec<f64> = report["epochs"]
        .as_object()
        .unwrap()
        .values()
        .map(|e| {
            e["datum_tilt"]["sigma_max_mm_per_m"]
                .as_f64()
                .expect("datum_tilt")
        })
        .collect();
    assert!(
        tilts.iter().all(|t| *t > 0.0 && *t == tilts[0]),
        "{tilts:?}"
    );
    assert!(
        centre_rmse < 2.0 * gsd,
        "camera centres off by {centre_rmse} m"
    );
    // The other outputs are readable and agree with cameras.json.
    let model = timesift_io::colmap::read_colmap_text(&out.join("colmap")).expect("colmap model");
    assert_eq!(model.images.len(), ours.images.len());
    let (epochs, points) =
        timesift_io::ply::read_tiepoints(&out.join("tiepoints.ply")).expect("tie points");
    assert_eq!(epochs.len(), 2);
    assert_eq!(points.len(), model.points.len());
    assert!(
        points
            .iter()
            .any(|p| p.epochs == [0, 1].into_iter().collect())
    );

    // `stp` on the same features and matches: the second epoch controlled by the reference
    // epoch's stable tie points (descriptors read back from the feature files) meets the same
    // bounds.
    let config = dir.path().join("project.toml");
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(
        &config,
        text.replace("method = \"timesift\"", "method = \"stp\""),
    )
    .unwrap();
    let (ok, _, err) = timesift(&["run", path, "--from", "align", "--to", "align"]);
    assert!(ok, "{err}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["method"], "stp");
    check_epochs(&report, gsd);
    // The later epoch's datum comes through the reference epoch's: only the reference's own
    // control is predicted.
    let predicted = report["epochs"]
        .as_object()
        .unwrap()
        .values()
        .filter(|e| !e["datum_tilt"].is_null())
        .count();
    assert_eq!(predicted, 1);
    // `stp` compares no epoch with the reference's surface: no mask of what it found stable.
    let found = out.join("stable_found.tif");
    assert!(!found.exists());

    // `timesift` without stable areas: the ground the block found unchanged (its surviving
    // inter-epoch ties; the later epoch's points that met the reference epoch's surface) is
    // the change stage's stable areas.
    std::fs::write(&config, text).unwrap();
    let _ = std::fs::remove_file(dir.path().join("stable.csv"));
    let (ok, _, err) = timesift(&["run", path, "--from", "align", "--to", "align"]);
    assert!(ok, "{err}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    check_epochs(&report, gsd);
    let mask = timesift_io::geotiff::read_f32(&found).expect("stable_found.tif");
    assert_eq!(mask.georef.crs, ours.crs.parse().unwrap());
    let stable = mask.data.iter().filter(|v| **v == 1.0).count();
    assert!(stable > 0 && mask.data.iter().all(|v| *v == 0.0 || *v == 1.0));

    // A stable area around the whole site: every tie point is on stable ground, so their
    // spread across the block is every tie point's.
    let (x, y) = (centroid.x, centroid.y);
    std::fs::write(
        dir.path().join("stable.csv"),
        format!(
            "name,wkt\nsite,\"POLYGON(({} {}, {} {}, {} {}, {} {}, {} {}))\"\n",
            x - 200.0,
            y - 200.0,
            x + 200.0,
            y - 200.0,
            x + 200.0,
            y + 200.0,
            x - 200.0,
            y + 200.0,
            x - 200.0,
            y - 200.0
        ),
    )
    .unwrap();
    let (ok, _, err) = timesift(&["run", path, "--from", "align", "--to", "align"]);
    assert!(ok, "{err}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    for pair in report["epoch_pairs"].as_array().unwrap() {
        let stable = pair["stable_across_std_m"].as_f64().expect("stable spread");
        let all = pair["all_across_std_m"].as_f64().expect("spread");
        assert!((stable - all).abs() <= 1e-9 * all, "{pair}");
    }
}

/// Every epoch fully oriented, RMS within 0.5 px, check points within 1 GSD across the wall
/// and 1.5 GSD in depth.
fn check_epochs(report: &serde_json::Value, gsd: f64) {
    assert_eq!(report["images_oriented"], report["images_given"]);
    for (name, epoch) in report["epochs"].as_object().unwrap() {
        assert_eq!(epoch["images_oriented"], epoch["images_given"], "{name}");
        let rms = epoch["rms_reprojection_px"].as_f64().unwrap();
        assert!(rms <= 0.5, "{name}: RMS {rms} px");
        let chk = &epoch["check_points"]["rmse"];
        let (de, dn, dh) = (
            chk["dE"].as_f64().unwrap(),
            chk["dN"].as_f64().unwrap(),
            chk["dH"].as_f64().unwrap(),
        );
        // The wall faces north: its "horizontal" plane is (E, H), depth is N.
        let horizontal = (de * de + dh * dh).sqrt();
        assert!(
            horizontal <= gsd && dn <= 1.5 * gsd,
            "{name}: check points dE {de} dN {dn} dH {dh} against GSD {gsd}"
        );
        // Each measured check point carries the σ its markers alone give, and the markers'
        // RMSE is their RMS over the same points.
        let points = epoch["check_points"]["points"].as_array().unwrap();
        let sigmas: Vec<f64> = points
            .iter()
            .filter(|p| !p["dH"].is_null())
            .map(|p| p["markers_sigma"][2].as_f64().expect("σH of the markers"))
            .collect();
        assert!(
            sigmas.iter().all(|s| s.is_finite() && *s > 0.0),
            "{sigmas:?}"
        );
        let markers = &epoch["check_points"]["markers_rmse"];
        assert_eq!(markers["n"].as_u64(), Some(sigmas.len() as u64));
        let rms = (sigmas.iter().map(|s| s * s).sum::<f64>() / sigmas.len() as f64).sqrt();
        assert!((markers["dH"].as_f64().unwrap() - rms).abs() < 1e-9 * rms.max(1.0));
    }
}
