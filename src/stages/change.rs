//! The `change` stage: DEM of difference and M3C2 of every pair of epochs (`[change] pairs`),
//! through the same comparisons as `timesift compare`, into `out/change/<a>__<b>/`.
//!
//! A pair is redone only when what it was made from changed: `work/change/<a>__<b>.json` records
//! the `[change]` settings, the stable-area file and the stamps of both epochs' DEMs and clouds,
//! and is written after the pair's outputs, so an interrupted pair is redone whole.

use std::path::PathBuf;

use timesift_change::m3c2::M3c2Params;

use super::cache::file_stamp;
use super::{PipelineStage, Stage};
use crate::commands::compare::{
    CloudCompareOptions, DemCompareOptions, compare_clouds, compare_dems, named_positions,
};
use crate::config::ChangePairs;
use crate::report::{read_sealed_json, write_sealed_json};
use crate::{Project, ProjectError};

/// The `change` stage.
pub(super) struct ChangeStage;

impl PipelineStage for ChangeStage {
    fn stage(&self) -> Stage {
        Stage::Change
    }
    fn inputs(&self, project: &Project) -> Vec<(PathBuf, Stage)> {
        // The DEMs of every compared epoch (the clouds are optional: M3C2 runs when both exist).
        let layout = project.layout();
        let mut files = Vec::new();
        for (a, b) in epoch_pairs(project) {
            for e in [a, b] {
                let dem = layout.dem(&e);
                if !files.iter().any(|(f, _)| f == &dem) {
                    files.push((dem, Stage::Dem));
                }
            }
        }
        files
    }
    fn outputs(&self, project: &Project) -> Vec<PathBuf> {
        epoch_pairs(project)
            .into_iter()
            .map(|(a, b)| project.layout().change_dir(&a, &b))
            .collect()
    }
    fn run(&self, project: &Project) -> Result<String, ProjectError> {
        if project.epochs.len() < 2 {
            return Ok("nothing to compare: the project has one epoch".into());
        }
        let (done, skipped) = run_change(project)?;
        Ok(format!(
            "change products of {} epoch pairs written, {skipped} up to date",
            done
        ))
    }
}

/// The compared pairs (earlier, later), by `[change] pairs`.
pub fn epoch_pairs(project: &Project) -> Vec<(String, String)> {
    let names: Vec<&str> = project.epochs.iter().map(|e| e.name.as_str()).collect();
    let reference = project.reference_epoch.0 as usize;
    match project.config.change.pairs {
        ChangePairs::Consecutive => names
            .windows(2)
            .map(|w| (w[0].to_string(), w[1].to_string()))
            .collect(),
        // Earlier epoch first (epochs are in chronological order), so positive differences
        // always mean raising ground.
        ChangePairs::Reference => (0..names.len())
            .filter(|&k| k != reference && reference < names.len())
            .map(|k| (k.min(reference), k.max(reference)))
            .map(|(a, b)| (names[a].to_string(), names[b].to_string()))
            .collect(),
    }
}

/// The project's stable areas: `[inputs] stable`, else `stable.csv` when present.
pub fn stable_file(project: &Project) -> Option<PathBuf> {
    project
        .config
        .inputs
        .stable
        .as_ref()
        .map(|s| project.dir.join(s))
        .or_else(|| Some(project.dir.join("stable.csv")).filter(|p| p.is_file()))
}

/// The stable areas the change stage judges co-registration on: the project's
/// ([`stable_file`]), else the ground the align stage found unchanged (`out/stable_found.tif`)
/// when it wrote it.
pub fn change_stable_areas(project: &Project) -> Option<PathBuf> {
    stable_file(project).or_else(|| Some(project.layout().stable_found()).filter(|p| p.is_file()))
}

/// Compares every pair; returns (pairs computed, pairs up to date).
fn run_change(project: &Project) -> Result<(usize, usize), ProjectError> {
    let stable = change_stable_areas(project);
    let (mut done, mut skipped) = (0, 0);
    for (a, b) in epoch_pairs(project) {
        if compare_pair(project, stable.as_ref(), &a, &b)? {
            done += 1;
        } else {
            skipped += 1;
        }
    }
    Ok((done, skipped))
}

/// A unit of the `change` step: the epoch pairs of `part`. The files it owns.
pub(super) fn unit(project: &Project, part: super::Part) -> Result<Vec<PathBuf>, ProjectError> {
    let stable = change_stable_areas(project);
    let layout = project.layout();
    let pairs = epoch_pairs(project);
    let mut owned = Vec::new();
    for (a, b) in &pairs[part.range(pairs.len())] {
        compare_pair(project, stable.as_ref(), a, b)?;
        let dir = layout.change_dir(a, b);
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .map_err(|e| timesift_io::IoError::io(&dir, e))?
            .flatten()
            .map(|e| e.path())
            .filter(|p| {
                p.is_file()
                    && p.file_name().is_some_and(|n| {
                        timesift_io::fsutil::temporary_owner(&n.to_string_lossy()).is_none()
                    })
            })
            .collect();
        files.sort();
        owned.extend(files);
        owned.push(layout.change_settings(a, b));
    }
    Ok(owned)
}

/// Compares one pair unless what it was made from is unchanged; whether it was computed.
fn compare_pair(
    project: &Project,
    stable: Option<&PathBuf>,
    a: &str,
    b: &str,
) -> Result<bool, ProjectError> {
    let config = &project.config.change;
    let layout = project.layout();
    let out = layout.change_dir(a, b);
    let (dem_a, dem_b) = (layout.dem(a), layout.dem(b));
    let (laz_a, laz_b) = (layout.dense_cloud(a), layout.dense_cloud(b));
    let have_clouds = laz_a.is_file() && laz_b.is_file();
    let settings = serde_json::json!({
        "change": format!("{config:?}"),
        "stable": stable.map(|p| (p.display().to_string(), file_stamp(p))),
        "checkpoints": format!("{:?}", project.checkpoints),
        "dems": [file_stamp(&dem_a), file_stamp(&dem_b)],
        "clouds": [file_stamp(&laz_a), file_stamp(&laz_b)],
    });
    let record = layout.change_settings(a, b);
    let mut expected = vec![layout.change_stats(a, b)];
    if have_clouds {
        expected.push(layout.m3c2_stats(a, b));
    }
    if read_sealed_json::<serde_json::Value>(&record).ok().as_ref() == Some(&settings)
        && expected.iter().all(|p| p.is_file())
    {
        tracing::info!(pair = %format!("{a}__{b}"), "change up to date");
        return Ok(false);
    }
    let options = DemCompareOptions {
        stable: stable.cloned(),
        coregistration: config.coregistration,
        checkpoints: named_positions(&project.checkpoints),
        ..Default::default()
    };
    compare_dems(&dem_a, &dem_b, &out, &options)?;
    if have_clouds {
        let options = CloudCompareOptions {
            stable: stable.cloned(),
            icp: None,
            m3c2: M3c2Params {
                normal_radii: vec![config.normal_radius],
                cylinder_radius: config.cylinder_radius,
                max_depth: config.max_depth,
                ..M3c2Params::default()
            },
            registration_error: Some(config.registration_error),
            core_spacing: config.core_spacing,
        };
        compare_clouds(&laz_a, &laz_b, &out, &options)?;
    }
    write_sealed_json(&record, &settings)?;
    Ok(true)
}
