//! What a block can promise, checked where the align stage knows it: the ground points are in
//! the frame of the camera priors (before orienting), and every epoch is tied to the
//! reference epoch (after).

use nalgebra::Vector3;

use super::stage_error;
use crate::project::CameraPrior;
use crate::report::{EpochPairTies, MIN_CO_REGISTERING_TIES};
use crate::{Project, ProjectError};

/// Ground points this far (horizontally, on median) from the camera priors are in another
/// frame: no block's control lies 100 km from its cameras.
const FAR_FROM_PRIORS_M: f64 = 100_000.0;

/// Refuses control and check points that lie, on median, [`FAR_FROM_PRIORS_M`] or more from the
/// camera priors' median: they are in another CRS (geographic degrees, another UTM zone, a
/// local grid) than the priors, and would bend the block or be silently ignored.
pub(super) fn check_ground_points_near_priors(
    project: &Project,
    priors: &[Option<CameraPrior>],
) -> Result<(), ProjectError> {
    let positions: Vec<Vector3<f64>> = priors.iter().flatten().map(|p| p.position).collect();
    if positions.is_empty() {
        return Ok(());
    }
    let centre = |values: &mut Vec<f64>| {
        values.sort_by(f64::total_cmp);
        values[values.len() / 2]
    };
    let x = centre(&mut positions.iter().map(|p| p.x).collect());
    let y = centre(&mut positions.iter().map(|p| p.y).collect());
    let inputs = &project.config.inputs;
    let files = [
        (&project.gcps, inputs.gcps.as_deref().unwrap_or("gcps.csv")),
        (
            &project.checkpoints,
            inputs.checkpoints.as_deref().unwrap_or("checkpoints.csv"),
        ),
    ];
    for (points, file) in files {
        if points.is_empty() {
            continue;
        }
        let mut distances: Vec<f64> = points
            .iter()
            .map(|p| (p.position.x - x).hypot(p.position.y - y))
            .collect();
        let median = centre(&mut distances);
        if median < FAR_FROM_PRIORS_M {
            continue;
        }
        let first = &points[0];
        let looks_geographic = points
            .iter()
            .all(|p| p.position.x.abs() <= 180.0 && p.position.y.abs() <= 90.0);
        let source = match priors.iter().flatten().next().map(|p| p.source) {
            Some(crate::project::PriorSource::Exif) => "EXIF GPS",
            _ => "gnss.csv",
        };
        return Err(stage_error(format!(
            "{}: its points lie {:.0} km from the camera positions ({source}, median at \
                 {x:.1}, {y:.1}) on median: they are not in the project's CRS `{}`{}; e.g. {} \
                 (line {}) at ({}, {}, {})",
            project.dir.join(file).display(),
            median / 1000.0,
            project.config.crs,
            if looks_geographic {
                " (they look like longitude and latitude in degrees: project them first)"
            } else {
                " (another zone or grid?)"
            },
            first.name,
            first.line,
            first.position.x,
            first.position.y,
            first.position.z
        )));
    }
    Ok(())
}

/// The epochs no chain of epoch pairs sharing at least [`MIN_CO_REGISTERING_TIES`] tie points
/// joins to the reference epoch, in the project's order.
pub(super) fn not_co_registered(project: &Project, pairs: &[EpochPairTies]) -> Vec<String> {
    let names: Vec<&str> = project.epochs.iter().map(|e| e.name.as_str()).collect();
    let index = |name: &str| names.iter().position(|n| *n == name);
    let mut tied = vec![false; names.len()];
    let mut stack = vec![project.reference_epoch.index()];
    while let Some(e) = stack.pop() {
        if std::mem::replace(&mut tied[e], true) {
            continue;
        }
        for pair in pairs.iter().filter(|p| p.ties >= MIN_CO_REGISTERING_TIES) {
            let (Some(a), Some(b)) = (index(&pair.epochs[0]), index(&pair.epochs[1])) else {
                continue;
            };
            match (a == e, b == e) {
                (true, _) if !tied[b] => stack.push(b),
                (_, true) if !tied[a] => stack.push(a),
                _ => {}
            }
        }
    }
    names
        .iter()
        .zip(&tied)
        .filter(|(_, t)| !**t)
        .map(|(n, _)| n.to_string())
        .collect()
}
