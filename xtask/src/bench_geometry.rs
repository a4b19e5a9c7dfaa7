//! `cargo xtask bench geometry`: timesift's RANSAC against OpenCV's `findHomography` and
//! `findEssentialMat` (Python, `pip install opencv-python-headless`) on the same 2,000
//! correspondences with 50 % outliers, in one run, printing the time ratios.

use std::io::Write;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};
use nalgebra::{UnitQuaternion, Vector2, Vector3};
use timesift_core::{Pose, SeededRng};
use timesift_geometry::essential::EssentialEstimator;
use timesift_geometry::homography::HomographyEstimator;
use timesift_geometry::ransac::{RansacOptions, ransac};

const FOCAL: f64 = 1000.0;
const CX: f64 = 800.0;
const CY: f64 = 600.0;

/// 2,000 pixel correspondences between two 1600 × 1200 views, half of them uniform outliers;
/// `planar` puts the scene on a plane (homography), otherwise depths vary (essential matrix).
fn correspondences(seed: u64, planar: bool) -> (Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
    let mut rng = SeededRng::new(seed);
    let axis = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    let rotation = UnitQuaternion::from_scaled_axis(axis * 0.2);
    let pose = Pose::from_rotation_and_center(rotation, &Vector3::new(1.0, 0.1, 0.05));
    let (mut a, mut b) = (Vec::new(), Vec::new());
    while a.len() < 1000 {
        let ray = Vector3::new(
            rng.uniform_range(-0.4, 0.4),
            rng.uniform_range(-0.3, 0.3),
            1.0,
        );
        let depth = if planar {
            5.0 / Vector3::new(0.1, -0.2, 1.0).normalize().dot(&ray)
        } else {
            rng.uniform_range(3.0, 8.0)
        };
        let q = pose.transform_point(&(ray * depth));
        if q.z < 1.0 || (q.x / q.z).abs() > 0.7 || (q.y / q.z).abs() > 0.55 {
            continue;
        }
        let noise = |rng: &mut SeededRng| Vector2::new(rng.normal(), rng.normal()) * 0.5;
        a.push(Vector2::new(CX + FOCAL * ray.x, CY + FOCAL * ray.y) + noise(&mut rng));
        b.push(Vector2::new(CX + FOCAL * q.x / q.z, CY + FOCAL * q.y / q.z) + noise(&mut rng));
    }
    for _ in 0..1000 {
        a.push(Vector2::new(
            rng.uniform_range(0.0, 1600.0),
            rng.uniform_range(0.0, 1200.0),
        ));
        b.push(Vector2::new(
            rng.uniform_range(0.0, 1600.0),
            rng.uniform_range(0.0, 1200.0),
        ));
    }
    (a, b)
}

fn write_csv(path: &Path, a: &[Vector2<f64>], b: &[Vector2<f64>]) -> anyhow::Result<()> {
    let mut f = std::fs::File::create(path)?;
    for (p, q) in a.iter().zip(b) {
        writeln!(f, "{},{},{},{}", p.x, p.y, q.x, q.y)?;
    }
    Ok(())
}

const OPENCV_SCRIPT: &str = r#"
import json, sys, time
import numpy as np
import cv2
cv2.setNumThreads(1)
def load(p):
    d = np.loadtxt(p, delimiter=",")
    return np.ascontiguousarray(d[:, :2]), np.ascontiguousarray(d[:, 2:])
runs = int(sys.argv[3])
out = {}
p1, p2 = load(sys.argv[1])
times = []
for _ in range(runs):
    t = time.perf_counter()
    H, m = cv2.findHomography(p1, p2, cv2.RANSAC, 2.0, maxIters=10000, confidence=0.999)
    times.append(time.perf_counter() - t)
out["homography"] = {"median_s": float(np.median(times)), "inliers": int(m.sum())}
p1, p2 = load(sys.argv[2])
times = []
for _ in range(runs):
    t = time.perf_counter()
    E, m = cv2.findEssentialMat(p1, p2, focal=1000.0, pp=(800.0, 600.0), method=cv2.RANSAC, prob=0.999, threshold=2.0)
    times.append(time.perf_counter() - t)
out["essential"] = {"median_s": float(np.median(times)), "inliers": int(m.sum())}
out["opencv"] = cv2.__version__
print(json.dumps(out))
"#;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs the comparison; `runs` repetitions of each estimator, single-threaded on both sides.
pub fn run(runs: usize) -> anyhow::Result<()> {
    let dir = std::env::temp_dir().join(format!("timesift-bench-geometry-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (ha, hb) = correspondences(3, true);
    let (ea, eb) = correspondences(2, false);
    write_csv(&dir.join("homography.csv"), &ha, &hb)?;
    write_csv(&dir.join("essential.csv"), &ea, &eb)?;
    let options = RansacOptions {
        max_error: 2.0,
        confidence: 0.999,
        ..RansacOptions::default()
    };

    // Median time over `runs` seeds, and the inlier count of the last run.
    let timed = |fit: &dyn Fn(u64) -> anyhow::Result<usize>| -> anyhow::Result<(f64, usize)> {
        let mut times = Vec::with_capacity(runs);
        let mut inliers = 0;
        for run in 0..runs {
            let t = Instant::now();
            inliers = fit(run as u64)?;
            times.push(t.elapsed().as_secs_f64());
        }
        Ok((median(times), inliers))
    };
    let rays = |p: &[Vector2<f64>]| -> Vec<Vector3<f64>> {
        p.iter()
            .map(|q| Vector3::new((q.x - CX) / FOCAL, (q.y - CY) / FOCAL, 1.0))
            .collect()
    };
    let (ra, rb) = (rays(&ea), rays(&eb));
    let homography = timed(&|seed| {
        let est = HomographyEstimator { p1: &ha, p2: &hb };
        Ok(ransac(&est, &RansacOptions { seed, ..options })?.num_inliers)
    })?;
    let essential = timed(&|seed| {
        let est = EssentialEstimator {
            x1: &ra,
            x2: &rb,
            focal_px: FOCAL,
        };
        Ok(ransac(&est, &RansacOptions { seed, ..options })?.num_inliers)
    })?;
    let ours = [
        ("homography", homography.0, homography.1),
        ("essential", essential.0, essential.1),
    ];

    let script = dir.join("opencv_ransac.py");
    std::fs::write(&script, OPENCV_SCRIPT)?;
    let output = Command::new("python3")
        .arg(&script)
        .arg(dir.join("homography.csv"))
        .arg(dir.join("essential.csv"))
        .arg(runs.to_string())
        .output()
        .context("running python3")?;
    if !output.status.success() {
        bail!(
            "OpenCV side failed (install it with `pip install opencv-python-headless`): {}",
            String::from_utf8_lossy(&output.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
    }
    let cv: serde_json::Value = serde_json::from_slice(&output.stdout)?;
    println!(
        "2,000 correspondences, 50 % outliers, threshold 2 px, confidence 0.999, median of {runs} runs, 1 thread each"
    );
    println!("OpenCV {}", cv["opencv"].as_str().unwrap_or("?"));
    println!(
        "{:<12} {:>14} {:>10} {:>14} {:>10} {:>22}",
        "estimator", "timesift ms", "inliers", "OpenCV ms", "inliers", "ratio OpenCV/timesift"
    );
    for (name, t, n) in ours {
        let cv_t = cv[name]["median_s"].as_f64().unwrap_or(f64::NAN);
        let cv_n = cv[name]["inliers"].as_u64().unwrap_or(0);
        println!(
            "{name:<12} {:>14.3} {n:>10} {:>14.3} {cv_n:>10} {:>22.2}",
            t * 1e3,
            cv_t * 1e3,
            cv_t / t
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
