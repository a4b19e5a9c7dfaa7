//! Helpers shared by the end-to-end tests.

use std::path::{Path, PathBuf};
use std::process::Command;

use timesift_io::cameras_json::read_cameras_json;

/// Runs the `timesift` binary: (success, stdout, stderr).
pub fn timesift(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args(args)
        .output()
        .expect("the binary runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Writes a grey image of the camera's size for every image of the truth.
pub fn grey_images(dir: &Path) {
    let truth = read_cameras_json(&dir.join("truth/cameras.json")).expect("truth");
    for image in &truth.images {
        let camera = &truth.cameras[&image.camera];
        use timesift_core::CameraModel;
        let (w, h) = (camera.width(), camera.height());
        let path = dir.join(&image.name);
        std::fs::create_dir_all(path.parent().expect("folder")).expect("mkdir");
        image::RgbImage::from_pixel(w, h, image::Rgb([120, 110, 100]))
            .save(&path)
            .expect("image");
    }
}

/// Appends a `[dense]` section to the project's `project.toml`: level 4 with the quick settings
/// (`DenseConfig::quick`), for tests of the stages rather than of the maps' accuracy.
pub fn quick_dense_level_4(dir: &Path) {
    let toml = dir.join("project.toml");
    let quick = timesift::config::DenseConfig::quick();
    let text = std::fs::read_to_string(&toml).expect("project.toml")
        + &format!(
            "\n[dense]\nlevel = 4\nrefine = {}\nmax_sources = {}\niterations = {}\ngeometric_iterations = {}\n",
            quick.refine, quick.max_sources, quick.iterations, quick.geometric_iterations
        );
    std::fs::write(&toml, text).expect("project.toml");
}

/// Copies a folder tree.
pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("read_dir").flatten() {
        let target = to.join(entry.file_name());
        if entry.path().is_dir() {
            copy_tree(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).expect("copy");
        }
    }
}

/// Every file under `dir`, relative, sorted.
pub fn files(dir: &Path) -> Vec<PathBuf> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(root, &p, out);
            } else if let Ok(rel) = p.strip_prefix(root) {
                out.push(rel.to_path_buf());
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

/// A JSON report without what legitimately differs between runs: wall times, work counted in
/// this run only, and the project's own path.
pub fn comparable_json(text: &str, dir: &Path) -> serde_json::Value {
    fn strip(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::Object(map) => {
                map.retain(|k, _| !k.contains("seconds") && k != "depth_maps_computed");
                map.values_mut().for_each(strip);
            }
            serde_json::Value::Array(items) => items.iter_mut().for_each(strip),
            _ => {}
        }
    }
    let text = text.replace(dir.to_str().expect("utf-8"), "<dir>");
    let mut v: serde_json::Value = serde_json::from_str(&text).expect("json");
    strip(&mut v);
    v
}
