//! `cargo xtask bench bundle [--problem FILE] [--json]`: solves the BAL problems of
//! `../shared/data/bal` (or one given file) with timesift's bundle adjuster, Huber loss of scale 1
//! as Ceres's `bundle_adjuster --robustify`, and prints initial cost, final cost, iterations and
//! time beside Ceres's reference final cost from the data set's `reference.json`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use timesift_bundle::bal::from_bal;
use timesift_bundle::{BundleOptions, Loss, solve};
use timesift_io::bal::read_bal;

fn bal_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/bal")
}

/// Principal point of each camera, and the image size.
type CameraLayout = (Vec<(f64, f64)>, (u32, u32));

/// Principal points and image size of a BAL file from the manifest (scene = file name prefix).
fn camera_layout(manifest: &serde_json::Value, file: &Path) -> anyhow::Result<CameraLayout> {
    let name = file
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or_default();
    let scene = name.split('-').next().unwrap_or_default();
    let cams = manifest["datasets"][scene]["principal_point_per_camera"]
        .as_array()
        .with_context(|| format!("{name}: scene `{scene}` not in bal_manifest.json"))?;
    let pp = cams
        .iter()
        .map(|c| {
            (
                c["cx"].as_f64().unwrap_or(0.0),
                c["cy"].as_f64().unwrap_or(0.0),
            )
        })
        .collect();
    let w = cams[0]["width"].as_u64().unwrap_or(0) as u32;
    let h = cams[0]["height"].as_u64().unwrap_or(0) as u32;
    Ok((pp, (w, h)))
}

/// Runs the benchmark.
pub fn run(problem: Option<PathBuf>, json: bool) -> anyhow::Result<()> {
    let dir = bal_dir();
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("bal_manifest.json"))?)?;
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("reference.json"))?)?;
    let files: Vec<PathBuf> = match problem {
        Some(p) => vec![p],
        None => {
            let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "txt"))
                .collect();
            v.sort();
            v
        }
    };
    if files.is_empty() {
        bail!("no BAL problem found in {}", dir.display());
    }
    let mut rows = Vec::new();
    for file in files {
        let (pp, size) = camera_layout(&manifest, &file)?;
        let bal = read_bal(&file)?;
        let mut p = from_bal(&bal, &pp, size)?;
        let t = Instant::now();
        let report = solve(
            &mut p,
            &BundleOptions {
                loss: Loss::Huber(1.0),
                ..BundleOptions::default()
            },
        )?;
        let seconds = t.elapsed().as_secs_f64();
        let name = file
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default()
            .to_string();
        let ceres = reference[&name].as_f64();
        rows.push(serde_json::json!({
            "problem": name,
            "cameras": bal.cameras.len(),
            "points": bal.points.len(),
            "observations": bal.observations.len(),
            "initial_cost": report.initial_cost,
            "final_cost": report.final_cost,
            "ceres_final_cost": ceres,
            "iterations": report.iterations,
            "termination": format!("{:?}", report.termination),
            "seconds": seconds,
        }));
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        println!(
            "{:<32} {:>14} {:>12} {:>12} {:>6} {:>8}",
            "problem", "initial cost", "final cost", "Ceres final", "iters", "time s"
        );
        for r in &rows {
            println!(
                "{:<32} {:>14.3} {:>12.3} {:>12} {:>6} {:>8.2}",
                r["problem"].as_str().unwrap_or(""),
                r["initial_cost"].as_f64().unwrap_or(f64::NAN),
                r["final_cost"].as_f64().unwrap_or(f64::NAN),
                r["ceres_final_cost"]
                    .as_f64()
                    .map_or("-".to_string(), |c| format!("{c:.3}")),
                r["iterations"],
                r["seconds"].as_f64().unwrap_or(f64::NAN)
            );
        }
        println!(
            "Ceres itself is not run here yet (pyceres): compare times with ../shared/data/bal/README.md."
        );
    }
    Ok(())
}
