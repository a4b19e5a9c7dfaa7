//! The `dense` stage of `timesift run` on a rendered two-epoch project (soil-pit) oriented by its
//! true cameras: a LAS 1.4/LAZ cloud per epoch with colours, normals, image counts and the CRS;
//! a resumed run recomputes exactly the depth maps that were deleted and gives the same cloud
//! bit for bit; bad inputs give one-line errors naming the file or epoch.

use std::path::Path;

use crate::common::{quick_dense_level_4, timesift};
use timesift::report::{DenseReport, read_json};
use timesift_eval::true_scene::write_true_orientation;
use timesift_io::pointcloud::{AttributeValues, PointCloud, read_las};
use timesift_synth::scenes::{Scale, build};
use timesift_synth::writer::{WriteOptions, write_scene};

/// A rendered soil-pit project oriented by its truth, dense matching at level 4 with the quick
/// settings (`DenseConfig::quick`: this file tests the stage's files, resumption and errors; the
/// accuracy of the maps is `timesift-dense`'s tests') but refined at level 2 as by default, so
/// that the refinement's maps go through the cache too; with each epoch cut to its first
/// `images` images (a row along the wall).
fn project(images: usize) -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut spec = build("soil-pit", Scale::Small, 1).expect("scene");
    spec.keep_first_images(images);
    write_scene(&spec, dir.path(), &WriteOptions::default()).expect("write");
    quick_dense_level_4(dir.path());
    let toml = dir.path().join("project.toml");
    let text = std::fs::read_to_string(&toml).expect("project.toml");
    assert!(text.contains("refine = false"));
    std::fs::write(&toml, text.replace("refine = false", "refine = true")).expect("project.toml");
    let points = write_true_orientation(dir.path(), &spec, 15.0).expect("orientation");
    assert!(points > 100, "{points} sparse points");
    dir
}

fn run_dense(dir: &Path) -> (bool, String) {
    let (ok, _, err) = timesift(&[
        "run",
        dir.to_str().expect("utf-8 path"),
        "--from",
        "dense",
        "--to",
        "dense",
    ]);
    (ok, err)
}

fn epochs(dir: &Path) -> Vec<String> {
    let report: DenseReport = read_json(&dir.join("out/dense.json")).expect("dense.json");
    report.epochs.keys().cloned().collect()
}

fn cloud(dir: &Path, epoch: &str) -> PointCloud {
    read_las(&dir.join("out/epochs").join(epoch).join("dense.laz")).expect("dense.laz")
}

#[test]
fn dense_stage_writes_clouds_and_resumes_image_by_image() {
    let dir = project(12);
    let (ok, err) = run_dense(dir.path());
    assert!(ok, "{err}");
    let names = epochs(dir.path());
    assert_eq!(names.len(), 2);
    for name in &names {
        let c = cloud(dir.path(), name);
        assert!(
            c.positions.len() > 5_000,
            "{name}: {} points",
            c.positions.len()
        );
        assert_eq!(c.crs.to_string(), "EPSG:32631");
        assert!(c.colors.as_ref().is_some_and(|c| c.len() == c.len()));
        let attribute = |n: &str| c.attributes.iter().find(|a| a.name == n).map(|a| &a.values);
        match attribute("images") {
            Some(AttributeValues::U8(v)) => assert!(v.iter().all(|&n| n >= 3)),
            other => panic!("images attribute: {other:?}"),
        }
        match (
            attribute("normal_x"),
            attribute("normal_y"),
            attribute("normal_z"),
        ) {
            (
                Some(AttributeValues::F32(x)),
                Some(AttributeValues::F32(y)),
                Some(AttributeValues::F32(z)),
            ) => {
                for k in 0..x.len() {
                    let len = (x[k] * x[k] + y[k] * y[k] + z[k] * z[k]).sqrt();
                    assert!((len - 1.0).abs() < 1e-3);
                }
            }
            other => panic!("normals: {other:?}"),
        }
    }
    // Delete some cached depth maps (of the first and the last pass) and the first epoch's
    // cloud, as an interrupted run would leave them: only those maps are recomputed, and the
    // cloud is the same bit for bit.
    let first = &names[0];
    let before = cloud(dir.path(), first);
    let work = dir.path().join("work/dense").join(first);
    let mut passes: Vec<_> = std::fs::read_dir(&work)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("pass"))
        })
        .collect();
    passes.sort();
    let mut deleted = 0;
    for (pass, images) in [
        (passes.first().unwrap(), [1usize, 4]),
        (passes.last().unwrap(), [2, 7]),
    ] {
        for i in images {
            let map = pass.join(format!("{i}.exr"));
            assert!(map.is_file(), "{}", map.display());
            std::fs::remove_file(map).unwrap();
            deleted += 1;
        }
    }
    std::fs::remove_file(dir.path().join("out/epochs").join(first).join("dense.laz")).unwrap();
    let (ok, err) = run_dense(dir.path());
    assert!(ok, "{err}");
    let report: DenseReport = read_json(&dir.path().join("out/dense.json")).unwrap();
    // Maps are deterministic, so the cached maps of later passes that read a deleted one stay
    // valid: only the deleted ones are redone.
    assert_eq!(report.epochs[first].depth_maps_computed, deleted);
    assert_eq!(report.epochs[&names[1]].depth_maps_computed, 0);
    let after = cloud(dir.path(), first);
    assert_eq!(before.positions.len(), after.positions.len());
    assert!(before.positions == after.positions, "positions differ");
    assert!(before.colors == after.colors && before.attributes == after.attributes);
    // Changing only a fusion option keeps the maps and redoes the cloud.
    let toml = dir.path().join("project.toml");
    let text = std::fs::read_to_string(&toml)
        .unwrap()
        .replace("level = 4", "level = 4\nmin_images = 4");
    std::fs::write(&toml, text).unwrap();
    let (ok, err) = run_dense(dir.path());
    assert!(ok, "{err}");
    let report: DenseReport = read_json(&dir.path().join("out/dense.json")).unwrap();
    assert_eq!(report.epochs[first].depth_maps_computed, 0);
    let strict = cloud(dir.path(), first);
    assert!(strict.positions.len() < after.positions.len());
}

#[test]
fn dense_stage_names_bad_inputs() {
    let dir = project(6);
    let path = dir.path();
    let toml = path.join("project.toml");
    let original = std::fs::read_to_string(&toml).unwrap();
    let names: Vec<String> = original
        .lines()
        .filter_map(|l| {
            l.strip_prefix("name = \"")
                .map(|n| n.trim_end_matches('"').to_string())
        })
        .collect();
    // An epoch with one oriented image (the others unoriented in cameras.json).
    let cameras = path.join("out/cameras.json");
    let full = std::fs::read_to_string(&cameras).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&full).unwrap();
    let keep = format!("images/{}/IMG_0001.jpg", names[1]);
    for im in json["images"].as_array_mut().unwrap() {
        let name = im["name"].as_str().unwrap().to_string();
        if name.starts_with(&format!("images/{}/", names[1])) && name != keep {
            for key in ["R", "t", "center"] {
                im[key] = serde_json::Value::Null;
            }
        }
    }
    std::fs::write(&cameras, serde_json::to_string(&json).unwrap()).unwrap();
    let (ok, err) = run_dense(path);
    assert!(!ok);
    assert!(
        err.lines().count() == 1
            && err.contains(&names[1])
            && err.contains("1 of its 6 images were oriented")
            && err.contains("dense matching needs two"),
        "{err}"
    );
    // cameras.json of another project: image names it does not have.
    std::fs::write(&cameras, full.replace("IMG_0003", "DSC_9999")).unwrap();
    let (ok, err) = run_dense(path);
    assert!(!ok);
    assert!(
        err.contains("DSC_9999") && err.contains("cameras.json"),
        "{err}"
    );
    // An image missing on disk.
    std::fs::write(&cameras, &full).unwrap();
    let image = format!("images/{}/IMG_0005.jpg", names[0]);
    std::fs::write(
        &toml,
        original.replacen(
            &format!("images = \"images/{}/*.jpg\"", names[0]),
            &format!(
                "images = [{}]",
                (1..=6)
                    .map(|k| format!("\"images/{}/IMG_{k:04}.jpg\"", names[0]))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            1,
        ),
    )
    .unwrap();
    std::fs::remove_file(path.join(&image)).unwrap();
    let (ok, err) = run_dense(path);
    assert!(!ok);
    assert!(
        err.lines().count() == 1 && err.contains("IMG_0005"),
        "{err}"
    );
}
