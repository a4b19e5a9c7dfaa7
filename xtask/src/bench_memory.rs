//! `cargo xtask bench memory`: the peak resident memory of the commands that handle the
//! largest data, each a process of its own (`VmHWM`), against the budget the cluster planner
//! asks Slurm for (`src/tasks/plan.rs`, the `mem/task` column of `timesift run --executor
//! slurm --dry-run`) or, for the two stand-alone commands, a budget stated here:
//!
//! - `timesift features` on a 100 MP image (lund's first photo upsampled): 512 MiB + the
//!   extractor's 512 MiB scale-space budget + 8 B per pixel (the decoded image and its grey);
//! - the dense stage of `rendered-mar` (real texture, two epochs, at level 2): the planner's
//!   larger of `dense-pass-*` and `dense-fuse`;
//! - the ortho stage of `rendered-mar` on 2 cm cells (a mosaic of some 10⁸ cells, streamed in
//!   row bands): the planner's `ortho`;
//! - `timesift dem` of a 30-million-point LAZ cloud: 512 MiB + 48 B per point (the planner's
//!   `dem` formula).
//!
//! Prints a table and fails when a peak exceeds its budget.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};

use crate::bench_dense_time::{DenseRun, time_command};
use crate::bench_film::copy_tree;

/// One measured command.
struct Row {
    what: String,
    wall: f64,
    peak_mib: f64,
    budget_mib: f64,
    budget: String,
}

fn timesift_exe() -> anyhow::Result<PathBuf> {
    let root = crate::api::workspace_root();
    let status = Command::new("cargo")
        .args(["build", "--release", "--quiet", "--bin", "timesift"])
        .current_dir(&root)
        .status()
        .context("cargo build")?;
    if !status.success() {
        bail!("cargo build --release --bin timesift failed");
    }
    Ok(root.join("target/release/timesift"))
}

/// The planner's memory per task of each step, MiB, from `--dry-run`'s table.
fn planned_memory(exe: &Path, dir: &Path) -> anyhow::Result<Vec<(String, f64)>> {
    let out = Command::new(exe)
        .args(["run", "--executor", "slurm", "--dry-run"])
        .arg(dir)
        .output()?;
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    let mut steps = Vec::new();
    for line in text.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        if let Some(at) = words.iter().position(|w| *w == "M")
            && at >= 1
            && let Ok(mib) = words[at - 1].parse::<f64>()
        {
            steps.push((words[0].to_string(), mib));
        }
    }
    if steps.is_empty() {
        bail!("no plan in the dry run's output:\n{text}");
    }
    Ok(steps)
}

fn planned(plan: &[(String, f64)], step: &dyn Fn(&str) -> bool) -> anyhow::Result<f64> {
    plan.iter()
        .filter(|(name, _)| step(name))
        .map(|(_, m)| *m)
        .reduce(f64::max)
        .context("a step missing from the plan")
}

/// `timesift ARGS` timed as a process of its own on 2 threads.
fn on_two_threads<S: AsRef<std::ffi::OsStr>>(
    exe: &Path,
    args: impl IntoIterator<Item = S>,
) -> anyhow::Result<DenseRun> {
    let mut command = Command::new(exe);
    command.args(args).env("RAYON_NUM_THREADS", "2");
    time_command(&mut command, 2)
}

/// `timesift run DIR -q --from S --to S` timed on 2 threads.
fn stage(exe: &Path, dir: &Path, name: &str) -> anyhow::Result<DenseRun> {
    let dir = dir.as_os_str();
    on_two_threads(
        exe,
        [
            "run".as_ref(),
            "-q".as_ref(),
            "--from".as_ref(),
            name.as_ref(),
            "--to".as_ref(),
            name.as_ref(),
            dir,
        ],
    )
}

/// `timesift run DIR -q ARGS`, which must succeed (the stages before the measured one).
fn run_quietly(exe: &Path, dir: &Path, args: &[&str], what: &str) -> anyhow::Result<()> {
    let status = Command::new(exe)
        .args(["run", "-q"])
        .args(args)
        .arg(dir)
        .status()?;
    if !status.success() {
        bail!("{}: {what} failed", dir.display());
    }
    Ok(())
}

pub fn run(out: &Path) -> anyhow::Result<()> {
    let exe = timesift_exe()?;
    let _ = std::fs::remove_dir_all(out);
    std::fs::create_dir_all(out)?;
    let mut rows = Vec::new();

    // Features of a 100 MP image.
    let lund = crate::shared_data().join("opensfm/lund/images/01.jpg");
    let big_path = out.join("100mp.png");
    let big = image::open(&lund)?.resize_exact(11548, 8660, image::imageops::FilterType::Triangle);
    big.to_luma8().save(&big_path)?;
    drop(big);
    let pixels = 11548.0 * 8660.0;
    let features_out = out.join("100mp.txt");
    let run = on_two_threads(
        &exe,
        [
            "features".as_ref(),
            big_path.as_os_str(),
            "--out".as_ref(),
            features_out.as_os_str(),
        ],
    )?;
    rows.push(Row {
        what: "timesift features, 100 MP image (11548 × 8660), 2 threads".into(),
        wall: run.wall,
        peak_mib: run.peak_mib,
        budget_mib: 1024.0 + 8.0 * pixels / 1048576.0,
        budget: "512 MiB + 512 MiB scale space + 8 B per pixel".into(),
    });

    // Dense and a large ortho of rendered-mar.
    let mar = out.join("rendered-mar");
    copy_tree(&crate::shared_data().join("rendered-mar"), &mar, &[])?;
    let toml = mar.join("project.toml");
    let text =
        std::fs::read_to_string(&toml)? + "\n[dense]\nlevel = 2\n\n[raster]\northo_cell = 0.02\n";
    std::fs::write(&toml, text)?;
    run_quietly(&exe, &mar, &["--to", "align"], "the stages before dense")?;
    let plan = planned_memory(&exe, &mar)?;
    let run = stage(&exe, &mar, "dense")?;
    rows.push(Row {
        what: "dense stage, rendered-mar (2 epochs of 22 images), level 2, 2 threads".into(),
        wall: run.wall,
        peak_mib: run.peak_mib,
        budget_mib: planned(&plan, &|s| s.starts_with("dense-pass") || s == "dense-fuse")?,
        budget: "planner: the larger of dense-pass-k and dense-fuse".into(),
    });
    run_quietly(
        &exe,
        &mar,
        &["--from", "dem", "--to", "dem"],
        "the dem stage",
    )?;
    let run = stage(&exe, &mar, "ortho")?;
    let cells = std::fs::read_to_string(mar.join("out/grid.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .map(|g| format!("{}", g["ortho_size"]))
        .unwrap_or_default();
    rows.push(Row {
        what: format!("ortho stage, rendered-mar on 2 cm cells {cells}, 2 threads"),
        wall: run.wall,
        peak_mib: run.peak_mib,
        budget_mib: planned(&plan, &|s| s == "ortho")?,
        budget: "planner: ortho".into(),
    });

    // `timesift dem` of a large cloud: 30 million points of a rough surface.
    let points = 30_000_000usize;
    let cloud_path = out.join("large.laz");
    let side = (points as f64).sqrt() as usize;
    let positions: Vec<[f64; 3]> = (0..points)
        .map(|k| {
            let (i, j) = ((k % side) as f64, (k / side) as f64);
            let x = 500_000.0 + i * 0.1 + 0.03 * ((k * 7919) % 13) as f64;
            let y = 5_000_000.0 + j * 0.1 + 0.03 * ((k * 104_729) % 11) as f64;
            [
                x,
                y,
                10.0 + (i * 0.01).sin() * 3.0 + (j * 0.013).cos() * 2.0,
            ]
        })
        .collect();
    timesift_io::pointcloud::write_las(
        &cloud_path,
        &timesift_io::pointcloud::PointCloud {
            positions,
            colors: None,
            attributes: Vec::new(),
            crs: timesift_io::coords::Crs::Epsg(32632),
        },
        &timesift_io::pointcloud::LasWriteOptions::default(),
    )?;
    let dem_out = out.join("large_dem.tif");
    let run = on_two_threads(
        &exe,
        [
            "dem".as_ref(),
            cloud_path.as_os_str(),
            "--cell".as_ref(),
            "0.5".as_ref(),
            "--out".as_ref(),
            dem_out.as_os_str(),
        ],
    )?;
    rows.push(Row {
        what: "timesift dem, 30 million points (LAZ), 0.5 m cells, 2 threads".into(),
        wall: run.wall,
        peak_mib: run.peak_mib,
        budget_mib: 512.0 + 48.0 * points as f64 / 1048576.0,
        budget: "512 MiB + 48 B per point (the planner's dem)".into(),
    });

    println!("| command | wall s | peak MiB | budget MiB | budget from | within |");
    println!("|---|---|---|---|---|---|");
    let mut over = Vec::new();
    for r in &rows {
        let within = r.peak_mib <= r.budget_mib;
        if !within {
            over.push(r.what.clone());
        }
        println!(
            "| {} | {:.1} | {:.0} | {:.0} | {} | {} |",
            r.what,
            r.wall,
            r.peak_mib,
            r.budget_mib,
            r.budget,
            if within { "yes" } else { "NO" }
        );
    }
    if !over.is_empty() {
        bail!("over budget: {}", over.join("; "));
    }
    Ok(())
}
