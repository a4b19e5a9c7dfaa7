//! Real data end to end: the three OpenSfM `berlin` photos (EXIF GPS) with OpenSfM's ground
//! control point file converted to `gcps.csv` + `markers.csv`: `timesift run --to align` orients
//! all three, georeferences them from the EXIF GPS, and reports the control point residuals in
//! report.json.

use std::fmt::Write as _;
use std::path::PathBuf;

use crate::common::timesift;
use timesift_io::coords::{Crs, Projector};

fn berlin() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/opensfm/berlin")
}

#[test]
fn berlin_is_oriented_from_exif_gps_and_reports_gcp_residuals() {
    let dir = tempfile::tempdir().unwrap();
    let images = dir.path().join("images/berlin");
    std::fs::create_dir_all(&images).unwrap();
    for name in ["01.jpg", "02.jpg", "03.jpg"] {
        std::fs::copy(berlin().join("images").join(name), images.join(name)).unwrap();
    }
    std::fs::write(
        dir.path().join("project.toml"),
        "crs = \"EPSG:32633\"\n[[epoch]]\nname = \"berlin\"\nimages = \"images/berlin/*.jpg\"\n\
         [inputs]\ngcps = \"gcps.csv\"\nmarkers = \"markers.csv\"\n[align]\nmax_keypoints = 8000\n",
    )
    .unwrap();
    // OpenSfM's GCPs: WGS84 positions, observations in normalised coordinates
    // ((pixel index + 0.5 − size / 2) / max(width, height)), i.e. docs/design.md pixels
    // u = x · max(w, h) + w / 2.
    let gcp: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(berlin().join("ground_control_points.json")).unwrap(),
    )
    .unwrap();
    let projector = Projector::new(Crs::Epsg(32633)).unwrap();
    let (w, h) = (3264.0, 2448.0);
    let mut gcps = String::from("name,x,y,z,sxy,sz\n");
    let mut markers = String::from("image,name,u,v\n");
    let mut with_position = Vec::new();
    for p in gcp["points"].as_array().unwrap() {
        let id = p["id"].as_str().unwrap();
        let Some(pos) = p.get("position") else {
            continue;
        };
        let (e, n) = projector
            .project(
                pos["latitude"].as_f64().unwrap(),
                pos["longitude"].as_f64().unwrap(),
            )
            .unwrap();
        let z = pos["altitude"].as_f64().unwrap();
        writeln!(gcps, "G{id},{e:.3},{n:.3},{z:.3},0.05,0.1").unwrap();
        for o in p["observations"].as_array().unwrap() {
            let xy = o["projection"].as_array().unwrap();
            let (x, y) = (xy[0].as_f64().unwrap(), xy[1].as_f64().unwrap());
            let shot = o["shot_id"].as_str().unwrap();
            writeln!(
                markers,
                "images/berlin/{shot},G{id},{:.2},{:.2}",
                x * w + w / 2.0,
                y * w + h / 2.0
            )
            .unwrap();
        }
        with_position.push((
            format!("G{id}"),
            p["observations"].as_array().unwrap().len(),
        ));
    }
    std::fs::write(dir.path().join("gcps.csv"), gcps).unwrap();
    std::fs::write(dir.path().join("markers.csv"), markers).unwrap();
    let (ok, _, err) = timesift(&["run", dir.path().to_str().unwrap(), "--to", "align"]);
    assert!(ok, "{err}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("out/report.json")).unwrap())
            .unwrap();
    println!("{report:#}");
    assert_eq!(report["images_oriented"], 3);
    assert!(report["datum"].as_str().unwrap().starts_with("Gnss"));
    assert!(report["rms_reprojection_px"].as_f64().unwrap() < 1.0);
    let points = report["epochs"]["berlin"]["control_points"]["points"]
        .as_array()
        .unwrap();
    assert_eq!(points.len(), with_position.len());
    for (name, observations) in &with_position {
        let p = points.iter().find(|p| p["name"] == name.as_str()).unwrap();
        if *observations >= 2 {
            // Intersected from its two markers and compared with its coordinates: within what
            // phone GPS (a few metres) allows.
            let d: Vec<f64> = ["dE", "dN", "dH"]
                .iter()
                .map(|k| p[k].as_f64().unwrap())
                .collect();
            println!("{name}: dE {:.2} dN {:.2} dH {:.2} m", d[0], d[1], d[2]);
            assert!(d.iter().all(|v| v.abs() < 25.0), "{name}: {d:?}");
        } else {
            assert!(p["dE"].is_null(), "{name} has one marker: no intersection");
        }
    }
}
