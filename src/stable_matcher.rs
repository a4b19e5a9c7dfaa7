//! The descriptor half of the `stp` strategy, and of `timesift`'s second look for inter-epoch
//! ties (`[align] join_epoch_ties`), for the align stage: the descriptors of the tie
//! points' observations come from the project's feature files (`work/features/<image>.feat`),
//! read one image at a time and only for the keypoints asked for, then
//! `timesift-matching::stp` pairs the points.

use std::collections::BTreeMap;
use std::path::PathBuf;

use timesift_align::{
    GuidedMatch, GuidedQuery, OfferedTiePoint, StableMatch, StableMatcher, StableSearch,
};
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
        let table = self.descriptors_of(wanted)?;
        let dim = table
            .values()
            .next()
            .map(Vec::len)
            .ok_or_else(|| "no tie point to match".to_string())?;
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

/// Largest descriptor distance of a guided match (unit-norm descriptors: 0 same, √2
/// unrelated): the candidates are few, so the nearest may be unrelated ground.
const GUIDED_MAX_DISTANCE: f32 = 0.8;
/// A guided match's distance over the second-nearest candidate's, at most: among a handful of
/// keypoints of one small window, looser than the feature matching's ratio over a whole image.
const GUIDED_RATIO: f32 = 0.9;

impl FeatureFileMatcher {
    /// Per image, the descriptors of the keypoints `wanted` names, unit-norm, by keypoint; each
    /// feature file read once. Descriptors of unequal length are an error naming the file.
    fn descriptors_of(
        &self,
        wanted: BTreeMap<usize, Vec<usize>>,
    ) -> Result<BTreeMap<(usize, usize), Vec<f32>>, String> {
        let mut dim = None;
        let mut table = BTreeMap::new();
        for (image, mut features) in wanted {
            features.sort_unstable();
            features.dedup();
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
        Ok(table)
    }
}

/// The mean of unit vectors, made unit again; `None` for none or vectors of unequal length.
fn mean_direction<'a>(vectors: impl Iterator<Item = &'a Vec<f32>>) -> Option<Vec<f32>> {
    let mut sum: Option<Vec<f32>> = None;
    for v in vectors {
        match &mut sum {
            None => sum = Some(v.clone()),
            Some(s) if s.len() == v.len() => s.iter_mut().zip(v).for_each(|(a, b)| *a += b),
            Some(_) => return None,
        }
    }
    let mut sum = sum?;
    let norm = sum
        .iter()
        .map(|x| x * x)
        .sum::<f32>()
        .sqrt()
        .max(f32::EPSILON);
    sum.iter_mut().for_each(|x| *x /= norm);
    Some(sum)
}

fn distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt()
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
    /// A point is described by the mean of its observations' descriptors (one epoch's views
    /// of it look alike); the nearest candidate is taken when within `GUIDED_MAX_DISTANCE`
    /// and `GUIDED_RATIO` of the second. The candidates' descriptors are read one image at
    /// a time; the points' are read once.
    fn guided_matches(
        &self,
        queries: &[GuidedQuery<'_>],
    ) -> Result<Vec<Option<GuidedMatch>>, String> {
        // One description per distinct point (its observations' slice).
        let mut point_of: BTreeMap<(usize, usize), usize> = BTreeMap::new();
        let mut observations: Vec<&[timesift_core::TrackElement]> = Vec::new();
        let query_point: Vec<usize> = queries
            .iter()
            .map(|q| {
                let key = (q.observations.as_ptr() as usize, q.observations.len());
                *point_of.entry(key).or_insert_with(|| {
                    observations.push(q.observations);
                    observations.len() - 1
                })
            })
            .collect();
        let mut wanted: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for e in observations.iter().flat_map(|o| o.iter()) {
            wanted
                .entry(e.image.index())
                .or_default()
                .push(e.feature.index());
        }
        let table = self.descriptors_of(wanted)?;
        let points: Vec<Option<Vec<f32>>> = observations
            .iter()
            .map(|o| {
                mean_direction(
                    o.iter()
                        .filter_map(|e| table.get(&(e.image.index(), e.feature.index()))),
                )
            })
            .collect();
        drop(table);
        let mut by_image: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (q, query) in queries.iter().enumerate() {
            by_image.entry(query.image.index()).or_default().push(q);
        }
        let mut found = vec![None; queries.len()];
        for (image, asked) in by_image {
            let mut wanted = BTreeMap::new();
            wanted.insert(
                image,
                asked
                    .iter()
                    .flat_map(|&q| queries[q].candidates.iter().map(|f| f.index()))
                    .collect(),
            );
            let candidates = self.descriptors_of(wanted)?;
            for q in asked {
                let Some(point) = &points[query_point[q]] else {
                    continue;
                };
                let mut best = (f32::INFINITY, None);
                let mut second = f32::INFINITY;
                for f in &queries[q].candidates {
                    let Some(v) = candidates.get(&(image, f.index())) else {
                        continue;
                    };
                    if v.len() != point.len() {
                        return Err(format!(
                            "descriptors of {} and {} values in one project (features stage \
                             run with different methods?)",
                            v.len(),
                            point.len()
                        ));
                    }
                    let d = distance(point, v);
                    if d < best.0 {
                        second = best.0;
                        best = (d, Some(*f));
                    } else if d < second {
                        second = d;
                    }
                }
                if let (d, Some(feature)) = best
                    && d <= GUIDED_MAX_DISTANCE
                    && d <= GUIDED_RATIO * second
                {
                    found[q] = Some(GuidedMatch {
                        feature,
                        distance: f64::from(d),
                    });
                }
            }
        }
        Ok(found)
    }
}
