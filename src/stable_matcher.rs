//! The descriptor half of the `stp` strategy, and of `timesift`'s second look for inter-epoch
//! ties (`[align] join_epoch_ties`), for the align stage: the descriptors of the tie
//! points' observations come from the project's feature files (`work/features/<image>.feat`),
//! read one image at a time and only for the keypoints asked for, then
//! `timesift-matching::stp` pairs the points.

use std::collections::BTreeMap;
use std::path::PathBuf;

use timesift_align::{OfferedTiePoint, StableMatch, StableMatcher, StableSearch};
use timesift_core::Descriptors;
use timesift_matching::storage::read_features;
use timesift_matching::stp::{StpOptions, TiePoint, stable_tie_points};

/// Reads descriptors from a project's feature files.
pub struct FeatureFileMatcher {
    /// `work/features` of the project.
    pub features_dir: PathBuf,
    /// Seed of the similarity RANSAC.
    pub seed: u64,
}

impl FeatureFileMatcher {
    /// The descriptors of every observation of `points`, as unit-norm float vectors, concatenated
    /// per point; and their length.
    fn tie_points(&self, points: &[OfferedTiePoint<'_>]) -> Result<(Vec<TiePoint>, usize), String> {
        // Which keypoints of which image are needed.
        let mut wanted: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for p in points {
            for e in p.observations {
                wanted
                    .entry(e.image.index())
                    .or_default()
                    .push(e.feature.index());
            }
        }
        let mut dim = None;
        let mut table: BTreeMap<(usize, usize), Vec<f32>> = BTreeMap::new();
        for (image, features) in wanted {
            let path = self.features_dir.join(format!("{image}.feat"));
            let (_, descriptors) = read_features(&path).map_err(|e| e.to_string())?;
            for f in features {
                let v = descriptor(&descriptors, f)
                    .ok_or_else(|| format!("{}: keypoint {f} has no descriptor", path.display()))?;
                match dim {
                    None => dim = Some(v.len()),
                    Some(d) if d != v.len() => {
                        return Err(format!(
                            "{}: descriptors of {} values where others have {d} (features of \
                             different methods in one project?)",
                            path.display(),
                            v.len()
                        ));
                    }
                    Some(_) => {}
                }
                table.insert((image, f), v);
            }
        }
        let dim = dim.ok_or_else(|| "no tie point to match".to_string())?;
        let tie_points = points
            .iter()
            .map(|p| TiePoint {
                position: p.position,
                descriptors: p
                    .observations
                    .iter()
                    .filter_map(|e| table.get(&(e.image.index(), e.feature.index())))
                    .flatten()
                    .copied()
                    .collect(),
            })
            .collect();
        Ok((tie_points, dim))
    }
}

/// Descriptor `i` as a unit-norm float vector. A binary descriptor becomes ±1/√bits per bit, so
/// that its Euclidean distance is 2·√(Hamming distance / bits).
fn descriptor(descriptors: &Descriptors, i: usize) -> Option<Vec<f32>> {
    match descriptors {
        Descriptors::Float { dim, data } => {
            let v = data.get(i * dim..(i + 1) * dim)?;
            let norm = v
                .iter()
                .map(|x| x * x)
                .sum::<f32>()
                .sqrt()
                .max(f32::EPSILON);
            Some(v.iter().map(|x| x / norm).collect())
        }
        Descriptors::Binary { bytes, data } => {
            let v = data.get(i * bytes..(i + 1) * bytes)?;
            let scale = 1.0 / ((8 * bytes) as f32).sqrt();
            Some(
                v.iter()
                    .flat_map(|b| (0..8).map(move |k| (b >> k) & 1))
                    .map(|bit| if bit == 1 { scale } else { -scale })
                    .collect(),
            )
        }
    }
}

impl StableMatcher for FeatureFileMatcher {
    fn stable_pairs(
        &self,
        reference: &[OfferedTiePoint<'_>],
        other: &[OfferedTiePoint<'_>],
        search: &StableSearch,
    ) -> Result<Vec<StableMatch>, String> {
        let (reference, dim) = self.tie_points(reference)?;
        let (other, other_dim) = self.tie_points(other)?;
        if dim != other_dim {
            return Err(format!(
                "descriptors of {dim} and {other_dim} values in one project (features stage \
                 run with different methods?)"
            ));
        }
        let options = StpOptions {
            radius: search.radius,
            ransac_threshold: search.tolerance,
            seed: self.seed,
            ..StpOptions::default()
        };
        let result =
            stable_tie_points(&reference, &other, dim, &options).map_err(|e| e.to_string())?;
        tracing::info!(
            candidates = result.candidates,
            stable = result.pairs.len(),
            moved = result.moved.len(),
            "stable tie points matched"
        );
        Ok(result
            .pairs
            .iter()
            .map(|p| StableMatch {
                reference: p.reference,
                other: p.other,
                score: f64::from(p.score),
            })
            .collect())
    }
}
