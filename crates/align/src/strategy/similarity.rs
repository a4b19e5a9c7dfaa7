//! How the strategies that orient epochs apart put one onto another: the 3-D points two
//! reconstructions share through the block's tracks, and a robust similarity between them.

use std::collections::HashMap;

use nalgebra::Vector3;
use timesift_core::{Track, TrackElement};
use timesift_geometry::ransac::{RansacOptions, ransac};
use timesift_geometry::similarity::{Similarity, SimilarityEstimator, TransformKind, umeyama};

use crate::AlignError;
use crate::model::Reconstruction;

use super::block::Block;

/// Map from a track element to the point that it observes.
pub(crate) fn point_index(rec: &Reconstruction) -> HashMap<TrackElement, usize> {
    let mut map = HashMap::new();
    for (p, point) in rec.points.iter().enumerate() {
        for e in &point.observations {
            map.insert(*e, p);
        }
    }
    map
}

/// 3-D correspondences between an epoch's points and the reference epoch's: one per track of
/// the whole block that has a point in both.
pub(crate) fn shared_points(
    tracks: &[Track],
    rec: &Reconstruction,
    reference: &Reconstruction,
    reference_points: &HashMap<TrackElement, usize>,
) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let ours = point_index(rec);
    let mut src = Vec::new();
    let mut dst = Vec::new();
    for track in tracks {
        let a = track.elements.iter().find_map(|e| ours.get(e));
        let b = track.elements.iter().find_map(|e| reference_points.get(e));
        if let (Some(&a), Some(&b)) = (a, b) {
            src.push(rec.points[a].position);
            dst.push(reference.points[b].position);
        }
    }
    (src, dst)
}

/// A component's placement: the largest of its epoch must be placed (a failed fit is the
/// epoch's error); another that shares too few tie points is left out with a warning (`None`).
pub(crate) fn placed_or_left_out(
    block: &Block,
    epoch: usize,
    largest: bool,
    rec: &Reconstruction,
    fit: Result<Similarity, AlignError>,
) -> Result<Option<Similarity>, AlignError> {
    match fit {
        Ok(t) => Ok(Some(t)),
        Err(source) if largest => Err(block.in_epoch(epoch, source)),
        Err(source) => {
            tracing::warn!(
                epoch = block.epoch_names[epoch].as_str(),
                images = rec.num_oriented(),
                %source,
                "component left out: it shares too few tie points to be placed"
            );
            Ok(None)
        }
    }
}

/// RANSAC similarity from an epoch's points to the reference's, with a threshold of three
/// times the reference's median ground pixel (object-space size of a pixel at the points).
pub(crate) fn fit_similarity(
    src: &[Vector3<f64>],
    dst: &[Vector3<f64>],
    reference: &Reconstruction,
    seed: u64,
) -> Result<Similarity, AlignError> {
    if src.len() < 3 {
        return Err(AlignError::Georeferencing(format!(
            "{} tie points shared with the reference epoch; a similarity needs 3",
            src.len()
        )));
    }
    let threshold = 3.0 * median_ground_pixel(reference);
    let result = ransac(
        &SimilarityEstimator {
            src,
            dst,
            kind: TransformKind::Similarity,
        },
        &RansacOptions {
            max_error: threshold,
            seed,
            ..RansacOptions::default()
        },
    )?;
    let (a, b): (Vec<_>, Vec<_>) = (0..src.len())
        .filter(|&k| result.inliers[k])
        .map(|k| (src[k], dst[k]))
        .unzip();
    tracing::debug!(shared = src.len(), inliers = a.len(), "chunk similarity");
    Ok(umeyama(&a, &b, None, TransformKind::Similarity)?)
}

/// Median over points of (distance to the first observing camera / the longest focal length of
/// the block).
pub(crate) fn median_ground_pixel(rec: &Reconstruction) -> f64 {
    let f = rec
        .cameras
        .iter()
        .map(|c| {
            let mut v = vec![0.0; timesift_core::CameraModel::num_params(c)];
            timesift_core::CameraModel::params(c, &mut v);
            v[0]
        })
        .fold(0.0, f64::max)
        .max(1.0);
    let mut sizes: Vec<f64> = rec
        .points
        .iter()
        .filter_map(|p| {
            let e = p.observations.first()?;
            let pose = rec.poses[e.image.index()]?;
            Some((p.position - pose.center()).norm() / f)
        })
        .collect();
    if sizes.is_empty() {
        return 1.0;
    }
    sizes.sort_by(f64::total_cmp);
    sizes[sizes.len() / 2]
}
