//! The dense stage's units of work (`crate::tasks`): each epoch's plan, one pass's maps of a
//! share of the images, one epoch's fusion, and `out/dense.json` from the epochs' summaries.

use std::path::PathBuf;

use super::{
    DensePhaseSeconds, EpochWork, MAP_CACHE_BYTES, MapCache, Oriented, compute_map, dense_epoch,
    read_map, read_settings, start_over_if_changed, write_map,
};
use crate::layout::Layout;
use crate::report::{DenseReport, EpochDense, write_json};
use crate::stages::cache::stage_error;
use crate::{Project, ProjectError};

/// The stage's first step (`dense-prepare`): each epoch's plan made and its work folder emptied
/// where the maps' settings or the orientation changed. The files it owns.
pub(crate) fn prepare(project: &Project) -> Result<Vec<PathBuf>, ProjectError> {
    let oriented = Oriented::read(project)?;
    let mut owned = Vec::new();
    for e in 0..project.epochs.len() {
        let work = EpochWork::new(project, e, &oriented)?;
        start_over_if_changed(&work.dir, &work.map_settings, &work.name)?;
        owned.push(Layout::settings_file(&work.dir));
    }
    Ok(owned)
}

/// A unit of step `dense-pass-<k>`: pass `k`'s map of each image of `part` (in project order)
/// that does not have it, for the images whose epoch's schedule has a pass `k`. Reads the maps
/// of pass `k − 1`, which the step before wrote. The files it owns.
pub(crate) fn pass_unit(
    project: &Project,
    k: usize,
    part: super::super::Part,
) -> Result<Vec<PathBuf>, ProjectError> {
    let oriented = Oriented::read(project)?;
    let layout = project.layout();
    let mine: Vec<usize> = part.range(project.images.len()).collect();
    let mut owned = Vec::new();
    for (e, epoch) in project.epochs.iter().enumerate() {
        let in_epoch: Vec<usize> = mine
            .iter()
            .copied()
            .filter(|&i| project.images[i].epoch.index() == e)
            .collect();
        if in_epoch.is_empty() {
            continue;
        }
        let work = EpochWork::new(project, e, &oriented)?;
        if read_settings(&Layout::settings_file(&work.dir)).as_ref() != Some(&work.map_settings) {
            return Err(stage_error(
                "dense",
                format!(
                    "epoch \"{}\": {} does not record today's settings: run the dense-prepare \
                     step first",
                    epoch.name,
                    Layout::settings_file(&work.dir).display()
                ),
            ));
        }
        let Some(pass) = work.passes.get(k) else {
            continue;
        };
        let views: Vec<usize> = work
            .images
            .iter()
            .enumerate()
            .filter(|(_, i)| in_epoch.contains(i))
            .map(|(v, _)| v)
            .collect();
        let mut cache = work.image_cache(project);
        let mut maps = MapCache::new(MAP_CACHE_BYTES);
        let mut phases = DensePhaseSeconds::default();
        let map_file =
            |pass: usize, view: usize| layout.depth_map_file(&work.name, pass, work.images[view]);
        for view in views {
            let path = map_file(k, view);
            if read_map(&path).is_none() {
                let map = compute_map(
                    &work.plan,
                    &mut cache,
                    &mut maps,
                    &map_file,
                    view,
                    k,
                    pass,
                    &work.options,
                    &mut phases,
                )?;
                write_map(&path, &map)?;
            }
            owned.push(path);
        }
    }
    Ok(owned)
}

/// A unit of step `dense-fuse`: the epochs of `part` filtered and fused into their clouds (any
/// map still missing computed first). The files it owns.
pub(crate) fn fuse_unit(
    project: &Project,
    part: super::super::Part,
) -> Result<Vec<PathBuf>, ProjectError> {
    let oriented = Oriented::read(project)?;
    let layout = project.layout();
    let mut owned = Vec::new();
    for e in part.range(project.epochs.len()) {
        dense_epoch(project, e, &oriented)?;
        let name = &project.epochs[e].name;
        owned.push(layout.dense_cloud(name));
        owned.push(layout.dense_summary(name));
        owned.push(layout.dense_work_dir(name).join("cloud.json"));
        owned.extend(
            project.epochs[e]
                .images
                .iter()
                .map(|i| layout.filtered_map_file(name, i.index())),
        );
    }
    Ok(owned)
}

/// The stage's last step (`dense-report`): `out/dense.json` from the summaries the fusion units
/// wrote (their times are the fusion's; each pass unit's time is in its completion record).
/// The files it owns.
pub(crate) fn report_unit(project: &Project) -> Result<Vec<PathBuf>, ProjectError> {
    let layout = project.layout();
    let mut report = DenseReport::default();
    for epoch in &project.epochs {
        let path = layout.dense_summary(&epoch.name);
        let summary = crate::report::read_sealed_json::<EpochDense>(&path).map_err(|e| {
            stage_error(
                "dense",
                format!("{e} (the dense-fuse step writes it: run it first)"),
            )
        })?;
        report.epochs.insert(epoch.name.clone(), summary);
    }
    write_json(&layout.dense_report(), &report)?;
    Ok(vec![layout.dense_report()])
}
