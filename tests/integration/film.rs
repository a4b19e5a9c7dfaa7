//! Scanned film on `synth archival`: every fiducial mark of every scan is found within a fifth
//! of a pixel of where it truly is, every scan gets an interior orientation with its residuals
//! reported, no keypoint falls on the film's edge, marks or data strip, and bad inputs — a mark
//! that is not there, a template larger than the search, certificate coordinates that do not
//! fit the scans — are named by image and mark while the other scans go on.

use std::collections::BTreeMap;
use std::path::Path;

use crate::common::timesift;
use nalgebra::Vector2;
use timesift_synth::scene::SceneSpec;
use timesift_synth::scenes::{Scale, build};
use timesift_synth::writer::{WriteOptions, write_scene};

/// `image,mark,u,v[,…]` rows of a CSV file, by (image, mark).
fn marks(path: &Path) -> BTreeMap<(String, String), Vector2<f64>> {
    let text = std::fs::read_to_string(path).expect("csv");
    text.lines()
        .skip(1)
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let n = |k: usize| f[k].parse::<f64>().expect("number");
            (
                (f[0].to_string(), f[1].to_string()),
                Vector2::new(n(2), n(3)),
            )
        })
        .collect()
}

/// The archival scene, rendered; `epochs` and `images` cut it down for tests of bad inputs.
fn archival(dir: &Path, epochs: usize, images: usize) -> SceneSpec {
    let mut spec = build("archival", Scale::Small, 5).expect("scene");
    spec.epochs.truncate(epochs);
    spec.keep_first_images(images);
    write_scene(&spec, dir, &WriteOptions::default()).expect("write");
    spec
}

#[test]
fn every_mark_is_found_within_a_fifth_of_a_pixel_and_no_keypoint_falls_on_the_film() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let spec = archival(dir, 4, usize::MAX);
    let d = dir.to_str().expect("utf-8");
    let (ok, out, err) = timesift(&["fiducials", d]);
    println!("{out}");
    assert!(ok, "{err}");
    let truth = marks(&dir.join("truth/fiducials.csv"));
    let found = marks(&dir.join("out/fiducials.csv"));
    assert_eq!(
        found.len(),
        truth.len(),
        "every mark of every scan is found"
    );
    let sum: f64 = truth
        .iter()
        .map(|(k, t)| (found[k] - t).norm_squared())
        .sum();
    let rms = (sum / truth.len() as f64).sqrt();
    println!("{} marks, position error RMS {rms:.3} px", truth.len());
    assert!(rms <= 0.2, "{rms}");
    // The interior-orientation residuals of every scan are reported.
    let scans: Vec<&str> = truth.keys().map(|(image, _)| image.as_str()).collect();
    for scan in &scans {
        assert!(
            out.lines()
                .any(|l| l.starts_with(scan) && l.contains("affine")),
            "{scan}"
        );
    }
    assert!(out.contains("residual RMS per mark"), "{out}");
    let sheet = image::open(dir.join("out/fiducials.png")).expect("contact sheet");
    assert!(
        sheet.height() as usize > 30 * (truth.len() / 8),
        "a row per scan"
    );

    // Features: only on the photograph.
    let (ok, _, err) = timesift(&["run", d, "--to", "features"]);
    assert!(ok, "{err}");
    let project = timesift::Project::load(dir).expect("project");
    let mut keypoints = 0;
    for (i, image) in project.images.iter().enumerate() {
        let epoch = &spec.epochs[image.epoch.index()];
        let film = epoch.film.as_ref().expect("film");
        let (kps, _) = timesift_matching::storage::read_features(&project.layout().feature_file(i))
            .expect("features");
        assert!(kps.len() > 100, "{}: {} keypoints", image.name, kps.len());
        for k in &kps {
            let p = Vector2::new(k.x, k.y);
            assert!(
                film.on_photo(&epoch.camera, &p),
                "{}: keypoint at {p} of the frame is off the photograph",
                image.name
            );
        }
        keypoints += kps.len();
    }
    println!("{keypoints} keypoints, all on the photographs");

    // A camera mask drawn on the frame `fiducials` shows: no keypoint where it is zero.
    let camera = &spec.epochs[0].name;
    let example = image::open(dir.join(format!("out/fiducials_frame_{camera}.png")))
        .expect("frame example")
        .to_luma8();
    let (w, h) = example.dimensions();
    assert_eq!(
        (w, h),
        (spec.epochs[0].camera.width, spec.epochs[0].camera.height)
    );
    let mask =
        image::GrayImage::from_fn(w, h, |x, _| image::Luma([if x < w / 2 { 0 } else { 255 }]));
    mask.save(dir.join("calibration/mask.png")).expect("mask");
    let toml = std::fs::read_to_string(dir.join("project.toml")).expect("toml");
    let with_mask = toml.replacen(
        &format!("name = \"{camera}\"\nfocal_mm"),
        &format!("name = \"{camera}\"\nmask = \"calibration/mask.png\"\nfocal_mm"),
        1,
    );
    assert_ne!(with_mask, toml);
    std::fs::write(dir.join("project.toml"), with_mask).expect("toml");
    let (ok, _, err) = timesift(&["run", d, "--to", "features"]);
    assert!(ok, "{err}");
    let project = timesift::Project::load(dir).expect("project");
    for &i in &project.epochs[0].images {
        let (kps, _) =
            timesift_matching::storage::read_features(&project.layout().feature_file(i.index()))
                .expect("features");
        assert!(!kps.is_empty());
        assert!(
            kps.iter().all(|k| k.x >= (w / 2) as f64),
            "a keypoint under the mask"
        );
    }
    // A mask of another size is an error naming it.
    image::GrayImage::new(w / 2, h)
        .save(dir.join("calibration/mask.png"))
        .expect("mask");
    let (ok, _, err) = timesift(&["run", d, "--to", "features"]);
    assert!(!ok);
    assert!(
        err.contains("mask.png") && err.contains("the mask is"),
        "{err}"
    );
}

#[test]
fn a_hidden_mark_a_large_template_and_wrong_coordinates_are_named_and_the_others_go_on() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    archival(dir, 1, 3);
    let d = dir.to_str().expect("utf-8");
    let truth = marks(&dir.join("truth/fiducials.csv"));
    let scan = "images/1971-06-14/IMG_0002.tif";

    // Mark 3 of one scan painted over with film base.
    let centre = truth[&(scan.to_string(), "3".to_string())];
    let mut grey = image::open(dir.join(scan)).expect("scan").to_luma8();
    for y in 0..grey.height() {
        for x in 0..grey.width() {
            if (Vector2::new(x as f64 + 0.5, y as f64 + 0.5) - centre).norm() < 14.0 {
                grey.put_pixel(x, y, image::Luma([10]));
            }
        }
    }
    grey.save(dir.join(scan)).expect("save");
    let (ok, out, err) = timesift(&["fiducials", d]);
    assert!(ok, "{err}");
    assert!(
        out.contains(&format!("warning: {scan}: mark 3 not found")),
        "{out}"
    );
    assert!(out.contains("3 scans: 23 of 24 marks used"), "{out}");
    // Measured by hand, in fiducials.csv: used as given.
    std::fs::write(
        dir.join("fiducials.csv"),
        format!("image,mark,u,v\n{scan},3,{:.2},{:.2}\n", centre.x, centre.y),
    )
    .expect("fiducials.csv");
    let (ok, out, err) = timesift(&["fiducials", d]);
    assert!(ok, "{err}");
    assert!(out.contains("3 scans: 24 of 24 marks used"), "{out}");
    let report: timesift::report::FiducialsReport =
        timesift::report::read_json(&dir.join("out/fiducials.json")).expect("report");
    let given = report
        .images
        .iter()
        .find(|s| s.image == scan)
        .and_then(|s| s.marks.iter().find(|m| m.mark == "3"))
        .expect("mark 3");
    assert_eq!(given.status, "given");
    std::fs::remove_file(dir.join("fiducials.csv")).expect("remove");

    // Fiducial coordinates 1.5 % off the scans: a warning per scan; 30 % off: an error per
    // scan, naming it.
    let toml_path = dir.join("project.toml");
    let original = std::fs::read_to_string(&toml_path).expect("toml");
    let scaled = |factor: f64| {
        original
            .lines()
            .map(|line| match line.split_once(" = [") {
                Some((name, rest)) if name.starts_with('"') => {
                    let v: Vec<f64> = rest
                        .trim_end_matches(']')
                        .split(',')
                        .map(|v| v.trim().parse::<f64>().expect("mm"))
                        .collect();
                    format!("{name} = [{}, {}]", v[0] * factor, v[1] * factor)
                }
                _ => line.to_string(),
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    std::fs::write(&toml_path, scaled(1.015)).expect("toml");
    let (ok, out, err) = timesift(&["fiducials", d]);
    assert!(ok, "{err}");
    assert!(out.contains("disagree with the scan"), "{out}");
    std::fs::write(&toml_path, scaled(1.3)).expect("toml");
    let (ok, out, err) = timesift(&["fiducials", d]);
    assert!(!ok, "{out}");
    assert!(
        err.lines().count() == 1 && err.contains("3 scans not oriented"),
        "{err}"
    );
    assert!(
        out.contains(&format!("{scan}  ")) && out.contains("disagree with the scan"),
        "{out}"
    );

    // A template larger than the search window.
    std::fs::write(&toml_path, &original).expect("toml");
    let big = image::GrayImage::from_fn(200, 200, |x, y| {
        image::Luma([((x * 7 + y * 3) % 251) as u8])
    });
    big.save(dir.join("calibration/mark_1971-06-14.png"))
        .expect("template");
    let (ok, out, err) = timesift(&["fiducials", d]);
    assert!(!ok);
    assert!(
        out.contains("larger than the search window"),
        "{out}\n{err}"
    );
    // `run` stops before features, naming the scan and the way out.
    let (ok, _, err) = timesift(&["run", d, "--to", "features"]);
    assert!(!ok);
    assert!(
        err.contains("without an interior orientation") && err.contains("fiducials.csv"),
        "{err}"
    );
}

/// `[[camera]] distortion_um`: each film camera's certificate curve, made from its true radial
/// distortion, is fitted and held: the align stage's cameras carry the true k1, k2, k3 to the
/// fit's rounding, whatever self-calibration would have made of them. A curve without
/// `focal_mm` is refused with its key named.
#[test]
fn a_certificates_distortion_curve_is_held_as_the_cameras_radial_terms() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let mut spec = build("archival", Scale::Small, 5).expect("scene");
    spec.epochs.drain(..2);
    write_scene(&spec, dir, &WriteOptions::default()).expect("write");
    let truth = timesift_io::cameras_json::read_cameras_json(&dir.join("truth/cameras.json"))
        .expect("truth");
    let radial = |name: &str| -> [f64; 3] {
        let mut p = vec![0.0; 11];
        timesift_core::CameraModel::params(&truth.cameras[name], &mut p);
        [p[5], p[6], p[7]]
    };
    let config = dir.join("project.toml");
    let text = std::fs::read_to_string(&config).expect("project.toml");
    // After each camera's focal length, the curve every 10 mm out to 160 mm, in µm.
    let mut with_curves = String::new();
    let mut camera = String::new();
    for line in text.lines() {
        with_curves += line;
        with_curves += "\n";
        if let Some(name) = line.strip_prefix("name = ") {
            camera = name.trim_matches('"').to_string();
        }
        if let Some(focal) = line.strip_prefix("focal_mm = ") {
            let f: f64 = focal.trim().parse().expect("focal_mm");
            let k = radial(&camera);
            let curve: Vec<String> = (0..=16)
                .map(|i| {
                    let r = 10.0 * i as f64;
                    let rho2 = (r / f).powi(2);
                    let dr = 1e3 * r * rho2 * (k[0] + rho2 * (k[1] + rho2 * k[2]));
                    format!("[{r:.1}, {dr:.9}]")
                })
                .collect();
            with_curves += &format!("distortion_um = [{}]\n", curve.join(", "));
        }
    }
    std::fs::write(&config, &with_curves).expect("project.toml");
    let path = dir.to_str().expect("utf-8 path");
    let (ok, _, err) = timesift(&["run", path, "--to", "align"]);
    assert!(ok, "{err}");
    let ours = timesift_io::cameras_json::read_cameras_json(&dir.join("out/cameras.json"))
        .expect("cameras.json");
    for (name, camera) in &ours.cameras {
        let mut p = vec![0.0; 11];
        timesift_core::CameraModel::params(camera, &mut p);
        let expected = radial(name);
        for t in 0..3 {
            assert!(
                (p[5 + t] - expected[t]).abs() < 1e-9,
                "{name}: k{} {} against the certificate's {}",
                t + 1,
                p[5 + t],
                expected[t]
            );
        }
    }
    // A curve in millimetres needs the focal length in millimetres.
    let broken = with_curves
        .replacen("focal_mm = ", "focal_px = ", 1)
        .replacen("pixel_mm = ", "# pixel_mm = ", 1);
    std::fs::write(&config, broken).expect("project.toml");
    let (ok, _, err) = timesift(&["run", path, "--from", "align", "--to", "align"]);
    assert!(!ok && err.contains("distortion_um"), "{err}");
}
