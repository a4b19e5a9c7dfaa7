//! Matching one pair coarse to fine: the largest-scale keypoints of both images matched
//! exhaustively and verified, then every keypoint searched near that geometry
//! ([`guided`](crate::guided)): along its epipolar lines, or, for a pair a homography explains
//! (nadir views of flat ground, where epipolar lines are ill-determined), about the
//! homography's transfer, then verified again.
//!
//! Exhaustive matching compares every descriptor of one image with every one of the other: a
//! pair of 3,000-keypoint images is 9 million distances, and a block of 800 images has 26,000
//! pairs, which made it the costliest step of the orientation. A thousand keypoints per image
//! find a pair's geometry as well as all of them do (a fundamental matrix needs eight matches,
//! RANSAC a few dozen); the guided search then looks at a few dozen candidates per keypoint.
//! A match found exhaustively that fits the geometry lies in its region and wins the ratio
//! test there too (it had fewer competitors), so the pair ends with nearly the same matches,
//! and more: those that lost the global ratio test to a look-alike elsewhere. What it can lose
//! is the few verified matches whose descriptors are less alike than nearly all others'
//! (exhaustive matching keeps them, the guided search's distance bound does not); the geometry
//! of the grown matches, which cover the image where the coarse ones may cluster, is searched a
//! second time.
//!
//! Where the coarse stage cannot stand for the pair, the pair is matched exhaustively, as
//! without it: fewer coarse inliers than asked (weak pairs, and pairs across epochs whose
//! ground changed, where every match counts), or no homography beside a degenerate epipolar
//! geometry.

use nalgebra::{Matrix3, Vector3};
use timesift_core::{Descriptors, Keypoint};
use timesift_geometry::homography::TwoViewType;

use crate::guided::{GuidedOptions, as_alike_as, check_counts, grow_verified, transfer_matches};
use crate::preselect::{descriptor_rows, largest_scale_indices};
use crate::verify::{VerifyOptions, verify_pair};
use crate::{Match, MatchOptions, MatchingError, match_descriptors};

/// Options of [`staged_matches`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StagedOptions {
    /// Keypoints per image matched exhaustively first: the largest-scale ones. 0 matches every
    /// keypoint exhaustively in one stage.
    pub coarse_keypoints: usize,
    /// The coarse stage stands for the pair when it verifies a general epipolar geometry with at
    /// least this many inliers; otherwise the pair is matched exhaustively.
    pub min_coarse_inliers: usize,
    /// Descriptor matching (ratio test, mutual check) of both the coarse and the exhaustive
    /// stage.
    pub matching: MatchOptions,
    /// Geometric verification.
    pub verify: VerifyOptions,
    /// The guided search that grows the verified matches.
    pub guided: GuidedOptions,
    /// `guided.distance_percentile` after the coarse stage. Exhaustive matching keeps its own
    /// verified matches beside the guided ones, however unalike their descriptors; after the
    /// coarse stage only the coarse keypoints' are kept, so the guided search admits as
    /// unalike a match as nearly all verified ones are.
    pub coarse_distance_percentile: usize,
}

impl Default for StagedOptions {
    fn default() -> Self {
        let guided = GuidedOptions::default();
        Self {
            coarse_keypoints: 1024,
            min_coarse_inliers: 20,
            matching: guided.matching,
            verify: VerifyOptions::default(),
            guided,
            coarse_distance_percentile: 99,
        }
    }
}

/// How a pair was matched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatchedBy {
    /// The coarse keypoints verified the pair, the guided search found the rest.
    CoarseThenGuided,
    /// Every keypoint exhaustively (the coarse stage was off, not smaller than the images'
    /// keypoints, or could not stand for the pair).
    Exhaustive,
}

/// A pair's verified matches (ordered as [`grow_verified`] orders them; empty when the pair does
/// not verify) and how they were found.
#[derive(Debug, Clone, PartialEq)]
pub struct StagedMatches {
    /// The verified matches.
    pub matches: Vec<Match>,
    /// Which way.
    pub by: MatchedBy,
}

/// The verified matches of keypoints `ka` (descriptors `da`) with `kb` (`db`): putative by
/// descriptor, verified geometrically, grown by guided matching; coarse to fine where the
/// coarse stage can stand for the pair (see the module's documentation).
pub fn staged_matches(
    (ka, da): (&[Keypoint], &Descriptors),
    (kb, db): (&[Keypoint], &Descriptors),
    options: &StagedOptions,
) -> Result<StagedMatches, MatchingError> {
    check_counts((ka, da), (kb, db))?;
    let coarse = options.coarse_keypoints;
    if coarse > 0
        && (ka.len() > coarse || kb.len() > coarse)
        && let Some(matches) = coarse_then_guided((ka, da), (kb, db), options)?
    {
        return Ok(StagedMatches {
            matches,
            by: MatchedBy::CoarseThenGuided,
        });
    }
    let putative = match_descriptors(da, db, &options.matching)?;
    let matches = match verify_pair(ka, kb, &putative, None, &options.verify)? {
        Some(verified) => grow_verified(ka, da, kb, db, &verified, &options.guided)?,
        None => Vec::new(),
    };
    Ok(StagedMatches {
        matches,
        by: MatchedBy::Exhaustive,
    })
}

/// The coarse stage and the guided search; `None` where the coarse stage cannot stand for the
/// pair.
fn coarse_then_guided(
    (ka, da): (&[Keypoint], &Descriptors),
    (kb, db): (&[Keypoint], &Descriptors),
    options: &StagedOptions,
) -> Result<Option<Vec<Match>>, MatchingError> {
    let (ia, ib) = (
        largest_scale_indices(ka, options.coarse_keypoints),
        largest_scale_indices(kb, options.coarse_keypoints),
    );
    let putative: Vec<Match> = match_descriptors(
        &descriptor_rows(da, &ia),
        &descriptor_rows(db, &ib),
        &options.matching,
    )?
    .into_iter()
    .map(|m| Match {
        query: ia[m.query as usize] as u32,
        train: ib[m.train as usize] as u32,
        distance: m.distance,
    })
    .collect();
    if putative.len() < options.min_coarse_inliers {
        return Ok(None);
    }
    let Some(verified) = verify_pair(ka, kb, &putative, None, &options.verify)? else {
        return Ok(None);
    };
    if verified.inliers.len() < options.min_coarse_inliers {
        return Ok(None);
    }
    let guided = GuidedOptions {
        distance_percentile: options.coarse_distance_percentile,
        ..options.guided
    };
    if verified.kind == TwoViewType::General && verified.fundamental.is_some() {
        let grown = grow_verified(ka, da, kb, db, &verified, &guided)?;
        // The coarse keypoints may cluster where an image has most large blobs, and lens
        // distortion bends lines away from them: the geometry of the grown matches, which
        // cover the image, searched again.
        return Ok(Some(
            match verify_pair(ka, kb, &grown, None, &options.verify)? {
                Some(again)
                    if again.kind == TwoViewType::General && again.fundamental.is_some() =>
                {
                    grow_verified(ka, da, kb, db, &again, &guided)?
                }
                _ => grown,
            },
        ));
    }
    // A homography explains the pair: searched about its transfer instead of along lines.
    let Some(h) = verified.homography else {
        return Ok(None);
    };
    let radius = transfer_radius(ka, kb, &verified.inliers, &h, options.verify.max_error_px);
    // A lone candidate in the disc passes the ratio test: only matches as alike as the coarse
    // ones.
    let Some(matching) = as_alike_as(&verified.inliers, da, &guided) else {
        return Ok(None);
    };
    let putative = transfer_matches((ka, da), (kb, db), &h, radius, &matching)?;
    match verify_pair(ka, kb, &putative, None, &options.verify)? {
        Some(verified) => grow_verified(ka, da, kb, db, &verified, &guided).map(Some),
        None => Ok(None),
    }
}

/// How far from the homography's transfer a pair's matches are searched, pixels: twice the
/// 95th percentile of the coarse inliers' transfer errors (their parallax off the plane), at
/// least twice the inlier threshold.
fn transfer_radius(
    ka: &[Keypoint],
    kb: &[Keypoint],
    inliers: &[Match],
    h: &Matrix3<f64>,
    max_error_px: f64,
) -> f64 {
    let mut errors: Vec<f64> = inliers
        .iter()
        .filter_map(|m| {
            let (p, q) = (ka.get(m.query as usize)?, kb.get(m.train as usize)?);
            let t = h * Vector3::new(p.x, p.y, 1.0);
            let e = ((t.x / t.z - q.x).powi(2) + (t.y / t.z - q.y).powi(2)).sqrt();
            e.is_finite().then_some(e)
        })
        .collect();
    errors.sort_unstable_by(f64::total_cmp);
    let p95 = errors.get(errors.len() * 95 / 100).copied().unwrap_or(0.0);
    (2.0 * p95).max(2.0 * max_error_px)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Rotation3, Vector3};
    use timesift_core::SeededRng;

    use super::*;

    /// Two 1200 × 900 views 4 m apart (a small yaw between them) of `shared` points, at depths
    /// of 15–40 m (`flat`: all at 25 m, which a homography explains), each image with `extra`
    /// keypoints of its own; a point's keypoints share its scale, and their descriptors are two
    /// noisy copies of one. Image b's keypoints are shuffled; `truth[i]` is the true match in b
    /// of keypoint i of a.
    struct Scene {
        ka: Vec<Keypoint>,
        da: Descriptors,
        kb: Vec<Keypoint>,
        db: Descriptors,
        truth: Vec<Option<u32>>,
    }

    fn unit(rng: &mut SeededRng, base: Option<&[f32]>, noise: f64) -> Vec<f32> {
        let v: Vec<f32> = (0..128)
            .map(|k| {
                let n = rng.normal() as f32;
                base.map_or(n, |b| b[k] + (noise / 128f64.sqrt()) as f32 * n)
            })
            .collect();
        let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.into_iter().map(|x| x / norm).collect()
    }

    fn keypoint(x: f64, y: f64, scale: f64) -> Keypoint {
        Keypoint {
            x,
            y,
            scale,
            orientation: 0.0,
            response: 1.0,
            octave: 0,
        }
    }

    fn scene(shared: usize, extra: usize, flat: bool, seed: u64) -> Scene {
        let mut rng = SeededRng::new(seed);
        let (f, cx, cy) = (800.0, 600.0, 450.0);
        let rotation_b = Rotation3::from_euler_angles(0.0, 0.0, 0.03);
        let centre_b = Vector3::new(4.0, 0.5, 0.0);
        let project = |rotation: &Rotation3<f64>, centre: &Vector3<f64>, x: &Vector3<f64>| {
            let c = rotation * (x - centre);
            let (u, v) = (f * c.x / c.z + cx, f * c.y / c.z + cy);
            (c.z > 0.0 && (0.0..1200.0).contains(&u) && (0.0..900.0).contains(&v)).then_some((u, v))
        };
        let (mut ka, mut da, mut kb_order, mut db_rows) = (vec![], vec![], vec![], vec![]);
        let mut truth = Vec::new();
        while ka.len() < shared {
            let depth = if flat {
                25.0
            } else {
                rng.uniform_range(15.0, 40.0)
            };
            let (u, v) = (
                rng.uniform_range(0.0, 1200.0),
                rng.uniform_range(0.0, 900.0),
            );
            let x = Vector3::new((u - cx) / f * depth, (v - cy) / f * depth, depth);
            let Some((ub, vb)) = project(&rotation_b, &centre_b, &x) else {
                continue;
            };
            let scale = 1.5 * (3.0 * rng.uniform()).exp();
            let base = unit(&mut rng, None, 0.0);
            let noisy = |rng: &mut SeededRng, p: f64| p + 0.2 * rng.normal();
            ka.push(keypoint(noisy(&mut rng, u), noisy(&mut rng, v), scale));
            da.extend(unit(&mut rng, Some(&base), 0.2));
            truth.push(Some(kb_order.len() as u32));
            kb_order.push(keypoint(noisy(&mut rng, ub), noisy(&mut rng, vb), scale));
            db_rows.push(unit(&mut rng, Some(&base), 0.2));
        }
        for _ in 0..extra {
            let scale = 1.5 * (3.0 * rng.uniform()).exp();
            ka.push(keypoint(
                rng.uniform_range(0.0, 1200.0),
                rng.uniform_range(0.0, 900.0),
                scale,
            ));
            da.extend(unit(&mut rng, None, 0.0));
            truth.push(None);
            let scale = 1.5 * (3.0 * rng.uniform()).exp();
            kb_order.push(keypoint(
                rng.uniform_range(0.0, 1200.0),
                rng.uniform_range(0.0, 900.0),
                scale,
            ));
            db_rows.push(unit(&mut rng, None, 0.0));
        }
        // Shuffle b: position k of the shuffled order holds original keypoint order[k].
        let mut order: Vec<usize> = (0..kb_order.len()).collect();
        for k in (1..order.len()).rev() {
            order.swap(k, rng.below(k + 1));
        }
        let mut moved_to = vec![0u32; order.len()];
        for (k, &o) in order.iter().enumerate() {
            moved_to[o] = k as u32;
        }
        let truth = truth
            .into_iter()
            .map(|t| t.map(|j| moved_to[j as usize]))
            .collect();
        let kb = order.iter().map(|&o| kb_order[o]).collect();
        let db = order.iter().flat_map(|&o| db_rows[o].clone()).collect();
        let float = |data| Descriptors::Float { dim: 128, data };
        Scene {
            ka,
            da: float(da),
            kb,
            db: float(db),
            truth,
        }
    }

    impl Scene {
        fn matched(&self, options: &StagedOptions) -> StagedMatches {
            staged_matches((&self.ka, &self.da), (&self.kb, &self.db), options).unwrap()
        }

        /// Right and wrong matches.
        fn score(&self, matches: &[Match]) -> (usize, usize) {
            let right = matches
                .iter()
                .filter(|m| self.truth[m.query as usize] == Some(m.train))
                .count();
            (right, matches.len() - right)
        }
    }

    fn exhaustive() -> StagedOptions {
        StagedOptions {
            coarse_keypoints: 0,
            ..StagedOptions::default()
        }
    }

    #[test]
    fn coarse_to_fine_finds_what_exhaustive_matching_finds() {
        for flat in [false, true] {
            let scene = scene(1500, 800, flat, 3);
            let options = StagedOptions {
                coarse_keypoints: 400,
                ..StagedOptions::default()
            };
            let staged = scene.matched(&options);
            let all = scene.matched(&exhaustive());
            assert_eq!(staged.by, MatchedBy::CoarseThenGuided, "flat {flat}");
            assert_eq!(all.by, MatchedBy::Exhaustive);
            let (right, wrong) = scene.score(&staged.matches);
            let (all_right, _) = scene.score(&all.matches);
            println!(
                "flat {flat}: coarse to fine {right} right, {wrong} wrong; exhaustive {all_right} \
                 right of 1500"
            );
            assert!(all_right >= 1400, "flat {flat}: exhaustive {all_right}");
            assert!(
                right * 100 >= all_right * 98,
                "flat {flat}: {right} of {all_right}"
            );
            assert!(wrong * 200 <= right, "flat {flat}: {wrong} wrong");
        }
    }

    #[test]
    fn pairs_the_coarse_keypoints_cannot_verify_are_matched_exhaustively() {
        // 25 shared points among 1,200 keypoints per image: too few among the coarse ones.
        let scene = scene(25, 1175, false, 5);
        let options = StagedOptions {
            coarse_keypoints: 300,
            ..StagedOptions::default()
        };
        let staged = scene.matched(&options);
        assert_eq!(staged.by, MatchedBy::Exhaustive);
        assert_eq!(staged, scene.matched(&exhaustive()));
        let (right, wrong) = scene.score(&staged.matches);
        assert!(right >= 20 && wrong == 0, "{right} right, {wrong} wrong");
        // Images with no more keypoints than the coarse count: one exhaustive stage.
        let small = StagedOptions {
            coarse_keypoints: 5000,
            ..StagedOptions::default()
        };
        assert_eq!(scene.matched(&small).by, MatchedBy::Exhaustive);
    }

    #[test]
    fn descriptors_that_do_not_fit_their_keypoints_are_an_error() {
        let scene = scene(40, 10, false, 7);
        let short = Descriptors::Float {
            dim: 128,
            data: vec![0.0; 128 * (scene.kb.len() - 1)],
        };
        assert!(matches!(
            staged_matches(
                (&scene.ka, &scene.da),
                (&scene.kb, &short),
                &StagedOptions::default()
            ),
            Err(MatchingError::InvalidOption {
                name: "descriptors",
                ..
            })
        ));
    }
}
