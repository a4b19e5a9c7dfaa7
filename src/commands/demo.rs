//! `timesift demo [DIR]`: renders a small synthetic project where the ground really changed (the
//! `landslide` scene: three drone surveys of a slope whose scarp lowers and whose toe grows, GCPs
//! in the first epoch, biased GNSS in all), runs every stage on it and prints what a user would
//! want to know against the truth: orientation accuracy, each epoch's DEM error, the stable-area
//! DoD statistics and the measured volume change of every changed region next to the true one.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use crate::commands::compare::DemReport;
use crate::config::{DenseConfig, PairSelection};
use crate::eval::{oriented_epochs, project_truth};
use crate::report::read_json;
use crate::stages::{Stage, epoch_pairs, run};
use crate::{Project, ProjectError};
use timesift_eval::accuracy::{epoch_accuracy, ground_sampling_distance};
use timesift_eval::products::{epoch_dem_error, region_volumes};
use timesift_eval::{ProjectTruth, triple};

/// The demo scene.
pub const DEMO_SCENE: &str = "landslide";

/// The demo's dense matching: [`DenseConfig::quick`] without the geometric-consistency pass.
/// On the demo scene that pass takes a third of the dense stage (19 of 54 s on 2 cores) for
/// little the demo shows: the DEMs' NMAD against the truth is 138 mm with it and 140 mm
/// without, the region volumes move by a few per cent either way; the stable-area DoD's NMAD
/// grows from 83 to 92 mm. Projects keep the pass by default (`[dense] geometric_iterations`).
fn demo_dense() -> DenseConfig {
    DenseConfig {
        geometric_iterations: 0,
        ..DenseConfig::quick()
    }
}

/// Ray samples per pixel and axis of the demo's rendering (the scenes' default is 2). Shading is
/// already taken once per pixel wherever its samples land on one smooth surface, so the extra
/// samples only anti-alias edges; on the demo scene one sample renders in 12 s instead of 20 s
/// on 2 cores, and the orientation, DEM and volume figures stay within their run-to-run spread
/// (DEM NMAD 140–145 mm either way, stable-area DoD NMAD 92.8 against 92.6 mm).
const DEMO_SUPERSAMPLING: u32 = 1;

/// The demo's pair selection: the spatial pairs, then only those whose largest-scale keypoints
/// match ([`PairSelection::Preselect`]). A third of the demo's spatial pairs do not overlap;
/// preselection drops them before full matching (match stage 26 → 19 s) and keeps 867 of the
/// 875 pairs that verify, for the same orientation to a tenth of a millimetre.
const DEMO_PAIRS: PairSelection = PairSelection::Preselect;

/// Writes the demo's settings into the project file the scene writer produced: the pair
/// selection into its `[align]` table and a `[dense]` table ([`demo_dense`]), so that the whole
/// demo stays within a few minutes on two cores. The writer's text is kept as written (a person
/// reads it), the settings are inserted after the `[align]` header and appended, and the
/// result must parse; `timesift demo` prints what differs from the defaults.
fn write_demo_settings(path: &Path) -> Result<(), ProjectError> {
    let text = std::fs::read_to_string(path).map_err(|e| timesift_io::IoError::io(path, e))?;
    let invalid = |message: String| ProjectError::Path {
        path: path.to_path_buf(),
        message,
    };
    let pairs = format!(
        "# The demo's pair selection (see `timesift demo`).\npair_selection = \"{}\"\n",
        DEMO_PAIRS.name()
    );
    let mut out = String::with_capacity(text.len() + 512);
    let mut inserted = false;
    for line in text.lines() {
        out.push_str(line);
        out.push('\n');
        if line.trim() == "[align]" && !inserted {
            out.push_str(&pairs);
            inserted = true;
        }
    }
    if !inserted {
        out.push_str("\n[align]\n");
        out.push_str(&pairs);
    }
    let dense = toml::to_string(&demo_dense()).map_err(|e| invalid(e.to_string()))?;
    out.push_str("\n# The demo's lighter dense matching (see `timesift demo`).\n[dense]\n");
    out.push_str(&dense);
    out.parse::<toml::Table>()
        .map_err(|e| invalid(format!("the demo's settings do not parse: {e}")))?;
    timesift_io::fsutil::write_atomically(path, |w| {
        w.write_all(out.as_bytes())
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
    let mut spec =
        timesift_synth::scenes::build(DEMO_SCENE, timesift_synth::scenes::Scale::Small, 1)
            .map_err(|e| ProjectError::Path {
                path: dir.to_path_buf(),
                message: e.to_string(),
            })?;
    let scene_supersampling = spec.epochs.first().map_or(1, |e| e.supersampling);
    for epoch in &mut spec.epochs {
        epoch.supersampling = DEMO_SUPERSAMPLING;
    }
    let written = timesift_synth::writer::write_scene(
        &spec,
        dir,
        &timesift_synth::writer::WriteOptions::default(),
    )
    .map_err(|e| ProjectError::Path {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    write_demo_settings(&dir.join("project.toml"))?;
    let mut text = format!(
        "demo: scene `{DEMO_SCENE}`, {} epochs, {} images rendered into {} ({:.0} s)\n\
         demo settings: rendering {} sample per pixel (scene {}×{}); [align] pair_selection \
         {} (default {}); [dense] {}\n",
        spec.epochs.len(),
        written.images,
        dir.display(),
        start.elapsed().as_secs_f64(),
        DEMO_SUPERSAMPLING * DEMO_SUPERSAMPLING,
        scene_supersampling,
        scene_supersampling,
        DEMO_PAIRS.name(),
        PairSelection::default().name(),
        demo_dense().differences()
    );
    let project = Project::load(dir)?;
    let start = Instant::now();
    let outcomes = run(&project, Some(Stage::Features), Some(Stage::Report))?;
    let truth = project_truth(&project)?;
    let gsd = ground_sampling_distance(&truth)?;
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
    let out = project.layout().out_dir();
    for row in epoch_accuracy(&truth, &oriented_epochs(&out)?, &out, gsd)? {
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
    text.push_str(&products_against_truth(&project, &truth, gsd)?);
    text.push_str(&format!(
        "\nreport: {}\nproducts: {}/out/ (cameras.json, epochs/<epoch>/dense.laz, dem.tif, \
         ortho.tif, change/<a>__<b>/)\n",
        project.layout().report_html().display(),
        dir.display()
    ));
    Ok(text)
}

/// The DEMs, the stable-area DoDs and the volumes against the truth, as printed lines.
fn products_against_truth(
    project: &Project,
    truth: &ProjectTruth<'_>,
    gsd: f64,
) -> Result<String, ProjectError> {
    let mut text = format!(
        "\nDEMs against the true surface (cells measured from the dense cloud)\n{:<18} {:>8} {:>10} {:>10} {:>10} {:>9}\n",
        "epoch", "cells", "mean mm", "median mm", "NMAD mm", "NMAD GSD"
    );
    for e in &project.epochs {
        if let Some((n, mean, median, nmad)) = epoch_dem_error(&truth.layout, &e.name)? {
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
    for v in region_volumes(truth)? {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ProjectConfig;

    const EPOCHS: &str =
        "crs = \"EPSG:32632\"\n\n[[epoch]]\nname = \"a\"\nimages = \"images/a/*.jpg\"\n";

    fn settings_of(text: &str) -> Result<(String, ProjectConfig), ProjectError> {
        let dir = tempfile::tempdir().map_err(|e| timesift_io::IoError::io(Path::new("."), e))?;
        let path = dir.path().join("project.toml");
        std::fs::write(&path, text).map_err(|e| timesift_io::IoError::io(&path, e))?;
        write_demo_settings(&path)?;
        let written =
            std::fs::read_to_string(&path).map_err(|e| timesift_io::IoError::io(&path, e))?;
        let config = ProjectConfig::parse(&path, &written)?;
        Ok((written, config))
    }

    #[test]
    fn settings_join_the_writers_align_table_and_keep_its_text() -> Result<(), ProjectError> {
        let text =
            format!("# written by the scene writer\n{EPOCHS}\n[align]\nmethod = \"independent\"\n");
        let (written, config) = settings_of(&text)?;
        assert!(written.starts_with(&text[..text.len() - "method = \"independent\"\n".len()]));
        assert_eq!(written.matches("[align]").count(), 1);
        assert_eq!(config.align.pair_selection, PairSelection::Preselect);
        assert_eq!(config.align.method, timesift_align::Method::Independent);
        assert_eq!(config.dense, demo_dense());
        assert_eq!(config.dense.geometric_iterations, 0);
        Ok(())
    }

    #[test]
    fn settings_add_an_align_table_when_there_is_none() -> Result<(), ProjectError> {
        let (written, config) = settings_of(EPOCHS)?;
        assert_eq!(written.matches("[align]").count(), 1);
        assert_eq!(config.align.pair_selection, PairSelection::Preselect);
        assert_eq!(config.dense, demo_dense());
        Ok(())
    }

    #[test]
    fn settings_refuse_a_project_file_that_does_not_parse() {
        let err = settings_of("[align\nmethod = 1\n").map(|_| ());
        let message = format!("{:?}", err);
        assert!(message.contains("project.toml"), "{message}");
        assert!(message.contains("do not parse"), "{message}");
    }
}
