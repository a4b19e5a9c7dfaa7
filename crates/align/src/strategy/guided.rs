//! `timesift`'s guided look for inter-epoch ties. The feature matching compares whole images:
//! a keypoint's nearest descriptor among thousands must be clearly nearer than the second, and
//! across epochs, where the ground's appearance changed (another season, another camera,
//! wet sand), most true correspondences fail that test and two surveys of one beach end up tied
//! by a few dozen points in a strip. Once the first block is oriented, every tie point is known
//! to a fraction of a metre, and so is where it appears in the images of the epochs that do not
//! see it yet: within a few pixels of its projection there are one or two keypoints, not
//! thousands, and the test becomes which of those few is the point, if any (the same move
//! COLMAP's and OpenMVG's guided matching make with a known epipolar geometry, here with the
//! point itself).
//!
//! Each point of the first block with three observations at least (on the stable ground when
//! one is given and the block has a datum) is projected into every oriented image of an epoch
//! it has no observation in; the keypoints within [`GUIDED_RADIUS_PX`] of the projection are
//! offered to the caller's matcher ([`StableMatcher::guided_matches`]), which names the one
//! whose descriptor clearly matches the point's. A keypoint claimed by several points goes to
//! the nearest by descriptor. A keypoint in another track joins that track to the point's (two
//! epochs' tracks, as `joined` joins them); a keypoint in no track becomes an observation of
//! the point. The second block then splits again what moved or lies off the stable ground.

use std::collections::HashMap;

use nalgebra::{Vector2, Vector3};
use timesift_core::{CameraModel, FeatureIndex, ImageId, TrackElement, project_world};

use crate::georef::Georeferenced;

use super::block::Block;
use super::stp::{GuidedQuery, StableMatcher};
use super::track_sets::TrackSets;

/// Search radius around a point's projection, pixels: a first block's inter-epoch placement
/// is off by a pixel or two where it is tied at all, and by a few where it hangs on few ties.
pub(crate) const GUIDED_RADIUS_PX: f64 = 6.0;
/// Fewest observations of a point sought in another epoch: its position rests on them.
const MIN_OBSERVATIONS: usize = 3;

/// Seeks every point of `placed` in the images of the epochs it is not seen in and adds what
/// `matcher` accepts to `sets`; the number of keypoints added and tracks joined.
pub(super) fn guided_ties(
    block: &Block,
    placed: &Georeferenced,
    matcher: &dyn StableMatcher,
    sets: &mut TrackSets<'_>,
) -> usize {
    let rec = &placed.reconstruction;
    let stable = block.stable_ground_for(placed);
    let sought: Vec<usize> = (0..rec.points.len())
        .filter(|&k| {
            let p = &rec.points[k];
            p.observations.len() >= MIN_OBSERVATIONS
                && stable.is_none_or(|s| s.contains(&p.position))
        })
        .collect();
    let epochs_of_point: Vec<Vec<usize>> = rec
        .points
        .iter()
        .map(|p| {
            let mut epochs: Vec<usize> = p
                .observations
                .iter()
                .filter_map(|e| block.epoch_of.get(e.image.index()).copied())
                .collect();
            epochs.sort_unstable();
            epochs.dedup();
            epochs
        })
        .collect();
    let points = PointGrid::new(rec.points.iter().map(|p| p.position), &sought);
    let footprints = footprints(rec);
    let mut queries = Vec::new();
    let mut asked = Vec::new();
    for (j, pose) in rec.poses.iter().enumerate() {
        let (Some(pose), Some(footprint), Some(&epoch)) =
            (pose, footprints[j], block.epoch_of.get(j))
        else {
            continue;
        };
        let Some(image) = block.sfm.images.get(j) else {
            continue;
        };
        let camera = &rec.cameras[image.group];
        let (w, h) = (f64::from(camera.width()), f64::from(camera.height()));
        let keypoints = KeypointGrid::new(&image.keypoints, GUIDED_RADIUS_PX);
        for k in points.within(footprint) {
            if epochs_of_point[k].binary_search(&epoch).is_ok() {
                continue;
            }
            let Ok(u) = project_world(camera, pose, &rec.points[k].position) else {
                continue;
            };
            if !(u.x >= 0.0 && u.y >= 0.0 && u.x < w && u.y < h) {
                continue;
            }
            let candidates = keypoints.near(&image.keypoints, &u, GUIDED_RADIUS_PX);
            if candidates.is_empty() {
                continue;
            }
            queries.push(GuidedQuery {
                observations: &rec.points[k].observations,
                image: ImageId::from(j),
                candidates,
            });
            asked.push(k);
        }
    }
    if queries.is_empty() {
        return 0;
    }
    let found = match matcher.guided_matches(&queries) {
        Ok(found) => found,
        Err(message) => {
            tracing::info!(%message, "no guided inter-epoch ties");
            return 0;
        }
    };
    // A keypoint claimed by several points goes to the nearest by descriptor.
    let mut claims: HashMap<(usize, usize), (f64, usize)> = HashMap::new();
    for (q, m) in found.iter().enumerate() {
        let Some(m) = m else { continue };
        let key = (queries[q].image.index(), m.feature.index());
        let better = claims.get(&key).is_none_or(|&(d, _)| m.distance < d);
        if better && m.distance.is_finite() {
            claims.insert(key, (m.distance, q));
        }
    }
    let mut accepted: Vec<(f64, usize, usize, usize)> = claims
        .into_iter()
        .map(|((image, feature), (d, q))| (d, asked[q], image, feature))
        .collect();
    accepted.sort_by(|a, b| {
        a.0.total_cmp(&b.0)
            .then((a.1, a.2, a.3).cmp(&(b.1, b.2, b.3)))
    });
    let track_of: HashMap<(usize, usize), usize> = block
        .sfm
        .tracks
        .iter()
        .enumerate()
        .flat_map(|(t, track)| {
            track
                .elements
                .iter()
                .map(move |e| ((e.image.index(), e.feature.index()), t))
        })
        .collect();
    // Whole tracks first: a keypoint added to a point first would bar its epoch's track.
    let mut added = 0;
    let mut free = Vec::new();
    for &(_, k, image, feature) in &accepted {
        let track = rec.points[k].track;
        match track_of.get(&(image, feature)) {
            Some(&other) => added += usize::from(sets.join(track, other)),
            None => free.push((track, image, feature)),
        }
    }
    for (track, image, feature) in free {
        let element = TrackElement {
            image: ImageId::from(image),
            feature: FeatureIndex::from(feature),
        };
        added += usize::from(sets.add_element(track, element));
    }
    tracing::info!(
        queries = queries.len(),
        matched = accepted.len(),
        added,
        "guided inter-epoch ties"
    );
    added
}

/// A horizontal box, metres: `(xmin, ymin, xmax, ymax)`.
type Footprint = (f64, f64, f64, f64);

/// Per image, the horizontal box of the points it observes, widened by a fifth on each side
/// (its edges see ground its own tie points do not reach); `None` for an image without points.
fn footprints(rec: &crate::model::Reconstruction) -> Vec<Option<Footprint>> {
    let mut boxes: Vec<Option<Footprint>> = vec![None; rec.poses.len()];
    for p in &rec.points {
        let (x, y) = (p.position.x, p.position.y);
        for e in &p.observations {
            let Some(b) = boxes.get_mut(e.image.index()) else {
                continue;
            };
            *b = Some(match *b {
                None => (x, y, x, y),
                Some((x0, y0, x1, y1)) => (x0.min(x), y0.min(y), x1.max(x), y1.max(y)),
            });
        }
    }
    boxes
        .into_iter()
        .map(|b| {
            b.map(|(x0, y0, x1, y1)| {
                let (mx, my) = (0.2 * (x1 - x0), 0.2 * (y1 - y0));
                (x0 - mx, y0 - my, x1 + mx, y1 + my)
            })
        })
        .collect()
}

/// The sought points in square cells of the horizontal plane, to find those under an image.
struct PointGrid {
    origin: (f64, f64),
    cell: f64,
    cells: HashMap<(i64, i64), Vec<usize>>,
}

impl PointGrid {
    /// About 64 cells across the points' extent.
    fn new(positions: impl Iterator<Item = Vector3<f64>>, sought: &[usize]) -> PointGrid {
        let positions: Vec<Vector3<f64>> = positions.collect();
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for &k in sought {
            let p = positions[k];
            (x0, y0, x1, y1) = (x0.min(p.x), y0.min(p.y), x1.max(p.x), y1.max(p.y));
        }
        let cell = ((x1 - x0).max(y1 - y0) / 64.0).max(1e-6);
        let mut grid = PointGrid {
            origin: (x0, y0),
            cell,
            cells: HashMap::new(),
        };
        for &k in sought {
            let key = grid.key(positions[k].x, positions[k].y);
            grid.cells.entry(key).or_default().push(k);
        }
        grid
    }

    fn key(&self, x: f64, y: f64) -> (i64, i64) {
        (
            ((x - self.origin.0) / self.cell).floor() as i64,
            ((y - self.origin.1) / self.cell).floor() as i64,
        )
    }

    /// The points in the cells the box touches, in increasing order.
    fn within(&self, (x0, y0, x1, y1): Footprint) -> Vec<usize> {
        let (c0, r0) = self.key(x0, y0);
        let (c1, r1) = self.key(x1, y1);
        let mut found = Vec::new();
        if self.cells.is_empty() {
            return found;
        }
        for r in r0..=r1 {
            for c in c0..=c1 {
                if let Some(list) = self.cells.get(&(c, r)) {
                    found.extend_from_slice(list);
                }
            }
        }
        found.sort_unstable();
        found
    }
}

/// An image's keypoints in square cells of the search radius, in compressed rows (offsets into
/// one index list), so a large image costs two integers per cell.
struct KeypointGrid {
    columns: usize,
    rows: usize,
    cell: f64,
    offsets: Vec<u32>,
    indices: Vec<u32>,
}

impl KeypointGrid {
    fn new(keypoints: &[Vector2<f64>], cell: f64) -> KeypointGrid {
        let extent = keypoints
            .iter()
            .fold((0.0f64, 0.0f64), |(w, h), k| (w.max(k.x), h.max(k.y)));
        let columns = (extent.0 / cell).floor() as usize + 1;
        let rows = (extent.1 / cell).floor() as usize + 1;
        let bucket = |k: &Vector2<f64>| {
            let c = ((k.x / cell).floor().max(0.0) as usize).min(columns - 1);
            let r = ((k.y / cell).floor().max(0.0) as usize).min(rows - 1);
            r * columns + c
        };
        let mut offsets = vec![0u32; columns * rows + 1];
        for k in keypoints {
            offsets[bucket(k) + 1] += 1;
        }
        for i in 1..offsets.len() {
            offsets[i] += offsets[i - 1];
        }
        let mut next = offsets.clone();
        let mut indices = vec![0u32; keypoints.len()];
        for (i, k) in keypoints.iter().enumerate() {
            let b = bucket(k);
            indices[next[b] as usize] = i as u32;
            next[b] += 1;
        }
        KeypointGrid {
            columns,
            rows,
            cell,
            offsets,
            indices,
        }
    }

    /// The keypoints within `radius` of `u`, nearest first.
    fn near(&self, keypoints: &[Vector2<f64>], u: &Vector2<f64>, radius: f64) -> Vec<FeatureIndex> {
        let span = (radius / self.cell).ceil() as i64;
        let (cu, ru) = (
            (u.x / self.cell).floor() as i64,
            (u.y / self.cell).floor() as i64,
        );
        let mut found: Vec<(f64, u32)> = Vec::new();
        for r in (ru - span).max(0)..=(ru + span).min(self.rows as i64 - 1) {
            for c in (cu - span).max(0)..=(cu + span).min(self.columns as i64 - 1) {
                let b = r as usize * self.columns + c as usize;
                for &i in &self.indices[self.offsets[b] as usize..self.offsets[b + 1] as usize] {
                    let d = (keypoints[i as usize] - u).norm();
                    if d <= radius {
                        found.push((d, i));
                    }
                }
            }
        }
        found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        found
            .into_iter()
            .map(|(_, i)| FeatureIndex::from(i as usize))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_keypoint_grid_finds_exactly_the_keypoints_within_the_radius_nearest_first() {
        let mut rng = timesift_core::SeededRng::new(5);
        let keypoints: Vec<Vector2<f64>> = (0..2000)
            .map(|_| Vector2::new(rng.uniform_range(0.0, 400.0), rng.uniform_range(0.0, 300.0)))
            .collect();
        let grid = KeypointGrid::new(&keypoints, 6.0);
        for _ in 0..200 {
            let u = Vector2::new(
                rng.uniform_range(-10.0, 410.0),
                rng.uniform_range(-10.0, 310.0),
            );
            let radius = rng.uniform_range(1.0, 15.0);
            let found: Vec<usize> = grid
                .near(&keypoints, &u, radius)
                .iter()
                .map(|f| f.index())
                .collect();
            let mut expected: Vec<(f64, usize)> = keypoints
                .iter()
                .enumerate()
                .map(|(i, k)| ((k - u).norm(), i))
                .filter(|(d, _)| *d <= radius)
                .collect();
            expected.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let expected: Vec<usize> = expected.into_iter().map(|(_, i)| i).collect();
            assert_eq!(found, expected);
        }
    }

    #[test]
    fn the_point_grid_returns_every_point_inside_a_box() {
        let positions: Vec<Vector3<f64>> = (0..100)
            .map(|i| Vector3::new(f64::from(i % 10) * 10.0, f64::from(i / 10) * 10.0, 0.0))
            .collect();
        let sought: Vec<usize> = (0..100).filter(|k| k % 3 != 0).collect();
        let grid = PointGrid::new(positions.iter().copied(), &sought);
        let found = grid.within((15.0, 15.0, 45.0, 35.0));
        for &k in &sought {
            let p = positions[k];
            if p.x >= 15.0 && p.x <= 45.0 && p.y >= 15.0 && p.y <= 35.0 {
                assert!(found.contains(&k), "point {k} at {p:?} missed");
            }
        }
        assert!(found.iter().all(|k| sought.contains(k)));
    }
}
