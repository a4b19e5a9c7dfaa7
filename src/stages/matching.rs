//! The `match` stage of `timesift run`: epoch-aware pairs, matching, verification, guided
//! matching and tracks, one file per pair under `work/matches/` so that a run resumes where it
//! stopped, and `work/matches/summary.json` ([`MatchSummary`]).

use std::collections::BTreeMap;

use rayon::prelude::*;
use timesift_core::{EpochId, ImageId};
use timesift_matching::pairs::{EpochPartners, PairPolicy, epoch_aware};
use timesift_matching::preselect::{PreselectOptions, coarse_matches, preselect};
use timesift_matching::storage::{read_features, read_matches, write_matches};
use timesift_matching::tracks::{PairMatches, build_tracks};
use timesift_matching::{StagedOptions, staged_matches};

use super::cache::{stage_error, start_with_settings};
use super::{PipelineStage, Stage};
use crate::config::PairSelection;
use crate::layout::Layout;
use crate::report::MatchSummary;
use crate::{Project, ProjectError};

/// The `match` stage.
pub(super) struct MatchStage;

impl PipelineStage for MatchStage {
    fn stage(&self) -> Stage {
        Stage::Match
    }
    fn inputs(&self, project: &Project) -> Vec<(std::path::PathBuf, Stage)> {
        (0..project.images.len())
            .map(|i| (project.layout().feature_file(i), Stage::Features))
            .collect()
    }
    fn outputs(&self, project: &Project) -> Vec<std::path::PathBuf> {
        vec![project.layout().match_summary()]
    }
    fn run(&self, project: &Project) -> Result<String, ProjectError> {
        Ok(match_stage(project)?.to_string())
    }
}

/// Neighbours of each image within its epoch, by prior camera centre.
const WITHIN_EPOCH_NEIGHBOURS: usize = 20;
/// Nearest images of every other epoch matched with each image.
const ACROSS_EPOCH_NEIGHBOURS: usize = 5;

/// Version of the match stage's algorithm, part of its settings: a change that alters the
/// verified matches (such as guided matching, version 2) makes a resumed run redo them.
/// Version 3: pairs matched coarse to fine (`[align] coarse_match_keypoints`).
const MATCH_ALGORITHM: u32 = 3;

/// Removes the match files of pairs not in `pairs` (sorted), left by a run with another pair
/// selection: the align stage reads every match file, and its tracks should be this run's.
fn remove_unselected(dir: &std::path::Path, pairs: &[(usize, usize)]) -> Result<(), ProjectError> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let file = entry.path();
        if let Some(pair) = Layout::match_file_pair(&file)
            && pairs.binary_search(&pair).is_err()
        {
            std::fs::remove_file(&file).map_err(|e| {
                stage_error("match", format!("{}: cannot remove: {e}", file.display()))
            })?;
        }
    }
    Ok(())
}

/// Matches and verifies the epoch-aware pairs whose match file is missing, then builds tracks
/// over all verified pairs and writes the summary: the stage's three steps in one process.
pub fn match_stage(project: &Project) -> Result<MatchSummary, ProjectError> {
    let features = read_all_features(project)?;
    let pairs = select_pairs(project, Some(&features))?;
    let matches = match_pairs(project, &pairs, &|i| Ok(&features[i]))?;
    let counts: Vec<usize> = features.iter().map(|f| f.0.len()).collect();
    build_summary(project, &pairs, matches, &counts)
}

type ImageFeatures = (Vec<timesift_core::Keypoint>, timesift_core::Descriptors);

fn read_all_features(project: &Project) -> Result<Vec<ImageFeatures>, ProjectError> {
    let layout = project.layout();
    (0..project.images.len())
        .into_par_iter()
        .map(|i| read_features(&layout.feature_file(i)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| stage_error("match", format!("{e} (run the features stage first)")))
}

/// The pairs this run matches (also recorded in `work/matches/pairs.json`), after the settings
/// check and the removal of match files of pairs no longer selected. `features` are needed
/// only for preselection; `None` reads them then.
fn select_pairs(
    project: &Project,
    features: Option<&[ImageFeatures]>,
) -> Result<PairList, ProjectError> {
    let layout = project.layout();
    let epoch_of: Vec<EpochId> = project.images.iter().map(|im| im.epoch).collect();
    let candidates = candidate_pairs(project, &epoch_of)?;
    // A pair's matches do not depend on which other pairs are selected: only the algorithm.
    let settings = serde_json::json!({
        "algorithm": MATCH_ALGORITHM,
        "coarse_match_keypoints": project.config.align.coarse_match_keypoints,
    });
    start_with_settings("match", &layout.matches_dir(), "match", &settings, &[])?;
    let candidate_count = candidates.len();
    let pairs = if project.config.align.pair_selection == PairSelection::Preselect {
        let read;
        let features = match features {
            Some(f) => f,
            None => {
                read = read_all_features(project)?;
                &read
            }
        };
        let options = PreselectOptions::default();
        let views: Vec<_> = features.iter().map(|(k, d)| (k.as_slice(), d)).collect();
        let coarse = coarse_matches(&views, &candidates, &options)
            .map_err(|e| stage_error("match", format!("preselection: {e}")))?;
        preselect(&coarse, &epoch_of, &options)
    } else {
        candidates
    };
    remove_unselected(&layout.matches_dir(), &pairs)?;
    let list = PairList {
        candidate_pairs: candidate_count,
        pairs,
    };
    crate::report::write_sealed_json(&layout.match_pairs(), &list)?;
    Ok(list)
}

/// The pairs the match stage matches, as `work/matches/pairs.json` records them.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct PairList {
    /// Pairs before preselection.
    candidate_pairs: usize,
    /// The pairs, sorted.
    pairs: Vec<(usize, usize)>,
}

/// The stage's first step (`match-prepare`): the pairs chosen and recorded. The files it owns.
pub(super) fn prepare(project: &Project) -> Result<Vec<std::path::PathBuf>, ProjectError> {
    select_pairs(project, None)?;
    let layout = project.layout();
    Ok(vec![
        layout.match_pairs(),
        Layout::settings_file(&layout.matches_dir()),
    ])
}

fn recorded_pairs(project: &Project) -> Result<PairList, ProjectError> {
    let path = project.layout().match_pairs();
    crate::report::read_sealed_json::<PairList>(&path).map_err(|e| {
        stage_error(
            "match",
            format!("{e} (the match-prepare step writes it: run it first)"),
        )
    })
}

/// A unit of the `match` step: the pairs of `part` (of `pairs.json`), each matched unless its
/// file is there; only the features of the images they touch are read. The files it owns.
pub(super) fn unit(
    project: &Project,
    part: super::Part,
) -> Result<Vec<std::path::PathBuf>, ProjectError> {
    let layout = project.layout();
    let list = recorded_pairs(project)?;
    let mine = &list.pairs[part.range(list.pairs.len())];
    let todo: Vec<(usize, usize)> = mine
        .iter()
        .copied()
        .filter(|&(a, b)| read_matches(&layout.match_file(a, b)).is_err())
        .collect();
    let images: std::collections::BTreeSet<usize> =
        todo.iter().flat_map(|&(a, b)| [a, b]).collect();
    let loaded: BTreeMap<usize, ImageFeatures> = images
        .into_par_iter()
        .map(|i| {
            read_features(&layout.feature_file(i))
                .map(|f| (i, f))
                .map_err(|e| stage_error("match", format!("{e} (run the features stage first)")))
        })
        .collect::<Result<_, _>>()?;
    let get = |i: usize| {
        loaded
            .get(&i)
            .ok_or_else(|| stage_error("match", format!("image {i}: features not loaded")))
    };
    let subset = PairList {
        candidate_pairs: list.candidate_pairs,
        pairs: todo,
    };
    match_pairs(project, &subset, &get)?;
    Ok(mine.iter().map(|&(a, b)| layout.match_file(a, b)).collect())
}

/// The stage's last step (`match-tracks`): tracks over every pair's matches and the summary.
/// The files it owns.
pub(super) fn finish(project: &Project) -> Result<Vec<std::path::PathBuf>, ProjectError> {
    let layout = project.layout();
    let list = recorded_pairs(project)?;
    let counts = (0..project.images.len())
        .into_par_iter()
        .map(|i| read_features(&layout.feature_file(i)).map(|f| f.0.len()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| stage_error("match", format!("{e} (run the features stage first)")))?;
    let matches = list
        .pairs
        .par_iter()
        .map(|&(a, b)| {
            read_matches(&layout.match_file(a, b))
                .map_err(|e| stage_error("match", format!("{e} (its match unit has not run)")))
        })
        .collect::<Result<_, _>>()?;
    build_summary(project, &list, matches, &counts)?;
    Ok(vec![layout.match_summary()])
}

/// Every pair of `list`'s matches: read where its file is there, else matched and written.
fn match_pairs<'f>(
    project: &Project,
    list: &PairList,
    features: &(dyn Fn(usize) -> Result<&'f ImageFeatures, ProjectError> + Sync),
) -> Result<Vec<Vec<timesift_matching::Match>>, ProjectError> {
    let layout = project.layout();
    let options = StagedOptions {
        coarse_keypoints: project.config.align.coarse_match_keypoints,
        ..StagedOptions::default()
    };
    list.pairs
        .par_iter()
        .map(|&(a, b)| {
            let path = layout.match_file(a, b);
            if let Ok(done) = read_matches(&path) {
                return Ok(done);
            }
            let inliers = verified_matches(features(a)?, features(b)?, &options)
                .map_err(|e| stage_error("match", e.to_string()))?;
            write_matches(&path, &inliers).map_err(|e| stage_error("match", e.to_string()))?;
            Ok(inliers)
        })
        .collect()
}

/// Tracks over `matches` (those of every pair of `list`, in its order), and the summary
/// written.
fn build_summary(
    project: &Project,
    list: &PairList,
    matches: Vec<Vec<timesift_matching::Match>>,
    keypoint_counts: &[usize],
) -> Result<MatchSummary, ProjectError> {
    let layout = project.layout();
    let epoch_of: Vec<EpochId> = project.images.iter().map(|im| im.epoch).collect();
    let verified: Vec<PairMatches> = list
        .pairs
        .iter()
        .zip(matches)
        .filter(|(_, m)| !m.is_empty())
        .map(|(&(a, b), matches)| PairMatches {
            a: ImageId::from(a),
            b: ImageId::from(b),
            matches,
        })
        .collect();
    let tracks = build_tracks(keypoint_counts, &verified)
        .map_err(|e| stage_error("match", e.to_string()))?;
    let per_epoch_pair = verified_per_epoch_pair(project, &epoch_of, &verified);
    let summary = MatchSummary {
        candidate_pairs: list.candidate_pairs,
        pairs: list.pairs.len(),
        verified_pairs: verified.len(),
        verified_pairs_per_epoch_pair: per_epoch_pair,
        tracks: tracks.tracks.len(),
        conflicting_matches: tracks.conflicts,
        track_lengths: tracks.length_histogram(),
    };
    crate::report::write_sealed_json(&layout.match_summary(), &summary)?;
    Ok(summary)
}

/// The pairs to match: within an epoch the spatial neighbours (every pair where an image has no
/// position prior, or with `pair_selection = "exhaustive"`), across epochs the nearest, with the
/// reference epoch and the `epoch_partners` epochs either side.
pub(crate) fn candidate_pairs(
    project: &Project,
    epoch_of: &[EpochId],
) -> Result<Vec<(usize, usize)>, ProjectError> {
    let priors = project.camera_priors()?;
    let positions: Vec<Option<[f64; 3]>> =
        if project.config.align.pair_selection == PairSelection::Exhaustive {
            vec![None; project.images.len()]
        } else {
            priors
                .iter()
                .map(|p| {
                    p.as_ref()
                        .map(|p| [p.position.x, p.position.y, p.position.z])
                })
                .collect()
        };
    let within = if positions.iter().all(Option::is_some) {
        PairPolicy::Spatial {
            neighbours: WITHIN_EPOCH_NEIGHBOURS,
            max_distance: None,
        }
    } else {
        PairPolicy::Exhaustive
    };
    let partners = match project.config.align.epoch_partners(project.epochs.len()) {
        Some(neighbours) => EpochPartners::Nearest {
            neighbours,
            reference: project.reference_epoch,
        },
        None => EpochPartners::All,
    };
    Ok(epoch_aware(
        epoch_of,
        &positions,
        within,
        ACROSS_EPOCH_NEIGHBOURS,
        partners,
    ))
}

/// One pair's matches: putative by descriptor, verified geometrically, grown by guided
/// matching (none where verification fails); coarse to fine where that stands for the pair.
fn verified_matches(
    (ka, da): &(Vec<timesift_core::Keypoint>, timesift_core::Descriptors),
    (kb, db): &(Vec<timesift_core::Keypoint>, timesift_core::Descriptors),
    options: &StagedOptions,
) -> Result<Vec<timesift_matching::Match>, timesift_matching::MatchingError> {
    Ok(staged_matches((ka, da), (kb, db), options)?.matches)
}

/// Verified pairs per pair of epochs (`<a>__<b>`, earlier first).
fn verified_per_epoch_pair(
    project: &Project,
    epoch_of: &[EpochId],
    verified: &[PairMatches],
) -> BTreeMap<String, usize> {
    let mut per_epoch_pair: BTreeMap<String, usize> = BTreeMap::new();
    for p in verified {
        let (ea, eb) = (epoch_of[p.a.index()], epoch_of[p.b.index()]);
        let (ea, eb) = (ea.min(eb), ea.max(eb));
        let key = format!(
            "{}__{}",
            project.epochs[ea.index()].name,
            project.epochs[eb.index()].name
        );
        *per_epoch_pair.entry(key).or_insert(0) += 1;
    }
    per_epoch_pair
}
