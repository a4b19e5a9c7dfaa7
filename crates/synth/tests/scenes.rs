//! Every scene at both scales, written without images (the geometry and truth do not depend on
//! them): each marker reprojects from its true 3-D point through truth/cameras.json within 4σ of
//! its noise; every GCP and check point lies in the stable mask (and in stable.csv); the true
//! volumes of truth/change.json agree with volumes integrated from the true DEMs to 0.1 %; the
//! true surfaces of all epochs agree exactly wherever the mask says stable.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector3;
use timesift_core::project_world;
use timesift_io::cameras_json::read_cameras_json;
use timesift_io::csv_inputs::{read_markers, read_stable_areas};
use timesift_io::geotiff::{GeoRaster, read_f32};
use timesift_io::wkt::parse_polygons;
use timesift_synth::scenes::{EXTRA_SCENES, SCENES, Scale, build};
use timesift_synth::writer::{WriteOptions, write_scene};

const GEOMETRY_ONLY: WriteOptions = WriteOptions { images: false };

/// truth/points.csv and truth/stable_points.csv: name → (kind, world position); the natural
/// stable points are of kind "natural".
fn truth_points(dir: &Path) -> BTreeMap<String, (String, Vector3<f64>)> {
    let text = std::fs::read_to_string(dir.join("truth/points.csv")).expect("points.csv");
    let natural =
        std::fs::read_to_string(dir.join("truth/stable_points.csv")).expect("stable_points.csv");
    text.lines()
        .skip(1)
        .map(|l| l.split(',').collect::<Vec<&str>>())
        .chain(natural.lines().skip(1).map(|l| {
            let mut f: Vec<&str> = l.split(',').collect();
            f.insert(1, "natural");
            f
        }))
        .map(|f| {
            let n = |i: usize| f[i].parse::<f64>().expect("number");
            (
                f[0].to_string(),
                (f[1].to_string(), Vector3::new(n(2), n(3), n(4))),
            )
        })
        .collect()
}

fn change_json(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("truth/change.json")).expect("change.json");
    serde_json::from_str(&text).expect("json")
}

/// Raster position (col, row) of a world point: (E, N) for ground scenes, (E, H) minus the
/// origin for wall scenes.
fn raster_xy(change: &serde_json::Value, p: &Vector3<f64>) -> (f64, f64) {
    let frame = change["frame"].as_str().expect("frame");
    let o: Vec<f64> = change["origin"]
        .as_array()
        .expect("origin")
        .iter()
        .map(|v| v.as_f64().expect("number"))
        .collect();
    if frame.starts_with("wall") {
        (p.x - o[0], p.z - o[2])
    } else {
        (p.x, p.y)
    }
}

fn value_at(raster: &GeoRaster<f32>, x: f64, y: f64) -> f32 {
    let (c, r) = raster.georef.transform.world_to_pixel(x, y);
    raster.get(c.floor() as usize, r.floor() as usize, 0)
}

/// Markers and control; returns (markers, worst |Δ| in σ).
/// `truth/scan_transforms.csv` of a scene with film scans: image → a11 … a23.
fn scan_transforms(dir: &Path) -> BTreeMap<String, [f64; 6]> {
    let Ok(text) = std::fs::read_to_string(dir.join("truth/scan_transforms.csv")) else {
        return BTreeMap::new();
    };
    text.lines()
        .skip(1)
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let a: Vec<f64> = f[1..].iter().map(|v| v.parse().expect("number")).collect();
            (f[0].to_string(), [a[0], a[1], a[2], a[3], a[4], a[5]])
        })
        .collect()
}

fn check_markers_and_control(name: &str, scale: Scale, dir: &Path) -> (usize, f64) {
    let spec = build(name, scale, 7).expect("scene");
    write_scene(&spec, dir, &GEOMETRY_ONLY).expect("write");
    let truth = read_cameras_json(&dir.join("truth/cameras.json")).expect("cameras.json");
    let points = truth_points(dir);
    let markers = read_markers(&dir.join("markers.csv")).expect("markers");
    let scans = scan_transforms(dir);
    assert_eq!(
        spec.epochs.iter().any(|e| e.film.is_some()),
        !scans.is_empty(),
        "{name}: scan transforms for the film epochs"
    );
    let images: BTreeMap<&str, _> = truth.images.iter().map(|i| (i.name.as_str(), i)).collect();
    let mut worst = 0.0f64;
    let mut sum_sq = 0.0;
    let mut seen: BTreeMap<&str, usize> = BTreeMap::new();
    // Natural points: (name, epoch) → images measuring it.
    let mut natural_seen: BTreeMap<(&str, &str), usize> = BTreeMap::new();
    for m in &markers {
        let image = images[m.image.as_str()];
        let camera = &truth.cameras[&image.camera];
        let pose = image.pose.as_ref().expect("true poses exist");
        let x = points[&m.name].1;
        let px = project_world(camera, pose, &x).expect("projects");
        // Film scans: markers are measured on the scan, the camera sees the frame.
        let px = match scans.get(m.image.as_str()) {
            Some(a) => nalgebra::Vector2::new(
                a[0] * px.x + a[1] * px.y + a[2],
                a[3] * px.x + a[4] * px.y + a[5],
            ),
            None => px,
        };
        let d = (m.pixel - px) / spec.marker_sigma;
        worst = worst.max(d.x.abs()).max(d.y.abs());
        sum_sq += d.norm_squared();
        let (point, (kind, _)) = points.get_key_value(&m.name).expect("known");
        *seen.entry(point).or_default() += 1;
        if kind == "natural" {
            *natural_seen
                .entry((point, image.epoch.as_str()))
                .or_default() += 1;
        }
    }
    assert!(!markers.is_empty(), "{name}: no markers");
    assert!(worst <= 4.0, "{name}: marker off by {worst:.2} σ");
    // The noise is there, at its stated level.
    let rms = (sum_sq / (2 * markers.len()) as f64).sqrt();
    if markers.len() >= 50 {
        assert!(
            (0.85..1.15).contains(&rms),
            "{name}: marker noise RMS {rms:.2} σ"
        );
    }
    let gcps_seen_twice = spec
        .gcps
        .iter()
        .filter(|g| seen.get(g.name.as_str()).copied().unwrap_or(0) >= 2)
        .count();
    assert!(
        gcps_seen_twice >= 3,
        "{name}: {gcps_seen_twice} GCPs in two images or more"
    );
    // Control on stable ground: the mask, and the stable.csv polygons of ground scenes.
    let change = change_json(dir);
    let mask = read_f32(&dir.join("truth/stable.tif")).expect("stable.tif");
    let stable_csv = dir.join("stable.csv");
    let areas = if stable_csv.is_file() {
        read_stable_areas(&stable_csv).expect("stable.csv")
    } else {
        Vec::new()
    };
    let mut control = 0;
    for (point, (kind, x)) in &points {
        if kind != "gcp" && kind != "checkpoint" && kind != "natural" {
            continue;
        }
        control += usize::from(kind != "natural");
        let (mx, my) = raster_xy(&change, x);
        assert_eq!(
            value_at(&mask, mx, my),
            1.0,
            "{name}: {point} off the stable mask"
        );
        if !areas.is_empty() {
            assert!(
                areas
                    .iter()
                    .any(|a| a.polygons.iter().any(|p| p.contains(x.x, x.y))),
                "{name}: {point} outside stable.csv"
            );
        }
    }
    assert!(control >= 7, "{name}: {control} control and check points");
    // Enough natural stable points for `manual`: intersected in four images of the reference
    // epoch, measured in two of every other.
    let listed = std::fs::read_to_string(dir.join("stable_points.csv")).expect("stable_points");
    let natural: Vec<&str> = listed.lines().skip(1).collect();
    assert_eq!(
        natural.len(),
        points.values().filter(|(k, _)| k == "natural").count()
    );
    let reference = &spec.epochs[0].name;
    let usable = natural
        .iter()
        .filter(|p| {
            natural_seen
                .get(&(**p, reference.as_str()))
                .is_some_and(|&n| n >= 4)
                && spec.epochs[1..].iter().all(|e| {
                    natural_seen
                        .get(&(**p, e.name.as_str()))
                        .is_some_and(|&n| n >= 2)
                })
        })
        .count();
    println!(
        "{name:<10} {usable} of {} natural stable points usable by `manual`",
        natural.len()
    );
    assert!(
        usable >= 4,
        "{name}: {usable} natural points usable by `manual`"
    );
    (markers.len(), worst)
}

#[test]
fn markers_reproject_and_control_is_on_stable_ground_in_every_scene_at_both_scales() {
    let root = tempfile::tempdir().expect("tempdir");
    for name in SCENES.into_iter().chain(EXTRA_SCENES) {
        for (scale, label) in [(Scale::Small, "small"), (Scale::Full, "full")] {
            let dir = root.path().join(format!("{name}-{label}"));
            let (n, worst) = check_markers_and_control(name, scale, &dir);
            println!("{name:<10} {label:<5} {n:>6} markers, worst {worst:.2} σ");
        }
    }
}

#[test]
fn true_volumes_match_the_true_surfaces_and_stable_ground_never_changes() {
    let root = tempfile::tempdir().expect("tempdir");
    for name in SCENES.into_iter().chain(EXTRA_SCENES) {
        let dir = root.path().join(name);
        let spec = build(name, Scale::Small, 3).expect("scene");
        write_scene(&spec, &dir, &GEOMETRY_ONLY).expect("write");
        let change = change_json(&dir);
        let dems: BTreeMap<String, GeoRaster<f32>> = spec
            .epochs
            .iter()
            .map(|e| {
                let path = dir.join(format!("truth/dem_{}.tif", e.name));
                (e.name.clone(), read_f32(&path).expect("dem"))
            })
            .collect();
        let first = dems.values().next().expect("an epoch");
        let t = first.georef.transform;
        let cell_area = (t.pixel_width * t.pixel_height).abs();
        let mut worst = 0.0f64;
        for region in change["regions"].as_array().expect("regions") {
            let wkt = region["polygon_wkt"].as_str().expect("wkt");
            let polygon = &parse_polygons(wkt).expect("polygon")[0];
            let inside: Vec<usize> = (0..first.width * first.height)
                .filter(|k| {
                    let (x, y) = t.pixel_to_world(
                        (k % first.width) as f64 + 0.5,
                        (k / first.width) as f64 + 0.5,
                    );
                    polygon.contains(x, y)
                })
                .collect();
            for v in region["volumes"].as_array().expect("volumes") {
                let (a, b) = (
                    &dems[v["from"].as_str().expect("from")],
                    &dems[v["to"].as_str().expect("to")],
                );
                let integrated: f64 = inside
                    .iter()
                    .map(|&k| (b.data[k] as f64 - a.data[k] as f64) * cell_area)
                    .sum();
                let truth = v["volume_m3"].as_f64().expect("volume");
                if truth == 0.0 {
                    assert!(
                        integrated.abs() < 1e-6,
                        "{name}: {integrated} for no change"
                    );
                    continue;
                }
                let rel = (integrated / truth - 1.0).abs();
                worst = worst.max(rel);
                assert!(
                    rel < 1e-3,
                    "{name} {} {}→{}: true {truth:.6} m³, integrated {integrated:.6} m³ ({:.3} %)",
                    region["name"],
                    v["from"],
                    v["to"],
                    100.0 * rel
                );
            }
        }
        let mask = read_f32(&dir.join("truth/stable.tif")).expect("mask");
        let changed_stable = (0..mask.data.len())
            .filter(|&k| mask.data[k] == 1.0 && dems.values().any(|d| d.data[k] != first.data[k]))
            .count();
        assert_eq!(
            changed_stable, 0,
            "{name}: stable cells whose height changes"
        );
        println!(
            "{name:<10} {} regions, worst volume error {:.4} %",
            change["regions"].as_array().map_or(0, Vec::len),
            100.0 * worst
        );
    }
}

#[test]
fn scenes_are_deterministic_for_a_seed() {
    let root = tempfile::tempdir().expect("tempdir");
    let write = |seed: u64, sub: &str| {
        let dir = root.path().join(sub);
        let spec = build("campus", Scale::Small, seed).expect("scene");
        write_scene(&spec, &dir, &GEOMETRY_ONLY).expect("write");
        (
            std::fs::read_to_string(dir.join("markers.csv")).expect("markers"),
            std::fs::read_to_string(dir.join("truth/cameras.json")).expect("cameras"),
        )
    };
    let (a, b, c) = (write(5, "a"), write(5, "b"), write(6, "c"));
    assert_eq!(a, b);
    assert_ne!(a.0, c.0);
}

#[test]
fn unknown_scene_and_scale_are_clear_errors() {
    let e = build("moon", Scale::Small, 1)
        .err()
        .expect("error")
        .to_string();
    assert!(e.contains("moon") && e.contains("glacier"), "{e}");
    let e = "huge".parse::<Scale>().expect_err("error");
    assert!(e.contains("small") && e.contains("huge"), "{e}");
}

#[test]
fn the_corridor_with_tracks_has_control_across_its_width_and_the_plain_one_along_its_band() {
    // Across the corridor (y): the dune band ends at 74 m, the corridor at 110 m.
    let spread = |name: &str| {
        let spec = build(name, Scale::Small, 1).expect("scene");
        let ys: Vec<f64> = spec.gcps.iter().map(|p| p.at.1).collect();
        let names: std::collections::BTreeSet<&str> =
            spec.gcps.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names.len(), spec.gcps.len(), "{name}: GCP names repeat");
        (
            spec.gcps.len(),
            ys.iter().copied().fold(f64::INFINITY, f64::min),
            ys.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let (n, _, top) = spread("corridor");
    assert!(n >= 4 && top < 74.0, "corridor: {n} GCPs up to y = {top}");
    let (n, _, top) = spread("corridor-tracks");
    assert!(
        n >= 6 && top > 90.0,
        "corridor-tracks: {n} GCPs up to y = {top}"
    );
}

#[test]
fn the_12_megapixel_bench_scene_is_one_epoch_of_nine_overlapping_4000_by_3000_images() {
    use timesift_core::CameraModel;
    let spec = build("landslide-12mp", Scale::Small, 1).expect("scene");
    assert_eq!(spec.epochs.len(), 1);
    let epoch = &spec.epochs[0];
    assert_eq!((epoch.camera.width, epoch.camera.height), (4000, 3000));
    assert_eq!(epoch.images.len(), 9);
    // Each image's centre, on the ground plane the flight was planned for (45 m), lies inside
    // at least four of the other images: every view has sources on every side.
    let ground = 45.0;
    for (a, image) in epoch.images.iter().enumerate() {
        let centre = image.pose.inverse().translation;
        let ray = image.pose.rotation.inverse() * Vector3::new(0.0, 0.0, 1.0);
        let point = centre + ray * ((ground - centre.z) / ray.z);
        let seen_by = epoch
            .images
            .iter()
            .enumerate()
            .filter(|(b, other)| {
                *b != a
                    && epoch
                        .camera
                        .project(&other.pose.transform_point(&point))
                        .is_ok_and(|p| p.x >= 0.0 && p.y >= 0.0 && p.x < 4000.0 && p.y < 3000.0)
            })
            .count();
        assert!(
            seen_by >= 4,
            "image {a}: its centre seen by {seen_by} others"
        );
    }
}
