//! `cargo xtask bench matching`: exhaustive matching of the 29 `lund` photos by timesift and by
//! COLMAP's CPU `exhaustive_matcher`, both with 2 threads, in one run: verified pairs, median
//! inliers per verified pair, and the time of matching plus verification (features excluded
//! on both sides; COLMAP's time is the wall time of its `exhaustive_matcher` process).
//!
//! timesift uses the settings of the `match` stage for SIFT: RootSIFT, contrast threshold 0.02
//! (COLMAP's peak threshold), at most 8192 keypoints, ratio 0.8 on descriptor angles with a mutual
//! check, fundamental-matrix verification at 4 px with 15 inliers at least, then guided matching
//! along the epipolar lines of the verified pairs (COLMAP's `guided_matching` is off by default:
//! its counts are those of the descriptor matches that passed verification). Then the same
//! pairs coarse to fine, as the match stage matches them by default
//! (`timesift_matching::staged`): its verified pairs, matches, the share of the exhaustive
//! matches it finds again and the time ratio.

use std::time::Instant;

use rayon::prelude::*;
use timesift_core::EpochId;
use timesift_features::{
    DetectorOptions, FeatureExtractor, KeypointLimit, SiftExtractor, SiftNormalization,
};
use timesift_matching::guided::{GuidedOptions, grow_verified};
use timesift_matching::pairs::{PairPolicy, select};
use timesift_matching::preselect::{PreselectOptions, coarse_matches, preselect};
use timesift_matching::verify::{VerifyOptions, verify_pair};
use timesift_matching::{
    FloatDistance, Match, MatchOptions, MatchedBy, StagedMatches, StagedOptions, match_descriptors,
    staged_matches,
};

const SCRIPT: &str = include_str!("../scripts/colmap_db_stats.py");
const THREADS: usize = 2;

pub fn run() -> anyhow::Result<()> {
    let dir = crate::shared_data().join("opensfm/lund/images");
    let paths = crate::lund_images()?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(THREADS)
        .build()?;
    let extractor = SiftExtractor {
        detector: DetectorOptions {
            limit: Some(KeypointLimit::spread(8192)),
            contrast_threshold: 0.02,
            ..DetectorOptions::default()
        },
        normalization: SiftNormalization::Root,
    };
    let (ours, features_seconds) = pool.install(|| -> anyhow::Result<_> {
        let start = Instant::now();
        let features = paths
            .par_iter()
            .map(|p| timesift_features::files::extract_file(p, &extractor as &dyn FeatureExtractor))
            .collect::<Result<Vec<_>, _>>()?;
        Ok((features, start.elapsed().as_secs_f64()))
    })?;
    let n = ours.len();
    let pairs = select(
        &(0..n).collect::<Vec<_>>(),
        &vec![None; n],
        PairPolicy::Exhaustive,
    );
    let options = MatchOptions {
        ratio_on: FloatDistance::Angle,
        ..MatchOptions::default()
    };
    let (counts, seconds) = pool.install(|| -> anyhow::Result<_> {
        let start = Instant::now();
        let verified = pairs
            .par_iter()
            .map(
                |&(a, b)| -> anyhow::Result<Option<(usize, usize, Vec<Match>)>> {
                    let (ka, da) = (&ours[a].keypoints, &ours[a].descriptors);
                    let (kb, db) = (&ours[b].keypoints, &ours[b].descriptors);
                    let m = match_descriptors(da, db, &options)?;
                    let Some(verified) = verify_pair(ka, kb, &m, None, &VerifyOptions::default())?
                    else {
                        return Ok(None);
                    };
                    let grown =
                        grow_verified(ka, da, kb, db, &verified, &GuidedOptions::default())?;
                    Ok(Some((grown.len(), verified.inliers.len(), grown)))
                },
            )
            .collect::<anyhow::Result<Vec<_>>>()?;
        Ok((verified, start.elapsed().as_secs_f64()))
    })?;
    let (counts, exhaustive): (Vec<_>, Vec<_>) = counts
        .into_iter()
        .map(|c| match c {
            Some((grown, unguided, matches)) => (Some((grown, unguided)), matches),
            None => (None, Vec::new()),
        })
        .unzip();
    let verified_set: Vec<(usize, usize)> = pairs
        .iter()
        .zip(&counts)
        .filter(|(_, c)| c.is_some())
        .map(|(p, _)| *p)
        .collect();
    let verified_components = components(n, &verified_set);
    let pair_inliers = counts;
    let counts: Vec<(usize, usize)> = pair_inliers.iter().flatten().copied().collect();
    let median = |mut v: Vec<usize>| {
        v.sort_unstable();
        v.get(v.len() / 2).copied().unwrap_or(0)
    };
    let verified_pairs = counts.len();
    let median_unguided = median(counts.iter().map(|c| c.1).collect());
    let median_inliers = median(counts.iter().map(|c| c.0).collect());
    let keypoints = ours.iter().map(|f| f.keypoints.len()).sum::<usize>() as f64 / n as f64;
    println!(
        "lund, {n} images, {} pairs, exhaustive, {THREADS} threads (features excluded from times)",
        pairs.len()
    );
    println!(
        "  {:<10} {:>10} {:>15} {:>15} {:>12}",
        "", "keypoints", "verified pairs", "median inliers", "seconds"
    );
    println!(
        "  {:<10} {keypoints:>10.0} {verified_pairs:>15} {median_inliers:>15} {seconds:>12.1}   \
         (features: {features_seconds:.1} s; median {median_unguided} inliers before guided \
         matching)",
        "timesift",
    );
    println!(
        "  verified pair graph: {verified_components} connected component{}",
        if verified_components == 1 { "" } else { "s" }
    );
    // Coarse to fine, as the match stage matches a pair by default: the same pairs.
    let (staged, staged_seconds) = pool.install(|| -> anyhow::Result<_> {
        let start = Instant::now();
        let staged = pairs
            .par_iter()
            .map(|&(a, b)| {
                staged_matches(
                    (&ours[a].keypoints, &ours[a].descriptors),
                    (&ours[b].keypoints, &ours[b].descriptors),
                    &StagedOptions::default(),
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok((staged, start.elapsed().as_secs_f64()))
    })?;
    print_coarse_to_fine(&exhaustive, &staged, (seconds, staged_seconds));
    // Preselection, as the match stage runs it with `[align] pair_selection = "preselect"`.
    let preselect_options = PreselectOptions::default();
    let features: Vec<_> = ours
        .iter()
        .map(|f| (f.keypoints.as_slice(), &f.descriptors))
        .collect();
    let (selected, preselect_seconds) = pool.install(|| -> anyhow::Result<_> {
        let start = Instant::now();
        let coarse = coarse_matches(&features, &pairs, &preselect_options)?;
        let selected = preselect(&coarse, &vec![EpochId::from(0); n], &preselect_options);
        Ok((selected, start.elapsed().as_secs_f64()))
    })?;
    // The verified pairs preselection keeps, and their share of all verified inliers.
    let (mut kept, mut kept_inliers, mut all_inliers) = (Vec::new(), 0, 0);
    for (p, c) in pairs.iter().zip(&pair_inliers) {
        let Some((inliers, _)) = c else { continue };
        all_inliers += inliers;
        if selected.binary_search(p).is_ok() {
            kept.push(*p);
            kept_inliers += inliers;
        }
    }
    let inlier_share = kept_inliers as f64 / all_inliers.max(1) as f64;
    println!(
        "  preselection ({} largest-scale keypoints per image, {} coarse matches or an image's {} \
         best): {} of {} pairs in {preselect_seconds:.1} s; they hold {} of the {} verified \
         pairs ({:.1} % of the inliers; {} components among them)",
        preselect_options.keypoints,
        preselect_options.min_matches,
        preselect_options.keep_best,
        selected.len(),
        pairs.len(),
        kept.len(),
        verified_set.len(),
        100.0 * inlier_share,
        components(n, &kept),
    );
    match colmap(&dir) {
        Ok((report, colmap_seconds)) => {
            let number = |key: &str| report[key].as_f64().unwrap_or(f64::NAN);
            println!(
                "  {:<10} {:>10.0} {:>15} {:>15} {colmap_seconds:>12.1}",
                "COLMAP",
                number("keypoints"),
                number("verified_pairs"),
                number("median_inliers"),
            );
            println!(
                "  time ratio COLMAP / timesift: {:.2}",
                colmap_seconds / seconds
            );
        }
        Err(e) => println!("  COLMAP unavailable: {e}"),
    }
    Ok(())
}

/// The coarse-to-fine matches against the exhaustive ones of the same pairs: verified pairs,
/// matches, the share of the exhaustive matches found again, how many pairs went which way,
/// and the time ratio.
fn print_coarse_to_fine(
    exhaustive: &[Vec<Match>],
    staged: &[StagedMatches],
    (exhaustive_seconds, staged_seconds): (f64, f64),
) {
    let verified = staged.iter().filter(|s| !s.matches.is_empty()).count();
    let coarse = staged
        .iter()
        .filter(|s| s.by == MatchedBy::CoarseThenGuided)
        .count();
    let (mut found, mut reference, mut total) = (0usize, 0usize, 0usize);
    for (e, s) in exhaustive.iter().zip(staged) {
        let mine: std::collections::HashSet<(u32, u32)> =
            s.matches.iter().map(|m| (m.query, m.train)).collect();
        found += e
            .iter()
            .filter(|m| mine.contains(&(m.query, m.train)))
            .count();
        reference += e.len();
        total += s.matches.len();
    }
    let mut sizes: Vec<usize> = staged
        .iter()
        .map(|s| s.matches.len())
        .filter(|&n| n > 0)
        .collect();
    sizes.sort_unstable();
    println!(
        "  coarse to fine (the match stage's default, {} largest-scale keypoints first): {verified} \
         verified pairs, median {} inliers, {total} matches against {reference} exhaustive \
         ({:.1} % of those found again), {coarse} of {} pairs matched coarse then guided, \
         {staged_seconds:.1} s: {:.2} x faster",
        StagedOptions::default().coarse_keypoints,
        sizes.get(sizes.len() / 2).copied().unwrap_or(0),
        100.0 * found as f64 / reference.max(1) as f64,
        staged.len(),
        exhaustive_seconds / staged_seconds,
    );
}

/// Connected components of the graph of `n` images with edges `pairs`.
fn components(n: usize, pairs: &[(usize, usize)]) -> usize {
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut count = n;
    for &(a, b) in pairs {
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        if ra != rb {
            parent[ra] = rb;
            count -= 1;
        }
    }
    count
}

/// COLMAP's CPU feature extraction then exhaustive matching; the stats of its database and the
/// matcher's wall time.
fn colmap(images: &std::path::Path) -> anyhow::Result<(serde_json::Value, f64)> {
    let dir = std::env::temp_dir().join(format!("timesift-bench-matching-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let database = dir.join("colmap.db");
    let threads = THREADS.to_string();
    crate::colmap(&[
        "feature_extractor".into(),
        "--database_path".into(),
        database.display().to_string(),
        "--image_path".into(),
        images.display().to_string(),
        "--ImageReader.single_camera".into(),
        "1".into(),
        "--SiftExtraction.use_gpu".into(),
        "0".into(),
        "--SiftExtraction.num_threads".into(),
        threads.clone(),
    ])?;
    let seconds = crate::colmap(&[
        "exhaustive_matcher".into(),
        "--database_path".into(),
        database.display().to_string(),
        "--SiftMatching.use_gpu".into(),
        "0".into(),
        "--SiftMatching.num_threads".into(),
        threads,
    ])?;
    let script = dir.join("colmap_db_stats.py");
    std::fs::write(&script, SCRIPT)?;
    let report = crate::python_json(&script, &[database.display().to_string()])?;
    let _ = std::fs::remove_dir_all(&dir);
    Ok((report, seconds))
}
