//! The `dem` and `ortho` stages of `timesift run` on a rendered two-epoch project (orchard) with
//! its true orientation and, as dense clouds, the true surfaces sampled at the dense stage's
//! density (one point per 2 × 2 GSD, as level 2 gives) with 0.5 GSD of noise: every epoch's
//! rasters stack on `out/grid.json`'s lattice, the DEM is within the accuracy the issue asks
//! for, the painted targets sit where they are in the orthos, GDAL reads the files, and a second
//! run redoes nothing.

use std::path::Path;

use crate::common::{grey_images, timesift};
use timesift::report::{GridFile, RasterReport, read_json};
use timesift_change::grid::Dem;
use timesift_change::stats::nmad;
use timesift_eval::products::{dem_height_errors, ortho_target_errors};
use timesift_eval::true_scene::{write_sampled_clouds, write_true_orientation};
use timesift_io::geotiff::{read_f32, read_rgb8};
use timesift_synth::scenes::{Scale, build};
use timesift_synth::writer::{WriteOptions, write_scene};

/// The project with its true orientation and sampled clouds; returns the epochs' GSDs.
fn project(dir: &Path) -> Vec<(String, f64)> {
    let spec = build("orchard", Scale::Small, 1).expect("scene");
    write_scene(&spec, dir, &WriteOptions::default()).expect("write");
    write_true_orientation(dir, &spec, 15.0).expect("orientation");
    write_sampled_clouds(dir, &spec, 2.0, 0.5, 7).expect("clouds")
}

fn run(dir: &Path) -> String {
    let (ok, _, err) = timesift(&[
        "-v",
        "run",
        dir.to_str().expect("utf-8"),
        "--from",
        "dem",
        "--to",
        "ortho",
    ]);
    assert!(ok, "{err}");
    err
}

fn gdalinfo(path: &Path) -> Option<String> {
    let out = std::process::Command::new("gdalinfo")
        .arg(path)
        .output()
        .ok()?;
    assert!(out.status.success());
    assert!(
        out.stderr.is_empty(),
        "gdalinfo warned on {}: {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    Some(String::from_utf8_lossy(&out.stdout).into_owned())
}

#[test]
fn dems_and_orthos_stack_are_accurate_and_show_the_targets_where_they_are() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let epochs = project(dir);
    run(dir);
    let grid: GridFile = read_json(&dir.join("out/grid.json")).expect("grid.json");
    let coarsest = epochs.iter().map(|e| e.1).fold(0.0, f64::max);
    // 2 × the coarsest GSD, tidied to 1, 2, 2.5 or 5 × 10ⁿ (within a factor 1.5).
    assert!(
        grid.dem_cell > 1.3 * coarsest && grid.dem_cell < 3.0 * coarsest,
        "{} vs GSD {coarsest}",
        grid.dem_cell
    );
    let report: RasterReport = read_json(&dir.join("out/raster.json")).expect("raster.json");
    let mut first: Option<(timesift_io::geotiff::GeoReference, usize, usize)> = None;
    let mut first_ortho = None;
    for (name, gsd) in &epochs {
        let epoch_dir = dir.join("out/epochs").join(name);
        // Stacking: the same grid for every epoch, that of grid.json.
        let dem = read_f32(&epoch_dir.join("dem.tif")).expect("dem.tif");
        let t = dem.georef.transform;
        assert_eq!([t.origin_x, t.origin_y], grid.origin);
        assert_eq!(t.pixel_width, grid.dem_cell);
        assert_eq!([dem.width, dem.height], grid.size);
        let key = (dem.georef, dem.width, dem.height);
        assert_eq!(*first.get_or_insert(key), key, "{name}: another grid");
        let ortho = read_rgb8(&epoch_dir.join("ortho.tif")).expect("ortho.tif");
        assert_eq!([ortho.width, ortho.height], grid.ortho_size);
        assert_eq!(ortho.width, dem.width * grid.ortho_factor);
        let okey = (ortho.georef.transform, ortho.width, ortho.height);
        assert_eq!(
            *first_ortho.get_or_insert(okey),
            okey,
            "{name}: another ortho grid"
        );
        for f in [
            "dem_count.tif",
            "dem_std.tif",
            "dem_filled.tif",
            "dem.png",
            "ortho.png",
        ] {
            assert!(epoch_dir.join(f).is_file(), "{name}: {f}");
        }

        // DEM accuracy on measured cells against the true surface.
        let truth = Dem::from_raster(
            read_f32(&dir.join(format!("truth/dem_{name}.tif"))).expect("truth"),
            None,
        )
        .expect("truth DEM");
        let count = read_f32(&epoch_dir.join("dem_count.tif")).expect("count");
        let mut err: Vec<f64> = dem_height_errors(&dem, &count, &truth, |_, _| true)
            .into_iter()
            .map(|e| e / gsd)
            .collect();
        let mean = err.iter().sum::<f64>() / err.len() as f64;
        let spread = nmad(&mut err);
        println!(
            "{name}: DEM {} cells, error mean {mean:.3} GSD, NMAD {spread:.3} GSD",
            err.len()
        );
        assert!(err.len() > 1000);
        assert!(mean.abs() <= 0.2, "{name}: mean {mean} GSD");
        assert!(spread <= 0.5, "{name}: NMAD {spread} GSD");

        // Targets in the ortho, against their true positions.
        let radius = build("orchard", Scale::Small, 1)
            .expect("scene")
            .target_radius;
        let (found, rmse) =
            ortho_target_errors(&timesift::layout::Layout::new(dir), &ortho, radius)
                .expect("targets");
        assert!(found >= 4, "{name}: {found} targets inside the ortho");
        let rmse = rmse.unwrap_or(f64::INFINITY);
        println!("{name}: {found} targets, RMSE {rmse:.2} ortho cells");
        assert!(rmse <= 1.0, "{name}: targets {rmse} cells off");
        let r = &report.epochs[name];
        assert!(r.ortho_painted_fraction.is_some_and(|f| f > 0.95), "{r:?}");

        // GDAL's reading of the files.
        match gdalinfo(&epoch_dir.join("dem.tif")) {
            Some(info) => {
                assert!(info.contains("NoData Value=-32767"), "{info}");
                assert!(info.contains("Block=256x256"), "{info}");
                let code = grid.crs.trim_start_matches("EPSG:");
                assert!(info.contains(&format!("ID[\"EPSG\",{code}]]")), "{info}");
                if dem.width.max(dem.height) > 256 {
                    assert!(info.contains("Overviews:"), "{info}");
                }
                let oinfo = gdalinfo(&epoch_dir.join("ortho.tif")).expect("gdalinfo");
                assert!(oinfo.contains("ColorInterp=Alpha"), "{oinfo}");
                assert!(oinfo.contains("Overviews:"), "{oinfo}");
            }
            None => println!("gdalinfo checks skipped: Debian gdal-bin is not installed"),
        }
    }

    // A second run finds everything up to date and rewrites nothing.
    let stamp = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    let files: Vec<_> = epochs
        .iter()
        .flat_map(|(n, _)| {
            let d = dir.join("out/epochs").join(n);
            [d.join("dem.tif"), d.join("ortho.tif")]
        })
        .collect();
    let before: Vec<_> = files.iter().map(|f| stamp(f)).collect();
    let log = run(dir);
    let after: Vec<_> = files.iter().map(|f| stamp(f)).collect();
    assert_eq!(before, after);
    assert!(
        log.contains("DEM up to date") && log.contains("ortho up to date"),
        "{log}"
    );
}

#[test]
fn the_dem_stage_says_which_stage_to_run_first() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let spec = build("orchard", Scale::Small, 1).expect("scene");
    // The stage stops before it reads an image: grey ones stand in for the rendered images.
    write_scene(&spec, tmp.path(), &WriteOptions { images: false }).expect("write");
    grey_images(tmp.path());
    write_true_orientation(tmp.path(), &spec, 15.0).expect("orientation");
    let (ok, _, err) = timesift(&[
        "run",
        tmp.path().to_str().expect("utf-8"),
        "--from",
        "dem",
        "--to",
        "dem",
    ]);
    assert!(!ok);
    assert!(
        err.contains("dense.laz") && err.contains("run the dense stage first"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}
