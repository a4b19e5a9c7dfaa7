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

/// Whether a product file is complete: it parses as what its name says.
pub fn complete(path: &Path) -> Result<(), String> {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    let bad = |e: String| format!("{}: {e}", path.display());
    match ext {
        "json" => serde_json::from_slice::<serde_json::Value>(
            &std::fs::read(path).map_err(|e| bad(e.to_string()))?,
        )
        .map(|_| ())
        .map_err(|e| bad(e.to_string())),
        "tif" if name.starts_with("ortho") => timesift_io::geotiff::read_rgb8(path)
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
        "tif" => timesift_io::geotiff::read_f32(path)
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
        "laz" => timesift_io::pointcloud::read_las(path)
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
        "png" => image::open(path)
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
        "ply" => timesift_io::ply::read_tiepoints(path)
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
        "txt" => timesift_io::colmap::read_colmap_text(path.parent().expect("dir"))
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
        "html" | "qml" | "qgs" => {
            let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
            let end = if ext == "html" { "</html>" } else { "</qgis>" };
            text.trim_end()
                .ends_with(end)
                .then_some(())
                .ok_or_else(|| bad("cut short".into()))
        }
        _ => Err(bad("unexpected product".into())),
    }
}

/// Asserts that `a` and `b` hold the same products under `out/`, byte for byte but for the
/// reports' times and paths (and report.html, which embeds them), and that `b` holds no
/// temporary file.
pub fn assert_same_products(a_dir: &Path, b_dir: &Path) {
    let (a, b) = (files(&a_dir.join("out")), files(&b_dir.join("out")));
    let leftovers: Vec<&PathBuf> = b
        .iter()
        .filter(|f| f.to_string_lossy().contains(".tmp-"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    assert_eq!(a, b, "different sets of products");
    let mut differing = Vec::new();
    for f in &a {
        let (pa, pb) = (a_dir.join("out").join(f), b_dir.join("out").join(f));
        let same = match f.extension().and_then(|e| e.to_str()) {
            Some("html") => continue,
            Some("json") => {
                // `a` may be a copy of `b`'s products made before `b` ran again: its reports
                // then name `b`'s folder.
                let a_text = std::fs::read_to_string(&pa).expect("read").replace(
                    b_dir.to_str().expect("utf-8"),
                    a_dir.to_str().expect("utf-8"),
                );
                comparable_json(&a_text, a_dir)
                    == comparable_json(&std::fs::read_to_string(&pb).expect("read"), b_dir)
            }
            _ => std::fs::read(&pa).expect("read") == std::fs::read(&pb).expect("read"),
        };
        if !same {
            differing.push(f.clone());
        }
    }
    assert!(differing.is_empty(), "products differ: {differing:?}");
}

/// Renders the project into `dir`: the first two epochs of `landslide`, each cut to its first ten
/// images (the same ground in both: one flight plan), dense matching at level 4 with the quick
/// settings (`DenseConfig::quick`) — every stage has work to do, and a run lasts long
/// enough to be killed in each.
pub fn small_landslide(dir: &Path) {
    let mut spec =
        timesift_synth::scenes::build("landslide", timesift_synth::scenes::Scale::Small, 3)
            .expect("scene");
    spec.epochs.truncate(2);
    spec.keep_first_images(10);
    timesift_synth::writer::write_scene(
        &spec,
        dir,
        &timesift_synth::writer::WriteOptions::default(),
    )
    .expect("write");
    quick_dense_level_4(dir);
}

/// Runs `command` with a resource limit of `bytes` (`libc::RLIMIT_AS`, `RLIMIT_FSIZE`, …) set in
/// the child; for `RLIMIT_FSIZE`, SIGXFSZ is ignored so that a write past it fails with EFBIG
/// instead of killing the child. (success, standard error)
pub fn output_with_limit(
    command: &mut Command,
    resource: libc::__rlimit_resource_t,
    bytes: u64,
) -> (bool, String) {
    use std::os::unix::process::CommandExt;
    // SAFETY: the closure runs in the forked child before exec and calls only signal and
    // setrlimit, which are async-signal-safe; an ignored signal stays ignored across exec.
    unsafe {
        command.pre_exec(move || {
            if resource == libc::RLIMIT_FSIZE {
                libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            }
            let limit = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            if libc::setrlimit(resource, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let out = command.output().expect("the binary runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
