//! End-to-end tests of the `timesift` binary: init/info on real photos, and one-line errors that
//! name the file and the line or key for every kind of bad input.

use crate::common::timesift;
use std::path::{Path, PathBuf};

fn shared_data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data")
}

/// Reference UTM 33N (EPSG:32633) positions of the lund photos' EXIF GPS, computed independently with
/// pyproj 3.7.2 (`Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True)`) from the exact
/// EXIF rationals, and checked against GDAL's gdaltransform for 01.jpg.
const LUND_UTM: [(&str, f64, f64, f64); 29] = [
    ("01.jpg", 386581.5883, 6173962.8754, 37.0),
    ("02.jpg", 386569.9354, 6173971.5297, 38.0),
    ("03.jpg", 386566.1595, 6173974.1024, 38.0),
    ("04.jpg", 386564.9778, 6173975.6796, 38.0),
    ("05.jpg", 386563.6537, 6173978.4977, 40.0),
    ("06.jpg", 386566.7339, 6173982.7477, 39.0),
    ("07.jpg", 386562.9202, 6173990.5794, 37.0),
    ("08.jpg", 386560.8360, 6173997.7475, 36.0),
    ("09.jpg", 386561.7193, 6174004.8384, 36.0),
    ("10.jpg", 386561.4748, 6174008.8656, 36.0),
    ("11.jpg", 386559.3101, 6174012.9428, 33.0),
    ("12.jpg", 386555.5101, 6174014.5883, 34.0),
    ("13.jpg", 386554.9486, 6174019.8609, 35.0),
    ("14.jpg", 386553.7292, 6174026.6972, 34.0),
    ("15.jpg", 386558.5171, 6174036.1608, 33.0),
    ("16.jpg", 386555.0792, 6174051.7152, 32.0),
    ("17.jpg", 386548.0431, 6174056.5378, 32.0),
    ("18.jpg", 386542.7445, 6174061.0059, 32.0),
    ("19.jpg", 386540.8028, 6174066.9332, 34.0),
    ("20.jpg", 386541.1785, 6174074.6558, 35.0),
    ("21.jpg", 386539.9269, 6174080.2557, 35.0),
    ("22.jpg", 386536.3417, 6174083.4421, 36.0),
    ("23.jpg", 386535.4820, 6174097.3829, 38.0),
    ("24.jpg", 386532.6137, 6174107.9737, 36.0),
    ("25.jpg", 386531.3405, 6174119.4508, 34.0),
    ("26.jpg", 386529.8847, 6174130.6234, 36.0),
    ("27.jpg", 386531.5925, 6174135.8370, 35.0),
    ("28.jpg", 386531.5925, 6174135.8370, 35.0),
    ("29.jpg", 386531.5925, 6174135.8370, 35.0),
];

#[test]
fn init_and_info_on_lund_give_reference_utm_priors() {
    let dir = tempfile::tempdir().unwrap();
    let epoch = dir.path().join("images/e1");
    std::fs::create_dir_all(&epoch).unwrap();
    for entry in std::fs::read_dir(shared_data().join("opensfm/lund/images")).unwrap() {
        let src = entry.unwrap().path();
        std::fs::copy(&src, epoch.join(src.file_name().unwrap())).unwrap();
    }
    let d = dir.path().to_str().unwrap();
    let (ok, out, err) = timesift(&["init", d]);
    assert!(ok, "{err}");
    assert!(out.contains("EPSG:32633"), "{out}");
    let (ok, out, err) = timesift(&["info", d, "--json"]);
    assert!(ok, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["crs"], "EPSG:32633");
    let images = report["images"].as_array().unwrap();
    assert_eq!(images.len(), 29);
    for (image, (name, e, n, h)) in images.iter().zip(LUND_UTM) {
        assert_eq!(image["name"], format!("images/e1/{name}"));
        let p = &image["prior"];
        let (x, y, z) = (
            p["x"].as_f64().unwrap(),
            p["y"].as_f64().unwrap(),
            p["z"].as_f64().unwrap(),
        );
        // 1 mm, plus the 0.05 mm rounding of the reference values.
        assert!(
            (x - e).abs() < 1.05e-3 && (y - n).abs() < 1.05e-3,
            "{name}: ({x}, {y}) vs ({e}, {n})"
        );
        assert_eq!(z, h);
        assert_eq!(p["source"], "exif");
    }
    assert_eq!(report["camera_groups"][0]["width"], 1024);
    assert_eq!(report["camera_groups"][0]["focal_length_35mm"], 35.0);
}

/// A small valid project: two epochs of three PNGs, GCPs, check points and markers.
fn small_project() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for epoch in ["2018", "2019"] {
        let folder = dir.path().join("images").join(epoch);
        std::fs::create_dir_all(&folder).unwrap();
        for i in 0..3 {
            image::GrayImage::from_fn(16, 12, |x, y| image::Luma([(x * 10 + y + i) as u8]))
                .save(folder.join(format!("img{i}.png")))
                .unwrap();
        }
    }
    write(
        dir.path(),
        "project.toml",
        "crs = \"local\"\n[[epoch]]\nname = \"2018\"\n[[epoch]]\nname = \"2019\"\nimages = \"images/2019/*.png\"\n[align]\nreference_epoch = \"2018\"\n",
    );
    write(
        dir.path(),
        "gcps.csv",
        "name,x,y,z\nG1,10,20,3\nG2,11,21,4\n",
    );
    write(dir.path(), "checkpoints.csv", "C1,12,22,5\n");
    write(
        dir.path(),
        "markers.csv",
        "image,name,u,v\nimages/2018/img0.png,G1,3.5,4.5\nimages/2019/img1.png,C1,5,6\n",
    );
    dir
}

fn write(dir: &Path, name: &str, text: &str) {
    std::fs::write(dir.join(name), text).unwrap();
}

/// Runs `info` and returns the single error line.
fn info_error(dir: &Path) -> String {
    let (ok, _, err) = timesift(&["info", dir.to_str().unwrap()]);
    assert!(!ok, "info should fail");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one error line, got:\n{err}");
    lines[0].to_string()
}

#[test]
fn valid_small_project_reports_its_inputs() {
    let p = small_project();
    let (ok, out, err) = timesift(&["info", p.path().to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["epochs"][1]["images"], 3);
    assert_eq!(report["inputs"]["gcps"], 2);
    assert_eq!(report["inputs"]["markers"], 2);
    assert_eq!(report["outputs"].as_array().unwrap().len(), 0);
}

#[test]
fn epoch_with_fewer_than_two_images_names_the_key() {
    let p = small_project();
    write(
        p.path(),
        "project.toml",
        "[[epoch]]\nname = \"2018\"\nimages = \"images/2018/img0.png\"\n",
    );
    let e = info_error(p.path());
    assert!(
        e.contains("project.toml") && e.contains("epoch[0].images") && e.contains("at least 2"),
        "{e}"
    );
}

#[test]
fn missing_image_file_names_the_key_and_file() {
    let p = small_project();
    write(
        p.path(),
        "project.toml",
        "[[epoch]]\nname = \"2018\"\nimages = [\"images/2018/img0.png\", \"images/2018/nope.jpg\"]\n",
    );
    let e = info_error(p.path());
    assert!(
        e.contains("project.toml") && e.contains("epoch[0].images") && e.contains("nope.jpg"),
        "{e}"
    );
}

#[test]
fn image_in_two_epochs_is_refused() {
    let p = small_project();
    write(
        p.path(),
        "project.toml",
        "[[epoch]]\nname = \"a\"\nimages = \"images/2018/*\"\n[[epoch]]\nname = \"b\"\nimages = [\"images/2018/img1.png\", \"images/2019/*\"]\n",
    );
    let e = info_error(p.path());
    assert!(
        e.contains("project.toml")
            && e.contains("epoch[1].images")
            && e.contains("images/2018/img1.png")
            && e.contains("\"a\""),
        "{e}"
    );
}

#[test]
fn unknown_key_is_named_with_its_line() {
    let p = small_project();
    write(
        p.path(),
        "project.toml",
        "crs = \"local\"\n[[epoch]]\nname = \"2018\"\n\n[align]\nmethod = \"timesift\"\nreference_epok = \"2018\"\n",
    );
    let e = info_error(p.path());
    assert!(
        e.contains("project.toml: line 7") && e.contains("reference_epok"),
        "{e}"
    );
    write(
        p.path(),
        "project.toml",
        "[[epoch]]\nname = \"2018\"\n[align]\nmethod = \"magic\"\n",
    );
    let e = info_error(p.path());
    assert!(e.contains("line 4") && e.contains("magic"), "{e}");
}

#[test]
fn geographic_crs_is_refused_by_key() {
    let p = small_project();
    write(
        p.path(),
        "project.toml",
        "crs = \"EPSG:4326\"\n[[epoch]]\nname = \"2018\"\n",
    );
    let e = info_error(p.path());
    assert!(e.contains("key `crs`") && e.contains("geographic"), "{e}");
}

#[test]
fn more_epochs_than_a_tie_point_can_name_are_refused_by_key() {
    let p = small_project();
    let epochs: String = (0..257)
        .map(|e| format!("[[epoch]]\nname = \"e{e}\"\nimages = \"images/e{e}/*.png\"\n"))
        .collect();
    write(
        p.path(),
        "project.toml",
        &format!("crs = \"local\"\n{epochs}"),
    );
    let e = info_error(p.path());
    assert!(
        e.contains("key `epoch`") && e.contains("257 epochs") && e.contains("at most 256"),
        "{e}"
    );
}

#[test]
fn marker_naming_unknown_point_or_image_names_file_and_line() {
    let p = small_project();
    write(
        p.path(),
        "markers.csv",
        "images/2018/img0.png,G1,3,4\nimages/2018/img2.png,G9,1,2\n",
    );
    let e = info_error(p.path());
    assert!(e.contains("markers.csv: line 2") && e.contains("G9"), "{e}");
    write(
        p.path(),
        "markers.csv",
        "image,name,u,v\nimages/2020/x.png,G1,3,4\n",
    );
    let e = info_error(p.path());
    assert!(
        e.contains("markers.csv: line 2") && e.contains("images/2020/x.png"),
        "{e}"
    );
}

/// Natural stable points (`stable_points.csv`, for `method = "manual"`): markers may name
/// them; one that is also a GCP is refused, naming the file and line.
#[test]
fn natural_stable_points_are_read_and_checked() {
    let p = small_project();
    write(
        p.path(),
        "markers.csv",
        "image,name,u,v\nimages/2018/img0.png,G1,3,4\nimages/2018/img1.png,rock,5,6\nimages/2019/img1.png,rock,5.5,6\n",
    );
    assert!(info_error(p.path()).contains("unknown point \"rock\""));
    write(
        p.path(),
        "stable_points.csv",
        "name,sxy,sz\nrock,0.01,0.02\n",
    );
    let (ok, out, err) = timesift(&["info", p.path().to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["inputs"]["markers"], 3);
    write(p.path(), "stable_points.csv", "rock\nG2\n");
    let e = info_error(p.path());
    assert!(
        e.contains("stable_points.csv: line 2") && e.contains("\"G2\" is also a GCP"),
        "{e}"
    );
}

#[test]
fn csv_row_with_wrong_field_count_names_file_and_line() {
    let p = small_project();
    write(
        p.path(),
        "gcps.csv",
        "name,x,y,z\nG1,10,20,3\n# comment\nG2,11,21\n",
    );
    let e = info_error(p.path());
    assert!(
        e.contains("gcps.csv: line 4") && e.contains("3 fields"),
        "{e}"
    );
    let p = small_project();
    write(p.path(), "gnss.csv", "images/2018/img0.png,1,2,3,4\n");
    let e = info_error(p.path());
    assert!(e.contains("gnss.csv: line 1"), "{e}");
}

#[test]
fn corrupt_jpeg_names_the_file() {
    let p = small_project();
    let folder = p.path().join("images/2018");
    // Sorted first in its epoch, so `info` reads it for the camera group.
    std::fs::write(
        folder.join("a_broken.jpg"),
        [
            0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x10, b'J', b'F', b'I', b'F', 0, 1,
        ],
    )
    .unwrap();
    let e = info_error(p.path());
    assert!(e.contains("a_broken.jpg"), "{e}");
}

#[test]
fn run_reports_missing_inputs_and_keeps_inputs() {
    let p = small_project();
    let before = std::fs::read(p.path().join("project.toml")).unwrap();
    // The features stage runs, and refuses images too small for a scale space, naming one.
    let (ok, _, err) = timesift(&["run", p.path().to_str().unwrap()]);
    assert!(!ok);
    assert!(
        err.contains("6 of 6 images failed")
            && err.contains("images/2018/img0.png")
            && err.contains("too small"),
        "{err}"
    );
    let (ok, _, err) = timesift(&["run", p.path().to_str().unwrap(), "--from", "align"]);
    assert!(!ok);
    assert!(
        err.contains("align") && err.contains("run the features stage first"),
        "{err}"
    );
    let (ok, _, err) = timesift(&[
        "run",
        p.path().to_str().unwrap(),
        "--from",
        "report",
        "--to",
        "report",
    ]);
    assert!(
        !ok && err.contains("report.json") && err.contains("run the align stage first"),
        "{err}"
    );
    let (ok, _, err) = timesift(&[
        "run",
        p.path().to_str().unwrap(),
        "--from",
        "dem",
        "--to",
        "ortho",
    ]);
    assert!(
        !ok && err.contains("cameras.json") && err.contains("run the align stage first"),
        "{err}"
    );
    let (ok, _, err) = timesift(&[
        "run",
        p.path().to_str().unwrap(),
        "--from",
        "report",
        "--to",
        "features",
    ]);
    assert!(!ok && err.contains("empty"), "{err}");
    assert_eq!(
        std::fs::read(p.path().join("project.toml")).unwrap(),
        before
    );
}

#[test]
fn init_refuses_to_overwrite_and_rejects_single_image_epochs() {
    let p = small_project();
    let d = p.path().to_str().unwrap();
    let (ok, _, err) = timesift(&["init", d]);
    assert!(
        !ok && err.contains("project.toml") && err.contains("--force"),
        "{err}"
    );
    std::fs::create_dir_all(p.path().join("images/2020")).unwrap();
    std::fs::copy(
        p.path().join("images/2018/img0.png"),
        p.path().join("images/2020/only.png"),
    )
    .unwrap();
    let (ok, _, err) = timesift(&["init", d, "--force"]);
    assert!(
        !ok && err.contains("epoch[2].images") && err.contains("at least 2"),
        "{err}"
    );
    std::fs::remove_dir_all(p.path().join("images/2020")).unwrap();
    let (ok, out, err) = timesift(&["init", d, "--force"]);
    assert!(ok, "{err}");
    assert!(
        out.contains("epoch 2018: 3 images") && out.contains("crs local"),
        "{out}"
    );
}

#[test]
fn project_path_with_glob_characters_and_dot_epochs() {
    // A project folder named with glob metacharacters still finds its images.
    let outer = tempfile::tempdir().unwrap();
    let p = small_project();
    let odd = outer.path().join("site[A]*");
    std::fs::rename(p.path(), &odd).unwrap();
    let (ok, out, err) = timesift(&["info", odd.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["images"].as_array().unwrap().len(), 6);
    // An epoch named ".." would put outputs outside out/epochs.
    write(
        &odd,
        "project.toml",
        "[[epoch]]\nname = \"..\"\nimages = \"images/2018/*\"\n",
    );
    let e = info_error(&odd);
    assert!(e.contains("epoch[0].name"), "{e}");
}

#[test]
fn demo_refuses_a_directory_that_is_not_empty() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("keep.txt"), "mine").unwrap();
    let (ok, _, err) = timesift(&["demo", dir.path().to_str().unwrap()]);
    assert!(!ok);
    assert!(
        err.contains("empty or new directory") && err.contains(dir.path().to_str().unwrap()),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(dir.path().join("keep.txt")).unwrap(),
        "mine"
    );
}

/// `[[camera]]`: a calibrated focal length in millimetres with the pixel size is shown by
/// `info` in pixels; a group that does not exist, a missing pixel size, two focal lengths and a
/// non-positive length are errors naming the key.
#[test]
fn camera_calibration_is_checked_and_shown() {
    let p = small_project();
    let d = p.path().to_str().unwrap();
    let head = "crs = \"local\"\n[[epoch]]\nname = \"2018\"\n[[epoch]]\nname = \"2019\"\n";
    write(
        p.path(),
        "project.toml",
        &format!("{head}[[camera]]\nname = \"2019\"\nfocal_mm = 8.8\npixel_mm = 0.0022\n"),
    );
    let (ok, out, err) = timesift(&["info", d, "--json"]);
    assert!(ok, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    let groups = report["camera_groups"].as_array().unwrap();
    let given = |name: &str| {
        groups
            .iter()
            .find(|g| g["name"] == name)
            .map(|g| g["calibrated_focal_px"].clone())
            .unwrap()
    };
    assert!((given("2019").as_f64().unwrap() - 4000.0).abs() < 1e-9);
    assert!(given("2018").is_null());
    let (ok, out, _) = timesift(&["info", d]);
    assert!(
        ok && out.contains("f = 4000.0 px (given in project.toml)"),
        "{out}"
    );
    for (camera, key, says) in [
        ("name = \"2020\"\nfocal_px = 900", "camera[0].name", "2020"),
        (
            "name = \"2018\"\nfocal_mm = 8.8",
            "camera[0].pixel_mm",
            "missing",
        ),
        (
            "name = \"2018\"\nfocal_px = 900\nfocal_mm = 8.8\npixel_mm = 0.01",
            "camera[0].focal_mm",
            "not both",
        ),
        (
            "name = \"2018\"\nfocal_px = -3",
            "camera[0].focal_px",
            "positive",
        ),
    ] {
        write(
            p.path(),
            "project.toml",
            &format!("{head}[[camera]]\n{camera}\n"),
        );
        let e = info_error(p.path());
        assert!(e.contains(key) && e.contains(says), "{e}");
    }
    write(
        p.path(),
        "project.toml",
        &format!(
            "{head}[[camera]]\nname = \"2018\"\nfocal_px = 900\n[[camera]]\nname = \"2018\"\nfocal_px = 901\n"
        ),
    );
    let e = info_error(p.path());
    assert!(e.contains("camera[1].name") && e.contains("twice"), "{e}");
}

/// Shell completions name every command; the manual has a page per command, each a roff page
/// of its command's options; an unknown shell is refused with the shells there are.
#[test]
fn completions_and_manual_pages_cover_every_command() {
    let commands = [
        "init",
        "info",
        "run",
        "task",
        "status",
        "features",
        "dem",
        "demo",
        "fiducials",
        "export",
        "compare",
        "completions",
        "man",
    ];
    for shell in ["bash", "zsh", "fish"] {
        let (ok, out, err) = timesift(&["completions", shell]);
        assert!(ok, "{shell}: {err}");
        for command in commands {
            assert!(out.contains(command), "{shell} completion lacks {command}");
        }
        assert!(out.contains("--executor"), "{shell}: run's options");
    }
    let (ok, _, err) = timesift(&["completions", "tcsh"]);
    assert!(!ok && err.contains("bash") && err.contains("fish"), "{err}");

    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("man1");
    let (ok, out, err) = timesift(&["man", dir.to_str().expect("utf-8")]);
    assert!(ok, "{err}");
    assert!(out.contains("manual pages"), "{out}");
    let top = std::fs::read_to_string(dir.join("timesift.1")).expect("timesift.1");
    assert!(
        top.starts_with(".ie") || top.contains(".TH timesift 1"),
        "a roff page"
    );
    for command in commands {
        let page = std::fs::read_to_string(dir.join(format!("timesift-{command}.1")))
            .unwrap_or_else(|e| panic!("timesift-{command}.1: {e}"));
        assert!(
            page.contains(&format!(".TH timesift-{command} 1")),
            "{command}"
        );
    }
    let run = std::fs::read_to_string(dir.join("timesift-run.1")).expect("run page");
    assert!(
        run.contains("executor") && run.contains("dry"),
        "run's options in its page"
    );
    // A file in the way of the folder is a one-line error naming it.
    let blocked = tmp.path().join("file");
    std::fs::write(&blocked, "x").expect("file");
    let (ok, _, err) = timesift(&["man", blocked.join("man1").to_str().expect("utf-8")]);
    assert!(
        !ok && err.contains("file") && err.lines().count() == 1,
        "{err}"
    );
}
