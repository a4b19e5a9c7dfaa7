//! Stacking, the contract of docs/design.md, on every `synth` scene: all epochs' `dem.tif` share one
//! geotransform and size — those of `out/grid.json` — and so do all epochs' `ortho.tif` (the DEM
//! lattice subdivided). The scenes are written without rendering (the true orientation, the
//! true surfaces sampled as dense clouds, uniform grey images of the cameras' sizes), so every
//! scene fits in a test; what the orthos show is checked on a rendered scene in `run_raster.rs`.
//! Also: an image whose size is not its camera's is an error naming the file.

use std::path::Path;

use crate::common::{grey_images, timesift};
use timesift::report::{GridFile, read_json};
use timesift_eval::true_scene::{write_sampled_clouds, write_true_orientation};
use timesift_io::cameras_json::read_cameras_json;
use timesift_io::geotiff::{read_f32, read_rgb8};
use timesift_synth::scenes::{SCENES, Scale, build};
use timesift_synth::writer::{WriteOptions, write_scene};

fn run(dir: &Path) -> (bool, String) {
    let (ok, _, err) = timesift(&[
        "run",
        dir.to_str().expect("utf-8"),
        "--from",
        "dem",
        "--to",
        "ortho",
    ]);
    (ok, err)
}

#[test]
fn every_scene_s_epochs_share_the_dem_and_ortho_grids() {
    for scene in SCENES {
        let tmp = tempfile::tempdir().expect("tempdir");
        let dir = tmp.path();
        let mut spec = build(scene, Scale::Small, 1).expect("scene");
        // Uniform grey images stand in for the photographs: film scans (tests/integration/film.rs) would
        // need their marks.
        for epoch in &mut spec.epochs {
            epoch.film = None;
        }
        write_scene(&spec, dir, &WriteOptions { images: false }).expect("write");
        grey_images(dir);
        write_true_orientation(dir, &spec, 30.0).expect("orientation");
        let epochs = write_sampled_clouds(dir, &spec, 4.0, 0.5, 3).expect("clouds");
        // Grids are what this test checks: the mosaic of grey images without its seam sweeps
        // and gain fit (what they do is `run_raster`'s and the raster crate's to check).
        let toml = dir.join("project.toml");
        let text = std::fs::read_to_string(&toml).expect("project.toml")
            + "\n[raster]\nseam_sweeps = 0\ngain_compensation = false\n";
        std::fs::write(&toml, text).expect("project.toml");
        let (ok, err) = run(dir);
        assert!(ok, "{scene}: {err}");
        let grid: GridFile = read_json(&dir.join("out/grid.json")).expect("grid.json");
        let mut dem_grid = None;
        let mut ortho_grid = None;
        for (name, _) in &epochs {
            let epoch_dir = dir.join("out/epochs").join(name);
            let dem = read_f32(&epoch_dir.join("dem.tif")).expect("dem");
            let t = dem.georef.transform;
            assert_eq!([t.origin_x, t.origin_y], grid.origin, "{scene} {name}");
            assert_eq!(
                (t.pixel_width, -t.pixel_height),
                (grid.dem_cell, grid.dem_cell),
                "{scene} {name}"
            );
            assert_eq!([dem.width, dem.height], grid.size, "{scene} {name}");
            let key = (dem.georef, dem.width, dem.height);
            assert_eq!(*dem_grid.get_or_insert(key), key, "{scene} {name}");
            let ortho = read_rgb8(&epoch_dir.join("ortho.tif")).expect("ortho");
            let key = (ortho.georef, ortho.width, ortho.height);
            assert_eq!(*ortho_grid.get_or_insert(key), key, "{scene} {name}");
            assert_eq!(
                [ortho.width, ortho.height],
                [
                    grid.size[0] * grid.ortho_factor,
                    grid.size[1] * grid.ortho_factor
                ],
                "{scene} {name}"
            );
            assert!(
                (ortho.georef.transform.pixel_width * grid.ortho_factor as f64 - grid.dem_cell)
                    .abs()
                    < 1e-12
            );
            // Cells outside an epoch's own footprint are nodata; inside, most have a height.
            let valid = dem.data.iter().filter(|h| **h != -32767.0).count();
            assert!(valid > 0 && valid <= dem.data.len(), "{scene} {name}");
        }
    }
}

#[test]
fn an_image_of_the_wrong_size_is_named() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let spec = build("landslide", Scale::Small, 1).expect("scene");
    write_scene(&spec, dir, &WriteOptions { images: false }).expect("write");
    grey_images(dir);
    write_true_orientation(dir, &spec, 30.0).expect("orientation");
    write_sampled_clouds(dir, &spec, 4.0, 0.5, 3).expect("clouds");
    let truth = read_cameras_json(&dir.join("truth/cameras.json")).expect("truth");
    let victim = &truth.images[0].name;
    image::RgbImage::from_pixel(40, 30, image::Rgb([1, 2, 3]))
        .save(dir.join(victim))
        .expect("image");
    let (ok, err) = run(dir);
    assert!(!ok);
    assert!(
        err.contains(victim.as_str()) && err.contains("40 × 30 pixels"),
        "{err}"
    );
    // One error line (the stages that finished before it print their own lines).
    assert_eq!(
        err.lines().filter(|l| l.starts_with("error")).count(),
        1,
        "{err}"
    );
}
