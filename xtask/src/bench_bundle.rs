//! `cargo xtask bench bundle [--problem FILE] [--json]`: solves the BAL problems of
//! `../shared/data/bal` (Huber loss of scale 1, as Ceres's `bundle_adjuster --robustify`) and the
//! libmv problems of `../shared/data/libmv-ba` (trivial loss, f/k1/k2 and all poses but the first
//! free, as `libmv_bundle_adjuster`) with timesift's bundle adjuster, and the same problems with
//! Ceres (pyceres + pycolmap, SPARSE_SCHUR) with 1 and 2 threads in the same run; prints costs,
//! iterations, times and the time ratios.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use timesift_bundle::bal::from_bal;
use timesift_bundle::libmv::from_libmv;
use timesift_bundle::{BundleOptions, Loss, solve};
use timesift_io::bal::read_bal;
use timesift_io::libmv::read_libmv;

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

const CERES_SCRIPT: &str = include_str!("../scripts/ceres_ba.py");

/// One problem to solve: a BAL text file (Huber(1) loss, as Ceres's `bundle_adjuster
/// --robustify` that produced the README's reference costs) or a libmv binary (trivial loss, as
/// `libmv_bundle_adjuster`).
enum Problem {
    Bal(PathBuf),
    Libmv(PathBuf),
}

impl Problem {
    fn path(&self) -> &Path {
        match self {
            Problem::Bal(p) | Problem::Libmv(p) => p,
        }
    }
}

fn libmv_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/libmv-ba")
}

fn files_with(dir: &Path, ext: &str) -> anyhow::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| dir.display().to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == ext))
        .collect();
    v.sort();
    Ok(v)
}

/// Ceres (pyceres 2.6 / pycolmap 4.2, Ceres 2.2) on the same problem: JSON of one run.
fn ceres(script: &Path, problem: &Problem, threads: usize) -> anyhow::Result<serde_json::Value> {
    let mut cmd = std::process::Command::new("python3");
    cmd.arg(script).arg(problem.path());
    match problem {
        Problem::Bal(_) => cmd.args([
            "--format",
            "bal",
            "--loss",
            "huber",
            "--max-iterations",
            "500",
        ]),
        Problem::Libmv(_) => cmd.args(["--format", "libmv", "--max-iterations", "500"]),
    };
    let out = cmd
        .args(["--threads", &threads.to_string(), "--repeat", "3"])
        .output()
        .context("running python3")?;
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().rev().find(|l| l.trim_start().starts_with('{'));
    match line {
        Some(l) => Ok(serde_json::from_str(l)?),
        None => bail!(
            "Ceres side failed (pip install pyceres pycolmap): {}",
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("")
        ),
    }
}

/// Runs the benchmark.
pub fn run(problem: Option<PathBuf>, json: bool) -> anyhow::Result<()> {
    let dir = bal_dir();
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("bal_manifest.json"))?)?;
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("reference.json"))?)?;
    let problems: Vec<Problem> = match problem {
        Some(p) if p.extension().is_some_and(|e| e == "bin") => vec![Problem::Libmv(p)],
        Some(p) => vec![Problem::Bal(p)],
        None => files_with(&dir, "txt")?
            .into_iter()
            .map(Problem::Bal)
            .chain(
                files_with(&libmv_dir(), "bin")?
                    .into_iter()
                    .map(Problem::Libmv),
            )
            .collect(),
    };
    if problems.is_empty() {
        bail!("no problem found in {}", dir.display());
    }
    let tmp = std::env::temp_dir().join(format!("timesift-bench-bundle-{}", std::process::id()));
    std::fs::create_dir_all(&tmp)?;
    let script = tmp.join("ceres_ba.py");
    std::fs::write(&script, CERES_SCRIPT)?;
    let mut rows = Vec::new();
    for problem in &problems {
        let file = problem.path();
        let name = file
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default()
            .to_string();
        let (mut p, loss, readme) = match problem {
            Problem::Bal(_) => {
                let (pp, size) = camera_layout(&manifest, file)?;
                let bal = read_bal(file)?;
                (
                    from_bal(&bal, &pp, size)?,
                    Loss::Huber(1.0),
                    reference[&name].as_f64(),
                )
            }
            Problem::Libmv(_) => (from_libmv(&read_libmv(file)?)?, Loss::Trivial, None),
        };
        let options = BundleOptions {
            loss,
            ..BundleOptions::default()
        };
        // Best of three, like the Ceres side.
        let mut seconds = f64::INFINITY;
        let mut report = None;
        for _ in 0..3 {
            let mut q = p.clone();
            let t = Instant::now();
            let r = solve(&mut q, &options)?;
            seconds = seconds.min(t.elapsed().as_secs_f64());
            report = Some(r);
        }
        let report = report.context("no run")?;
        solve(&mut p, &options)?;
        let c1 = ceres(&script, problem, 1);
        let c2 = ceres(&script, problem, 2);
        let get = |c: &anyhow::Result<serde_json::Value>, k: &str| {
            c.as_ref()
                .ok()
                .and_then(|v| v[k].as_f64())
                .unwrap_or(f64::NAN)
        };
        rows.push(serde_json::json!({
            "problem": name,
            "cameras": p.images.len(),
            "points": p.points.len(),
            "observations": p.observations.len(),
            "loss": format!("{loss:?}"),
            "initial_cost": report.initial_cost,
            "final_cost": report.final_cost,
            "readme_ceres_final_cost": readme,
            "iterations": report.iterations,
            "termination": format!("{:?}", report.termination),
            "seconds": seconds,
            "ceres_1_thread": c1.as_ref().ok(),
            "ceres_2_threads": c2.as_ref().ok(),
            "ceres_error": c1.as_ref().err().map(|e| e.to_string()),
            "ratio_ceres1_over_timesift": get(&c1, "seconds") / seconds,
            "ratio_ceres2_over_timesift": get(&c2, "seconds") / seconds,
            "final_cost_vs_ceres": report.final_cost / get(&c1, "final_cost") - 1.0,
        }));
    }
    let _ = std::fs::remove_dir_all(&tmp);
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "timesift (rayon, {} threads) against Ceres SPARSE_SCHUR (pyceres/pycolmap), same problem and loss; times best of 3",
        rayon::current_num_threads()
    );
    println!(
        "{:<30} {:>13} {:>12} {:>12} {:>9} {:>5} {:>8} {:>8} {:>8} {:>7} {:>7}",
        "problem",
        "initial cost",
        "final cost",
        "Ceres final",
        "Δ cost",
        "iters",
        "time s",
        "Ceres1 s",
        "Ceres2 s",
        "C1/ts",
        "C2/ts"
    );
    for r in &rows {
        let ceres_final = r["ceres_1_thread"]["final_cost"]
            .as_f64()
            .unwrap_or(f64::NAN);
        println!(
            "{:<30} {:>13.3} {:>12.3} {:>12.3} {:>8.4}% {:>5} {:>8.3} {:>8.3} {:>8.3} {:>7.2} {:>7.2}",
            r["problem"].as_str().unwrap_or(""),
            r["initial_cost"].as_f64().unwrap_or(f64::NAN),
            r["final_cost"].as_f64().unwrap_or(f64::NAN),
            ceres_final,
            100.0 * r["final_cost_vs_ceres"].as_f64().unwrap_or(f64::NAN),
            r["iterations"],
            r["seconds"].as_f64().unwrap_or(f64::NAN),
            r["ceres_1_thread"]["seconds"].as_f64().unwrap_or(f64::NAN),
            r["ceres_2_threads"]["seconds"].as_f64().unwrap_or(f64::NAN),
            r["ratio_ceres1_over_timesift"].as_f64().unwrap_or(f64::NAN),
            r["ratio_ceres2_over_timesift"].as_f64().unwrap_or(f64::NAN),
        );
        if let Some(e) = r["ceres_error"].as_str() {
            println!("    {e}");
        }
        if let Some(readme) = r["readme_ceres_final_cost"].as_f64() {
            println!("    README reference final cost {readme:.3}");
        }
    }
    Ok(())
}
