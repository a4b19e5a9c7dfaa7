//! The `features` and `match` stages of `timesift run`: keypoints and descriptors per image, then
//! epoch-aware pairs, matching, verification, guided matching and tracks, written under `work/` of the project so
//! that a run resumes where it stopped and memory holds one image's features per thread while
//! extracting.
//!
//! Files: `work/features/<n>.feat` for image number n (its index in the project), `work/matches/
//! <a>_<b>.match` with the verified matches of images a and b, and `work/matches/summary.json`
//! (pairs, verified pairs per epoch pair, track lengths).

use std::collections::BTreeMap;
use std::path::PathBuf;

use rayon::prelude::*;
use timesift_core::{EpochId, ImageId};
use timesift_features::{
    DetectorOptions, FeatureExtractor, KeypointLimit, LdbExtractor, SiftExtractor,
    SiftNormalization,
};
use timesift_matching::guided::{GuidedOptions, grow_verified};
use timesift_matching::pairs::{PairPolicy, epoch_aware};
use timesift_matching::preselect::{PreselectOptions, coarse_matches, preselect};
use timesift_matching::storage::{read_features, read_matches, write_features, write_matches};
use timesift_matching::tracks::{PairMatches, build_tracks};
use timesift_matching::verify::{VerifyOptions, verify_pair};
use timesift_matching::{FloatDistance, MatchOptions, match_descriptors};

use crate::config::{FeatureMethod, PairSelection};
use crate::{Project, ProjectError};

/// Neighbours of each image within its epoch, by prior camera centre.
const WITHIN_EPOCH_NEIGHBOURS: usize = 20;
/// Nearest images of every other epoch matched with each image.
const ACROSS_EPOCH_NEIGHBOURS: usize = 5;

fn features_path(project: &Project, image: usize) -> PathBuf {
    project
        .dir
        .join("work/features")
        .join(format!("{image}.feat"))
}

fn matches_path(project: &Project, a: usize, b: usize) -> PathBuf {
    project
        .dir
        .join("work/matches")
        .join(format!("{a}_{b}.match"))
}

/// The image pair of a `work/matches/<a>_<b>.match` file; `None` for any other file.
pub(crate) fn match_file_pair(path: &std::path::Path) -> Option<(usize, usize)> {
    let stem = path.file_name()?.to_str()?.strip_suffix(".match")?;
    let (a, b) = stem.split_once('_')?;
    Some((a.parse().ok()?, b.parse().ok()?))
}

fn stage_error(stage: &'static str, message: String) -> ProjectError {
    ProjectError::Stage { stage, message }
}

/// Version of the match stage's algorithm, part of its settings: a change that alters the
/// verified matches (such as guided matching, version 2) makes a resumed run redo them.
const MATCH_ALGORITHM: u32 = 2;

/// Makes `dir` hold only results made with `settings`: when `dir/settings.json` records other
/// settings (or is missing while results of an earlier run are there), the files with extension
/// `ext` are removed, as are those of every folder in `dependents`; then the settings are
/// recorded. A resumed run thus reuses only what the current settings would produce.
fn start_with_settings(
    stage: &'static str,
    dir: &std::path::Path,
    ext: &str,
    settings: &serde_json::Value,
    dependents: &[(&std::path::Path, &str)],
) -> Result<(), ProjectError> {
    let path = dir.join("settings.json");
    let recorded: Option<serde_json::Value> = std::fs::read_to_string(&path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok());
    if recorded.as_ref() == Some(settings) {
        return Ok(());
    }
    for (folder, extension) in std::iter::once((dir, ext)).chain(dependents.iter().copied()) {
        let Ok(entries) = std::fs::read_dir(folder) else {
            continue;
        };
        for entry in entries.flatten() {
            let file = entry.path();
            if file.extension().is_some_and(|e| e == extension) {
                std::fs::remove_file(&file).map_err(|e| {
                    stage_error(stage, format!("{}: cannot remove: {e}", file.display()))
                })?;
            }
        }
    }
    if recorded.is_some() {
        tracing::info!(stage, "settings changed: earlier results removed");
    }
    let text = serde_json::to_string_pretty(settings).unwrap_or_default();
    timesift_io::fsutil::write_atomically(&path, |w| {
        use std::io::Write;
        w.write_all(text.as_bytes())
            .map_err(|e| timesift_io::IoError::io(&path, e))
    })?;
    Ok(())
}

/// Removes the match files of pairs not in `pairs` (sorted), left by a run with another pair
/// selection: the align stage reads every match file, and its tracks should be this run's.
fn remove_unselected(dir: &std::path::Path, pairs: &[(usize, usize)]) -> Result<(), ProjectError> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let file = entry.path();
        if let Some(pair) = match_file_pair(&file) {
            if pairs.binary_search(&pair).is_err() {
                std::fs::remove_file(&file).map_err(|e| {
                    stage_error("match", format!("{}: cannot remove: {e}", file.display()))
                })?;
            }
        }
    }
    Ok(())
}

/// Extracts the features of every image whose feature file is missing or unreadable.
pub fn features_stage(project: &Project) -> Result<usize, ProjectError> {
    let detector = DetectorOptions {
        limit: Some(KeypointLimit::spread(project.config.align.max_keypoints)),
        // COLMAP's peak threshold: more keypoints in weak texture, which epochs years apart need.
        contrast_threshold: 0.02,
        ..DetectorOptions::default()
    };
    let extractor: Box<dyn FeatureExtractor> = match project.config.align.features {
        FeatureMethod::Sift => Box::new(SiftExtractor {
            detector,
            normalization: SiftNormalization::Root,
        }),
        FeatureMethod::Ldb => Box::new(LdbExtractor { detector }),
    };
    let settings = serde_json::json!({
        "features": project.config.align.features,
        "max_keypoints": project.config.align.max_keypoints,
        "contrast_threshold": detector.contrast_threshold,
    });
    let features_dir = project.dir.join("work/features");
    let matches_dir = project.dir.join("work/matches");
    start_with_settings(
        "features",
        &features_dir,
        "feat",
        &settings,
        &[(&matches_dir, "match")],
    )?;
    let todo: Vec<usize> = (0..project.images.len())
        .filter(|&i| read_features(&features_path(project, i)).is_err())
        .collect();
    let failures: Vec<String> = todo
        .par_iter()
        .filter_map(|&i| {
            let image = project.dir.join(&project.images[i].name);
            let result = timesift_features::files::extract_file(&image, extractor.as_ref())
                .map_err(|e| format!("{}: {e}", project.images[i].name))
                .and_then(|f| {
                    write_features(&features_path(project, i), &f.keypoints, &f.descriptors)
                        .map_err(|e| e.to_string())
                });
            result.err()
        })
        .collect();
    if let Some(first) = failures.first() {
        return Err(stage_error(
            "features",
            format!(
                "{} of {} images failed; first: {first}",
                failures.len(),
                todo.len()
            ),
        ));
    }
    tracing::info!(
        extracted = todo.len(),
        total = project.images.len(),
        "features"
    );
    Ok(todo.len())
}

/// Matches and verifies the epoch-aware pairs whose match file is missing, then builds tracks
/// over all verified pairs and writes the summary.
pub fn match_stage(project: &Project) -> Result<serde_json::Value, ProjectError> {
    let n = project.images.len();
    let features = (0..n)
        .into_par_iter()
        .map(|i| read_features(&features_path(project, i)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| stage_error("match", format!("{e} (run the features stage first)")))?;
    let priors = project.camera_priors()?;
    let positions: Vec<Option<[f64; 3]>> = priors
        .iter()
        .map(|p| {
            p.as_ref()
                .map(|p| [p.position.x, p.position.y, p.position.z])
        })
        .collect();
    let epoch_of: Vec<EpochId> = project.images.iter().map(|im| im.epoch).collect();
    let selection = project.config.align.pair_selection;
    let positions = if selection == PairSelection::Exhaustive {
        vec![None; n]
    } else {
        positions
    };
    let within = if positions.iter().all(Option::is_some) {
        PairPolicy::Spatial {
            neighbours: WITHIN_EPOCH_NEIGHBOURS,
            max_distance: None,
        }
    } else {
        PairPolicy::Exhaustive
    };
    let candidates = epoch_aware(&epoch_of, &positions, within, ACROSS_EPOCH_NEIGHBOURS);
    // A pair's matches do not depend on which other pairs are selected: only the algorithm.
    let settings = serde_json::json!({ "algorithm": MATCH_ALGORITHM });
    start_with_settings(
        "match",
        &project.dir.join("work/matches"),
        "match",
        &settings,
        &[],
    )?;
    let candidate_count = candidates.len();
    let pairs = if selection == PairSelection::Preselect {
        let options = PreselectOptions::default();
        let views: Vec<_> = features.iter().map(|(k, d)| (k.as_slice(), d)).collect();
        let coarse = coarse_matches(&views, &candidates, &options)
            .map_err(|e| stage_error("match", format!("preselection: {e}")))?;
        preselect(&coarse, &epoch_of, &options)
    } else {
        candidates
    };
    remove_unselected(&project.dir.join("work/matches"), &pairs)?;
    let options = MatchOptions {
        ratio_on: FloatDistance::Angle,
        ..MatchOptions::default()
    };
    let verify = VerifyOptions::default();
    let guided = GuidedOptions::default();
    let results: Vec<Result<Vec<timesift_matching::Match>, String>> = pairs
        .par_iter()
        .map(|&(a, b)| {
            let path = matches_path(project, a, b);
            if let Ok(done) = read_matches(&path) {
                return Ok(done);
            }
            let (ka, da) = &features[a];
            let (kb, db) = &features[b];
            let putative = match_descriptors(da, db, &options).map_err(|e| e.to_string())?;
            let inliers =
                match verify_pair(ka, kb, &putative, None, &verify).map_err(|e| e.to_string())? {
                    Some(verified) => grow_verified(ka, da, kb, db, &verified, &guided)
                        .map_err(|e| e.to_string())?,
                    None => Vec::new(),
                };
            write_matches(&path, &inliers).map_err(|e| e.to_string())?;
            Ok(inliers)
        })
        .collect();
    let mut verified = Vec::new();
    for (&(a, b), result) in pairs.iter().zip(results) {
        let matches = result.map_err(|e| stage_error("match", e))?;
        if !matches.is_empty() {
            verified.push(PairMatches {
                a: ImageId::from(a),
                b: ImageId::from(b),
                matches,
            });
        }
    }
    let counts: Vec<usize> = features.iter().map(|f| f.0.len()).collect();
    let tracks =
        build_tracks(&counts, &verified).map_err(|e| stage_error("match", e.to_string()))?;
    let mut per_epoch_pair: BTreeMap<String, usize> = BTreeMap::new();
    for p in &verified {
        let (ea, eb) = (epoch_of[p.a.index()], epoch_of[p.b.index()]);
        let (ea, eb) = (ea.min(eb), ea.max(eb));
        let key = format!(
            "{}__{}",
            project.epochs[ea.index()].name,
            project.epochs[eb.index()].name
        );
        *per_epoch_pair.entry(key).or_insert(0) += 1;
    }
    let summary = serde_json::json!({
        "candidate_pairs": candidate_count,
        "pairs": pairs.len(),
        "verified_pairs": verified.len(),
        "verified_pairs_per_epoch_pair": per_epoch_pair,
        "tracks": tracks.tracks.len(),
        "conflicting_matches": tracks.conflicts,
        "track_lengths": tracks.length_histogram(),
    });
    let path = project.dir.join("work/matches/summary.json");
    let text = serde_json::to_string_pretty(&summary).unwrap_or_default();
    timesift_io::fsutil::write_atomically(&path, |w| {
        use std::io::Write;
        w.write_all(text.as_bytes())
            .map_err(|e| timesift_io::IoError::io(&path, e))
    })?;
    Ok(summary)
}
