//! The libmv (Blender camera-tracking) problems of ../shared/data/libmv-ba: read, converted and
//! solved to the final cost Ceres 2.2 reaches on the same problem (f, k1, k2 and every pose but the
//! first free; SPARSE_SCHUR, default tolerances; run by `cargo xtask bench bundle`).
//! With 333–500 cameras and 26–71 points, the solver eliminates the poses (as Ceres does); a second
//! run eliminating the points (a dense ~2000–3000 parameter camera system) reaches the same cost.

use std::path::PathBuf;

use timesift_bundle::libmv::from_libmv;
use timesift_bundle::{BundleOptions, cost, solve};
use timesift_io::libmv::read_libmv;

fn problem_path(k: usize) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/libmv-ba")
        .join(format!("problem_0{k}.bin"))
}

#[test]
fn libmv_problems_read_with_the_readme_counts() {
    for (k, cameras, points, markers) in
        [(1, 333, 26, 5421), (2, 440, 71, 16718), (3, 500, 37, 6184)]
    {
        let p = read_libmv(&problem_path(k)).expect("read");
        assert!(p.pixel_space);
        assert_eq!(
            (p.cameras.len(), p.points.len(), p.markers.len()),
            (cameras, points, markers)
        );
    }
}

#[test]
fn libmv_problems_solve() {
    // Ceres 2.2 final costs (pyceres/pycolmap, SPARSE_SCHUR, trivial loss, default tolerances).
    for (k, ceres) in [(1, 4530.471408), (2, 5207.924491), (3, 297.042410)] {
        let raw = read_libmv(&problem_path(k)).expect("read");
        let mut p = from_libmv(&raw).expect("convert");
        let before = cost(&p, &timesift_bundle::Loss::Trivial);
        let report = solve(&mut p, &BundleOptions::default()).expect("solve");
        println!(
            "problem_0{k}: cost {before:.6e} → {:.6e} in {} iterations ({:?}), RMS {:.4} px",
            report.final_cost, report.iterations, report.termination, report.rms_px
        );
        assert!(report.final_cost <= before);
        assert!(
            report.final_cost <= ceres * 1.001,
            "{} vs Ceres {ceres}",
            report.final_cost
        );
    }
}

#[test]
fn truncated_and_bad_files_are_errors() {
    let bytes = std::fs::read(problem_path(1)).expect("read");
    let dir = tempfile::tempdir().expect("tmp");
    let cut = dir.path().join("cut.bin");
    std::fs::write(&cut, &bytes[..bytes.len() - 3]).expect("write");
    let e = read_libmv(&cut).unwrap_err().to_string();
    assert!(e.contains("cut.bin") && e.contains("bytes follow"), "{e}");
    let mut bad = bytes.clone();
    bad[0] = b'x';
    let path = dir.path().join("bad.bin");
    std::fs::write(&path, &bad).expect("write");
    let e = read_libmv(&path).unwrap_err().to_string();
    assert!(e.contains("byte 0"), "{e}");
}
