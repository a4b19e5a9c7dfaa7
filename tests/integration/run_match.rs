//! `timesift run --to match` on a rendered two-epoch project: features and verified matches are
//! written under `work/`, inter-epoch pairs are verified, and a second run resumes (rewrites
//! nothing, same summary).

use crate::common::timesift;
use timesift_synth::scenes::{Scale, build};
use timesift_synth::writer::{WriteOptions, Written, write_scene};

/// The `soil-pit` scene (small, seed 1), each epoch cut to its first 12 images, written into a
/// fresh folder.
fn soil_pit() -> (tempfile::TempDir, Written) {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut spec = build("soil-pit", Scale::Small, 1).expect("scene");
    spec.keep_first_images(12);
    let written = write_scene(&spec, dir.path(), &WriteOptions::default()).expect("write");
    (dir, written)
}

/// Number of files with extension `ext` in `dir`.
fn count_files(dir: &std::path::Path, ext: &str) -> usize {
    std::fs::read_dir(dir)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .is_ok_and(|e| e.path().extension().is_some_and(|x| x == ext))
        })
        .count()
}

#[test]
fn features_and_match_stages_write_work_files_and_resume() {
    let (dir, written) = soil_pit();
    let path = dir.path().to_str().expect("utf-8 path");
    // Matching before features is a clear error.
    let (ok, _, err) = timesift(&["run", path, "--from", "match", "--to", "match"]);
    assert!(!ok);
    assert!(err.contains("run the features stage first"), "{err}");
    let (ok, _, err) = timesift(&["run", path, "--to", "match"]);
    assert!(ok, "{err}");
    let features = count_files(&dir.path().join("work/features"), "feat");
    assert_eq!(features, written.images);
    let summary_path = dir.path().join("work/matches/summary.json");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary_path).unwrap()).unwrap();
    println!("{summary}");
    assert!(summary["verified_pairs"].as_u64().unwrap() > 0);
    let per_epoch = summary["verified_pairs_per_epoch_pair"]
        .as_object()
        .unwrap();
    let inter: u64 = per_epoch
        .iter()
        .filter(|(k, _)| {
            let (a, b) = k.split_once("__").unwrap();
            a != b
        })
        .map(|(_, v)| v.as_u64().unwrap())
        .sum();
    assert!(inter > 0, "no verified inter-epoch pair: {per_epoch:?}");
    // Resume: nothing is recomputed, the summary is the same.
    let stamp = |p: &std::path::Path| std::fs::metadata(p).unwrap().modified().unwrap();
    let first_feature = dir.path().join("work/features/0.feat");
    let before = stamp(&first_feature);
    let (ok, _, err) = timesift(&["run", path, "--to", "match"]);
    assert!(ok, "{err}");
    assert_eq!(stamp(&first_feature), before);
    let again: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary_path).unwrap()).unwrap();
    assert_eq!(again, summary);
}

#[test]
fn preselection_keeps_every_epoch_linked_and_bad_values_are_named() {
    let (dir, _) = soil_pit();
    let path = dir.path().to_str().expect("utf-8 path");
    let toml_path = dir.path().join("project.toml");
    let original = std::fs::read_to_string(&toml_path).unwrap();
    assert!(original.contains("[align]\n"), "{original}");
    let with = |value: &str| {
        original.replace("[align]\n", &format!("[align]\npair_selection = {value}\n"))
    };
    std::fs::write(&toml_path, with("\"fast\"")).unwrap();
    let (ok, _, err) = timesift(&["run", path, "--to", "match"]);
    assert!(!ok);
    assert!(
        err.contains("pair_selection") && err.contains("preselect"),
        "{err}"
    );
    std::fs::write(&toml_path, with("\"preselect\"")).unwrap();
    let (ok, _, err) = timesift(&["run", path, "--to", "match"]);
    assert!(ok, "{err}");
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("work/matches/summary.json")).unwrap(),
    )
    .unwrap();
    println!("{summary}");
    let (pairs, candidates) = (
        summary["pairs"].as_u64().unwrap(),
        summary["candidate_pairs"].as_u64().unwrap(),
    );
    assert!(pairs > 0 && pairs <= candidates, "{pairs} of {candidates}");
    let per_epoch = summary["verified_pairs_per_epoch_pair"]
        .as_object()
        .unwrap();
    // Two epochs: both within-epoch groups and the inter-epoch group keep verified pairs.
    assert_eq!(per_epoch.len(), 3, "{per_epoch:?}");
    assert!(per_epoch.values().all(|v| v.as_u64().unwrap() > 0));
    // Only the selected pairs have match files: one left by another selection is removed.
    let stray = dir.path().join("work/matches/0_999.match");
    std::fs::copy(dir.path().join("work/matches/settings.json"), &stray).unwrap();
    let (ok, _, err) = timesift(&["run", path, "--from", "match", "--to", "match"]);
    assert!(ok, "{err}");
    assert!(!stray.exists());
    let files = count_files(&dir.path().join("work/matches"), "match");
    assert_eq!(files as u64, pairs);
}

#[test]
fn changed_settings_redo_the_features_and_the_matches() {
    let (dir, written) = soil_pit();
    let path = dir.path().to_str().expect("utf-8 path");
    let toml_path = dir.path().join("project.toml");
    let original = std::fs::read_to_string(&toml_path).unwrap();
    let with_limit = |n: usize| {
        std::fs::write(
            &toml_path,
            original.replace("[align]\n", &format!("[align]\nmax_keypoints = {n}\n")),
        )
        .unwrap()
    };
    let most_keypoints = || {
        (0..written.images)
            .map(|i| {
                let file = dir.path().join(format!("work/features/{i}.feat"));
                timesift_matching::storage::read_features(&file)
                    .unwrap()
                    .0
                    .len()
            })
            .max()
            .unwrap()
    };
    let match_files = || count_files(&dir.path().join("work/matches"), "match");
    with_limit(300);
    let (ok, _, err) = timesift(&["run", path, "--to", "match"]);
    assert!(ok, "{err}");
    assert!(most_keypoints() <= 300);
    assert!(match_files() > 0);
    // A smaller budget: the features are extracted again, and the matches made from the old
    // ones are gone.
    with_limit(150);
    let (ok, _, err) = timesift(&["run", path, "--to", "features"]);
    assert!(ok, "{err}");
    let most = most_keypoints();
    assert!(most <= 150 && most > 0, "{most}");
    assert_eq!(match_files(), 0);
}
