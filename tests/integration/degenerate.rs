//! Degenerate projects, as users make them: one image, one epoch, an epoch that shares no
//! ground with the others, identical photos, photos of another size in one camera group, a
//! control point typed far outside the block, control points in another CRS, a file that is not
//! an image. Each either runs to the end and says what it could not do, or stops with one line
//! that names the file or the point and what to do.

use std::path::Path;

use crate::common::{copy_tree, timesift};

const EPOCHS: [&str; 2] = ["2023-06-15", "2023-08-16"];

/// The first two epochs of `landslide` (rendered with `seed`), `images` photos each, dense
/// matching at level 4 with the quick settings.
fn landslide(dir: &Path, seed: u64, images: usize) {
    let mut spec =
        timesift_synth::scenes::build("landslide", timesift_synth::scenes::Scale::Small, seed)
            .expect("scene");
    spec.epochs.truncate(2);
    spec.keep_first_images(images);
    timesift_synth::writer::write_scene(
        &spec,
        dir,
        &timesift_synth::writer::WriteOptions::default(),
    )
    .expect("write");
    crate::common::quick_dense_level_4(dir);
}

/// `timesift run DIR [args]`: (success, stdout, stderr).
fn run(dir: &Path, args: &[&str]) -> (bool, String, String) {
    let mut all = vec!["run", dir.to_str().expect("utf-8")];
    all.extend_from_slice(args);
    timesift(&all)
}

/// The one error line of a failed run.
fn error_line(dir: &Path, args: &[&str]) -> String {
    let (ok, out, err) = run(dir, args);
    assert!(!ok, "the run should fail: {out}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
    assert_eq!(lines.len(), 1, "one error line: {err}");
    lines[0].to_string()
}

/// The line a stage printed as it finished (progress goes to standard error).
fn stage_line(out: &str, err: &str, stage: &str) -> String {
    out.lines()
        .chain(err.lines())
        .find(|l| l.starts_with(stage) && l.split_whitespace().next() == Some(stage))
        .unwrap_or_else(|| panic!("no line of stage {stage}: {out}{err}"))
        .to_string()
}

/// Rewrites `project.toml` with `f`.
fn edit_toml(dir: &Path, f: impl FnOnce(String) -> String) {
    let path = dir.join("project.toml");
    let text = std::fs::read_to_string(&path).expect("project.toml");
    std::fs::write(&path, f(text)).expect("project.toml");
}

/// Keeps the lines of a CSV file for which `keep` holds (and its header).
fn filter_csv(path: &Path, keep: impl Fn(&str) -> bool) {
    let text = std::fs::read_to_string(path).expect("csv");
    let mut lines = text.lines();
    let mut out = format!("{}\n", lines.next().expect("header"));
    for line in lines.filter(|l| keep(l)) {
        out.push_str(line);
        out.push('\n');
    }
    std::fs::write(path, out).expect("csv");
}

/// A copy of `base` (its work/ caches too) in a new folder, for one case.
fn case(base: &Path) -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("tempdir");
    copy_tree(base, dir.path());
    dir
}

fn report(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("out/report.json")).expect("report"))
        .expect("json")
}

/// Inputs the block cannot be made from stop the run at the stage that meets them, with one
/// line naming the file and what to do.
#[test]
fn inputs_no_block_can_be_made_from_are_refused_naming_the_file() {
    let base = tempfile::tempdir().expect("tempdir");
    landslide(base.path(), 3, 5);
    let (ok, _, err) = run(base.path(), &["--to", "match"]);
    assert!(ok, "{err}");

    // A photo replaced after its features were extracted: its features (and its matches) are
    // made again, never taken from the file of the photo it replaced.
    let replaced = case(base.path());
    let from = replaced
        .path()
        .join(format!("images/{}/IMG_0005.jpg", EPOCHS[1]));
    let to = replaced
        .path()
        .join(format!("images/{}/IMG_0001.jpg", EPOCHS[1]));
    std::fs::copy(&from, &to).expect("copy");
    let (ok, _, err) = run(replaced.path(), &["--to", "features"]);
    assert!(ok, "{err}");
    let features = stage_line("", &err, "features");
    assert!(
        features.contains("features of 1 images extracted (9 cached)"),
        "{features}"
    );

    // One image: refused when the project is read.
    let one = case(base.path());
    edit_toml(one.path(), |t| {
        let first = t.find("[[epoch]]").expect("epoch");
        let align = t.find("[align]").expect("align");
        format!(
            "{}[[epoch]]\nname = \"{}\"\nimages = \"images/{}/IMG_0001.jpg\"\n\n{}",
            &t[..first],
            EPOCHS[0],
            EPOCHS[0],
            &t[align..]
        )
    });
    let line = error_line(one.path(), &[]);
    assert!(
        line.contains("project.toml") && line.contains("epoch"),
        "{line}"
    );

    // Every image the same photo: no baseline, said so with two of them named.
    let same = case(base.path());
    let photo = same
        .path()
        .join(format!("images/{}/IMG_0002.jpg", EPOCHS[0]));
    for e in EPOCHS {
        for k in 1..=5 {
            let path = same.path().join(format!("images/{e}/IMG_{k:04}.jpg"));
            if path != photo {
                std::fs::copy(&photo, &path).expect("copy");
            }
        }
    }
    let line = error_line(same.path(), &["--to", "align"]);
    assert!(
        line.contains("no baseline") && line.contains("IMG_") && line.contains("identical"),
        "{line}"
    );

    // A photo of another size in a camera group.
    let mixed = case(base.path());
    let odd = mixed
        .path()
        .join(format!("images/{}/IMG_0003.jpg", EPOCHS[0]));
    let img = image::open(&odd).expect("image");
    img.resize_exact(
        img.width() * 3 / 4,
        img.height() * 3 / 4,
        image::imageops::Triangle,
    )
    .save(&odd)
    .expect("save");
    let line = error_line(mixed.path(), &["--to", "align"]);
    assert!(
        line.contains(&format!("camera group \"{}\"", EPOCHS[0]))
            && line.contains("IMG_0003.jpg")
            && line.contains(&format!("{}×{}", img.width() * 3 / 4, img.height() * 3 / 4)),
        "{line}"
    );

    // Control points in geographic degrees while the project is in UTM.
    let degrees = case(base.path());
    let gcps = degrees.path().join("gcps.csv");
    let text = std::fs::read_to_string(&gcps).expect("gcps");
    let mut out = String::new();
    for (k, line) in text.lines().enumerate() {
        let mut fields: Vec<String> = line.split(',').map(str::to_string).collect();
        if k > 0 {
            fields[1] = format!("{:.6}", 7.19 + k as f64 * 1e-4);
            fields[2] = format!("{:.6}", 45.87 + k as f64 * 1e-4);
        }
        out.push_str(&fields.join(","));
        out.push('\n');
    }
    std::fs::write(&gcps, out).expect("gcps");
    let line = error_line(degrees.path(), &["--to", "align"]);
    assert!(
        line.contains("gcps.csv")
            && line.contains("not in the project's CRS")
            && line.contains("longitude and latitude")
            && line.contains("(line 2)"),
        "{line}"
    );

    // A text file named as a photo.
    let text_file = case(base.path());
    let fake = text_file
        .path()
        .join(format!("images/{}/IMG_0004.jpg", EPOCHS[1]));
    std::fs::write(&fake, "<html>404 Not Found</html>\n").expect("write");
    let line = error_line(text_file.path(), &[]);
    assert!(
        line.contains(&format!("images/{}/IMG_0004.jpg", EPOCHS[1]))
            && line.contains("not an image")
            && line.contains("3c 68 74 6d"),
        "{line}"
    );
}

/// A project of one epoch runs every stage; the change stage says there is nothing to compare.
#[test]
fn one_epoch_runs_to_the_end_with_nothing_to_compare() {
    let dir = tempfile::tempdir().expect("tempdir");
    landslide(dir.path(), 5, 6);
    edit_toml(dir.path(), |t| {
        let second = t.match_indices("[[epoch]]").nth(1).expect("two epochs").0;
        let align = t.find("[align]").expect("align");
        format!("{}{}", &t[..second], &t[align..])
    });
    for file in ["markers.csv", "gnss.csv"] {
        filter_csv(&dir.path().join(file), |l| !l.contains(EPOCHS[1]));
    }
    let (ok, out, err) = run(dir.path(), &[]);
    assert!(ok, "{err}");
    let change = stage_line(&out, &err, "change");
    assert!(
        change.contains("nothing to compare: the project has one epoch"),
        "{change}"
    );
    for product in ["dem.tif", "ortho.tif", "dense.laz"] {
        let path = dir
            .path()
            .join(format!("out/epochs/{}/{product}", EPOCHS[0]));
        assert!(path.is_file(), "{} missing", path.display());
    }
    assert!(dir.path().join("out/report.html").is_file());
    assert!(!dir.path().join("out/change").exists());
}

/// An epoch photographed over ground that shares nothing with the other's (rendered from
/// another seed: other textures everywhere), placed by its own GNSS priors: the block cannot
/// tie it, so the run says it is not co-registered, and both epochs' products are made.
#[test]
fn an_epoch_sharing_nothing_is_reported_not_co_registered_and_the_others_are_produced() {
    let dir = tempfile::tempdir().expect("tempdir");
    landslide(dir.path(), 3, 6);
    let other = tempfile::tempdir().expect("tempdir");
    landslide(other.path(), 4, 6);
    for k in 1..=6 {
        let name = format!("images/{}/IMG_{k:04}.jpg", EPOCHS[1]);
        std::fs::copy(other.path().join(&name), dir.path().join(&name)).expect("copy");
    }
    // The markers were measured on the first rendering's photos.
    filter_csv(&dir.path().join("markers.csv"), |l| !l.contains(EPOCHS[1]));
    let (ok, out, err) = run(dir.path(), &["--to", "dem"]);
    assert!(ok, "{err}");
    let align = stage_line(&out, &err, "align");
    assert!(
        align.contains(&format!("epoch {} NOT co-registered", EPOCHS[1])),
        "{align}"
    );
    let report = report(dir.path());
    assert_eq!(report["not_co_registered"], serde_json::json!([EPOCHS[1]]));
    assert_eq!(report["epochs"][EPOCHS[1]]["inter_epoch_tie_points"], 0);
    for e in EPOCHS {
        assert_eq!(report["epochs"][e]["images_oriented"], 6, "{e}");
        assert!(dir.path().join(format!("out/epochs/{e}/dem.tif")).is_file());
    }
}

/// A control point typed 100 km east of where it is: the placement leaves it out and names it;
/// the block and the other control points are as good as without it.
#[test]
fn a_control_point_far_outside_the_block_is_left_out_and_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    landslide(dir.path(), 3, 6);
    let gcps = dir.path().join("gcps.csv");
    let text = std::fs::read_to_string(&gcps).expect("gcps");
    // The reference epoch's best-measured control point (the most markers) is moved.
    let markers = std::fs::read_to_string(dir.path().join("markers.csv")).expect("markers");
    let names: Vec<String> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap_or("").to_string())
        .collect();
    let moved = names
        .iter()
        .max_by_key(|n| {
            markers
                .lines()
                .filter(|l| l.contains(EPOCHS[0]) && l.split(',').nth(1) == Some(n.as_str()))
                .count()
        })
        .expect("a control point")
        .clone();
    let mut out = String::new();
    for line in text.lines() {
        let mut fields: Vec<String> = line.split(',').map(str::to_string).collect();
        if fields[0] == moved {
            let x: f64 = fields[1].parse().expect("x");
            fields[1] = format!("{:.4}", x + 100_000.0);
        }
        out.push_str(&fields.join(","));
        out.push('\n');
    }
    std::fs::write(&gcps, out).expect("gcps");
    let (ok, out, err) = run(dir.path(), &["--to", "align"]);
    assert!(ok, "{err}");
    let align = stage_line(&out, &err, "align");
    assert!(
        align.contains("control points left out") && align.contains(&moved),
        "{align}"
    );
    let report = report(dir.path());
    assert_eq!(
        report["control_points_rejected"],
        serde_json::json!([moved])
    );
    assert_eq!(report["gnss_priors_rejected"], 0);
    let points = report["epochs"][EPOCHS[0]]["control_points"]["points"]
        .as_array()
        .expect("points");
    for p in points {
        let Some(de) = p["dE"].as_f64() else { continue };
        let miss = (de.powi(2)
            + p["dN"].as_f64().unwrap_or(0.0).powi(2)
            + p["dH"].as_f64().unwrap_or(0.0).powi(2))
        .sqrt();
        if p["name"] == moved.as_str() {
            assert!(
                (miss - 100_000.0).abs() < 10.0,
                "{moved} misses by {miss} m"
            );
        } else {
            // The other control points fit as in a block without the typing error (the scene's
            // markers are clicked to 0.3 px, about 0.1 m on the ground).
            assert!(miss < 0.5, "{} misses by {miss} m", p["name"]);
        }
    }
}
