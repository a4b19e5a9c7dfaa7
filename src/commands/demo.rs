//! `timesift demo [DIR]`: renders a small synthetic project where the ground really changed (the
//! `landslide` scene: three drone surveys of a slope whose scarp lowers and whose toe grows, GCPs
//! in the first epoch, biased GNSS in all), runs every stage on it and prints what a user would
//! want to know against the truth: orientation accuracy, each epoch's DEM error, the stable-area
//! DoD statistics and the measured volume change of every changed region next to the true one.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use crate::commands::compare::DemReport;
use crate::config::DenseConfig;
use crate::report::read_json;
use crate::stages::{Stage, epoch_pairs, run};
use crate::truth::{
    epoch_accuracy, epoch_dem_error, ground_sampling_distance, region_volumes, triple,
};
use crate::{Project, ProjectError};

/// The demo scene.
pub const DEMO_SCENE: &str = "landslide";

/// Appends the demo's `[dense]` section ([`DenseConfig::quick`]) to the project file the scene
/// writer produced: the whole demo then stays within a few minutes on two cores.
fn append_demo_settings(path: &Path) -> Result<(), ProjectError> {
    let mut text = std::fs::read_to_string(path).map_err(|e| timesift_io::IoError::io(path, e))?;
    let dense = toml::to_string(&DenseConfig::quick()).map_err(|e| ProjectError::Path {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    text.push_str("\n# The demo's lighter dense matching (see `timesift demo`).\n[dense]\n");
    text.push_str(&dense);
    timesift_io::fsutil::write_atomically(path, |w| {
        w.write_all(text.as_bytes())
            .map_err(|e| timesift_io::IoError::io(path, e))
    })?;
    Ok(())
}

/// Writes the demo project into `dir` (which must be empty or absent), runs every stage and
/// returns the printed summary.
pub fn demo(dir: &Path) -> Result<String, ProjectError> {
    if dir.exists()
        && std::fs::read_dir(dir)
            .map_err(|e| timesift_io::IoError::io(dir, e))?
            .next()
            .is_some()
    {
        return Err(ProjectError::Path {
            path: dir.to_path_buf(),
            message: "the demo needs an empty or new directory".into(),
        });
    }
    let start = Instant::now();
    let spec = timesift_synth::scenes::build(DEMO_SCENE, timesift_synth::scenes::Scale::Small, 1)
        .map_err(|e| ProjectError::Path {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let written = timesift_synth::writer::write_scene(
        &spec,
        dir,
        &timesift_synth::writer::WriteOptions::default(),
    )
    .map_err(|e| ProjectError::Path {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    append_demo_settings(&dir.join("project.toml"))?;
    let mut text = format!(
        "demo: scene `{DEMO_SCENE}`, {} epochs, {} images rendered into {} ({:.0} s)\n\
         demo settings: [dense] {}\n",
        spec.epochs.len(),
        written.images,
        dir.display(),
        start.elapsed().as_secs_f64(),
        DenseConfig::quick().differences()
    );
    let project = Project::load(dir)?;
    let start = Instant::now();
    let outcomes = run(&project, Some(Stage::Features), Some(Stage::Report))?;
    let gsd = ground_sampling_distance(&project)?;
    let times: Vec<String> = outcomes
        .iter()
        .map(|o| format!("{} {:.0} s", o.stage.name(), o.seconds))
        .collect();
    text.push_str(&format!(
        "every stage in {:.0} s ({}); ground sampling distance {:.1} mm\n\n",
        start.elapsed().as_secs_f64(),
        times.join(", "),
        gsd * 1000.0
    ));
    text.push_str("orientation against the true cameras\n");
    text.push_str(&format!(
        "{:<18} {:>9} {:>8} {:>30} {:>22} {:>30}\n",
        "epoch",
        "oriented",
        "RMS px",
        "check points dE/dN/dH (mm)",
        "(in GSD)",
        "camera centres dE/dN/dH (mm)"
    ));
    for row in epoch_accuracy(&project, &project.layout().out_dir(), gsd)? {
        let mm = |v: Option<[f64; 3]>| v.map(|v| v.map(|x| x * 1000.0));
        text.push_str(&format!(
            "{:<18} {:>9} {:>8} {:>30} {:>22} {:>30}\n",
            row.epoch,
            format!("{}/{}", row.images_oriented, row.images_given),
            row.rms_px.map_or("–".into(), |v| format!("{v:.3}")),
            triple(mm(row.check_rmse_m), 1),
            triple(row.check_rmse_gsd, 2),
            triple(mm(row.centre_rmse_m), 1),
        ));
    }
    text.push_str(&products_against_truth(&project, gsd)?);
    text.push_str(&format!(
        "\nreport: {}\nproducts: {}/out/ (cameras.json, epochs/<epoch>/dense.laz, dem.tif, \
         ortho.tif, change/<a>__<b>/)\n",
        project.layout().report_html().display(),
        dir.display()
    ));
    Ok(text)
}

/// The DEMs, the stable-area DoDs and the volumes against the truth, as printed lines.
fn products_against_truth(project: &Project, gsd: f64) -> Result<String, ProjectError> {
    let mut text = format!(
        "\nDEMs against the true surface (cells measured from the dense cloud)\n{:<18} {:>8} {:>10} {:>10} {:>10} {:>9}\n",
        "epoch", "cells", "mean mm", "median mm", "NMAD mm", "NMAD GSD"
    );
    for e in &project.epochs {
        if let Some((n, mean, median, nmad)) = epoch_dem_error(project, &e.name)? {
            text.push_str(&format!(
                "{:<18} {:>8} {:>10.1} {:>10.1} {:>10.1} {:>9.2}\n",
                e.name,
                n,
                mean * 1000.0,
                median * 1000.0,
                nmad * 1000.0,
                nmad / gsd
            ));
        }
    }
    text.push_str(&format!(
        "\nDoDs over the stable areas (no co-registration step)\n{:<26} {:>8} {:>10} {:>9} {:>14} {:>9}\n",
        "pair", "cells", "median mm", "NMAD mm", "plane mm/m", "LoD95 mm"
    ));
    let layout = project.layout();
    for (a, b) in epoch_pairs(project) {
        let stats: DemReport = read_json(&layout.change_stats(&a, &b))?;
        if let Some(s) = &stats.stable {
            text.push_str(&format!(
                "{:<26} {:>8} {:>10.1} {:>9.1} {:>14} {:>9}\n",
                format!("{a} → {b}"),
                s.count,
                s.median * 1000.0,
                s.nmad * 1000.0,
                stats
                    .stable_trend
                    .map_or("–".into(), |t| format!("{:.2}", t.slope * 1000.0)),
                stats
                    .lod95
                    .map_or("–".into(), |l| format!("{:.1}", l * 1000.0)),
            ));
        }
    }
    text.push_str(&format!(
        "\nvolume change of the changed regions (the DoD inside each region; cells without a height \
         in both DEMs are not counted)\n{:<10} {:<26} {:>11} {:>18} {:>8} {:>9}\n",
        "region", "pair", "true m³", "measured m³ ± σ", "error", "covered"
    ));
    for v in region_volumes(project)? {
        text.push_str(&format!(
            "{:<10} {:<26} {:>11.1} {:>18} {:>7.1}% {:>8.0}%\n",
            v.region,
            format!("{} → {}", v.from, v.to),
            v.true_m3,
            format!("{:.1} ± {:.1}", v.measured_m3, v.sigma_m3),
            100.0 * (v.measured_m3 - v.true_m3) / v.true_m3.abs().max(1e-9),
            100.0 * v.coverage
        ));
    }
    Ok(text)
}
