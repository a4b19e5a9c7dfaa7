//! `timesift dem` on real data: the sandpyper `mar` DSMs (1 m cells, slightly non-square,
//! EPSG:32754, −10000 as undeclared nodata), turned into clouds of their own cell centres and
//! gridded back onto their own grid with `--like`, reproduce the input bit for bit — an identity
//! test of the georeferencing (origin, cell size, row direction, half-cell convention): bit for
//! bit in process, and through `timesift dem` and a LAZ file to the height resolution the LAZ
//! stores (1e-7 m). Also the command's one-line errors.

use std::path::PathBuf;

use crate::common::timesift;
use timesift_io::coords::Crs;
use timesift_io::geotiff::read_f32;
use timesift_io::pointcloud::{LasWriteOptions, PointCloud, write_las};

fn shared_data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data")
}

#[test]
fn sandpyper_dsms_regridded_from_their_cell_centres_are_reproduced() {
    let dir = tempfile::tempdir().unwrap();
    let dsm_dir = shared_data().join("sandpyper-mar/dsm");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dsm_dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert_eq!(files.len(), 9);
    for src in files.iter().step_by(4) {
        let dsm = read_f32(src).unwrap();
        let t = dsm.georef.transform;
        let mut positions = Vec::new();
        for row in 0..dsm.height {
            for col in 0..dsm.width {
                let z = dsm.data[row * dsm.width + col];
                if z > -1000.0 && z.is_finite() {
                    let (x, y) = t.pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
                    positions.push([x, y, z as f64]);
                }
            }
        }
        // In process, from the exact f32 heights: the same cells, bit for bit.
        let lattice = timesift_raster::Lattice::with_cells(
            t.origin_x,
            t.origin_y,
            t.pixel_width,
            -t.pixel_height,
            dsm.width,
            dsm.height,
        )
        .unwrap();
        let options = timesift_raster::DemOptions {
            max_gap: 0,
            ..Default::default()
        };
        let exact = timesift_raster::grid_cloud(&positions, &lattice, &options).unwrap();
        for (a, b) in exact.height.iter().zip(&dsm.data) {
            if *b > -1000.0 {
                assert_eq!(a.to_bits(), b.to_bits());
            } else {
                assert!(a.is_nan());
            }
        }
        let cloud = dir.path().join("centres.laz");
        // LAS stores scaled integers: 1e-7 m for heights, below the f32 resolution of heights
        // above 1 m.
        let options = LasWriteOptions {
            scale: [1e-5, 1e-5, 1e-7],
        };
        let pc = PointCloud {
            positions: positions.clone(),
            colors: None,
            attributes: Vec::new(),
            crs: Crs::Epsg(32754),
        };
        write_las(&cloud, &pc, &options).unwrap();
        let out = dir.path().join("regridded.tif");
        let (ok, stdout, err) = timesift(&[
            "dem",
            cloud.to_str().unwrap(),
            "--like",
            src.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        println!("{}: {}", src.display(), stdout.lines().next().unwrap_or(""));
        let mut exact = 0;
        let back = read_f32(&out).unwrap();
        assert_eq!((back.width, back.height), (dsm.width, dsm.height));
        assert_eq!(back.georef.transform, dsm.georef.transform);
        assert_eq!(back.georef.crs, Crs::Epsg(32754));
        assert_eq!(back.georef.nodata, Some(-32767.0));
        let mut valid = 0;
        for (a, b) in back.data.iter().zip(&dsm.data) {
            if *b > -1000.0 {
                assert!((a - b).abs() <= 5e-8 + b.abs() * f32::EPSILON, "{a} vs {b}");
                exact += (a.to_bits() == b.to_bits()) as usize;
                valid += 1;
            } else {
                assert_eq!(*a, -32767.0);
            }
        }
        assert_eq!(valid, positions.len());
        println!("{exact} of {valid} heights bit for bit, the others within the LAZ resolution");
        let count = read_f32(&dir.path().join("regridded_count.tif")).unwrap();
        assert!(
            count
                .data
                .iter()
                .zip(&dsm.data)
                .all(|(n, z)| *n == if *z > -1000.0 { 1.0 } else { 0.0 })
        );
    }
}

#[test]
fn dem_command_errors_name_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dem.tif");
    let missing = dir.path().join("missing.laz");
    let (ok, _, err) = timesift(&[
        "dem",
        missing.to_str().unwrap(),
        "--cell",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("missing.laz"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");

    let cloud = dir.path().join("c.laz");
    let pc = PointCloud {
        positions: vec![[10.0, 20.0, 1.0], [12.0, 23.0, 2.0]],
        colors: None,
        attributes: Vec::new(),
        crs: Crs::Local,
    };
    write_las(&cloud, &pc, &LasWriteOptions::default()).unwrap();
    let (ok, _, err) = timesift(&[
        "dem",
        cloud.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("--cell"), "{err}");
    let (ok, _, err) = timesift(&[
        "dem",
        cloud.to_str().unwrap(),
        "--cell",
        "-2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("-2"), "{err}");
    let (ok, stdout, err) = timesift(&[
        "dem",
        cloud.to_str().unwrap(),
        "--cell",
        "0.5",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    // x 10..12 and y 20..23 in 0.5 m cells, edges on multiples of 0.5; a point on a cell edge
    // belongs to the cell east or south of it, so (12, 23) and (10, 20) add a column and a row:
    // 5 × 7 cells, 2 heights.
    assert!(
        stdout.contains("2 points -> 5 × 7 cells, 2 with a height"),
        "{stdout}"
    );
}

#[test]
fn a_closed_pipe_ends_the_command_quietly() {
    // `timesift dem … | head -0`: the reader is gone before the summary is printed.
    let dir = tempfile::tempdir().unwrap();
    let cloud = dir.path().join("c.laz");
    let pc = PointCloud {
        positions: (0..20_000)
            .map(|i| [(i % 200) as f64 * 0.1, (i / 200) as f64 * 0.1, 1.0])
            .collect(),
        colors: None,
        attributes: Vec::new(),
        crs: Crs::Local,
    };
    write_las(&cloud, &pc, &LasWriteOptions::default()).unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args(["dem", cloud.to_str().unwrap(), "--cell", "0.2", "--out"])
        .arg(dir.path().join("dem.tif"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}
