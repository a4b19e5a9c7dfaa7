//! `timesift demo [DIR]`: renders a small two-epoch synthetic project (the `soil-pit` scene: a
//! soil wall photographed before and after sampling, GCPs marked in the first epoch only), runs
//! the pipeline so far on it and prints each epoch's orientation accuracy against the truth.

use std::path::Path;
use std::time::Instant;

use crate::stages::{Stage, run};
use crate::truth::{epoch_accuracy, ground_sampling_distance, triple};
use crate::{Project, ProjectError};

/// The demo scene.
pub const DEMO_SCENE: &str = "soil-pit";

/// Writes the demo project into `dir` (which must be empty or absent), runs features, match and
/// align, and returns the printed summary.
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
    let mut text = format!(
        "demo: scene `{DEMO_SCENE}`, {} epochs, {} images rendered into {} ({:.0} s)\n",
        spec.epochs.len(),
        written.images,
        dir.display(),
        start.elapsed().as_secs_f64()
    );
    let project = Project::load(dir)?;
    let start = Instant::now();
    run(&project, Some(Stage::Features), Some(Stage::Align))?;
    let gsd = ground_sampling_distance(&project)?;
    text.push_str(&format!(
        "features, matching and orientation in {:.0} s; ground sampling distance {:.2} mm\n\n",
        start.elapsed().as_secs_f64(),
        gsd * 1000.0
    ));
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
    text.push_str(&format!(
        "\noutputs: {0}/out/cameras.json, {0}/out/report.json, {0}/out/colmap/, {0}/out/tiepoints.ply\n",
        dir.display()
    ));
    Ok(text)
}
