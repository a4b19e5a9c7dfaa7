//! `timesift run` through every stage on a rendered two-epoch project (landslide, dense at level
//! 4 to keep the test short):
//! - killed with SIGKILL after random delays, several times, and run again, it ends with the same
//!   products as an uninterrupted run, and no product is ever left half-written at a kill;
//! - a second run finds every stage up to date;
//! - `out/report.html` renders in headless Chromium with every section and no broken image
//!   (skipped with a printed reason where no Chromium is installed);
//! - `out/timesift.qgs` opens in QGIS (Debian's python3-qgis, headless) with every layer valid,
//!   drawn by the renderer its product calls for, on the product's extent, and renders (skipped
//!   with a printed reason where QGIS's Python is not installed).

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::common::{assert_same_products, complete, copy_tree, files, small_landslide, timesift};
use timesift_core::SeededRng;

fn run(dir: &Path) -> String {
    let (ok, out, err) = timesift(&["run", dir.to_str().expect("utf-8")]);
    assert!(ok, "{err}");
    format!("{out}{err}")
}

#[test]
fn a_killed_run_resumes_to_the_same_products_and_the_report_renders() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (whole, killed) = (tmp.path().join("whole"), tmp.path().join("killed"));
    small_landslide(&whole);
    copy_tree(&whole, &killed);

    let log = run(&whole);
    for stage in [
        "features", "match", "align", "dense", "dem", "ortho", "change", "report",
    ] {
        assert!(log.contains(stage), "{stage} missing from the log:\n{log}");
    }
    assert!(log.contains("report.html"), "{log}");
    // A second run redoes nothing.
    let again = run(&whole);
    for expected in [
        "features of 0 images extracted",
        "up to date: ",
        "0 epoch pairs written, 1 up to date",
    ] {
        assert!(again.contains(expected), "{expected}:\n{again}");
    }

    // Kills at random moments; every product present at a kill is complete.
    let mut rng = SeededRng::new(20_261_123);
    let mut kills = Vec::new();
    for _ in 0..6 {
        let delay = 0.3 + 6.0 * rng.uniform();
        let mut child = Command::new(env!("CARGO_BIN_EXE_timesift"))
            .args(["run", killed.to_str().expect("utf-8"), "--quiet"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn");
        std::thread::sleep(Duration::from_secs_f64(delay));
        if child.try_wait().expect("wait").is_none() {
            child.kill().expect("SIGKILL");
            kills.push(format!("{delay:.1} s"));
        }
        let _ = child.wait();
        let out = killed.join("out");
        for f in files(&out) {
            if !f.to_string_lossy().contains(".tmp-") {
                complete(&out.join(&f))
                    .unwrap_or_else(|e| panic!("after a kill at {delay:.1} s: {e}"));
            }
        }
    }
    println!("killed after {}", kills.join(", "));
    assert!(
        kills.len() >= 3,
        "only {} runs were still going when killed",
        kills.len()
    );
    run(&killed);

    // Same products, byte for byte, but for the reports' times and paths; no temporary left.
    assert_same_products(&whole, &killed);

    check_exports(&whole);
    check_in_browser(&whole.join("out/report.html"), tmp.path());
    check_in_qgis(&whole, tmp.path());
}

/// The first of the programs that runs `probe` successfully.
fn first_that_runs(programs: &[&'static str], probe: &[&str]) -> Option<&'static str> {
    programs.iter().copied().find(|program| {
        Command::new(program)
            .args(probe)
            .output()
            .is_ok_and(|o| o.status.success())
    })
}

/// An image that shows something: more than 50 colours among every `step`-th pixel.
fn assert_not_blank(image: &image::RgbImage, step: usize, what: &str) {
    let distinct: std::collections::BTreeSet<[u8; 3]> =
        image.pixels().step_by(step).map(|p| p.0).collect();
    assert!(distinct.len() > 50, "{what}: {} colours", distinct.len());
}

fn check_in_qgis(dir: &Path, tmp: &Path) {
    // Debian installs QGIS's Python for the system's `/usr/bin/python3`.
    let Some(python) = first_that_runs(
        &["/usr/bin/python3", "python3"],
        &["-c", "import qgis.core"],
    ) else {
        println!(
            "skipped: QGIS's Python is not installed (.ci/run installs Debian's python3-qgis)"
        );
        return;
    };
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/integration/scripts/qgis_layers.py");
    let render = tmp.join("qgis.png");
    let out = Command::new(python)
        .arg(&script)
        .arg(dir.join("out/timesift.qgs"))
        .arg(&render)
        .env("QT_QPA_PLATFORM", "offscreen")
        .output()
        .expect("python runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let mut renderers = BTreeMap::new();
    for line in text.lines() {
        let fields: Vec<&str> = line.split('\t').collect();
        assert_eq!(fields.len(), 9, "{line}");
        let (name, valid, renderer, source) = (fields[0], fields[1], fields[2], fields[7]);
        assert_eq!(valid, "1", "layer {name} is not valid in QGIS: {source}");
        // The raster added on its own takes the style beside it (the DEM's, for its hillshade).
        if renderer != "hillshade" {
            assert_eq!(fields[8], renderer, "{name}: the .qml beside {source}");
        }
        let extent: Vec<f64> = fields[3..7]
            .iter()
            .map(|v| v.parse().expect("extent"))
            .collect();
        let grid = timesift_io::geotiff::read_grid(Path::new(source)).expect("the layer's raster");
        let (xmin, ymin, xmax, ymax) = timesift_change::grid::Grid {
            transform: grid.georef.transform,
            width: grid.width,
            height: grid.height,
            crs: grid.georef.crs,
        }
        .extent();
        let expected = [xmin, ymin, xmax, ymax];
        for (got, want) in extent.iter().zip(expected) {
            assert!(
                (got - want).abs() < 1e-6,
                "{name}: extent {extent:?}, product {expected:?}"
            );
        }
        let kind = name.split(' ').next().unwrap_or(name);
        let previous = renderers.insert(kind.to_string(), renderer.to_string());
        assert!(previous.is_none_or(|p| p == renderer), "{name}: {renderer}");
    }
    let expected = [
        ("DEM", "singlebandpseudocolor"),
        ("hillshade", "hillshade"),
        ("ortho", "multibandcolor"),
        ("DoD", "singlebandpseudocolor"),
        ("points", "singlebandpseudocolor"),
        ("height", "singlebandpseudocolor"),
        ("filled", "paletted"),
        ("beyond", "paletted"),
    ];
    for (kind, renderer) in expected {
        assert_eq!(
            renderers.get(kind).map(String::as_str),
            Some(renderer),
            "{kind}: {text}"
        );
    }
    // Two epochs: 6 layers each, one pair: 2, and the ground the block found unchanged when
    // the align stage wrote it.
    let found = dir.join("out/stable_found.tif").is_file();
    if found {
        assert_eq!(
            renderers.get("ground").map(String::as_str),
            Some("paletted")
        );
    }
    assert_eq!(text.lines().count(), 14 + usize::from(found), "{text}");
    let image = image::open(&render).expect("QGIS's render").to_rgb8();
    assert_not_blank(&image, 53, "a blank map");
}

/// The value between `<tag>` and `</tag>` after `from`, with where it ends.
fn element<'a>(text: &'a str, tag: &str, from: usize) -> Option<(&'a str, usize)> {
    let open = format!("<{tag}");
    let start = from + text[from..].find(&open)?;
    let body = start + text[start..].find('>')? + 1;
    let end = body + text[body..].find(&format!("</{}>", tag.trim()))?;
    Some((&text[body..end], end))
}

fn numbers(text: &str) -> Vec<f64> {
    text.split_whitespace()
        .map(|v| v.parse().expect("number"))
        .collect()
}

/// `timesift export` in the three formats: COLMAP reads back through our reader unchanged;
/// OpenSfM's and Metashape's files, read as those tools define them, put every sparse point on
/// the pixel where our own cameras put it (within 0.15 px: the grid's horizontal scale differs
/// from its vertical one by ~1.5e-4 here, which no rotation of a camera can absorb — the points
/// are converted exactly, the cameras rigidly).
fn check_exports(dir: &Path) {
    use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};
    use timesift_core::{BrownCamera, CameraModel};
    let d = dir.to_str().expect("utf-8");
    for format in ["colmap", "opensfm", "metashape"] {
        let (ok, out, err) = timesift(&["export", d, "--format", format]);
        assert!(ok && out.contains("wrote"), "{format}: {err}");
    }
    let ours = timesift_io::colmap::read_colmap_text(&dir.join("out/colmap")).expect("colmap");
    let back =
        timesift_io::colmap::read_colmap_text(&dir.join("out/export/colmap")).expect("export");
    // Written from what was read: the same model (text keeps 17 significant digits).
    assert_eq!(ours.cameras, back.cameras);
    assert_eq!(ours.images.len(), back.images.len());
    for (a, b) in ours.images.values().zip(back.images.values()) {
        assert_eq!(
            (&a.name, a.camera_id, &a.points2d, &a.epoch),
            (&b.name, b.camera_id, &b.points2d, &b.epoch)
        );
        assert!(
            a.pose.rotation.angle_to(&b.pose.rotation) < 1e-12,
            "{}",
            a.name
        );
        assert!(
            (a.pose.translation - b.pose.translation).norm() < 1e-9,
            "{}",
            a.name
        );
    }
    assert_eq!(ours.points.len(), back.points.len());
    for (a, b) in ours.points.values().zip(back.points.values()) {
        assert!((a.xyz - b.xyz).norm() < 1e-9 && a.rgb == b.rgb && a.track == b.track);
    }
    let recon = timesift_io::cameras_json::read_cameras_json(&dir.join("out/cameras.json"))
        .expect("cameras");
    let pose_of = |name: &str| {
        let i = recon.images.iter().find(|i| i.name == name).expect("image");
        (i.pose.expect("oriented"), &recon.cameras[&i.camera])
    };
    // (point index in the export, world point, image name, our pixel), a sample of observations.
    let mut samples = Vec::new();
    for (k, p) in ours.points.values().enumerate().step_by(37) {
        let (image_id, _) = p.track[0];
        let name = &ours.images[&image_id].name;
        let (pose, camera) = pose_of(name);
        let px = camera
            .project(&pose.transform_point(&p.xyz))
            .expect("projects");
        samples.push((k, p.xyz, name.clone(), px));
    }
    assert!(samples.len() > 50, "{}", samples.len());

    // OpenSfM.
    let r: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("out/export/opensfm/reconstruction.json")).expect("json"),
    )
    .expect("parse");
    let r = &r[0];
    assert!(r["reference_lla"]["latitude"].as_f64().is_some());
    let mut worst: f64 = 0.0;
    for (k, _, name, px) in &samples {
        let shot = &r["shots"][name.as_str()];
        let v = |x: &serde_json::Value| {
            Vector3::new(
                x[0].as_f64().unwrap(),
                x[1].as_f64().unwrap(),
                x[2].as_f64().unwrap(),
            )
        };
        let rotation = nalgebra::UnitQuaternion::from_scaled_axis(v(&shot["rotation"]));
        let p_cam =
            rotation * v(&r["points"][k.to_string()]["coordinates"]) + v(&shot["translation"]);
        let cam = &r["cameras"][shot["camera"].as_str().unwrap()];
        let params: BTreeMap<String, f64> = cam
            .as_object()
            .unwrap()
            .iter()
            .filter_map(|(k, v)| Some((k.clone(), v.as_f64()?)))
            .collect();
        let (w, h) = (params["width"], params["height"]);
        let q = timesift_io::opensfm::project_opensfm(&params, w, h, &p_cam);
        worst = worst.max((q[0] - px.x).hypot(q[1] - px.y));
    }
    println!("OpenSfM export: worst pixel difference {worst:.4} px");
    assert!(worst < 0.15, "OpenSfM export moves points by {worst} px");

    // Metashape: calibration per sensor, camera transforms, chunk transform to ECEF.
    let xml = std::fs::read_to_string(dir.join("out/export/metashape/cameras.xml")).expect("xml");
    let (chunk, _) = element(&xml, "transform", xml.find("</cameras>").expect("cameras"))
        .expect("chunk transform");
    let rot = numbers(element(chunk, "rotation", 0).expect("rotation").0);
    let tr = numbers(element(chunk, "translation", 0).expect("translation").0);
    let ecef_from_internal = Matrix3::from_row_slice(&rot);
    let origin = Vector3::new(tr[0], tr[1], tr[2]);
    let projector =
        timesift_io::coords::Projector::new(recon.crs.parse().expect("crs")).expect("projector");
    let mut sensors = Vec::new();
    let mut at = 0;
    while let Some((body, end)) = element(&xml, "sensor ", at) {
        let g = |tag: &str| element(body, tag, 0).map_or(0.0, |(v, _)| v.parse().expect("number"));
        let res = &body[body.find("width=\"").unwrap() + 7..];
        let w: u32 = res[..res.find('"').unwrap()].parse().unwrap();
        let res = &body[body.find("height=\"").unwrap() + 8..];
        let h: u32 = res[..res.find('"').unwrap()].parse().unwrap();
        let mut c = BrownCamera::new(w, h, g("f")).expect("camera");
        c.set_params(
            &[
                "f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2",
            ]
            .map(g),
        )
        .expect("params");
        sensors.push(c);
        at = end;
    }
    let mut worst: f64 = 0.0;
    let labels = timesift_io::metashape::camera_labels(&recon);
    for (_, world, name, px) in &samples {
        let index = recon
            .images
            .iter()
            .position(|i| &i.name == name)
            .expect("image");
        let start = xml
            .find(&format!("label=\"{}\">", labels[index]))
            .expect("camera");
        let tag_start = xml[..start].rfind("<camera ").unwrap();
        let sensor: usize = {
            let s = &xml[tag_start..];
            let s = &s[s.find("sensor_id=\"").unwrap() + 11..];
            s[..s.find('"').unwrap()].parse().unwrap()
        };
        let m = Matrix4::from_row_slice(&numbers(element(&xml, "transform", start).unwrap().0));
        let (lat, lon) = projector.unproject(world.x, world.y).expect("unproject");
        let ecef = timesift_io::topocentric::ecef_from_geodetic(lat, lon, world.z);
        let internal = ecef_from_internal.transpose() * (ecef - origin);
        let p_cam = m.try_inverse().expect("invertible")
            * Vector4::new(internal.x, internal.y, internal.z, 1.0);
        let q = sensors[sensor].project(&p_cam.xyz()).expect("projects");
        worst = worst.max((q - px).norm());
    }
    println!("Metashape export: worst pixel difference {worst:.4} px");
    assert!(worst < 0.15, "Metashape export moves points by {worst} px");
}

/// Loads the report in headless Chromium: the DOM after load must hold every section and no
/// image that failed to decode, and a screenshot must show a page, not a blank.
fn check_in_browser(report: &Path, tmp: &Path) {
    let Some(browser) = first_that_runs(
        &["chromium", "chromium-browser", "google-chrome"],
        &["--version"],
    ) else {
        println!("skipped: no Chromium installed (.ci/run installs Debian's chromium)");
        return;
    };
    let html = std::fs::read_to_string(report).expect("report");
    for id in timesift::html::SECTIONS {
        assert!(
            html.contains(&format!("<section id=\"{id}\">")),
            "section {id}"
        );
    }
    assert!(
        !html.contains("http://") || !html.contains("src=\"http"),
        "no network resource"
    );
    // A copy with a probe script (the report itself has none) that writes what loaded into the DOM.
    let probe = tmp.join("probe.html");
    let script = "<script>window.addEventListener('load',()=>{const imgs=[...document.images];\
        document.body.setAttribute('data-images',imgs.length);\
        document.body.setAttribute('data-broken',imgs.filter(i=>!(i.complete&&i.naturalWidth>0)).length);\
        document.body.setAttribute('data-sections',document.querySelectorAll('section h2').length);\
        document.body.setAttribute('data-svg',document.querySelectorAll('svg').length);});</script></body>";
    std::fs::write(&probe, html.replace("</body>", script)).expect("probe");
    let headless = |extra: &[&str], page: &Path| {
        let mut args = vec![
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--virtual-time-budget=10000",
        ];
        args.extend_from_slice(extra);
        let url = format!("file://{}", page.display());
        let out = Command::new(browser)
            .args(&args)
            .arg(&url)
            .output()
            .expect("chromium runs");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let dom = headless(&["--dump-dom"], &probe);
    let attr = |name: &str| -> usize {
        let key = format!("{name}=\"");
        let at = dom
            .find(&key)
            .unwrap_or_else(|| panic!("{name} not set: the page did not load"));
        dom[at + key.len()..]
            .split('"')
            .next()
            .and_then(|v| v.parse().ok())
            .expect("number")
    };
    assert_eq!(attr("data-broken"), 0, "broken images");
    assert!(attr("data-images") >= 8, "{} images", attr("data-images"));
    assert_eq!(attr("data-sections"), 6);
    assert!(attr("data-svg") >= 4);
    let shot = tmp.join("report.png");
    let window = "--window-size=1200,1800";
    headless(
        &[window, &format!("--screenshot={}", shot.display())],
        report,
    );
    let image = image::open(&shot).expect("screenshot").to_rgb8();
    assert_eq!(image.dimensions(), (1200, 1800));
    assert_not_blank(&image, 97, "a blank page");
}
