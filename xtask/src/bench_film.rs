//! `cargo xtask bench film`: scanned film with and without fiducial handling, on `synth
//! archival`. The scene's images are scans, each with a transform of its own (shift of tens of
//! pixels, rotation up to 1°, film shrinkage, differential scale and shear). Printed:
//! - the marks: position error against `truth/fiducials.csv` (RMS, largest), the interior
//!   orientation's error over the frame against `truth/scan_transforms.csv`, and its residuals
//!   per scan;
//! - the orientation with fiducials (every scan resampled to its camera's frame) and without
//!   (the same project, `[camera.fiducials]`, template and principal point removed: the scans
//!   used as images, one calibration per film camera, as COLMAP or ODM would): per epoch,
//!   check-point RMSE (E, N, H) in GSD and camera-centre RMSE;
//! - with `--products` (default), the DEM of each epoch against its true surface (dense and dem
//!   stages, `[dense]` quick): mean and NMAD in GSD, with the align stage's cameras and, on the
//!   scans with fiducials, with the true cameras (`truth/cameras.json`): the floor the dense
//!   stage sets, which the orientation's DEMs are judged against.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use timesift::Project;
use timesift::config::DenseConfig;
use timesift::eval::{oriented_epochs, project_truth};
use timesift::report::{FiducialsReport, read_json};
use timesift::stages::{Stage, run};
use timesift_eval::accuracy::{EpochAccuracy, epoch_accuracy, ground_sampling_distance};
use timesift_eval::products::epoch_dem_error;
use timesift_eval::triple;

/// What to run.
pub struct FilmBench {
    pub seed: u64,
    pub out: PathBuf,
    pub products: bool,
}

/// `image,mark,u,v[,…]` rows by (image, mark).
fn mark_rows(
    path: &Path,
) -> anyhow::Result<std::collections::BTreeMap<(String, String), [f64; 2]>> {
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    let mut rows = std::collections::BTreeMap::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        rows.insert(
            (f[0].to_string(), f[1].to_string()),
            [f[2].parse()?, f[3].parse()?],
        );
    }
    Ok(rows)
}

/// The marks and interior orientations against the truth.
fn fiducial_figures(dir: &Path) -> anyhow::Result<String> {
    let truth = mark_rows(&dir.join("truth/fiducials.csv"))?;
    let found = mark_rows(&dir.join("out/fiducials.csv"))?;
    let errors: Vec<f64> = truth
        .iter()
        .filter_map(|(k, t)| found.get(k).map(|f| (f[0] - t[0]).hypot(f[1] - t[1])))
        .collect();
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len().max(1) as f64).sqrt();
    let max = errors.iter().copied().fold(0.0, f64::max);
    // The interior orientation over the frame: every 64 frame pixels, estimated against true.
    let report: FiducialsReport = read_json(&dir.join("out/fiducials.json"))?;
    let text = std::fs::read_to_string(dir.join("truth/scan_transforms.csv"))?;
    let mut io_errors = Vec::new();
    let mut residuals = Vec::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let a: Vec<f64> = f[1..].iter().map(|v| v.parse()).collect::<Result<_, _>>()?;
        let Some(scan) = report.images.iter().find(|s| s.image == f[0]) else {
            continue;
        };
        residuals.extend(scan.rms_px);
        let Some(m) = scan.scan_from_frame else {
            continue;
        };
        for i in (0..=512).step_by(64) {
            for j in (0..=512).step_by(64) {
                let (x, y) = (i as f64, j as f64);
                let w = m[2][0] * x + m[2][1] * y + m[2][2];
                let u = (m[0][0] * x + m[0][1] * y + m[0][2]) / w;
                let v = (m[1][0] * x + m[1][1] * y + m[1][2]) / w;
                let (tu, tv) = (a[0] * x + a[1] * y + a[2], a[3] * x + a[4] * y + a[5]);
                io_errors.push((u - tu).hypot(v - tv));
            }
        }
    }
    let io_rms =
        (io_errors.iter().map(|e| e * e).sum::<f64>() / io_errors.len().max(1) as f64).sqrt();
    let io_max = io_errors.iter().copied().fold(0.0, f64::max);
    residuals.sort_by(f64::total_cmp);
    let median = residuals
        .get(residuals.len() / 2)
        .copied()
        .unwrap_or(f64::NAN);
    Ok(format!(
        "Marks: {} of {} found, position error RMS {rms:.3} px, largest {max:.3} px (truth/fiducials.csv).\n\
         Interior orientation over the frame against the true scan transform: RMS {io_rms:.3} px, \
         largest {io_max:.3} px.\n\
         Interior-orientation residual RMS per scan: median {median:.3} px, largest {:.3} px \
         (out/fiducials.json, every scan).\n",
        errors.len(),
        truth.len(),
        residuals.last().copied().unwrap_or(f64::NAN),
    ))
}

/// The project without fiducial handling: the film keys removed from `[[camera]]`.
fn without_fiducials(with: &Path, without: &Path) -> anyhow::Result<()> {
    let _ = std::fs::remove_dir_all(without);
    copy_tree(with, without, &["out", "work"])?;
    let project = Project::load(with)?;
    let mut config = project.config.clone();
    for camera in &mut config.cameras {
        camera.fiducials = None;
        camera.fiducial_template = None;
        camera.principal_point_mm = None;
    }
    std::fs::write(without.join("project.toml"), toml::to_string(&config)?)?;
    Ok(())
}

/// Copies a folder, leaving out the top-level entries named in `skip`.
pub(crate) fn copy_tree(from: &Path, to: &Path, skip: &[&str]) -> anyhow::Result<()> {
    std::fs::create_dir_all(to)?;
    for entry in std::fs::read_dir(from)? {
        let entry = entry?;
        let name = entry.file_name();
        if skip.iter().any(|s| name == *s) {
            continue;
        }
        let target = to.join(&name);
        if entry.file_type()?.is_dir() {
            copy_tree(&entry.path(), &target, &[])?;
        } else {
            std::fs::copy(entry.path(), &target)?;
        }
    }
    Ok(())
}

/// The DEMs of the scans with fiducials made from the true orientation (the dense and dem
/// stages again, after the align stage's outputs are replaced by the truth's).
fn true_camera_dems(
    dir: &Path,
    spec: &timesift_synth::scene::SceneSpec,
) -> anyhow::Result<DemErrors> {
    let mut project = Project::load(dir)?;
    project.config.dense = DenseConfig::quick();
    timesift_eval::true_scene::write_true_orientation(dir, spec, 15.0)?;
    run(&project, Some(Stage::Dense), Some(Stage::Dem))?;
    let truth = project_truth(&project)?;
    let gsd = ground_sampling_distance(&truth)?;
    project
        .epochs
        .iter()
        .map(|epoch| {
            let e = epoch_dem_error(&truth.layout, &epoch.name)?
                .map(|(_, mean, _, nmad)| (mean / gsd, nmad / gsd));
            Ok((epoch.name.clone(), e))
        })
        .collect()
}

/// Each epoch's DEM error against the truth (mean, NMAD in GSD), when measured.
type DemErrors = Vec<(String, Option<(f64, f64)>)>;

/// Orientation (and products) of one variant.
fn variant(dir: &Path, products: bool) -> anyhow::Result<(Vec<EpochAccuracy>, DemErrors)> {
    let mut project = Project::load(dir)?;
    project.config.dense = DenseConfig::quick();
    run(&project, Some(Stage::Features), Some(Stage::Align))?;
    let truth = project_truth(&project)?;
    let gsd = ground_sampling_distance(&truth)?;
    let out = dir.join("out");
    let accuracy = epoch_accuracy(&truth, &oriented_epochs(&out)?, &out, gsd)?;
    let mut dems = Vec::new();
    if products {
        run(&project, Some(Stage::Dense), Some(Stage::Dem))?;
        for epoch in &project.epochs {
            let e = epoch_dem_error(&truth.layout, &epoch.name)?
                .map(|(_, mean, _, nmad)| (mean / gsd, nmad / gsd));
            dems.push((epoch.name.clone(), e));
        }
    }
    Ok((accuracy, dems))
}

pub fn run_bench(bench: &FilmBench) -> anyhow::Result<()> {
    std::fs::create_dir_all(&bench.out)?;
    let with = bench.out.join("archival");
    let without = bench.out.join("archival-no-fiducials");
    let _ = std::fs::remove_dir_all(&with);
    let spec = timesift_synth::scenes::build(
        "archival",
        timesift_synth::scenes::Scale::Small,
        bench.seed,
    )?;
    timesift_synth::writer::write_scene(
        &spec,
        &with,
        &timesift_synth::writer::WriteOptions::default(),
    )?;
    without_fiducials(&with, &without)?;
    let start = std::time::Instant::now();
    let outcome = timesift::commands::fiducials::fiducials(&Project::load(&with)?)?;
    let seconds = start.elapsed().as_secs_f64();
    let mut md = format!(
        "# Scanned film: archival (small, seed {}), with and without fiducials\n\n{}\nMeasured in {seconds:.2} s ({} scans).\n",
        bench.seed,
        fiducial_figures(&with)?,
        outcome.report.images.len()
    );
    let mut results = Vec::new();
    for (label, dir) in [("with fiducials", &with), ("without", &without)] {
        let start = std::time::Instant::now();
        let r =
            variant(dir, bench.products).with_context(|| format!("{label}: {}", dir.display()))?;
        println!("{label}: {:.1} s", start.elapsed().as_secs_f64());
        results.push((label, r));
    }
    if bench.products {
        let start = std::time::Instant::now();
        let dems = true_camera_dems(&with, &spec).context("true cameras")?;
        println!("true cameras: {:.1} s", start.elapsed().as_secs_f64());
        results.push(("true cameras", (Vec::new(), dems)));
    }
    md.push_str(
        "\n| epoch | fiducials | oriented | RMS px | check RMSE E / N / H (GSD) | centre RMSE E / N / H (m) | DEM mean / NMAD (GSD) |\n|---|---|---|---|---|---|---|\n",
    );
    let epochs: Vec<String> = results[0].1.0.iter().map(|a| a.epoch.clone()).collect();
    for epoch in &epochs {
        for (label, (accuracy, dems)) in &results {
            let dem = dems
                .iter()
                .find(|d| &d.0 == epoch)
                .and_then(|d| d.1)
                .map_or("–".to_string(), |(m, n)| format!("{m:+.2} / {n:.2}"));
            let Some(a) = accuracy.iter().find(|a| &a.epoch == epoch) else {
                // The true cameras: no orientation of ours to score.
                let _ = writeln!(md, "| {epoch} | {label} | – | – | – | – | {dem} |");
                continue;
            };
            let _ = writeln!(
                md,
                "| {epoch} | {label} | {}/{} | {:.3} | {} | {} | {dem} |",
                a.images_oriented,
                a.images_given,
                a.rms_px.unwrap_or(f64::NAN),
                triple(a.check_rmse_gsd, 2),
                triple(a.centre_rmse_m, 2),
            );
        }
    }
    println!("{md}");
    std::fs::write(bench.out.join("film.md"), &md)?;
    println!("written: {}", bench.out.join("film.md").display());
    Ok(())
}
