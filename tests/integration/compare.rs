//! End-to-end tests of `timesift compare` and the `change` stage: files in, products out, and a
//! one-line error for every kind of bad pair.

use crate::common::timesift;
use std::path::{Path, PathBuf};

use timesift_change::grid::{Dem, Grid};
use timesift_io::coords::Crs;
use timesift_io::geotiff::{GeoTransform, read_f32, write_f32};
use timesift_io::pointcloud::{AttributeValues, LasWriteOptions, PointCloud, read_las, write_las};

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

const X0: f64 = 352_000.0;
const Y0: f64 = 4_781_000.0;
const CELL: f64 = 0.25;

fn grid(crs: Crs, x0: f64) -> Grid {
    Grid {
        transform: GeoTransform {
            origin_x: x0,
            origin_y: Y0,
            pixel_width: CELL,
            pixel_height: -CELL,
        },
        width: 320,
        height: 240,
        crs,
    }
}

/// Gentle terrain.
fn ground(x: f64, y: f64) -> f64 {
    let (u, v) = (x - X0, y - Y0);
    120.0 + 0.05 * u - 0.03 * v + 0.8 * (u / 9.0).sin() * (v / 7.0).cos()
}

/// A paraboloid excavation of depth 2 m and radius 12 m centred at (30, −30) from the corner:
/// volume π R² h / 2.
fn pit(x: f64, y: f64) -> f64 {
    let r2 = (x - X0 - 30.0).powi(2) + (y - Y0 + 30.0).powi(2);
    if r2 < 144.0 {
        -2.0 * (1.0 - r2 / 144.0)
    } else {
        0.0
    }
}
const PIT_VOLUME: f64 = std::f64::consts::PI * 144.0 * 2.0 / 2.0;

fn write_dem(path: &Path, grid: Grid, f: impl Fn(f64, f64) -> f64) {
    let values = (0..grid.len())
        .map(|i| {
            let (x, y) = grid.cell_center(i % grid.width, i / grid.width);
            f(x, y) as f32
        })
        .collect();
    write_f32(path, &Dem { grid, values }.to_raster()).expect("write dem");
}

/// Stable everywhere except a square around the excavation.
fn write_stable(path: &Path) {
    let (a, b) = (X0 + 15.0, X0 + 45.0);
    let (c, d) = (Y0 - 45.0, Y0 - 15.0);
    let text = format!(
        "name,wkt\nall but the pit,\"POLYGON (({x0} {y0}, {x1} {y0}, {x1} {y1}, {x0} {y1}, {x0} {y0}), ({a} {c}, {b} {c}, {b} {d}, {a} {d}, {a} {c}))\"\n",
        x0 = X0,
        y0 = Y0,
        x1 = X0 + 80.0,
        y1 = Y0 - 60.0,
    );
    std::fs::write(path, text).expect("write stable");
}

#[test]
fn dem_compare_recovers_the_excavation_volume_after_vertical_coregistration() {
    let dir = tempfile::tempdir().expect("tmp");
    let (a, b) = (dir.path().join("a.tif"), dir.path().join("b.tif"));
    write_dem(&a, grid(Crs::Epsg(32633), X0), ground);
    // The later survey is 0.3 m too high everywhere and has the pit.
    write_dem(&b, grid(Crs::Epsg(32633), X0), |x, y| {
        ground(x, y) + pit(x, y) + 0.3
    });
    let stable = dir.path().join("stable.csv");
    write_stable(&stable);
    let out = dir.path().join("out");
    // Check points on stable ground (true heights), one off the DEM.
    let checkpoints = dir.path().join("checkpoints.csv");
    let mut csv = String::from("name,x,y,z\n");
    for (name, x, y) in [
        ("c1", X0 + 5.3, Y0 - 7.1),
        ("c2", X0 + 70.2, Y0 - 50.4),
        ("c3", X0 + 60.0, Y0 - 10.0),
    ] {
        csv.push_str(&format!("{name},{x},{y},{}\n", ground(x, y)));
    }
    csv.push_str(&format!("off,{},{},100\n", X0 - 50.0, Y0));
    std::fs::write(&checkpoints, csv).expect("write");
    let (ok, stdout, err) = timesift(&[
        "compare",
        path(&a),
        path(&b),
        "--stable",
        path(&stable),
        "--coregister",
        "vertical",
        "--checkpoints",
        path(&checkpoints),
        "--out",
        path(&out),
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("volumes:"), "{stdout}");
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stats.json")).expect("stats"))
            .expect("json");
    let shift = stats["coregistration"]["shift_z"].as_f64().expect("shift");
    assert!((shift + 0.3).abs() < 1e-4, "{shift}");
    let cut = stats["volumes"]["cut"].as_f64().expect("cut");
    let fill = stats["volumes"]["fill"].as_f64().expect("fill");
    assert!(
        (cut - PIT_VOLUME).abs() < 0.005 * PIT_VOLUME,
        "{cut} vs {PIT_VOLUME}"
    );
    assert!(fill < 1e-3 * PIT_VOLUME, "{fill}");
    assert!(stats["stable"]["nmad"].as_f64().expect("nmad") < 1e-4);
    // Bilinear DEM heights at the check points: within the interpolation error of the smooth
    // surface, for the earlier DEM and for the co-registered later one; the point off the DEM is
    // listed as missing.
    for k in 0..2 {
        let c = &stats["checkpoints"][k];
        assert_eq!(c["height"]["count"].as_u64(), Some(3), "{c}");
        assert!(c["height"]["rmse"].as_f64().expect("rmse") < 5e-3, "{c}");
        assert_eq!(c["missing"][0].as_str(), Some("off"));
    }
    // The DoD on disk is the later minus the earlier, co-registered.
    let dod = read_f32(&out.join("dod.tif")).expect("dod");
    let centre = dod.get(120, 120, 0);
    assert!((centre + 2.0).abs() < 0.01, "{centre}");
    // Relative volume error, for the record.
    eprintln!(
        "excavation: cut {cut:.3} m³ vs analytic {PIT_VOLUME:.3} m³ ({:+.4} %)",
        100.0 * (cut / PIT_VOLUME - 1.0)
    );
    // With σ = 5 cm per DEM (LoD95 = 0.139 m) the pit is significant and stable ground is not.
    let out_sigma = dir.path().join("out_sigma");
    let (ok, stdout, err) = timesift(&[
        "compare",
        path(&a),
        path(&b),
        "--coregister",
        "vertical",
        "--stable",
        path(&stable),
        "--sigma",
        "0.05",
        "0.05",
        "--out",
        path(&out_sigma),
    ]);
    assert!(
        ok && stdout.contains("LoD95 0.1386 m (sigmas given)"),
        "{stdout}{err}"
    );
    let significant = read_f32(&out_sigma.join("significant.tif")).expect("significant");
    assert_eq!(significant.get(120, 120, 0), 1.0);
    assert_eq!(significant.get(300, 20, 0), 0.0);
    for f in ["dod.png", "histogram.png", "coregistered.tif"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let png = image::open(out.join("dod.png")).expect("png");
    assert!(png.width() > 600 && png.height() > 400);
}

#[test]
fn dem_compare_bad_pairs_give_one_line_errors() {
    let dir = tempfile::tempdir().expect("tmp");
    let a = dir.path().join("a.tif");
    write_dem(&a, grid(Crs::Epsg(32633), X0), ground);
    let other_crs = dir.path().join("utm34.tif");
    write_dem(&other_crs, grid(Crs::Epsg(32634), X0), ground);
    let far = dir.path().join("far.tif");
    write_dem(&far, grid(Crs::Epsg(32633), X0 + 10_000.0), ground);
    let out = dir.path().join("out");
    let run = |b: &Path, extra: &[&str]| {
        let mut args = vec!["compare", path(&a), path(b), "--out", path(&out)];
        args.extend_from_slice(extra);
        let (ok, _, err) = timesift(&args);
        assert!(!ok);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        err
    };
    let e = run(&other_crs, &[]);
    assert!(
        e.contains("EPSG:32633") && e.contains("EPSG:32634") && e.contains("utm34.tif"),
        "{e}"
    );
    let e = run(&far, &[]);
    assert!(e.contains("do not overlap") && e.contains("far.tif"), "{e}");
    // A stable polygon that misses the DEM.
    let nowhere = dir.path().join("nowhere.csv");
    std::fs::write(&nowhere, "POLYGON ((0 0, 1 0, 1 1, 0 1, 0 0))\n").expect("write");
    let e = run(&a, &["--stable", path(&nowhere)]);
    assert!(
        e.contains("nowhere.csv") && e.contains("stable area is empty"),
        "{e}"
    );
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "name,wkt\nx,POLYGON ((0 0, 1 0\n").expect("write");
    let e = run(&a, &["--stable", path(&bad)]);
    assert!(e.contains("bad.csv") && e.contains("line 2"), "{e}");
    let cloud = dir.path().join("c.laz");
    let e = run(&cloud, &[]);
    assert!(e.contains("like with like"), "{e}");
    let text = dir.path().join("c.txt");
    let e = run(&text, &[]);
    assert!(e.contains("c.txt") && e.contains(".las"), "{e}");
    assert!(
        !out.join("dod.tif").exists(),
        "no output from a failed comparison"
    );
}

fn write_cloud(path: &Path, points: Vec<[f64; 3]>) {
    let cloud = PointCloud {
        positions: points,
        colors: None,
        attributes: Vec::new(),
        crs: Crs::Epsg(32754),
    };
    write_las(path, &cloud, &LasWriteOptions::default()).expect("write las");
}

/// `timesift compare a b --icp rigid` with M3C2 on the sandpyper DSMs' scale and `extra`
/// arguments, into `out`; the core points and their M3C2 distances.
fn icp_then_m3c2(a: &Path, b: &Path, extra: &[&str], out: &Path) -> (Vec<[f64; 3]>, Vec<f64>) {
    let mut args = vec!["compare", path(a), path(b), "--icp", "rigid"];
    args.extend_from_slice(extra);
    args.extend([
        "--normal-radius",
        "2.5",
        "--cylinder-radius",
        "1.5",
        "--max-depth",
        "4.5",
        "--core-spacing",
        "2",
        "--out",
        path(out),
    ]);
    let (ok, stdout, err) = timesift(&args);
    assert!(ok, "{err}");
    assert!(stdout.contains("ICP:"), "{stdout}");
    let result = read_las(&out.join("m3c2.laz")).expect("m3c2.laz");
    let distance = result
        .attributes
        .iter()
        .find(|a| a.name == "distance")
        .expect("distance attribute");
    let AttributeValues::F64(d) = &distance.values else {
        panic!("distance is f64");
    };
    (result.positions.clone(), d.clone())
}

#[test]
fn cloud_compare_runs_icp_then_m3c2_on_sandpyper() {
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/sandpyper-mar/dsm");
    let load = |d: &str| {
        let r = read_f32(&shared.join(format!("mar_{d}_dsm_resampled_1m.tif"))).expect("dsm");
        Dem::from_raster(r, Some(-10000.0))
            .expect("dem")
            .to_points()
    };
    let dir = tempfile::tempdir().expect("tmp");
    let (a, b) = (dir.path().join("a.laz"), dir.path().join("b.laz"));
    write_cloud(&a, load("20180601"));
    // The same survey moved by a known offset: ICP must undo it and M3C2 then sees no change.
    write_cloud(
        &b,
        load("20180601")
            .iter()
            .map(|p| [p[0] + 0.4, p[1] - 0.3, p[2] + 0.2])
            .collect(),
    );
    let out = dir.path().join("out");
    let (_, d) = icp_then_m3c2(&a, &b, &[], &out);
    let defined: Vec<f64> = d.iter().copied().filter(|v| v.is_finite()).collect();
    assert!(defined.len() > 10_000, "{}", defined.len());
    // Rounding to the LAS millimetre grid is the only difference left.
    let worst = defined.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(worst < 5e-3, "{worst}");
    for f in ["m3c2_stats.json", "m3c2_histogram.png", "m3c2.png"] {
        assert!(out.join(f).is_file(), "{f}");
    }
}

/// ICP on the stable ground of a mask GeoTIFF (as the align stage's `out/stable_found.tif`):
/// half the survey rose by 2 m, the mask marks the other half stable, and the known offset is
/// undone from it alone.
#[test]
fn cloud_icp_takes_its_stable_ground_from_a_mask_geotiff() {
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/sandpyper-mar/dsm");
    let raster = read_f32(&shared.join("mar_20180601_dsm_resampled_1m.tif")).expect("dsm");
    let dem = Dem::from_raster(raster, Some(-10000.0)).expect("dem");
    let points = dem.to_points();
    let mid = {
        let mut x: Vec<f64> = points.iter().map(|p| p[0]).collect();
        x.sort_by(f64::total_cmp);
        x[x.len() / 2]
    };
    let dir = tempfile::tempdir().expect("tmp");
    let (a, b) = (dir.path().join("a.laz"), dir.path().join("b.laz"));
    write_cloud(&a, points.clone());
    write_cloud(
        &b,
        points
            .iter()
            .map(|p| {
                let rise = if p[0] > mid { 2.0 } else { 0.0 };
                [p[0] + 0.4, p[1] - 0.3, p[2] + 0.2 + rise]
            })
            .collect(),
    );
    // 1 west of the middle, 0 east of it.
    let mut values = vec![0.0f32; dem.grid.width * dem.grid.height];
    for r in 0..dem.grid.height {
        for c in 0..dem.grid.width {
            let (x, _) = dem.grid.cell_center(c, r);
            values[r * dem.grid.width + c] = if x < mid { 1.0 } else { 0.0 };
        }
    }
    let mask = dir.path().join("mask.tif");
    write_f32(
        &mask,
        &Dem {
            grid: dem.grid,
            values,
        }
        .to_raster(),
    )
    .expect("mask");
    let out = dir.path().join("out");
    let (positions, d) = icp_then_m3c2(&a, &b, &["--stable", path(&mask)], &out);
    // West of the middle (a few metres in): no change left but the LAS millimetre grid's.
    let west: Vec<f64> = positions
        .iter()
        .zip(&d)
        .filter(|(p, v)| p[0] < mid - 5.0 && v.is_finite())
        .map(|(_, v)| *v)
        .collect();
    assert!(west.len() > 5_000, "{}", west.len());
    let worst = west.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(worst < 5e-3, "{worst}");
}

#[test]
fn change_stage_compares_epoch_dems() {
    let dir = tempfile::tempdir().expect("tmp");
    let p = dir.path();
    for e in ["2019", "2020", "2021"] {
        std::fs::create_dir_all(p.join("images").join(e)).expect("dir");
        for name in ["a.png", "b.png"] {
            image::RgbImage::from_pixel(32, 24, image::Rgb([90, 90, 90]))
                .save(p.join("images").join(e).join(name))
                .expect("png");
        }
        std::fs::create_dir_all(p.join("out/epochs").join(e)).expect("dir");
    }
    std::fs::write(
        p.join("project.toml"),
        "crs = \"EPSG:32633\"\n[[epoch]]\nname = \"2019\"\n[[epoch]]\nname = \"2020\"\n[[epoch]]\nname = \"2021\"\n[change]\npairs = \"reference\"\n",
    )
    .expect("toml");
    write_stable(&p.join("stable.csv"));
    let g = grid(Crs::Epsg(32633), X0);
    write_dem(&p.join("out/epochs/2019/dem.tif"), g, ground);
    write_dem(&p.join("out/epochs/2020/dem.tif"), g, |x, y| {
        ground(x, y) + 0.5 * pit(x, y)
    });
    write_dem(&p.join("out/epochs/2021/dem.tif"), g, |x, y| {
        ground(x, y) + pit(x, y)
    });
    let (ok, _, err) = timesift(&["run", path(p), "--from", "change", "--to", "change"]);
    assert!(ok, "{err}");
    for (pair, fraction) in [("2019__2020", 0.5), ("2019__2021", 1.0)] {
        let stats: serde_json::Value = serde_json::from_slice(
            &std::fs::read(p.join("out/change").join(pair).join("stats.json")).expect("stats"),
        )
        .expect("json");
        let cut = stats["volumes"]["cut"].as_f64().expect("cut");
        assert!(
            (cut - fraction * PIT_VOLUME).abs() < 0.005 * PIT_VOLUME,
            "{pair}: {cut}"
        );
        assert!(p.join("out/change").join(pair).join("dod.tif").is_file());
    }
    // Without DEMs the stage says what is missing.
    std::fs::remove_file(p.join("out/epochs/2021/dem.tif")).expect("rm");
    let (ok, _, err) = timesift(&["run", path(p), "--from", "change", "--to", "change"]);
    assert!(
        !ok && err.contains("2021") && err.contains("dem.tif") && err.contains("dem stage"),
        "{err}"
    );
}
