//! The 29 `lund` photos, exhaustively matched and verified: the verified pair graph connects
//! every image, and every track is consistent.

mod common;

use std::collections::BTreeSet;
use std::path::PathBuf;

use timesift_core::ImageId;
use timesift_features::FeatureExtractor;
use timesift_matching::pairs::{PairPolicy, select};
use timesift_matching::tracks::{PairMatches, build_tracks};
use timesift_matching::verify::{VerifyOptions, verify_pair};
use timesift_matching::{MatchOptions, match_descriptors};

#[test]
fn lund_pair_graph_is_connected() {
    let dir =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/opensfm/lund/images");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("../shared/data/opensfm/lund is present")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    paths.sort();
    let extractor = common::rootsift(2000);
    let features: Vec<_> = paths
        .iter()
        .map(|p| {
            timesift_features::files::extract_file(p, &extractor as &dyn FeatureExtractor).unwrap()
        })
        .collect();
    let n = features.len();
    let pairs = select(
        &(0..n).collect::<Vec<_>>(),
        &vec![None; n],
        PairPolicy::Exhaustive,
    );
    assert_eq!(pairs.len(), n * (n - 1) / 2);
    let mut verified = Vec::new();
    let mut inlier_counts = Vec::new();
    for &(a, b) in &pairs {
        let matches = match_descriptors(
            &features[a].descriptors,
            &features[b].descriptors,
            &MatchOptions::default(),
        )
        .unwrap();
        if let Some(v) = verify_pair(
            &features[a].keypoints,
            &features[b].keypoints,
            &matches,
            None,
            &VerifyOptions::default(),
        )
        .unwrap()
        {
            inlier_counts.push(v.inliers.len());
            verified.push(PairMatches {
                a: ImageId::from(a),
                b: ImageId::from(b),
                matches: v.inliers,
            });
        }
    }
    // Connectivity by flood fill over verified pairs.
    let mut reached = BTreeSet::from([0usize]);
    let mut frontier = vec![0usize];
    while let Some(i) = frontier.pop() {
        for p in &verified {
            let (a, b) = (p.a.index(), p.b.index());
            let other = if a == i {
                b
            } else if b == i {
                a
            } else {
                continue;
            };
            if reached.insert(other) {
                frontier.push(other);
            }
        }
    }
    inlier_counts.sort_unstable();
    let counts: Vec<usize> = features.iter().map(|f| f.keypoints.len()).collect();
    let tracks = build_tracks(&counts, &verified).unwrap();
    println!(
        "{} of {} pairs verified, median {} inliers; {} tracks ({} conflicting matches left out), \
         lengths {:?}",
        verified.len(),
        pairs.len(),
        inlier_counts[inlier_counts.len() / 2],
        tracks.tracks.len(),
        tracks.conflicts,
        tracks.length_histogram()
    );
    assert_eq!(
        reached.len(),
        n,
        "images reached from the first: {reached:?}"
    );
    assert!(verified.len() >= n - 1);
    for t in &tracks.tracks {
        assert!(t.elements.windows(2).all(|w| w[0].image != w[1].image));
    }
}
