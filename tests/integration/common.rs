//! Helpers shared by the end-to-end tests.

use std::path::Path;
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
